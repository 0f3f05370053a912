"""Public entry: generate one room of a kind, deterministically for a seed, as a 3D-FRONT house folder."""

from __future__ import annotations

from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np

from spotlessgs.io.seeding import numpy_rng

from . import architecture as arch
from .furniture import FURNITURE_TYPES, FurnitureModel, build_model, stable_uuid
from .house_writer import HouseFiles, write_house
from .materials import PALETTES, Surface
from .meshes import MeshData
from .rooms import RECIPES, RoomPlan, model_counts, plan_room, yaw_quaternion

ROOM_KINDS: tuple[str, ...] = ("bedroom", "living_room", "office", "storage_room", "corridor", "white_room")
"""Room kinds :func:`generate_room` knows."""

GENERATOR_VERSION = 1
"""Bumped whenever the same seed would produce a different room."""

_STYLES = {"bedroom": "Nordic", "living_room": "Modern", "office": "Minimalist", "storage_room": "Industrial",
           "corridor": "Modern", "white_room": "Minimalist"}
_IDENTITY_UV = [1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0]


@dataclass(frozen=True)
class GeneratorConfig:
    """Generation settings (the layout does not depend on them; only image sizes do)."""

    texture_size: int = 512  # floor texture height (px; size/2 in long rooms); walls and ceiling are size/2 high
    furniture_texture_size: int = 256  # furniture/door/painting texture side (px); lamps and baseboards get half

    def __post_init__(self) -> None:
        for name in ("texture_size", "furniture_texture_size"):
            v = getattr(self, name)
            if v < 32 or v % 2:
                raise ValueError(f"GeneratorConfig.{name} must be an even number >= 32, got {v}")

    @classmethod
    def tiny(cls) -> GeneratorConfig:
        """Small textures for fast tests (the geometry is identical)."""
        return cls(texture_size=64, furniture_texture_size=32)


def generate_room(kind: str, out_dir: Path, seed: int, config: GeneratorConfig | None = None) -> Path:
    """Generate a room of ``kind`` into ``out_dir`` (replacing a room generated there before).

    Returns:
        The path of the written ``house.json``.

    Raises:
        ValueError: unknown ``kind``.
        FileExistsError: ``out_dir`` holds something that is not a generated room.
    """
    return write_house(Path(out_dir), build_house(kind, seed, config or GeneratorConfig()))


def _r(x) -> float:
    """A JSON float rounded to 6 decimals (and -0.0 -> 0.0) so that files are byte-stable."""
    return round(float(x), 6) + 0.0


def _flat(a: np.ndarray) -> list[float]:
    return [_r(v) for v in np.asarray(a, dtype=np.float64).reshape(-1)]


def build_models(kind: str, seed: int) -> dict[str, list[FurnitureModel]]:
    """All furniture models of a room kind (one per instance, see ``rooms.model_counts``), by type."""
    palette = PALETTES[kind]
    models: dict[str, list[FurnitureModel]] = {}
    for type_name, count in model_counts(RECIPES[kind]).items():
        models[type_name] = [
            build_model(type_name, numpy_rng(seed, f"generator/{kind}/model/{type_name}/{k}"),
                        palette.for_furniture(type_name), stable_uuid("model", kind, seed, type_name, k),
                        _STYLES[kind])
            for k in range(count)
        ]
    return models


def plan(kind: str, seed: int) -> tuple[RoomPlan, dict[str, list[FurnitureModel]]]:
    """The room layout and its furniture models (no images, no files)."""
    if kind not in ROOM_KINDS:
        raise ValueError(f"unknown room kind {kind!r}; known: {', '.join(ROOM_KINDS)}")
    models = build_models(kind, seed)
    sizes = {t: [m.size for m in ms] for t, ms in models.items()}
    return plan_room(kind, RECIPES[kind], sizes, numpy_rng(seed, f"generator/{kind}/layout")), models


def _texture(kind: str, seed: int, name: str, surface: Surface, size: int, aspect: int | None = None) -> np.ndarray:
    """The image of one texture, from its own random stage (so adding a texture never changes the others)."""
    rng = numpy_rng(seed, f"generator/{kind}/texture/{name}")
    return surface.wide_image(rng, size, surface.aspect if aspect is None else aspect)


def _architecture(kind: str, seed: int, room_plan: RoomPlan, config: GeneratorConfig):
    """Architecture of a room: (material entries, textures [(jid, image)], mesh entries, room children)."""
    palette, prefix = PALETTES[kind], f"{kind}-{seed}"
    materials: list[dict] = []
    textures: list[tuple[str, np.ndarray]] = []

    def add_material(name: str, surface: Surface, size: int | None, aspect: int | None = None) -> str:
        uid = f"{prefix}/material/{name}"
        jid = stable_uuid("texture", kind, seed, name)
        entry = {"uid": uid, "jid": jid, "texture": "", "normaltexture": "",
                 "color": [*surface.color, 255], "UVTransform": list(_IDENTITY_UV),
                 "roughness": _r(surface.roughness), "metallic": _r(surface.metallic)}
        if surface.texture and size:
            entry["texture"] = f"https://spotlessgs.invalid/texture/{jid}/texture.png"
            entry["color"] = [255, 255, 255, 255]
            textures.append((jid, _texture(kind, seed, name, surface, size, aspect)))
        materials.append(entry)
        return uid

    ts, fs = config.texture_size, config.furniture_texture_size
    poly, h = room_plan.polygon, room_plan.height
    wide = arch.floor_aspect(poly.bounds)  # long rooms get wide floor/ceiling textures
    walls = arch.edges(poly)
    perimeter = float(sum(e.length for e in walls))
    rects = arch.disjoint_rects(list(room_plan.rects))
    d = room_plan.door
    m_floor = add_material("floor", palette.floor, ts if wide == 1 else ts // 2, wide)
    m_wall = add_material("wall", palette.walls, ts // 2)
    meshes: list[tuple[str, str, MeshData]] = [
        ("Floor", m_floor, arch.horizontal(rects, 0.0, True, poly.bounds)),
        ("Ceiling", add_material("ceiling", palette.ceiling, ts // 2, wide),
         arch.horizontal(rects, h, False, poly.bounds)),
        *[("WallInner", m_wall, arch.wall(e, h, perimeter)) for e in walls],
        ("Baseboard", add_material("baseboard", palette.baseboard, fs // 2), arch.baseboards(walls, perimeter)),
        ("Door", add_material("door", palette.door, fs), arch.door(walls[d.edge], d.centre, d.width, d.height,
                                                                   d.thickness)),
    ]
    if room_plan.light_bands:
        m_band = add_material("lightband", Surface("", color=(255, 250, 240), roughness=0.9), None)
        meshes += [("LightBand", m_band, arch.light_band(*r, h - 0.005)) for r in room_plan.light_bands]
    entries, children = [], []
    for i, (mtype, mat, m) in enumerate(meshes):
        uid = f"{prefix}/mesh/{i}"
        entries.append({"uid": uid, "jid": stable_uuid("mesh", kind, seed, i), "type": mtype, "material": mat,
                        "xyz": _flat(m.positions), "normal": _flat(m.normals), "uv": _flat(m.uvs),
                        "faces": [int(v) for v in m.faces.reshape(-1)]})
        children.append({"ref": uid, "instanceid": f"{mtype.lower()}-{i}", "pos": [0.0, 0.0, 0.0],
                         "rot": [0.0, 0.0, 0.0, 1.0], "scale": [1.0, 1.0, 1.0]})
    return materials, textures, entries, children


def _furniture(kind: str, seed: int, room_plan: RoomPlan, models: dict[str, list[FurnitureModel]],
               config: GeneratorConfig):
    """Furniture of a room: (furniture entries, [(model, texture image)], room children); only placed models."""
    used = sorted({(p.type_name, p.model) for p in room_plan.placements},
                  key=lambda tm: (list(FURNITURE_TYPES).index(tm[0]), tm[1]))
    fs = config.furniture_texture_size
    entries, files, uid_of = [], [], {}
    for type_name, k in used:
        model = models[type_name][k]
        uid = f"{kind}-{seed}/furniture/{len(entries)}"
        uid_of[(type_name, k)] = uid
        ft = model.kind
        entries.append({"uid": uid, "jid": model.jid, "title": ft.title, "category": ft.category, "valid": True,
                        "size": _flat(model.size)})
        size = fs // 2 if "lamp" in ft.category.lower() else fs
        files.append((model, _texture(kind, seed, f"model/{type_name}/{k}", model.surface, size)))
    children = [{"ref": uid_of[(p.type_name, p.model)], "instanceid": f"furniture-{j}", "pos": _flat(p.position),
                 "rot": _flat(yaw_quaternion(p.yaw)), "scale": [1.0, 1.0, 1.0]}
                for j, p in enumerate(room_plan.placements)]
    return entries, files, children


def build_house(kind: str, seed: int, config: GeneratorConfig) -> HouseFiles:
    """Everything of one room in memory: the house JSON object, the models and all texture images."""
    room_plan, models = plan(kind, seed)
    materials, textures, meshes, arch_children = _architecture(kind, seed, room_plan, config)
    furniture, model_files, furniture_children = _furniture(kind, seed, room_plan, models, config)
    identity = {"pos": [0.0, 0.0, 0.0], "rot": [0.0, 0.0, 0.0, 1.0], "scale": [1.0, 1.0, 1.0]}
    room = {"type": room_plan.room_type, "instanceid": f"{room_plan.room_type.replace('/', '')}-{seed}",
            "size": _r(room_plan.polygon.area), **identity, "empty": 0,
            "children": arch_children + furniture_children}
    house = {
        "uid": f"spotlessgs-{kind}-{seed}",
        "jid": stable_uuid("house", kind, seed),
        "furniture": furniture,
        "mesh": meshes,
        "material": materials,
        "scene": {"uid": f"{kind}-{seed}/scene", "jid": stable_uuid("scene", kind, seed), **identity,
                  "room": [room]},
        "spotlessgs": {"generator": "simulator.generator", "generator_version": GENERATOR_VERSION, "kind": kind,
                       "seed": int(seed), "config": asdict(config)},
    }
    return HouseFiles(house, tuple(model_files), tuple(textures))
