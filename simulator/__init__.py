"""SpotlessGS simulator: 3D-FRONT-format rooms -> paired spotlight-only / evenly lit image datasets.

Only ``simulator.blender`` imports bpy; everything else is plain Python and numpy.
"""
