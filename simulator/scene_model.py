"""The bpy-free scene model between a 3D-FRONT house file and Blender.

Everything here is plain Python and numpy in the world frame used throughout the project: metres, **z up** (Blender's
convention). The 3D-FRONT parser (``simulator.front3d``) produces a :class:`Scene`; the Blender builder
(``simulator.blender.build``) only reads one. Parsing, validation and geometry are therefore testable without Blender.
"""

from __future__ import annotations

import hashlib
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np


@dataclass(frozen=True)
class Material:
    """A principled-BSDF style material.

    Attributes:
        name: unique name within the scene (the 3D-FRONT material ``uid`` or a furniture ``jid``).
        base_color: linear RGB in [0, 1], multiplied with the texture when one is given.
        texture: an sRGB image file, or None for a plain colour.
        uv_scale: (u, v) repeat factors applied to the mesh UVs (3D-FRONT ``UVTransform``).
        roughness: GGX roughness in [0, 1].
        metallic: metalness in [0, 1].
        emission: emission strength (Blender units, W/m^2-like) of this surface in the *ground-truth* render only;
            0 for ordinary surfaces. The spotlight-only render never has emitting surfaces.
        emission_color: linear RGB colour of that emission.
    """

    name: str
    base_color: tuple[float, float, float] = (0.8, 0.8, 0.8)
    texture: Path | None = None
    uv_scale: tuple[float, float] = (1.0, 1.0)
    roughness: float = 0.6
    metallic: float = 0.0
    emission: float = 0.0
    emission_color: tuple[float, float, float] = (1.0, 0.95, 0.88)


@dataclass
class MeshObject:
    """One triangle mesh in world coordinates.

    Attributes:
        name: unique object name (architecture mesh ``uid`` or furniture ``instanceid``).
        source: ``"mesh"`` for 3D-FRONT architecture, ``"furniture"`` for a 3D-FUTURE model instance.
        category: the mesh ``type`` (Floor, Ceiling, WallInner, ...) or the furniture category/title.
        vertices: (V, 3) float64, world frame, z up, metres.
        faces: (F, 3) int64 vertex indices, counter-clockwise seen from the front.
        material: the surface material.
        uvs: (V, 2) float64 texture coordinates, or None.
        normals: (V, 3) float64 unit vertex normals, or None (Blender then computes them).
        is_light: True for lamps and ceiling lights: they emit (``material.emission``) in the ground-truth render.
    """

    name: str
    source: str
    category: str
    vertices: np.ndarray
    faces: np.ndarray
    material: Material
    uvs: np.ndarray | None = None
    normals: np.ndarray | None = None
    is_light: bool = False

    def bounds(self) -> tuple[np.ndarray, np.ndarray]:
        """Axis-aligned bounding box ``(lo, hi)``, each (3,)."""
        return self.vertices.min(axis=0), self.vertices.max(axis=0)

    def area(self) -> float:
        """Total surface area in m^2."""
        tri = self.vertices[self.faces]
        return float(0.5 * np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1).sum())


@dataclass(frozen=True)
class LightFixture:
    """A Blender light added for the ground-truth render (lamps and ceiling lights), off in the spotlight render.

    Attributes:
        name: unique name.
        kind: ``"point"`` or ``"area"`` (an area light faces down, -z).
        position: (3,) world position in metres.
        power_w: radiant power in watts (Blender's light power).
        color: linear RGB colour.
        size: radius of a point light / edge length of a square area light, metres.
    """

    name: str
    kind: str
    position: tuple[float, float, float]
    power_w: float
    color: tuple[float, float, float] = (1.0, 0.95, 0.88)
    size: float = 0.1


@dataclass
class Room:
    """One room of a house.

    Attributes:
        instance_id: the 3D-FRONT room ``instanceid``.
        type: room type (Bedroom, LivingRoom, ...).
        floor_polygon: (K, 2) float64 world x-y vertices of the floor outline, counter-clockwise, not closed.
        floor_z: floor height (m).
        ceiling_z: ceiling height (m).
        object_names: names of the :class:`MeshObject` s that belong to this room.
    """

    instance_id: str
    type: str
    floor_polygon: np.ndarray
    floor_z: float
    ceiling_z: float
    object_names: list[str] = field(default_factory=list)

    def floor_area(self) -> float:
        """Floor area in m^2 (shoelace formula)."""
        x, y = self.floor_polygon[:, 0], self.floor_polygon[:, 1]
        return float(0.5 * abs(np.dot(x, np.roll(y, -1)) - np.dot(y, np.roll(x, -1))))


@dataclass
class Scene:
    """A house ready for rendering: meshes, ground-truth light fixtures and rooms, all z up in metres.

    Attributes:
        scene_id: the house ``uid``.
        source: the file it was read from.
        objects: every mesh (architecture and furniture instances).
        lights: Blender lights for the ground-truth render (in addition to emissive ``is_light`` meshes).
        rooms: the rooms, each with its floor polygon.
    """

    scene_id: str
    source: Path
    objects: list[MeshObject]
    lights: list[LightFixture]
    rooms: list[Room]

    def room(self, instance_id: str | None = None) -> Room:
        """The room with this instance id, or the room with the largest floor area when None."""
        if not self.rooms:
            raise ValueError(f"{self.source}: scene {self.scene_id!r} has no rooms")
        if instance_id is None:
            return max(self.rooms, key=lambda r: r.floor_area())
        for room in self.rooms:
            if room.instance_id == instance_id:
                return room
        known = ", ".join(r.instance_id for r in self.rooms)
        raise ValueError(f"{self.source}: no room {instance_id!r} (rooms: {known})")

    def objects_in(self, room: Room) -> list[MeshObject]:
        """The mesh objects that belong to ``room``."""
        names = set(room.object_names)
        return [o for o in self.objects if o.name in names]

    def furniture_boxes(self, room: Room | None = None) -> list[tuple[np.ndarray, np.ndarray]]:
        """Axis-aligned boxes ``(lo, hi)`` of the furniture (in ``room`` when given): obstacles for camera paths."""
        objs = self.objects if room is None else self.objects_in(room)
        return [o.bounds() for o in objs if o.source == "furniture"]

    def bounds(self) -> tuple[np.ndarray, np.ndarray]:
        """Bounding box of all geometry, ``(lo, hi)``, each (3,)."""
        lo = np.min([o.bounds()[0] for o in self.objects], axis=0)
        hi = np.max([o.bounds()[1] for o in self.objects], axis=0)
        return lo, hi


def content_sha256(objects: list[MeshObject], lights: list[LightFixture]) -> str:
    """Hex SHA-256 of what a render of ``objects`` under ``lights`` draws: every object's name, kind, geometry (the
    vertex, face, UV and normal arrays' bytes) and material, each texture by its file's content (not its path). Two
    loads agree when their models, textures and the options that chose them (``--future-dir``, ``--texture-dir``,
    ``--allow-missing``) give the same room."""
    digest = hashlib.sha256()

    def add(*parts: object) -> None:
        for part in parts:
            data = part.tobytes() if isinstance(part, np.ndarray) else repr(part).encode()
            digest.update(len(data).to_bytes(8, "little") + data)

    for obj in objects:
        m = obj.material
        texture = None if m.texture is None else hashlib.sha256(Path(m.texture).read_bytes()).hexdigest()
        add(obj.name, obj.source, obj.category, obj.is_light, obj.vertices.shape, obj.vertices, obj.faces.shape,
            obj.faces, obj.uvs is None, obj.uvs if obj.uvs is not None else b"", obj.normals is None,
            obj.normals if obj.normals is not None else b"",
            (m.name, m.base_color, m.uv_scale, m.roughness, m.metallic, m.emission, m.emission_color, texture))
    for light in lights:
        add(light)
    return digest.hexdigest()
