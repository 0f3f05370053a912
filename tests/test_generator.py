"""Tests of the procedural 3D-FRONT room generator (simulator.generator).

The rooms are checked from the written files only (house.json, OBJ/MTL, PNG), with independent helpers here (an OBJ
parser, scipy rotations, shapely geometry), against the format contract that simulator.front3d reads.
"""

from __future__ import annotations

import hashlib
import json
import math
import shutil
from pathlib import Path

import numpy as np
import pytest
import shapely
import shapely.affinity
import trimesh
from PIL import Image
from scipy import ndimage
from scipy.spatial.transform import Rotation
from shapely.geometry import LineString, Polygon

from simulator.generator import ROOM_KINDS, GeneratorConfig, generate_room, plan
from simulator.generator import architecture as arch
from simulator.generator import rooms, textures
from simulator.generator.furniture import FURNITURE_TYPES, build_model, mtl_text, obj_text
from simulator.generator.house_writer import HouseFiles, write_house
from simulator.generator.materials import PALETTES, Surface, surf
from simulator.generator.meshes import MeshData, box, flat_from_trimesh
from spotlessgs.io.seeding import numpy_rng

REPO = Path(__file__).resolve().parents[1]
SEED = 0
TINY = GeneratorConfig.tiny()


# ----------------------------------------------------------------------------------------------------------- helpers
def tree_digest(root: Path) -> dict[str, str]:
    """Relative path -> sha256 of every file under ``root``."""
    return {str(p.relative_to(root)): hashlib.sha256(p.read_bytes()).hexdigest()
            for p in sorted(root.rglob("*")) if p.is_file()}


def read_obj(path: Path) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Minimal independent OBJ reader: positions (V,3), uvs (T,2), normals (N,3), faces (F,3,3) of v/vt/vn indices."""
    v, vt, vn, f = [], [], [], []
    for line in path.read_text().splitlines():
        parts = line.split()
        if not parts:
            continue
        if parts[0] == "v":
            v.append([float(x) for x in parts[1:4]])
        elif parts[0] == "vt":
            vt.append([float(x) for x in parts[1:3]])
        elif parts[0] == "vn":
            vn.append([float(x) for x in parts[1:4]])
        elif parts[0] == "f":
            f.append([[int(i) - 1 for i in c.split("/")] for c in parts[1:]])
    return np.array(v), np.array(vt), np.array(vn), np.array(f)


def instance_vertices(child: dict, verts: np.ndarray) -> np.ndarray:
    """World vertices of a furniture instance: R(q) (scale * v) + pos, q = [x, y, z, w] (scipy's order)."""
    return Rotation.from_quat(child["rot"]).apply(verts * np.asarray(child["scale"])) + np.asarray(child["pos"])


class Room:
    """A generated room read back from disk."""

    def __init__(self, house_json: Path):
        self.dir = house_json.parent
        self.house = json.loads(house_json.read_text())
        self.meshes = {m["uid"]: m for m in self.house["mesh"]}
        self.furniture = {f["uid"]: f for f in self.house["furniture"]}
        self.materials = {m["uid"]: m for m in self.house["material"]}
        (self.room,) = self.house["scene"]["room"]
        self._objs: dict[str, tuple] = {}

    def obj(self, jid: str):
        if jid not in self._objs:
            self._objs[jid] = read_obj(self.dir / "models" / jid / "raw_model.obj")
        return self._objs[jid]

    def meshes_of(self, mtype: str) -> list[dict]:
        return [m for m in self.house["mesh"] if m["type"] == mtype]

    def floor_polygon(self) -> Polygon:
        """Union of the floor triangles in the (x, z) plane."""
        (floor,) = self.meshes_of("Floor")
        xyz = np.asarray(floor["xyz"]).reshape(-1, 3)
        tris = np.asarray(floor["faces"]).reshape(-1, 3)
        return shapely.union_all([Polygon(xyz[t][:, [0, 2]]) for t in tris]).simplify(1e-9)

    def height(self) -> float:
        (ceiling,) = self.meshes_of("Ceiling")
        return float(np.asarray(ceiling["xyz"]).reshape(-1, 3)[:, 1].max())

    def instances(self) -> list[tuple[dict, dict, np.ndarray, np.ndarray]]:
        """(child, furniture entry, world AABB lo (3,), hi (3,)) of every furniture instance, from the OBJ vertices."""
        out = []
        for ch in self.room["children"]:
            if ch["ref"] in self.furniture:
                f = self.furniture[ch["ref"]]
                w = instance_vertices(ch, self.obj(f["jid"])[0])
                out.append((ch, f, w.min(axis=0), w.max(axis=0)))
        return out


@pytest.fixture(scope="module")
def tiny_rooms(tmp_path_factory) -> dict[str, Room]:
    root = tmp_path_factory.mktemp("rooms")
    return {k: Room(generate_room(k, root / k, SEED, TINY)) for k in ROOM_KINDS}


# ------------------------------------------------------------------------------------------------------ determinism
def test_same_seed_same_bytes_different_seed_different(tmp_path):
    a = generate_room("bedroom", tmp_path / "a", 3, TINY)
    b = generate_room("bedroom", tmp_path / "b", 3, TINY)
    c = generate_room("bedroom", tmp_path / "c", 4, TINY)
    assert tree_digest(a.parent) == tree_digest(b.parent)
    assert a.read_bytes() != c.read_bytes()
    assert tree_digest(a.parent) != tree_digest(c.parent)


def test_regenerating_into_the_same_folder_replaces_it(tmp_path):
    out = tmp_path / "room"
    generate_room("corridor", out, 1, TINY)
    first = tree_digest(out)
    generate_room("corridor", out, 2, TINY)
    second = tree_digest(out)
    assert first != second
    assert not any(p.name.startswith(".") for p in tmp_path.iterdir()), "temporary folders left behind"
    generate_room("corridor", out, 1, TINY)
    assert tree_digest(out) == first


# -------------------------------------------------------------------------------------------------- json structure
@pytest.mark.parametrize("kind", ROOM_KINDS)
def test_house_json_structure(tiny_rooms, kind):
    r = tiny_rooms[kind]
    h = r.house
    assert {"uid", "jid", "furniture", "mesh", "material", "scene"} <= set(h)
    assert isinstance(h["uid"], str) and isinstance(h["jid"], str)
    scene = h["scene"]
    assert scene["pos"] == [0, 0, 0] and scene["rot"] == [0, 0, 0, 1] and scene["scale"] == [1, 1, 1]
    room = r.room
    assert room["type"] in {"Bedroom", "LivingRoom", "Office/Library", "StorageRoom", "Hallway", "OtherRoom"}
    assert room["empty"] == 0
    assert room["size"] == pytest.approx(r.floor_polygon().area, abs=1e-6)
    children = room["children"]
    ids = [c["instanceid"] for c in children]
    assert len(ids) == len(set(ids)), "instance ids must be unique"
    refs = [c["ref"] for c in children]
    assert set(refs) <= set(r.meshes) | set(r.furniture), "every child ref resolves"
    assert set(r.furniture) <= set(refs), "every furniture entry is used"
    for uid in r.meshes:  # every architecture mesh exactly once, identity transform
        (ch,) = [c for c in children if c["ref"] == uid]
        assert ch["pos"] == [0, 0, 0] and ch["rot"] == [0, 0, 0, 1] and ch["scale"] == [1, 1, 1]
    for f in h["furniture"]:
        assert f["valid"] is True and f["category"] and f["title"] and len(f["size"]) == 3
    for m in h["material"]:
        assert {"uid", "jid", "texture", "normaltexture", "color", "UVTransform", "roughness", "metallic"} <= set(m)
        assert len(m["color"]) == 4 and all(0 <= c <= 255 and isinstance(c, int) for c in m["color"])
        assert len(m["UVTransform"]) == 9
        assert 0 <= m["roughness"] <= 1 and 0 <= m["metallic"] <= 1
        if m["texture"]:
            img = Image.open(r.dir / "textures" / m["jid"] / "texture.png")
            assert img.mode == "RGB"
    info = json.loads((r.dir / "models" / "model_info.json").read_text())
    assert {e["model_id"] for e in info} == {f["jid"] for f in h["furniture"]}
    assert all({"model_id", "super-category", "category", "style", "theme", "material"} <= set(e) for e in info)


@pytest.mark.parametrize("kind", ROOM_KINDS)
def test_architecture_meshes(tiny_rooms, kind):
    r = tiny_rooms[kind]
    types = {m["type"] for m in r.house["mesh"]}
    assert {"Floor", "Ceiling", "WallInner", "Baseboard", "Door"} <= types
    poly = r.floor_polygon()
    h = r.height()
    assert 2.6 - 1e-9 <= h <= 3.0 + 1e-9
    x0, z0, x1, z1 = poly.bounds
    assert 2.6 <= min(x1 - x0, z1 - z0) and max(x1 - x0, z1 - z0) <= 9.0
    for m in r.house["mesh"]:
        xyz = np.asarray(m["xyz"], dtype=float).reshape(-1, 3)
        nrm = np.asarray(m["normal"], dtype=float).reshape(-1, 3)
        uv = np.asarray(m["uv"], dtype=float)
        faces = np.asarray(m["faces"]).reshape(-1, 3)
        assert len(m["xyz"]) % 3 == 0 and len(nrm) == len(xyz) and uv.size in (0, 2 * len(xyz))
        assert np.isfinite(xyz).all() and np.isfinite(nrm).all() and np.isfinite(uv).all()
        assert faces.min() >= 0 and faces.max() < len(xyz)
        np.testing.assert_allclose(np.linalg.norm(nrm, axis=1), 1.0, atol=1e-5)
        assert m["material"] in r.materials
        # counter-clockwise seen from the normal side
        tri = xyz[faces]
        geo = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
        assert (np.einsum("ij,ij->i", geo, nrm[faces].mean(axis=1)) > 0).all(), m["type"]
        if m["type"] == "Floor":
            assert np.all(xyz[:, 1] == 0.0) and np.allclose(nrm, [0, 1, 0])
        if m["type"] == "Ceiling":
            assert np.allclose(xyz[:, 1], h) and np.allclose(nrm, [0, -1, 0])
        if m["type"] == "LightBand":
            assert np.allclose(nrm, [0, -1, 0]) and np.all(xyz[:, 1] > h - 0.05)
        if m["type"] in ("WallInner", "Baseboard", "Door"):
            centre = xyz[faces].mean(axis=1)
            inward = centre[:, [0, 2]] + 0.05 * nrm[faces].mean(axis=1)[:, [0, 2]]
            assert all(poly.contains(shapely.Point(p)) for p in inward), f"{m['type']} normal points out"
    walls = r.meshes_of("WallInner")
    assert len(walls) == len(poly.exterior.coords) - 1
    wall_area = sum(trimesh.Trimesh(np.asarray(w["xyz"]).reshape(-1, 3), np.asarray(w["faces"]).reshape(-1, 3),
                                    process=False).area for w in walls)
    assert wall_area == pytest.approx(poly.length * h, rel=1e-6)


def test_living_room_is_l_shaped(tiny_rooms):
    poly = tiny_rooms["living_room"].floor_polygon()
    assert len(poly.exterior.coords) - 1 == 6
    assert poly.area < 0.95 * shapely.box(*poly.bounds).area
    assert not poly.equals(poly.convex_hull)


# ------------------------------------------------------------------------------------------------------- furniture
@pytest.mark.parametrize("kind", ROOM_KINDS)
def test_models_match_declared_size_and_mtl_is_opaque(tiny_rooms, kind):
    r = tiny_rooms[kind]
    for f in r.house["furniture"]:
        folder = r.dir / "models" / f["jid"]
        v, vt, vn, faces = r.obj(f["jid"])
        lo, hi = v.min(axis=0), v.max(axis=0)
        np.testing.assert_allclose(hi - lo, f["size"], atol=2e-6)
        assert lo[1] == pytest.approx(0.0, abs=1e-6)
        np.testing.assert_allclose([(lo[0] + hi[0]) / 2, (lo[2] + hi[2]) / 2], 0.0, atol=1e-6)
        assert len(vt) and len(vn) and faces.shape[1:] == (3, 3)
        assert faces[..., 0].max() < len(v) and faces[..., 1].max() < len(vt) and faces[..., 2].max() < len(vn)
        np.testing.assert_allclose(np.linalg.norm(vn, axis=1), 1.0, atol=1e-5)
        obj = (folder / "raw_model.obj").read_text()
        assert obj.startswith("mtllib model.mtl\n")
        mtl = (folder / "model.mtl").read_text().splitlines()
        keys = {line.split()[0]: line.split()[1:] for line in mtl if line.strip()}
        assert "Tf" not in keys
        assert float(keys.get("d", ["1"])[0]) >= 1.0
        assert keys["map_Kd"] == ["texture.png"] and "Kd" in keys and "Ns" in keys
        assert 0 <= float(keys["Pr"][0]) <= 1 and 0 <= float(keys["Pm"][0]) <= 1
        assert Image.open(folder / "texture.png").mode == "RGB"
        # trimesh reads the same geometry
        tm = trimesh.load(folder / "raw_model.obj", force="mesh", process=False)
        np.testing.assert_allclose(tm.bounds[1] - tm.bounds[0], f["size"], atol=2e-6)


@pytest.mark.parametrize("kind", ROOM_KINDS)
def test_furniture_inside_room_and_not_overlapping(tiny_rooms, kind):
    r = tiny_rooms[kind]
    poly = r.floor_polygon().buffer(1e-7)
    h = r.height()
    inst = r.instances()
    for ch, f, lo, hi in inst:
        yaw = Rotation.from_quat(ch["rot"]).as_rotvec()
        assert abs(yaw[0]) < 1e-9 and abs(yaw[2]) < 1e-9, "furniture rotates about +y only"
        assert poly.covers(shapely.box(lo[0], lo[2], hi[0], hi[2])), f"{f['title']} leaves the floor"
        assert lo[1] >= -1e-9 and hi[1] <= h + 1e-6, f"{f['title']} pierces floor or ceiling"
    for i in range(len(inst)):
        for j in range(i + 1, len(inst)):
            (_, fa, la, ha), (_, fb, lb, hb) = inst[i], inst[j]
            overlap = np.minimum(ha, hb) - np.maximum(la, lb)
            assert not np.all(overlap > 1e-6), f"{fa['title']} overlaps {fb['title']}"


@pytest.mark.parametrize("kind", ROOM_KINDS)
def test_free_walkway_around_camera_loop(tiny_rooms, kind):
    r = tiny_rooms[kind]
    room_plan, _ = plan(kind, SEED)
    loop = room_plan.camera_loop()
    ring = LineString(np.vstack([loop, loop[:1]]))
    walkway = Polygon(loop).buffer(rooms.WALKWAY_HALF_WIDTH - 1e-6)  # the loop, its inside and 0.6 m around it
    assert r.floor_polygon().covers(walkway)
    assert ring.length > 2.0
    assert walkway.area >= 1.2 * 1.2
    low = [shapely.box(lo[0], lo[2], hi[0], hi[2]) for _, f, lo, hi in r.instances() if lo[1] < 1.9]
    for fp in low:
        assert fp.intersection(walkway).area < 1e-9


@pytest.mark.parametrize("kind", ROOM_KINDS)
def test_door_is_reachable(tiny_rooms, kind):
    """Nothing below 1.9 m stands within 0.8 m in front of the door leaf."""
    r = tiny_rooms[kind]
    (door,) = r.meshes_of("Door")
    xyz = np.asarray(door["xyz"]).reshape(-1, 3)
    nrm = np.asarray(door["normal"]).reshape(-1, 3)
    assert xyz[:, 1].min() == 0.0 and xyz[:, 1].max() == pytest.approx(2.05)
    poly = r.floor_polygon()
    centre = xyz[:, [0, 2]].mean(axis=0)
    horizontal = {tuple(np.round(v[[0, 2]], 6)) for v in nrm if abs(v[1]) < 0.5}
    (n,) = [np.array(v) for v in horizontal if not poly.contains(shapely.Point(centre - 0.3 * np.array(v)))]
    leaf = shapely.MultiPoint(xyz[:, [0, 2]]).convex_hull
    zone = shapely.union_all([leaf, shapely.affinity.translate(leaf, *(0.8 * n))]).convex_hull
    for _, f, lo, hi in r.instances():
        if lo[1] < 1.9:
            assert shapely.box(lo[0], lo[2], hi[0], hi[2]).intersection(zone).area < 1e-9, f["title"]


@pytest.mark.parametrize("kind", ROOM_KINDS)
def test_every_room_has_ceiling_lights_and_another_lamp(tiny_rooms, kind):
    r = tiny_rooms[kind]
    h = r.height()
    lamps = [(f, lo, hi) for _, f, lo, hi in r.instances()
             if "lamp" in f["category"].lower() or "lamp" in f["title"].lower()]
    ceiling = [x for x in lamps if x[2][1] > h - 1e-6]
    bands = r.meshes_of("LightBand")
    assert len(ceiling) + len(bands) >= (1 if r.floor_polygon().area < 13.0 else 2)  # one panel lights a small room
    assert len(lamps) - len(ceiling) >= 1, "needs a lamp besides the ceiling lights"
    # the ceiling lights are spread: every floor point within 2.2 m (horizontally) of one
    centres = np.array([[(lo[0] + hi[0]) / 2, (lo[2] + hi[2]) / 2] for _, lo, hi in ceiling])
    poly = r.floor_polygon()
    xs, zs = np.meshgrid(np.linspace(*poly.bounds[0::2], 25), np.linspace(*poly.bounds[1::2], 25))
    pts = [(x, z) for x, z in zip(xs.ravel(), zs.ravel()) if poly.contains(shapely.Point(x, z))]
    d = np.linalg.norm(np.asarray(pts)[:, None] - centres[None], axis=2).min(axis=1)
    assert d.max() < 2.2


# -------------------------------------------------------------------------------------------------------- materials
def _all_pbr(room: Room) -> list[tuple[float, float]]:
    """(roughness, metallic) of every architecture material and model MTL of a room."""
    vals = [(m["roughness"], m["metallic"]) for m in room.house["material"]]
    for f in room.house["furniture"]:
        keys = {ln.split()[0]: ln.split()[1:] for ln in (room.dir / "models" / f["jid"] / "model.mtl").read_text()
                .splitlines() if ln.strip()}
        vals.append((float(keys["Pr"][0]), float(keys["Pm"][0])))
    return vals


def test_storage_room_is_metallic_and_glossy_bedroom_fully_diffuse(tiny_rooms):
    storage = _all_pbr(tiny_rooms["storage_room"])
    assert sum(m == 1.0 for _, m in storage) >= 6
    assert sum(r <= 0.2 for r, _ in storage) >= 6
    (floor,) = tiny_rooms["storage_room"].meshes_of("Floor")
    assert tiny_rooms["storage_room"].materials[floor["material"]]["roughness"] <= 0.2
    bedroom = _all_pbr(tiny_rooms["bedroom"])
    assert all(r >= 0.8 and m == 0.0 for r, m in bedroom)
    for kind in ("living_room", "office", "corridor"):  # mixed rooms have some glossy surface each
        assert any(r <= 0.2 for r, _ in _all_pbr(tiny_rooms[kind]))


def test_white_room_is_small_white_and_matte(tiny_rooms):
    """The interreflection room: floor under 13 m², floor/walls/ceiling mean linear albedo >= 0.65 (sRGB decoded by hand:
    ((c + 0.055) / 1.055)^2.4), every surface but paintings and lamp shades rough and dielectric."""
    room = tiny_rooms["white_room"]
    assert room.floor_polygon().area < 13.0
    for mtype in ("Floor", "WallInner", "Ceiling"):
        material = room.materials[room.meshes_of(mtype)[0]["material"]]
        texture = np.asarray(Image.open(room.dir / "textures" / material["jid"] / "texture.png").convert("RGB"))
        srgb = texture.astype(np.float64) / 255.0
        linear = np.where(srgb <= 0.04045, srgb / 12.92, ((srgb + 0.055) / 1.055) ** 2.4)
        assert linear.mean() >= 0.65, (mtype, linear.mean())  # 0.73-0.81 at the shipped texture size
    assert all(m["roughness"] >= 0.8 and m["metallic"] == 0.0 for m in room.house["material"])
    for f in room.house["furniture"]:
        if "painting" in f["title"] or "lamp" in f["title"].lower() or "light" in f["title"]:
            continue
        keys = {ln.split()[0]: ln.split()[1:] for ln in (room.dir / "models" / f["jid"] / "model.mtl").read_text()
                .splitlines() if ln.strip()}
        assert float(keys["Pr"][0]) >= 0.8 and float(keys["Pm"][0]) == 0.0, f["title"]


# --------------------------------------------------------------------------------------------------------- textures
def _grey(img: np.ndarray) -> np.ndarray:
    """Grey image divided by its mean: contrast relative to the surface's brightness (lighting scales it anyway)."""
    g = img.astype(np.float64).mean(axis=2)
    return g / g.mean()


def _highpass_std(img: np.ndarray) -> float:
    g = _grey(img)
    return float((g - ndimage.gaussian_filter(g, 2.0)).std())


def _dog_extrema(img: np.ndarray) -> int:
    """Number of local extrema of a difference of Gaussians above 0.01 (a proxy for SIFT keypoints)."""
    g = _grey(img)
    d = np.abs(ndimage.gaussian_filter(g, 1.6) - ndimage.gaussian_filter(g, 2.6))
    return int(((d == ndimage.maximum_filter(d, 5)) & (d > 0.01)).sum())


def _off_peak_autocorrelation(img: np.ndarray, radius: int = 16) -> float:
    """Largest normalised autocorrelation of the high-passed image at shifts longer than ``radius`` px; near 1 for a
    texture that repeats itself."""
    g = _grey(img)
    g = g - ndimage.gaussian_filter(g, 8.0)
    g = (g - g.mean()) / g.std()
    spec = np.fft.fft2(g)
    ac = np.fft.fftshift(np.real(np.fft.ifft2(spec * np.conj(spec)))) / g.size
    h, w = ac.shape
    yy, xx = np.mgrid[:h, :w]
    return float(ac[(yy - h // 2) ** 2 + (xx - w // 2) ** 2 > radius**2].max())


def _palette_textures() -> list[tuple[str, Surface]]:
    seen, out = set(), []
    for kind, pal in PALETTES.items():
        for s in pal.all_surfaces():
            if s.texture and (s.texture, s.params, s.color) not in seen:
                seen.add((s.texture, s.params, s.color))
                out.append((f"{kind}/{s.texture}", s))
    return out


@pytest.mark.parametrize("name,surface", _palette_textures(), ids=[n for n, _ in _palette_textures()])
def test_textures_have_detail_and_do_not_repeat(name, surface):
    img = surface.image(numpy_rng(7, name), 256)
    assert img.dtype == np.uint8 and img.shape[2] == 3
    if surface.texture == "lamp_diffuser":  # emitters: only faint structure, by design
        assert 0.0005 < _highpass_std(img) < 0.01
        return
    assert _highpass_std(img) > 0.012, "too little fine detail"
    assert _dog_extrema(img) > 250, "too few blob-like features"
    if surface.texture not in ("wood", "brushed_metal"):  # grain/brushing is anisotropic by nature
        assert _off_peak_autocorrelation(img) < 0.5, "texture repeats itself"


def test_autocorrelation_detector_flags_a_tiled_texture():
    tile = textures.carpet(numpy_rng(0, "tile"), 64, (120, 100, 90))
    tiled = np.tile(tile, (4, 4, 1))
    assert _off_peak_autocorrelation(tiled) > 0.9
    assert _off_peak_autocorrelation(textures.carpet(numpy_rng(0, "tile"), 256, (120, 100, 90))) < 0.5


def test_value_noise_statistics_and_interpolation_weights():
    n = textures.value_noise(numpy_rng(0, "n"), (64, 96), (4, 6))
    assert n.shape == (64, 96)
    assert abs(n.mean()) < 1e-12 and n.std() == pytest.approx(1.0)
    m = textures._cubic_matrix(50, 5)
    np.testing.assert_allclose(m.sum(axis=1), 1.0, atol=1e-12)  # Catmull-Rom weights are a partition of unity
    knots = np.arange(9, dtype=float)  # a linear function is reproduced exactly
    np.testing.assert_allclose(m @ knots, np.linspace(1.5, 6.5, 50), atol=1e-12)


def test_wall_texture_is_wide_and_floor_maps_once(tiny_rooms):
    r = tiny_rooms["office"]
    wall_mat = r.materials[r.meshes_of("WallInner")[0]["material"]]
    img = Image.open(r.dir / "textures" / wall_mat["jid"] / "texture.png")
    assert img.size == (TINY.texture_size // 2 * 6, TINY.texture_size // 2)
    (floor,) = r.meshes_of("Floor")
    uv = np.asarray(floor["uv"]).reshape(-1, 2)
    assert uv.min() >= 0 and uv.max() == pytest.approx(1.0)
    u_all = np.concatenate([np.asarray(w["uv"]).reshape(-1, 2)[:, 0] for w in r.meshes_of("WallInner")])
    assert u_all.min() == 0 and u_all.max() == pytest.approx(1.0)


def test_long_room_gets_wide_floor_texture_along_its_long_side(tiny_rooms):
    r = tiny_rooms["corridor"]
    (floor,) = r.meshes_of("Floor")
    x0, z0, x1, z1 = r.floor_polygon().bounds
    assert (x1 - x0) / (z1 - z0) > 2.5
    img = Image.open(r.dir / "textures" / r.materials[floor["material"]]["jid"] / "texture.png")
    assert img.size == (3 * (TINY.texture_size // 2), TINY.texture_size // 2)
    xyz = np.asarray(floor["xyz"]).reshape(-1, 3)
    uv = np.asarray(floor["uv"]).reshape(-1, 2)
    np.testing.assert_allclose(uv[:, 0], (xyz[:, 0] - x0) / (x1 - x0), atol=1e-6)  # u runs along x, the long side
    np.testing.assert_allclose(uv[:, 1], (xyz[:, 2] - z0) / (z1 - z0), atol=1e-6)
    assert arch.floor_aspect((0, 0, 2, 9)) == 3 and arch.floor_aspect((0, 0, 5, 4)) == 1
    assert arch.floor_aspect((0, 0, 3, 5)) == 2
    tall = arch.horizontal([(0, 0, 2, 6)], 0.0, True, (0, 0, 2, 6))  # longer along z: u follows z
    np.testing.assert_allclose(tall.uvs[:, 0], tall.positions[:, 2] / 6)


# ---------------------------------------------------------------------------------------------- unit-level geometry
def test_placed_box_and_yaw_quaternion_by_hand():
    size = np.array([2.0, 1.0, 0.5])
    lo, hi = rooms.placed_box(np.array([1.0, 0.2, 3.0]), math.pi / 2, size)
    np.testing.assert_allclose(lo, [0.75, 0.2, 2.0])
    np.testing.assert_allclose(hi, [1.25, 1.2, 4.0])
    q = rooms.yaw_quaternion(math.pi / 2)
    np.testing.assert_allclose(Rotation.from_quat(q).apply([0, 0, 1]), [1, 0, 0], atol=1e-12)
    np.testing.assert_allclose(Rotation.from_quat(q).as_matrix(), Rotation.from_euler("y", 90, degrees=True)
                               .as_matrix(), atol=1e-12)


def test_outline_edges_and_baseboard_mitre():
    poly = arch.outline([(0, 0, 4, 2), (0, 2, 2, 3)])
    assert list(poly.exterior.coords)[:-1] == [(0, 0), (4, 0), (4, 2), (2, 2), (2, 3), (0, 3)]
    walls = arch.edges(poly)
    np.testing.assert_allclose([w.normal for w in walls], [[0, 1], [-1, 0], [0, -1], [-1, 0], [0, -1], [1, 0]],
                               atol=1e-12)
    assert [w.offset for w in walls] == [0, 4, 6, 8, 9, 11]
    bb = arch.baseboards(walls, 13.0)
    front = bb.positions[np.abs(bb.normals[:, 1]) < 0.5]
    d = arch.BASEBOARD_DEPTH
    # mitred: convex corners move in along both walls, the concave corner (2, 2) moves out of the notch
    assert {tuple(np.round(p[[0, 2]], 9)) for p in front} == {
        (d, d), (4 - d, d), (4 - d, 2 - d), (2 - d, 2 - d), (2 - d, 3 - d), (d, 3 - d)}
    floor = arch.horizontal(arch.disjoint_rects([(0, 0, 4, 2), (0, 2, 2, 3)]), 0.0, True, poly.bounds)
    area = trimesh.Trimesh(floor.positions, floor.faces, process=False).area
    assert area == pytest.approx(poly.area)


def test_obj_writer_round_trip_and_deduplication():
    mesh = flat_from_trimesh(box((1.0, 2.0, 0.5), (0, 1, 0)), 1.0)
    text = obj_text(mesh, "model.mtl", "m")
    lines = text.splitlines()
    assert sum(ln.startswith("v ") for ln in lines) == 8  # 36 corners -> 8 distinct positions
    assert sum(ln.startswith("vn ") for ln in lines) == 6
    assert sum(ln.startswith("f ") for ln in lines) == 12
    assert "-0.000000" not in text


def test_painting_texture_maps_once_on_front():
    m = build_model("painting", numpy_rng(0, "p"), PALETTES["office"].for_furniture("painting"), "jid", "Modern")
    front = m.mesh.normals[:, 2] > 0.99
    uv = m.mesh.uvs[front]
    np.testing.assert_allclose([uv.min(axis=0), uv.max(axis=0)], [[0, 0], [1, 1]], atol=1e-12)


def test_every_furniture_type_builds_centred_on_the_floor():
    for name in FURNITURE_TYPES:
        m = build_model(name, numpy_rng(1, name), PALETTES["office"].default, "jid", "Modern")
        lo, hi = m.mesh.bounds()
        assert lo[1] == pytest.approx(0.0, abs=1e-12)
        np.testing.assert_allclose([lo[0] + hi[0], lo[2] + hi[2]], 0.0, atol=1e-12)
        assert np.all(m.size > 0.01) and np.all(m.size < 2.5), name


def test_mtl_ns_follows_blender_roughness_mapping():
    text = mtl_text("m", surf("wood", 0.2, metallic=1.0))
    ns = float(next(ln.split()[1] for ln in text.splitlines() if ln.startswith("Ns")))
    assert 1.0 - math.sqrt(ns / 1000.0) == pytest.approx(0.2)
    assert "Pm 1.000000" in text and "Tf" not in text and "\nd " not in text


# ------------------------------------------------------------------------------------------------------ error paths
def test_error_paths(tmp_path):
    with pytest.raises(ValueError, match="unknown room kind 'kitchen'"):
        generate_room("kitchen", tmp_path / "k", 0, TINY)
    other = tmp_path / "mine"
    other.mkdir()
    (other / "notes.txt").write_text("keep me")
    with pytest.raises(FileExistsError, match="not a room made by this generator"):
        generate_room("bedroom", other, 0, TINY)
    assert (other / "notes.txt").read_text() == "keep me"
    foreign = tmp_path / "front"
    foreign.mkdir()
    (foreign / "house.json").write_text(json.dumps({"uid": "a-real-3d-front-house"}))
    with pytest.raises(FileExistsError, match="not a room made by this generator"):
        generate_room("bedroom", foreign, 0, TINY)
    assert json.loads((foreign / "house.json").read_text()) == {"uid": "a-real-3d-front-house"}
    a_file = tmp_path / "file"
    a_file.write_text("x")
    with pytest.raises(FileExistsError, match="not a room made by this generator"):
        generate_room("bedroom", a_file, 0, TINY)
    # a generated room with a dataset rendered into its folder: replacing the room would delete the dataset
    room = tmp_path / "room"
    generate_room("bedroom", room, 0, TINY)
    (room / "my_render").mkdir()
    (room / "my_render" / "notes.txt").write_text("keep me")
    house = (room / "house.json").read_bytes()
    with pytest.raises(FileExistsError, match=r"room: holds a generated room and also my_render, which replacing the "
                                              r"room would delete; refusing to replace it"):
        generate_room("bedroom", room, 1, TINY)
    assert (room / "my_render" / "notes.txt").read_text() == "keep me" and (room / "house.json").read_bytes() == house
    shutil.rmtree(room / "my_render")
    generate_room("bedroom", room, 1, TINY)  # the room alone is replaced
    assert (room / "house.json").read_bytes() != house
    with pytest.raises(ValueError, match="texture_size must be an even number >= 32"):
        GeneratorConfig(texture_size=31)
    with pytest.raises(ValueError, match="unknown texture kind 'marble'"):
        textures.make_texture("marble", numpy_rng(0, "t"), 64)
    with pytest.raises(ValueError, match="texture size must be >= 16"):
        textures.make_texture("plaster", numpy_rng(0, "t"), 8, color=(1, 2, 3))
    with pytest.raises(ValueError, match=r"roughness/metallic must lie in \[0, 1\]"):
        surf("wood", 1.5)
    with pytest.raises(ValueError, match="untextured surface has no image"):
        Surface("").image(numpy_rng(0, "t"), 32)
    with pytest.raises(ValueError, match="do not form one simple polygon"):
        arch.outline([(0, 0, 1, 1), (2, 2, 3, 3)])
    with pytest.raises(ValueError, match="uv_span must be positive"):
        flat_from_trimesh(box((1, 1, 1), (0, 0, 0)), 0.0)
    with pytest.raises(ValueError, match="unknown furniture type 'piano'"):
        build_model("piano", numpy_rng(0, "t"), PALETTES["office"].default, "j", "s")
    with pytest.raises(ValueError, match="not counter-clockwise"):
        arch._quad(np.array([[0, 0, 0], [0, 0, 1], [1, 0, 1], [1, 0, 0]], float), np.array([0.0, -1.0, 0.0]),
                   np.zeros((4, 2)))


def test_layout_errors():
    recipe = rooms.RECIPES["storage_room"]
    narrow = rooms.RoomRecipe("StorageRoom", (3.0, 3.0), (3.0, 3.0), (2.6, 2.6), None, {}, 1.0, 0, False, ())
    walls = arch.edges(arch.outline([(0, 0, 3, 3)]))
    with pytest.raises(ValueError, match="walkway too narrow"):
        rooms.walkway_region(arch.outline([(0, 0, 3, 3)]), walls, narrow.bands, narrow.default_band)
    huge = {t: [np.array([6.0, 1.0, 0.6])] for t in rooms.model_counts(recipe)}  # longer than any wall
    with pytest.raises(RuntimeError, match="no layout after"):
        rooms.plan_room("storage_room", recipe, huge, numpy_rng(0, "layout"))
    bad_door = rooms.RoomRecipe("StorageRoom", (5.0, 5.0), (4.0, 4.0), (2.6, 2.6), None, {}, 0.7, 9, False, ())
    with pytest.raises(ValueError, match="door edge 9 not in 0..3"):
        rooms.plan_room("x", bad_door, {}, numpy_rng(0, "layout"))
    orphan = rooms.RoomRecipe("StorageRoom", (5.0, 5.0), (4.0, 4.0), (2.6, 2.6), None, {}, 0.7, 0, False,
                              (rooms.ItemSpec("desk_lamp", "top", parent=None),))
    with pytest.raises(ValueError, match="needs a placed parent"):
        rooms.plan_room("x", orphan, {"desk_lamp": [np.array([0.2, 0.4, 0.2])]}, numpy_rng(0, "layout"))


def test_write_house_leaves_nothing_behind_on_failure(tmp_path):
    out = tmp_path / "room"
    bad = HouseFiles({"uid": "x"}, (), (("jid", np.zeros((4, 4, 5), np.uint8)),))  # 5 channels cannot be RGB
    with pytest.raises(TypeError, match="Cannot handle this data type"):
        write_house(out, bad)
    assert not out.exists()
    assert list(tmp_path.iterdir()) == []


def test_mesh_data_translated_keeps_topology():
    m = MeshData(np.zeros((3, 3)), np.tile([0, 1.0, 0], (3, 1)), np.zeros((3, 2)), np.array([[0, 1, 2]]))
    t = m.translated(np.array([1.0, 2.0, 3.0]))
    np.testing.assert_allclose(t.positions, [[1, 2, 3]] * 3)
    assert t.faces is m.faces


# ------------------------------------------------------------------------------------------------- shipped scenes
def test_shipped_scenes_exist_and_are_small():
    scenes = REPO / "scenes"
    for kind in ROOM_KINDS:
        house = json.loads((scenes / kind / "house.json").read_text())
        assert house["spotlessgs"]["kind"] == kind and house["spotlessgs"]["config"] == {
            "texture_size": 512, "furniture_texture_size": 256}
    total = sum(p.stat().st_size for p in scenes.rglob("*") if p.is_file())
    assert total < 12 * 1024 * 1024
    assert (scenes / "README.md").is_file()


def _check_reproduces(kind: str, tmp_path: Path) -> None:
    """Regenerate a shipped room: JSON/OBJ/MTL must match byte for byte, PNGs pixel for pixel (their compressed
    bytes also match under the same Pillow/zlib build, but zlib implementations may encode differently)."""
    shipped = REPO / "scenes" / kind
    house = json.loads((shipped / "house.json").read_text())
    out = generate_room(kind, tmp_path / kind, house["spotlessgs"]["seed"]).parent
    new, old = tree_digest(out), tree_digest(shipped)
    assert set(new) == set(old)
    for rel in sorted(new):
        if rel.endswith(".png"):
            np.testing.assert_array_equal(np.asarray(Image.open(out / rel)), np.asarray(Image.open(shipped / rel)))
        else:
            assert new[rel] == old[rel], rel


def test_shipped_storage_room_reproduces_byte_for_byte(tmp_path):
    _check_reproduces("storage_room", tmp_path)


@pytest.mark.slow
@pytest.mark.parametrize("kind", [k for k in ROOM_KINDS if k != "storage_room"])
def test_shipped_rooms_reproduce_byte_for_byte(kind, tmp_path):
    _check_reproduces(kind, tmp_path)


def test_generate_help_names_every_room_kind():
    """The help pointed to a --list option that does not exist."""
    from click.testing import CliRunner

    from simulator.cli import main
    from simulator.generator import ROOM_KINDS

    result = CliRunner().invoke(main, ["generate", "--help"])
    assert result.exit_code == 0 and "--list" not in result.output
    assert all(kind in " ".join(result.output.split()) for kind in ROOM_KINDS)
