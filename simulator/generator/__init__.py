"""Procedural rooms in the 3D-FRONT / 3D-FUTURE file format (we cannot ship 3D-FRONT itself).

Entry point: :func:`generate_room` (``kind`` in :data:`ROOM_KINDS`). Modules: ``textures`` (numpy textures),
``materials`` (surfaces and per-room palettes), ``meshes`` (triangle soups, OBJ text), ``furniture`` (3D-FUTURE models),
``architecture`` (floor/ceiling/wall/baseboard/door/light-band meshes), ``rooms`` (layouts and furniture placement),
``house_writer`` (the folder writer), ``generate`` (glue).
"""

from .generate import ROOM_KINDS, GeneratorConfig, build_house, generate_room, plan

__all__ = ["ROOM_KINDS", "GeneratorConfig", "build_house", "generate_room", "plan"]
