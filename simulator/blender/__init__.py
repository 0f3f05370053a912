"""The only part of the project that imports bpy (Blender as a Python module).

``scene_builder`` turns a bpy-free :class:`~simulator.scene_model.Scene` into Blender objects; ``renderer`` sets
up Cycles and renders one pose in both lighting modes. Import these modules only in a process that renders: one bpy per
process.
"""
