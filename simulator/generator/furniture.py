"""3D-FUTURE-style furniture models: trimesh geometry per furniture type, and the model-folder writer.

Model frame: y up, metres, the front faces +z, centred in x and z with the bottom at y = 0 (as 3D-FUTURE
``raw_model.obj``). Each model has one material and one ``texture.png``.
"""

from __future__ import annotations

import hashlib
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

import numpy as np
import trimesh
from PIL import Image

from spotlessgs.io.atomic import atomic_path, write_text

from .materials import Surface
from .meshes import MeshData, box, centre_on_floor, concatenate, cylinder, flat_from_trimesh, obj_text

Parts = list[trimesh.Trimesh]


def _legs(w: float, d: float, h: float, t: float, inset: float = 0.0) -> Parts:
    """Four square legs of side ``t`` and height ``h`` under a w x d top (model frame)."""
    xs, zs = (w / 2 - t / 2 - inset), (d / 2 - t / 2 - inset)
    return [box((t, h, t), (sx * xs, h / 2, sz * zs)) for sx in (-1, 1) for sz in (-1, 1)]


def _table(w: float, d: float, h: float, top: float = 0.04, leg: float = 0.05) -> Parts:
    return [box((w, top, d), (0, h - top / 2, 0)), *_legs(w, d, h - top, leg, 0.03)]


def _cabinet(w: float, h: float, d: float, doors: int, plinth: float = 0.06) -> Parts:
    """A closed cabinet: body on a plinth, door/drawer fronts with gaps and handles (front at +z)."""
    parts = [box((w - 0.04, plinth, d - 0.04), (0, plinth / 2, -0.02)),
             box((w, h - plinth, d - 0.02), (0, plinth + (h - plinth) / 2, -0.01))]
    fw = (w - 0.02) / doors
    for i in range(doors):
        x = -w / 2 + 0.01 + fw * (i + 0.5)
        parts.append(box((fw - 0.012, h - plinth - 0.02, 0.018), (x, plinth + (h - plinth) / 2, d / 2 - 0.011)))
        hx = x + (fw / 2 - 0.06) * (1 if i % 2 == 0 else -1)
        parts.append(box((0.02, 0.14, 0.025), (hx, plinth + (h - plinth) * 0.55, d / 2 + 0.01)))
    return parts


def _shelving(w: float, h: float, d: float, levels: int, post: float, closed_sides: bool, rng) -> Parts:
    """Open shelving: posts or side panels, ``levels`` boards, and a few boxes/books of random sizes on them."""
    parts: Parts = []
    if closed_sides:
        parts += [box((0.025, h, d), (sx * (w / 2 - 0.0125), h / 2, 0)) for sx in (-1, 1)]
        parts.append(box((w, h, 0.01), (0, h / 2, -d / 2 + 0.005)))
    else:
        parts += [box((post, h, post), (sx * (w / 2 - post / 2), h / 2, sz * (d / 2 - post / 2)))
                  for sx in (-1, 1) for sz in (-1, 1)]
    inner = w - (0.05 if closed_sides else 2 * post)
    ys = np.linspace(0.08, h - 0.02, levels)
    for i, y in enumerate(ys):
        parts.append(box((inner, 0.02, d - 0.01), (0, y, 0)))
        if i == len(ys) - 1:
            break
        gap = ys[i + 1] - y - 0.04
        x = -inner / 2 + 0.02
        while True:
            bw = rng.uniform(0.03, 0.25)
            if x + bw > inner / 2 - 0.02:
                break
            if rng.random() < 0.75:
                bh = gap * rng.uniform(0.45, 0.95)
                bd = (d - 0.05) * rng.uniform(0.6, 0.95)
                parts.append(box((bw, bh, bd), (x + bw / 2, y + 0.01 + bh / 2, -d / 2 + 0.02 + bd / 2)))
            x += bw + rng.uniform(0.002, 0.06)
    return parts


def _sofa(w: float, d: float, h: float, seats: int) -> Parts:
    arm, base_h, seat_h = 0.16, 0.22, 0.44
    parts = [box((w, base_h, d), (0, base_h / 2, 0)),
             box((w - 2 * arm, h - base_h, 0.2), (0, base_h + (h - base_h) / 2, -d / 2 + 0.1))]
    parts += [box((arm, 0.62 - base_h, d), (sx * (w / 2 - arm / 2), base_h + (0.62 - base_h) / 2, 0)) for sx in (-1, 1)]
    cw = (w - 2 * arm) / seats
    for i in range(seats):
        x = -w / 2 + arm + cw * (i + 0.5)
        parts.append(box((cw - 0.015, seat_h - base_h, d - 0.24), (x, base_h + (seat_h - base_h) / 2, 0.1)))
        parts.append(box((cw - 0.03, 0.4, 0.14), (x, seat_h + 0.2, -d / 2 + 0.27)))
    return parts


def _chair(w: float, d: float, h: float, seat: float = 0.46) -> Parts:
    return [box((w, 0.05, d), (0, seat - 0.025, 0)), *_legs(w, d, seat - 0.05, 0.035),
            box((w, h - seat, 0.04), (0, seat + (h - seat) / 2, -d / 2 + 0.02))]


def _office_chair(w: float, d: float, h: float) -> Parts:
    parts = [cylinder(0.03, 0.4, (0, 0.05, 0), 12), box((w, 0.08, d), (0, 0.49, 0)),
             box((w * 0.9, h - 0.6, 0.06), (0, 0.6 + (h - 0.6) / 2, -d / 2 + 0.03))]
    for a in np.linspace(0, 2 * np.pi, 5, endpoint=False):
        parts.append(box((0.05, 0.05, w / 2), (0, 0.025, 0)).apply_transform(
            trimesh.transformations.rotation_matrix(a, [0, 1, 0]) @ trimesh.transformations.translation_matrix(
                [0, 0, w / 4])))
    return parts


def _floor_lamp(h: float) -> Parts:
    return [cylinder(0.16, 0.03, (0, 0, 0)), cylinder(0.015, h - 0.3, (0, 0.03, 0), 12),
            cylinder(0.22, 0.3, (0, h - 0.3, 0), 24, top_radius=0.14)]


def _desk_lamp(h: float) -> Parts:
    return [cylinder(0.08, 0.025, (0, 0, 0)), cylinder(0.012, h - 0.16, (0, 0.025, 0), 10),
            cylinder(0.11, 0.16, (0, h - 0.16, 0), 20, top_radius=0.06)]


def _pendant_lamp(drop: float) -> Parts:
    return [cylinder(0.06, 0.03, (0, drop - 0.03, 0), 16), cylinder(0.006, drop - 0.25, (0, 0.22, 0), 8),
            cylinder(0.25, 0.22, (0, 0, 0), 28, top_radius=0.08)]


def _ceiling_lamp(w: float) -> Parts:
    return [box((w, 0.03, w), (0, 0.035, 0)), box((w - 0.04, 0.02, w - 0.04), (0, 0.01, 0))]


def _wall_lamp() -> Parts:
    return [box((0.12, 0.2, 0.02), (0, 0.1, -0.06)), box((0.03, 0.03, 0.08), (0, 0.1, -0.02)),
            cylinder(0.09, 0.14, (0, 0.03, 0.02), 20, top_radius=0.06)]


def _bed(w: float, l: float) -> Parts:
    frame_h, mat_h = 0.3, 0.22
    parts = [box((w, frame_h, l), (0, frame_h / 2, 0)),
             box((w - 0.06, mat_h, l - 0.08), (0, frame_h + mat_h / 2, 0.02)),
             box((w + 0.04, 1.05, 0.08), (0, 0.525, -l / 2 - 0.04 + 0.04)),
             box((w - 0.1, 0.06, l * 0.55), (0, frame_h + mat_h + 0.03, l * 0.2))]
    parts += [box((w / 2 - 0.15, 0.14, 0.38), (sx * w / 4, frame_h + mat_h + 0.07, -l / 2 + 0.3)) for sx in (-1, 1)]
    return parts


def _painting(w: float, h: float) -> Parts:
    return [box((w, h, 0.03), (0, h / 2, 0))]


@dataclass(frozen=True)
class FurnitureType:
    """One kind of furniture.

    Attributes:
        category: 3D-FUTURE category (lamps contain "Lamp": the renderer makes them emit).
        super_category: 3D-FUTURE super-category.
        title: human-readable title (also written to the house JSON).
        build: ``build(rng) -> Parts``: the geometry in the model frame, sizes jittered by ``rng``.
        smooth: use smooth normals (round parts).
        front_uv: map the texture once onto the +z front face (paintings).
    """

    category: str
    super_category: str
    title: str
    build: Callable[[np.random.Generator], Parts]
    smooth: bool = False
    front_uv: bool = False


def _u(rng: np.random.Generator, lo: float, hi: float) -> float:
    return float(rng.uniform(lo, hi))


FURNITURE_TYPES: dict[str, FurnitureType] = {
    "bed": FurnitureType("King-size Bed", "Bed", "double bed with headboard",
                         lambda r: _bed(_u(r, 1.6, 1.8), _u(r, 2.0, 2.1))),
    "nightstand": FurnitureType("Nightstand", "Cabinet/Shelf/Desk", "nightstand",
                                lambda r: _cabinet(_u(r, 0.42, 0.5), _u(r, 0.5, 0.58), 0.4, 1)),
    "wardrobe": FurnitureType("Wardrobe", "Cabinet/Shelf/Desk", "two-door wardrobe",
                              lambda r: _cabinet(_u(r, 1.0, 1.3), _u(r, 2.0, 2.2), 0.58, 2)),
    "dresser": FurnitureType("Drawer Chest / Corner cabinet", "Cabinet/Shelf/Desk", "chest of drawers",
                             lambda r: _cabinet(_u(r, 0.8, 1.0), _u(r, 0.8, 0.95), 0.45, 3)),
    "desk": FurnitureType("Desk", "Cabinet/Shelf/Desk", "desk",
                          lambda r: _table(_u(r, 1.2, 1.5), _u(r, 0.65, 0.75), 0.75)),
    "office_chair": FurnitureType("Lounge Chair / Cafe Chair / Office Chair", "Chair", "office chair",
                                  lambda r: _office_chair(0.55, 0.55, _u(r, 1.0, 1.1))),
    "dining_chair": FurnitureType("Dining Chair", "Chair", "dining chair",
                                  lambda r: _chair(0.45, 0.48, _u(r, 0.85, 0.95))),
    "bookcase": FurnitureType("Bookcase / jewelry Armoire", "Cabinet/Shelf/Desk", "bookcase",
                              lambda r: _shelving(_u(r, 0.8, 1.0), _u(r, 1.8, 2.0), 0.34, 5, 0.0, True, r)),
    "metal_shelf": FurnitureType("Shelf", "Cabinet/Shelf/Desk", "steel shelving rack",
                                 lambda r: _shelving(_u(r, 1.0, 1.2), _u(r, 1.8, 2.0), 0.45, 5, 0.035, False, r)),
    "steel_cabinet": FurnitureType("Cabinet", "Cabinet/Shelf/Desk", "steel locker cabinet",
                                   lambda r: _cabinet(_u(r, 0.8, 1.0), _u(r, 1.8, 1.95), 0.5, 2)),
    "filing_cabinet": FurnitureType("Cabinet", "Cabinet/Shelf/Desk", "steel filing cabinet",
                                    lambda r: _cabinet(0.45, _u(r, 1.0, 1.3), 0.6, 1)),
    "tool_chest": FurnitureType("Drawer Chest / Corner cabinet", "Cabinet/Shelf/Desk", "metal tool chest",
                                lambda r: _cabinet(_u(r, 0.7, 0.9), _u(r, 0.9, 1.0), 0.48, 2)),
    "workbench": FurnitureType("Desk", "Cabinet/Shelf/Desk", "workbench",
                               lambda r: _table(_u(r, 1.5, 1.8), 0.7, 0.9, top=0.06, leg=0.07)),
    "sofa": FurnitureType("Three-seat / Multi-seat Sofa", "Sofa", "three-seat sofa",
                          lambda r: _sofa(_u(r, 2.0, 2.3), _u(r, 0.88, 0.95), 0.85, 3)),
    "armchair": FurnitureType("Armchair", "Sofa", "armchair", lambda r: _sofa(_u(r, 0.8, 0.9), 0.85, 0.85, 1)),
    "coffee_table": FurnitureType("Coffee Table", "Table", "coffee table",
                                  lambda r: _table(_u(r, 1.0, 1.2), _u(r, 0.55, 0.65), 0.42, top=0.05)),
    "tv_stand": FurnitureType("TV Stand", "Cabinet/Shelf/Desk", "low media cabinet",
                              lambda r: _cabinet(_u(r, 1.5, 1.8), 0.5, 0.42, 3)),
    "console_table": FurnitureType("Sideboard / Side Cabinet / Console Table", "Cabinet/Shelf/Desk",
                                   "console table", lambda r: _table(_u(r, 1.0, 1.3), 0.35, 0.8)),
    "bench": FurnitureType("Stool", "Pier/Stool", "hall bench", lambda r: _table(_u(r, 1.1, 1.4), 0.38, 0.46)),
    "shoe_cabinet": FurnitureType("Shoe Cabinet", "Cabinet/Shelf/Desk", "shoe cabinet",
                                  lambda r: _cabinet(_u(r, 0.9, 1.1), _u(r, 1.0, 1.15), 0.35, 2)),
    "painting": FurnitureType("Wall Decoration", "Others", "framed painting",
                              lambda r: _painting(_u(r, 0.6, 1.0), _u(r, 0.5, 0.8)), front_uv=True),
    "floor_lamp": FurnitureType("Floor Lamp", "Lighting", "floor lamp with shade",
                                lambda r: _floor_lamp(_u(r, 1.5, 1.7)), smooth=True),
    "desk_lamp": FurnitureType("Desk Lamp", "Lighting", "desk lamp", lambda r: _desk_lamp(_u(r, 0.4, 0.5)),
                               smooth=True),
    "pendant_lamp": FurnitureType("Pendant Lamp", "Lighting", "pendant lamp", lambda r: _pendant_lamp(0.8),
                                  smooth=True),
    "ceiling_lamp": FurnitureType("Ceiling Lamp", "Lighting", "square ceiling light panel",
                                  lambda r: _ceiling_lamp(_u(r, 0.5, 0.6))),
    "wall_lamp": FurnitureType("Wall Lamp", "Lighting", "wall sconce", lambda r: _wall_lamp(), smooth=True),
}
"""Furniture types by name."""


@dataclass(frozen=True)
class FurnitureModel:
    """A generated model, ready to write into ``models/<jid>/``.

    Attributes:
        jid: model id (folder name), a UUID-formatted string.
        type_name: key of :data:`FURNITURE_TYPES`.
        mesh: geometry in the model frame (bottom at y = 0, centred in x and z).
        surface: its material.
        style: 3D-FUTURE style tag.
    """

    jid: str
    type_name: str
    mesh: MeshData
    surface: Surface
    style: str

    @property
    def kind(self) -> FurnitureType:
        """The furniture type."""
        return FURNITURE_TYPES[self.type_name]

    @property
    def size(self) -> np.ndarray:
        """(3,) bounding size (x, y, z) in metres."""
        lo, hi = self.mesh.bounds()
        return hi - lo


def stable_uuid(*parts: object) -> str:
    """A UUID-formatted id derived from ``parts`` by SHA-256 (deterministic)."""
    h = hashlib.sha256(":".join(str(p) for p in parts).encode()).hexdigest()
    return f"{h[:8]}-{h[8:12]}-{h[12:16]}-{h[16:20]}-{h[20:32]}"


def build_model(type_name: str, rng: np.random.Generator, surface: Surface, jid: str, style: str) -> FurnitureModel:
    """Build one furniture model of ``type_name`` with sizes drawn from ``rng``."""
    if type_name not in FURNITURE_TYPES:
        raise ValueError(f"unknown furniture type {type_name!r}; known: {', '.join(sorted(FURNITURE_TYPES))}")
    ft = FURNITURE_TYPES[type_name]
    geometry = ft.build(rng)
    extent = max(float(np.ptp(np.vstack([g.vertices for g in geometry]), axis=0).max()), 1e-3)
    parts = [flat_from_trimesh(p, max(surface.uv_span, extent), ft.smooth) for p in geometry]
    mesh = centre_on_floor(concatenate(parts))
    if ft.front_uv:
        mesh = _fit_front_uv(mesh)
    return FurnitureModel(jid, type_name, mesh, surface, style)


def _fit_front_uv(mesh: MeshData) -> MeshData:
    """Map the whole texture once onto the faces whose normal is +z (the picture side of a painting)."""
    lo, hi = mesh.bounds()
    uv = mesh.uvs.copy()
    front = mesh.normals[:, 2] > 0.99
    uv[front, 0] = (mesh.positions[front, 0] - lo[0]) / (hi[0] - lo[0])
    uv[front, 1] = (mesh.positions[front, 1] - lo[1]) / (hi[1] - lo[1])
    return MeshData(mesh.positions, mesh.normals, uv, mesh.faces)


def mtl_text(name: str, surface: Surface) -> str:
    """``model.mtl`` text: one opaque material with ``map_Kd texture.png`` and PBR ``Pr``/``Pm`` lines.

    No ``Tf``/``d`` lines (real files misuse them and loaders then make the furniture transparent). ``Ns`` follows
    Blender's OBJ importer mapping roughness = 1 - sqrt(Ns / 1000).
    """
    ns = 1000.0 * (1.0 - surface.roughness) ** 2
    spec = 0.5 if surface.metallic < 0.5 else 1.0
    return (f"newmtl {name}\n"
            "Ka 0.000000 0.000000 0.000000\n"
            "Kd 1.000000 1.000000 1.000000\n"
            f"Ks {spec:.6f} {spec:.6f} {spec:.6f}\n"
            f"Ns {ns:.6f}\n"
            "illum 2\n"
            f"Pr {surface.roughness:.6f}\n"
            f"Pm {surface.metallic:.6f}\n"
            "map_Kd texture.png\n")


def save_png(path: Path, image: np.ndarray) -> None:
    """Write an (H, W, 3) uint8 image as an optimised PNG, atomically and byte-reproducibly."""
    with atomic_path(path) as tmp:
        Image.fromarray(image, mode="RGB").save(tmp, format="PNG", optimize=True)


def write_model(model: FurnitureModel, models_dir: Path, texture: np.ndarray) -> Path:
    """Write ``models_dir/<jid>/{raw_model.obj, model.mtl, texture.png}``; returns the model folder."""
    folder = Path(models_dir) / model.jid
    folder.mkdir(parents=True, exist_ok=True)
    material = f"mat_{model.type_name}"
    write_text(folder / "raw_model.obj", obj_text(model.mesh, "model.mtl", material))
    write_text(folder / "model.mtl", mtl_text(material, model.surface))
    save_png(folder / "texture.png", texture)
    return folder


def model_info(model: FurnitureModel) -> dict:
    """The ``model_info.json`` entry of a model."""
    ft = model.kind
    return {"model_id": model.jid, "super-category": ft.super_category, "category": ft.category,
            "style": model.style, "theme": None, "material": _material_name(model.surface)}


def _material_name(surface: Surface) -> str:
    if surface.metallic >= 0.5:
        return "Metal"
    return {"wood": "Wood", "fabric": "Cloth", "tiles": "Stone", "terrazzo": "Stone", "brushed_metal": "Metal",
            "lamp_diffuser": "Cloth", "painting": "Others", "carpet": "Cloth", "plaster": "Others"}.get(
        surface.texture, "Others")
