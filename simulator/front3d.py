"""Read 3D-FRONT house files (and 3D-FUTURE furniture models) into the bpy-free :class:`~simulator.scene_model.Scene`.

The files are y up, metres. Everything is converted once to the project's z-up world with the proper rotation
``(x, y, z) -> (x, -z, y)`` (a plain y/z swap would mirror the house). Quaternions in the files are ``[x, y, z, w]``;
a furniture instance's world vertex is ``R(q) (scale * v) + pos`` in the y-up frame.

Textures: architecture materials name a texture by URL in 3D-FRONT; like the 3D-FRONT-texture dataset we look for
``<texture_dir>/<material jid>/texture.png``. Furniture: ``<future_dir>/<jid>/raw_model.obj`` with ``model.mtl`` and
``texture.png``. A missing model, texture or room reference is an error that lists every missing item by name, unless
``allow_missing=True`` (then each is skipped with a warning). Nothing is ever downloaded.

Optional extension keys that other 3D-FRONT loaders ignore: a material entry may carry ``roughness`` and ``metallic``;
a furniture ``model.mtl`` may carry the PBR lines ``Pr`` (roughness) and ``Pm`` (metallic). ``Tf`` and ``d`` in MTL
files are deliberately ignored: real 3D-FUTURE files misuse them, which makes furniture transparent in naive loaders.
"""

from __future__ import annotations

import json
import logging
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from spotlessgs.io.colorspace import srgb_to_linear
from simulator.scene_model import Material, MeshObject, Room, Scene

log = logging.getLogger(__name__)

#: Mesh types that emit light in the ground-truth render (ceiling light strips).
LIGHT_MESH_TYPES = ("lightband",)
#: A vertex farther than this from the house's origin (metres, any axis) is an error: no house is 100 km across.
MAX_COORDINATE_M = 1e5
#: Words in a furniture category/title that make it a lamp (an emitter in the ground-truth render).
LAMP_WORDS = ("lamp", "light", "chandelier", "sconce")


class Front3DError(ValueError):
    """A 3D-FRONT file (or a model it references) is invalid; the message names the file, the entry and the problem."""


@dataclass(frozen=True)
class LoadOptions:
    """How to resolve external files.

    Attributes:
        future_dir: root of the 3D-FUTURE models (``<future_dir>/<jid>/raw_model.obj``); default
            ``<house dir>/models`` when that folder exists.
        texture_dir: root of architecture textures (``<texture_dir>/<material jid>/texture.png``); default
            ``<house dir>/textures`` when that folder exists.
        allow_missing: skip (with a warning) missing models, textures and unknown room references instead of failing.
    """

    future_dir: Path | None = None
    texture_dir: Path | None = None
    allow_missing: bool = False


# --------------------------------------------------------------------------------------------------------------------
# Frame conversion


def yup_to_zup(points: np.ndarray) -> np.ndarray:
    """Convert (..., 3) points or directions from the y-up file frame to the z-up world: (x, y, z) -> (x, -z, y)."""
    points = np.asarray(points, dtype=np.float64)
    return np.stack([points[..., 0], -points[..., 2], points[..., 1]], axis=-1)


def quat_xyzw_to_matrix(q: np.ndarray) -> np.ndarray:
    """Rotation matrix (3, 3) of a quaternion stored ``[x, y, z, w]`` (normalised here; zero norm is an error)."""
    q = np.asarray(q, dtype=np.float64)
    n = np.linalg.norm(q)
    if not np.isfinite(n) or n < 1e-12:
        raise ValueError(f"quaternion {q.tolist()} has zero or non-finite norm")
    x, y, z, w = q / n
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
            [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
            [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
        ]
    )


# --------------------------------------------------------------------------------------------------------------------
# Small validated readers


class _Ctx:
    """Error context: the file being read, so every error names it."""

    def __init__(self, path: Path):
        self.path = path

    def fail(self, entry: str, problem: str) -> Front3DError:
        return Front3DError(f"{self.path}: {entry}: {problem}")

    def key(self, obj: Any, key: str, entry: str) -> Any:
        if not isinstance(obj, dict):
            raise self.fail(entry, f"expected an object, got {type(obj).__name__}")
        if key not in obj:
            raise self.fail(entry, f"missing key {key!r}")
        return obj[key]

    def items(self, obj: Any, key: str, entry: str) -> list:
        """``obj[key]`` when it is a list (a JSON array)."""
        value = self.key(obj, key, entry)
        if not isinstance(value, list):
            raise self.fail(f"{entry}.{key}" if entry != "top level" else key,
                            f"expected a list, got {type(value).__name__}")
        return value

    def number(self, obj: dict, key: str, entry: str, default: float) -> float:
        """``obj[key]`` (``default`` when absent) when it is a finite number."""
        value = obj.get(key, default)
        try:
            number = float(value) if isinstance(value, (int, float)) and not isinstance(value, bool) else math.nan
        except OverflowError:  # an integer beyond the float range
            number = math.inf
        if not math.isfinite(number):
            shown = repr(value) if len(repr(value)) < 40 else f"{repr(value)[:37]}..."
            raise self.fail(f"{entry}.{key}", f"expected a finite number, got {shown}")
        return number

    def plain_name(self, value: Any, entry: str) -> str:
        """``value`` as text when it can name a folder inside a models or textures root: not empty, no path
        separator, not ``.`` or ``..`` (a file may not reach outside its roots)."""
        name = str(value)
        if not name or name in (".", "..") or "/" in name or "\\" in name or Path(name).is_absolute():
            raise self.fail(entry, f"{name!r} is not a plain name (no path separators, not '..'): it names a folder "
                                   "under the models or textures root")
        return name

    def floats(self, values: Any, entry: str, count: int | None = None, group: int = 1) -> np.ndarray:
        try:
            arr = np.asarray(values, dtype=np.float64).reshape(-1)
        except (TypeError, ValueError, OverflowError) as exc:
            raise self.fail(entry, f"not a list of numbers ({exc})") from None
        if count is not None and arr.size != count:
            raise self.fail(entry, f"expected {count} numbers, got {arr.size}")
        if arr.size % group:
            raise self.fail(entry, f"length {arr.size} is not a multiple of {group}")
        if not np.all(np.isfinite(arr)):
            bad = int(np.flatnonzero(~np.isfinite(arr))[0])
            raise self.fail(entry, f"non-finite value {arr[bad]} at index {bad}")
        return arr


def _room_entry(room: Any, index: int) -> str:
    return f"scene.room[{index}] ({room.get('instanceid', '?')})" if isinstance(room, dict) else f"scene.room[{index}]"


# --------------------------------------------------------------------------------------------------------------------
# Materials


def _parse_materials(ctx: _Ctx, data: dict, texture_dir: Path | None, missing: list[str]) -> dict[str, Material]:
    materials: dict[str, Material] = {}
    first: dict[str, int] = {}
    for i, entry in enumerate(ctx.items(data, "material", "top level")):
        name = f"material[{i}]"
        uid = str(ctx.key(entry, "uid", name))
        name = f"material[{i}] ({uid})"
        if uid in first:
            raise ctx.fail(name, f"uid {uid!r} repeats material[{first[uid]}]'s; each material needs its own")
        first[uid] = i
        color = ctx.floats(entry.get("color", [204, 204, 204, 255]), f"{name}.color")
        if color.size not in (3, 4):
            raise ctx.fail(f"{name}.color", f"expected [r, g, b, a], got {color.size} numbers")
        base = tuple(float(c) for c in srgb_to_linear(np.clip(color[:3] / 255.0, 0.0, 1.0)))
        rough = ctx.number(entry, "roughness", name, 0.6)
        metal = ctx.number(entry, "metallic", name, 0.0)
        for key, val in (("roughness", rough), ("metallic", metal)):
            if not (0.0 <= val <= 1.0):
                raise ctx.fail(f"{name}.{key}", f"must be in [0, 1], got {val}")
        texture = None
        if entry.get("texture"):
            jid = ctx.plain_name(entry.get("jid") or uid, f"{name}.jid")
            candidate = texture_dir / jid / "texture.png" if texture_dir is not None else None
            if candidate is not None and candidate.is_file():
                texture = check_texture(candidate)
            else:
                missing.append(f"texture of {name}: {candidate or f'<no texture dir>/{jid}/texture.png'}")
        materials[uid] = Material(name=uid, base_color=base, texture=texture, roughness=rough, metallic=metal)
    return materials


def check_texture(path: Path) -> Path:
    """``path`` when it is an image file that decodes (its PNG chunks' checksums verified); Front3DError naming it
    otherwise. Blender would render an undecodable texture as magenta without failing."""
    from PIL import Image, UnidentifiedImageError

    try:
        with Image.open(path) as image:
            image.verify()
    except (UnidentifiedImageError, OSError, SyntaxError, ValueError, Image.DecompressionBombError) as exc:
        raise Front3DError(f"{path}: texture does not decode as an image ({exc})") from None
    return path


def _uv_transform(ctx: _Ctx, entry: dict, name: str) -> np.ndarray | None:
    if "UVTransform" not in entry or entry["UVTransform"] is None:
        return None
    return ctx.floats(entry["UVTransform"], f"{name}.UVTransform", count=9).reshape(3, 3)


# --------------------------------------------------------------------------------------------------------------------
# Architecture meshes


def _parse_meshes(ctx: _Ctx, data: dict, materials: dict[str, Material], uv_transforms: dict) -> dict[str, MeshObject]:
    meshes: dict[str, MeshObject] = {}
    first: dict[str, int] = {}
    for i, entry in enumerate(ctx.items(data, "mesh", "top level")):
        uid = str(ctx.key(entry, "uid", f"mesh[{i}]"))
        name = f"mesh[{i}] ({uid})"
        if uid in first:
            raise ctx.fail(name, f"uid {uid!r} repeats mesh[{first[uid]}]'s; each mesh needs its own")
        first[uid] = i
        mtype = str(ctx.key(entry, "type", name))
        xyz = ctx.floats(ctx.key(entry, "xyz", name), f"{name}.xyz", group=3).reshape(-1, 3)
        if xyz.size and np.abs(xyz).max() > MAX_COORDINATE_M:
            raise ctx.fail(f"{name}.xyz", f"a vertex lies {np.abs(xyz).max():.3g} m from the origin (more than "
                                          f"{MAX_COORDINATE_M:.0e} m: not a house)")
        faces_raw = ctx.floats(ctx.key(entry, "faces", name), f"{name}.faces", group=3)
        if np.any(faces_raw != np.round(faces_raw)):
            raise ctx.fail(f"{name}.faces", "face indices must be integers")
        faces = faces_raw.astype(np.int64).reshape(-1, 3)
        if len(xyz) == 0 or len(faces) == 0:
            raise ctx.fail(name, "mesh has no vertices or no faces")
        if faces.min() < 0 or faces.max() >= len(xyz):
            bad = int(faces.max()) if faces.max() >= len(xyz) else int(faces.min())
            raise ctx.fail(f"{name}.faces", f"index {bad} out of range for {len(xyz)} vertices")
        normals = None
        if entry.get("normal"):
            normals = ctx.floats(entry["normal"], f"{name}.normal", count=xyz.size).reshape(-1, 3)
            normals = yup_to_zup(normals)
            normals = normals / np.maximum(np.linalg.norm(normals, axis=1, keepdims=True), 1e-12)
        uvs = None
        if entry.get("uv"):
            uvs = ctx.floats(entry["uv"], f"{name}.uv", count=2 * len(xyz)).reshape(-1, 2)
        mat_uid = str(ctx.key(entry, "material", name))
        if mat_uid not in materials:
            raise ctx.fail(f"{name}.material", f"unknown material {mat_uid!r}")
        if uvs is not None and mat_uid in uv_transforms:
            m = uv_transforms[mat_uid]
            uvs = (np.c_[uvs, np.ones(len(uvs))] @ m.T)[:, :2]
        is_light = mtype.lower() in LIGHT_MESH_TYPES
        meshes[uid] = MeshObject(
            name=uid,
            source="mesh",
            category=mtype,
            vertices=yup_to_zup(xyz),
            faces=faces,
            material=materials[mat_uid],
            uvs=uvs,
            normals=normals,
            is_light=is_light,
        )
    return meshes


# --------------------------------------------------------------------------------------------------------------------
# 3D-FUTURE furniture models


@dataclass
class FurnitureModel:
    """A 3D-FUTURE model in its own y-up frame: vertices (V,3), faces (F,3), uvs (V,2)|None, normals (V,3)|None."""

    jid: str
    vertices: np.ndarray
    faces: np.ndarray
    uvs: np.ndarray | None
    normals: np.ndarray | None
    material: Material


def read_mtl(path: Path) -> dict[str, Any]:
    """Read the first material of an MTL file: ``Kd`` (3,), ``Ns``, ``Pr``, ``Pm``, ``map_Kd`` (when present).

    ``Tf`` and ``d`` are ignored on purpose (see module docstring).
    """
    out: dict[str, Any] = {}
    seen_material = False
    for lineno, line in enumerate(path.read_text(encoding="utf-8", errors="replace").splitlines(), 1):
        parts = line.strip().split()
        if not parts or parts[0].startswith("#"):
            continue
        key, args = parts[0], parts[1:]
        if key == "newmtl":
            if seen_material:
                break
            seen_material = True
            continue
        try:
            if key == "Kd":
                if len(args) < 3:
                    raise ValueError
                out["Kd"] = tuple(float(a) for a in args[:3])
            elif key in ("Ns", "Pr", "Pm"):
                out[key] = float(args[0])
            elif key == "map_Kd":
                out["map_Kd"] = args[-1]
        except (ValueError, IndexError):
            raise Front3DError(f"{path}: line {lineno}: cannot parse {line.strip()!r}") from None
        numbers = out.get(key, ()) if key == "Kd" else (out[key],) if key in ("Ns", "Pr", "Pm") else ()
        if not all(math.isfinite(v) for v in numbers):
            raise Front3DError(f"{path}: line {lineno}: {key} must be finite, got {line.strip()!r}")
        if key == "map_Kd" and (Path(out["map_Kd"]).is_absolute() or ".." in Path(out["map_Kd"]).parts):
            raise Front3DError(f"{path}: line {lineno}: map_Kd {out['map_Kd']!r} leaves the model's folder")
    return out


def _material_from_mtl(jid: str, model_dir: Path, mtl: dict[str, Any]) -> Material:
    kd = mtl.get("Kd", (0.8, 0.8, 0.8))
    if "Pr" in mtl:
        rough = mtl["Pr"]
    elif "Ns" in mtl:
        rough = math.sqrt(2.0 / (max(mtl["Ns"], 0.0) + 2.0))  # Blinn-Phong exponent -> GGX roughness
    else:
        rough = 0.6
    texture = model_dir / "texture.png"
    if "map_Kd" in mtl and (model_dir / mtl["map_Kd"]).is_file():
        texture = model_dir / mtl["map_Kd"]
    return Material(
        name=jid,
        base_color=tuple(float(c) for c in np.clip(kd, 0.0, 1.0)) if not texture.is_file() else (1.0, 1.0, 1.0),
        texture=check_texture(texture) if texture.is_file() else None,
        roughness=float(np.clip(rough, 0.0, 1.0)),
        metallic=float(np.clip(mtl.get("Pm", 0.0), 0.0, 1.0)),
    )


def load_future_model(model_dir: Path, jid: str) -> FurnitureModel:
    """Load ``<model_dir>/raw_model.obj`` (+ ``model.mtl``, ``texture.png``) in the model's y-up frame."""
    import trimesh

    obj = model_dir / "raw_model.obj"
    try:
        loaded = trimesh.load(obj, force="mesh", process=False, skip_materials=True)
    except Exception as exc:  # trimesh raises many types for bad files
        raise Front3DError(f"{obj}: cannot read OBJ ({exc})") from None
    vertices = np.asarray(loaded.vertices, dtype=np.float64)
    faces = np.asarray(loaded.faces, dtype=np.int64)
    if len(vertices) == 0 or len(faces) == 0:
        raise Front3DError(f"{obj}: model has no vertices or no faces")
    if not np.all(np.isfinite(vertices)):
        raise Front3DError(f"{obj}: non-finite vertex coordinates")
    uvs = None
    visual_uv = getattr(loaded.visual, "uv", None)
    if visual_uv is not None and len(visual_uv) == len(vertices):
        uvs = np.asarray(visual_uv, dtype=np.float64)
    normals = np.asarray(loaded.vertex_normals, dtype=np.float64)  # the file's `vn` when present, else computed
    mtl_path = model_dir / "model.mtl"
    mtl = read_mtl(mtl_path) if mtl_path.is_file() else {}
    return FurnitureModel(jid, vertices, faces, uvs, normals, _material_from_mtl(jid, model_dir, mtl))


def is_lamp(category: str, title: str = "") -> bool:
    """True when a furniture category/title names a lamp or light fixture."""
    text = f"{category} {title}".lower()
    return any(word in text for word in LAMP_WORDS)


# --------------------------------------------------------------------------------------------------------------------
# Rooms


def _floor_polygon(ctx: _Ctx, floors: list[MeshObject], entry: str) -> np.ndarray:
    """Union of the floor triangles in x-y: (K, 2) counter-clockwise outline of the largest part."""
    from shapely.geometry import Polygon
    from shapely.ops import unary_union

    tris = []
    for mesh in floors:
        for tri in mesh.vertices[mesh.faces][:, :, :2]:
            poly = Polygon(tri)
            if poly.area > 1e-9:
                tris.append(poly)
    area = float(sum(t.area for t in tris))
    if not math.isfinite(area):
        raise ctx.fail(entry, "its floor meshes' coordinates are too large: the floor area is not finite")
    if area < 1e-4:
        raise ctx.fail(entry, f"zero-area room: its floor meshes cover {area:.2e} m^2")
    union = unary_union(tris).buffer(1e-4).buffer(-1e-4)
    if union.geom_type == "MultiPolygon":
        union = max(union.geoms, key=lambda g: g.area)
    union = union.simplify(1e-3)
    if union.is_empty or union.area < 1e-4:  # slivers whose union thins away
        raise ctx.fail(entry, f"zero-area room: its floor meshes' outline covers {union.area:.2e} m^2")
    if not union.exterior.is_ccw:
        union = Polygon(list(union.exterior.coords)[::-1])
    return np.asarray(union.exterior.coords, dtype=np.float64)[:-1]


def _parse_rooms(
    ctx: _Ctx,
    data: dict,
    meshes: dict[str, MeshObject],
    furniture: dict[str, dict],
    opts: LoadOptions,
    future_dir: Path | None,
    missing: list[str],
) -> tuple[list[Room], list[MeshObject]]:
    scene = ctx.key(data, "scene", "top level")
    rooms_raw = ctx.items(scene, "room", "scene")
    models: dict[str, FurnitureModel] = {}
    instances: list[MeshObject] = []
    rooms: list[Room] = []
    room_ids: dict[str, int] = {}
    for r, room in enumerate(rooms_raw):
        entry = _room_entry(room, r)
        room_id = str(ctx.key(room, "instanceid", entry))
        if room_id in room_ids:
            raise ctx.fail(entry, f"instanceid {room_id!r} repeats scene.room[{room_ids[room_id]}]'s; each room needs "
                                  "its own")
        room_ids[room_id] = r
        names: list[str] = []
        child_ids: dict[str, int] = {}
        for c, child in enumerate(ctx.items(room, "children", entry)):
            centry = f"{entry}.children[{c}]"
            ref = str(ctx.key(child, "ref", centry))
            if ref in meshes:
                names.append(ref)
                continue
            if ref not in furniture:
                missing.append(f"{centry}: unknown ref {ref!r}")
                continue
            fentry = furniture[ref]
            jid = ctx.plain_name(fentry.get("jid", ""), f"furniture ({ref}).jid")
            if jid not in models:
                model_dir = future_dir / jid if future_dir is not None else None
                if model_dir is None or not (model_dir / "raw_model.obj").is_file():
                    where = model_dir / "raw_model.obj" if model_dir is not None else f"<no --future-dir>/{jid}"
                    missing.append(f"model {jid!r} ({fentry.get('title') or fentry.get('category', '')}): {where}")
                    continue
                models[jid] = load_future_model(model_dir, jid)
            model = models[jid]
            pos = ctx.floats(child.get("pos", [0, 0, 0]), f"{centry}.pos", count=3)
            rot = ctx.floats(child.get("rot", [0, 0, 0, 1]), f"{centry}.rot", count=4)
            scale = ctx.floats(child.get("scale", [1, 1, 1]), f"{centry}.scale", count=3)
            try:
                rmat = quat_xyzw_to_matrix(rot)
            except ValueError as exc:
                raise ctx.fail(f"{centry}.rot", str(exc)) from None
            if np.any(scale <= 0):
                raise ctx.fail(f"{centry}.scale", f"scale must be positive, got {scale.tolist()}")
            with np.errstate(over="ignore", invalid="ignore"):  # huge values are refused just below
                world = (model.vertices * scale) @ rmat.T + pos
            if not np.isfinite(world).all() or np.abs(world).max() > MAX_COORDINATE_M:
                raise ctx.fail(centry, f"its scale {scale.tolist()} and position {pos.tolist()} put the model's "
                                       f"vertices more than {MAX_COORDINATE_M:.0e} m from the origin (not a house)")
            normals = None
            if model.normals is not None:
                # normals transform with the inverse transpose of R diag(scale)
                n = (model.normals / scale) @ rmat.T
                normals = yup_to_zup(n / np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-12))
            category = str(fentry.get("category") or "")
            title = str(fentry.get("title") or "")
            child_id = str(child.get("instanceid", c))
            if child_id in child_ids:
                raise ctx.fail(centry, f"instanceid {child_id!r} repeats {entry}.children[{child_ids[child_id]}]'s; "
                                       "each piece of furniture in a room needs its own")
            child_ids[child_id] = c
            obj_name = f"{room_id}/{child_id}"
            lamp = is_lamp(category, title)
            instances.append(
                MeshObject(
                    name=obj_name,
                    source="furniture",
                    category=category or title,
                    vertices=yup_to_zup(world),
                    faces=model.faces,
                    material=model.material,
                    uvs=model.uvs,
                    normals=normals,
                    is_light=lamp,
                )
            )
            names.append(obj_name)
        floors = [meshes[n] for n in names if n in meshes and meshes[n].category.lower() == "floor"]
        if not floors:
            log.warning("%s: %s has no Floor mesh; skipped as a room", ctx.path, entry)
            continue
        polygon = _floor_polygon(ctx, floors, entry)
        floor_z = float(min(m.vertices[:, 2].min() for m in floors))
        ceilings = [meshes[n] for n in names if n in meshes and meshes[n].category.lower() == "ceiling"]
        walls = [meshes[n] for n in names if n in meshes and meshes[n].category.lower().startswith("wall")]
        tops = ceilings or walls
        ceiling_z = float(max(m.vertices[:, 2].max() for m in tops)) if tops else floor_z + 2.8
        if ceiling_z - floor_z < 1.0:
            raise ctx.fail(entry, f"ceiling {ceiling_z:.3f} m is less than 1 m above the floor {floor_z:.3f} m")
        rooms.append(Room(room_id, str(room.get("type", "")), polygon, floor_z, ceiling_z, names))
    return rooms, instances


# --------------------------------------------------------------------------------------------------------------------
# Entry point


def load_house(path: str | Path, options: LoadOptions = LoadOptions()) -> Scene:
    """Read a 3D-FRONT house JSON file into a z-up :class:`Scene` (lights are added later by the lighting module).

    Raises:
        Front3DError: bad JSON, missing keys, out-of-range face indices, non-finite numbers, zero-area rooms, unknown
            references, or missing models/textures (unless ``options.allow_missing``); the message names the file,
            the entry and the problem.
    """
    path = Path(path)
    ctx = _Ctx(path)
    if not path.is_file():
        raise Front3DError(f"{path}: no such file")
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise Front3DError(f"{path}: invalid JSON ({exc})") from None
    except RecursionError:
        raise Front3DError(f"{path}: invalid JSON (nested too deeply)") from None
    if not isinstance(data, dict):
        raise ctx.fail("top level", f"expected an object, got {type(data).__name__}")
    house_dir = path.parent
    future_dir = options.future_dir or (house_dir / "models" if (house_dir / "models").is_dir() else None)
    texture_dir = options.texture_dir or (house_dir / "textures" if (house_dir / "textures").is_dir() else None)

    missing: list[str] = []
    materials = _parse_materials(ctx, data, texture_dir, missing)
    uv_transforms = {}
    for i, entry in enumerate(data["material"]):
        m = _uv_transform(ctx, entry, f"material[{i}] ({entry['uid']})")
        if m is not None:
            uv_transforms[str(entry["uid"])] = m
    meshes = _parse_meshes(ctx, data, materials, uv_transforms)
    furniture = {}
    for i, entry in enumerate(ctx.items(data, "furniture", "top level")):
        uid = str(ctx.key(entry, "uid", f"furniture[{i}]"))
        ctx.key(entry, "jid", f"furniture[{i}] ({uid})")
        if entry.get("valid", True) is False:
            continue
        furniture[uid] = entry
    rooms, instances = _parse_rooms(ctx, data, meshes, furniture, options, future_dir, missing)

    if missing:
        listing = "\n  ".join(missing)
        if not options.allow_missing:
            raise Front3DError(
                f"{path}: {len(missing)} missing item(s) (pass allow_missing / --allow-missing to skip them):\n  {listing}"
            )
        log.warning("%s: skipping %d missing item(s):\n  %s", path, len(missing), listing)
    if not rooms:
        raise Front3DError(f"{path}: no room with a floor")
    return Scene(
        scene_id=str(data.get("uid", path.stem)),
        source=path,
        objects=list(meshes.values()) + instances,
        lights=[],
        rooms=rooms,
    )
