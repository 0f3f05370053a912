"""File formats and I/O helpers shared by the simulator, the trainer and the evaluation package.

Nothing here imports torch or bpy.
"""
