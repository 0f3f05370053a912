"""3D-FRONT parsing, validation and the y-up -> z-up conversion (no Blender)."""

from __future__ import annotations

import copy
import json
import math
import re

import numpy as np
import pytest

from simulator.front3d import Front3DError, LoadOptions, is_lamp, load_house, quat_xyzw_to_matrix, yup_to_zup

# A model with one vertex per axis tip so that transforms are easy to follow: a tetrahedron, y up, bottom at y = 0.
TETRA_OBJ = """mtllib model.mtl
v 0 0 0
v 1 0 0
v 0 1 0
v 0 0 1
vt 0 0
vt 1 0
vt 0 1
vt 1 1
f 1/1 3/3 2/2
f 1/1 2/2 4/4
f 1/1 4/4 3/3
f 2/2 3/3 4/4
"""
MTL = "newmtl m\nKd 0.5 0.25 0.125\nNs 98\nPm 1\nTf 0 0 0\nd 0.2\n"


def _flat(points):
    return [float(c) for p in points for c in p]


def make_house(tmp_path, *, lamp=True):
    """An L-shaped room (y up) with one tetrahedron 'cabinet' and optionally a lamp; returns (house dict, dir)."""
    # L-shaped floor at y=0 (file frame): x in [0,4], z in [0,3] minus the corner x>2, z>2.
    floor_xz = [(0, 0), (4, 0), (4, 2), (2, 2), (2, 3), (0, 3)]
    tris = [(0, 1, 2), (0, 2, 3), (0, 3, 4), (0, 4, 5)]
    # Normals point up (+y). Winding: counter-clockwise seen from +y.
    floor_xyz = [(x, 0.0, z) for x, z in floor_xz]
    ceiling_xyz = [(x, 2.8, z) for x, z in floor_xz]
    house = {
        "uid": "house-1",
        "jid": "j",
        "material": [
            {"uid": "m-floor", "jid": "tex-floor", "texture": "", "normaltexture": "", "color": [255, 128, 0, 255]},
            {"uid": "m-ceil", "jid": "tex-ceil", "texture": "", "normaltexture": "", "color": [200, 200, 200, 255],
             "roughness": 0.1, "metallic": 1.0},
        ],
        "mesh": [
            {"uid": "floor-1", "jid": "", "type": "Floor", "material": "m-floor", "xyz": _flat(floor_xyz),
             "normal": _flat([(0, 1, 0)] * 6), "uv": _flat([(x, z) for x, z in floor_xz]),
             "faces": [i for t in tris for i in (t[0], t[2], t[1])]},
            {"uid": "ceil-1", "jid": "", "type": "Ceiling", "material": "m-ceil", "xyz": _flat(ceiling_xyz),
             "normal": _flat([(0, -1, 0)] * 6), "uv": [], "faces": [i for t in tris for i in t]},
        ],
        "furniture": [
            {"uid": "f-cab", "jid": "model-cab", "title": "cabinet", "category": "Cabinet", "valid": True,
             "size": [1, 1, 1]},
            {"uid": "f-lamp", "jid": "model-lamp", "title": "lamp", "category": "Ceiling Lamp", "valid": True,
             "size": [1, 1, 1]},
        ],
        "scene": {
            "uid": "s", "jid": "", "pos": [0, 0, 0], "rot": [0, 0, 0, 1], "scale": [1, 1, 1],
            "room": [
                {"type": "Bedroom", "instanceid": "Bedroom-1", "size": [4, 2.8, 3], "pos": [0, 0, 0],
                 "rot": [0, 0, 0, 1], "scale": [1, 1, 1], "empty": 0,
                 "children": [
                     {"ref": "floor-1", "instanceid": "c0", "pos": [0, 0, 0], "rot": [0, 0, 0, 1], "scale": [1, 1, 1]},
                     {"ref": "ceil-1", "instanceid": "c1", "pos": [0, 0, 0], "rot": [0, 0, 0, 1], "scale": [1, 1, 1]},
                     # yaw +90 degrees about +Y, at (1, 0, 2), scaled x2 along the model's x
                     {"ref": "f-cab", "instanceid": "c2", "pos": [1, 0, 2],
                      "rot": [0, math.sin(math.pi / 4), 0, math.cos(math.pi / 4)], "scale": [2, 1, 1]},
                 ]},
            ],
        },
    }
    if lamp:
        house["scene"]["room"][0]["children"].append(
            {"ref": "f-lamp", "instanceid": "c3", "pos": [1, 2.3, 1], "rot": [0, 0, 0, 1], "scale": [0.3, 0.3, 0.3]}
        )
    models = tmp_path / "models"
    for jid in ("model-cab", "model-lamp"):
        (models / jid).mkdir(parents=True, exist_ok=True)
        (models / jid / "raw_model.obj").write_text(TETRA_OBJ)
        (models / jid / "model.mtl").write_text(MTL)
    return house, tmp_path


def write(tmp_path, house, name="house.json"):
    path = tmp_path / name
    path.write_text(json.dumps(house))
    return path


def test_conversion_is_a_rotation_not_a_mirror():
    basis = yup_to_zup(np.eye(3))
    assert np.linalg.det(basis) == pytest.approx(1.0)
    np.testing.assert_allclose(yup_to_zup([0.0, 1.0, 0.0]), [0.0, 0.0, 1.0])  # up stays up
    np.testing.assert_allclose(yup_to_zup([1.0, 2.0, 3.0]), [1.0, -3.0, 2.0])


def test_quaternion_xyzw_order_and_errors():
    q = [0, math.sin(math.pi / 4), 0, math.cos(math.pi / 4)]  # +90 deg about y
    np.testing.assert_allclose(quat_xyzw_to_matrix(q) @ [1, 0, 0], [0, 0, -1], atol=1e-12)
    with pytest.raises(ValueError, match="zero or non-finite norm"):
        quat_xyzw_to_matrix([0, 0, 0, 0])


def test_load_house_geometry_materials_and_rooms(tmp_path):
    house, root = make_house(tmp_path)
    scene = load_house(write(root, house))
    assert scene.scene_id == "house-1"
    room = scene.room()
    assert room.instance_id == "Bedroom-1" and room.type == "Bedroom"
    assert room.floor_z == pytest.approx(0.0) and room.ceiling_z == pytest.approx(2.8)
    # L-shape: 4*3 - 2*1 = 10 m^2; outline counter-clockwise seen from +z
    assert room.floor_area() == pytest.approx(10.0, abs=1e-3)
    poly = room.floor_polygon
    signed = 0.5 * np.sum(poly[:, 0] * np.roll(poly[:, 1], -1) - np.roll(poly[:, 0], -1) * poly[:, 1])
    assert signed > 0
    # The L's notch is at file x>2, z>2 -> world x>2, y<-2 (a mirror would put it at y>2).
    from shapely.geometry import Point, Polygon

    outline = Polygon(poly)
    assert not outline.contains(Point(3.0, -2.5))
    assert outline.contains(Point(1.0, -2.5)) and outline.contains(Point(3.0, -1.0))

    objs = {o.name: o for o in scene.objects}
    floor = objs["floor-1"]
    np.testing.assert_allclose(floor.normals, np.tile([0.0, 0.0, 1.0], (6, 1)))
    # faces keep their orientation: the geometric normal of every floor triangle points up (+z)
    tri = floor.vertices[floor.faces]
    assert np.all(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])[:, 2] > 0)
    # materials: sRGB 255/128/0 -> linear
    assert floor.material.base_color[0] == pytest.approx(1.0)
    assert floor.material.base_color[1] == pytest.approx(((128 / 255 + 0.055) / 1.055) ** 2.4)
    ceil = objs["ceil-1"]
    assert (ceil.material.roughness, ceil.material.metallic) == (0.1, 1.0)

    cab = objs["Bedroom-1/c2"]
    assert cab.source == "furniture" and not cab.is_light
    # model vertex (1,0,0) -> scale x2 -> yaw +90 about +Y -> (0,0,-2) -> + pos (1,0,2) -> (1,0,0) y-up -> (1,0,0) z-up
    # model vertex (0,0,1) -> (0,0,1) -> yaw -> (1,0,0) -> (2,0,2) -> z-up (2,-2,0); model (0,1,0) -> (1,0,2)+y -> (1,-2,1)
    np.testing.assert_allclose(cab.vertices, [[1, -2, 0], [1, 0, 0], [1, -2, 1], [2, -2, 0]], atol=1e-12)
    # MTL: Ns 98 -> roughness sqrt(2/100); Pm 1 -> metallic; Tf/d ignored (opaque)
    assert cab.material.roughness == pytest.approx(math.sqrt(0.02))
    assert cab.material.metallic == 1.0
    assert cab.uvs is not None and cab.uvs.shape == (4, 2)
    lamp = objs["Bedroom-1/c3"]
    assert lamp.is_light and lamp.category == "Ceiling Lamp"
    assert set(room.object_names) == {"floor-1", "ceil-1", "Bedroom-1/c2", "Bedroom-1/c3"}
    assert len(scene.furniture_boxes(room)) == 2


def test_is_lamp_words():
    assert is_lamp("Pendant Lamp") and is_lamp("", "floor lamp") and is_lamp("Ceiling Lamp")
    assert not is_lamp("King-size Bed", "bed")


def _expect_error(tmp_path, house, match, **opts):
    path = write(tmp_path, house)
    with pytest.raises(Front3DError, match=match) as info:
        load_house(path, LoadOptions(**opts))
    assert str(path) in str(info.value)  # every error names the file


def test_invalid_json_and_missing_file(tmp_path):
    bad = tmp_path / "bad.json"
    bad.write_text("{not json")
    with pytest.raises(Front3DError, match=r"bad\.json: invalid JSON"):
        load_house(bad)
    with pytest.raises(Front3DError, match="no such file"):
        load_house(tmp_path / "missing.json")


@pytest.mark.parametrize(
    "mutate, match",
    [
        (lambda h: h.pop("mesh"), r"top level: missing key 'mesh'"),
        (lambda h: h["mesh"][0].pop("type"), r"mesh\[0\] \(floor-1\): missing key 'type'"),
        (lambda h: h["mesh"][0]["faces"].__setitem__(0, 99), r"mesh\[0\] \(floor-1\)\.faces: index 99 out of range"),
        (lambda h: h["mesh"][0]["faces"].__setitem__(0, 0.5), r"faces: face indices must be integers"),
        (lambda h: h["mesh"][0]["xyz"].__setitem__(4, float("nan")), r"floor-1\)\.xyz: non-finite value"),
        (lambda h: h["mesh"][0]["xyz"].pop(), r"floor-1\)\.xyz: length 17 is not a multiple of 3"),
        (lambda h: h["mesh"][0].__setitem__("material", "nope"), r"unknown material 'nope'"),
        (lambda h: h["material"][0].__setitem__("color", [1, 2]), r"material\[0\] \(m-floor\)\.color: expected"),
        (lambda h: h["material"][1].__setitem__("roughness", 2.0), r"roughness: must be in \[0, 1\]"),
        (lambda h: h["scene"]["room"][0]["children"][2].__setitem__("rot", [0, 0, 0, 0]),
         r"children\[2\]\.rot: quaternion"),
        (lambda h: h["scene"]["room"][0]["children"][2].__setitem__("scale", [1, 0, 1]),
         r"children\[2\]\.scale: scale must be positive"),
        (lambda h: h["mesh"][0].__setitem__("xyz", [0.0] * 18), r"zero-area room"),
        (lambda h: h["scene"]["room"][0]["children"].append({"ref": "ghost", "instanceid": "g"}),
         r"unknown ref 'ghost'"),
        # wrong types: one line naming the entry, not a traceback
        (lambda h: h.__setitem__("material", 3), r"house\.json: material: expected a list, got int"),
        (lambda h: h.__setitem__("furniture", None), r"furniture: expected a list, got NoneType"),
        (lambda h: h["scene"].__setitem__("room", 1), r"scene\.room: expected a list, got int"),
        (lambda h: h["scene"]["room"].__setitem__(0, "room"), r"scene\.room\[0\]: expected an object, got str"),
        (lambda h: h["scene"]["room"][0].__setitem__("children", 5), r"\(Bedroom-1\)\.children: expected a list"),
        (lambda h: h["material"][1].__setitem__("roughness", None), r"roughness: expected a finite number, got None"),
        (lambda h: h["material"][1].__setitem__("metallic", 10**400),
         r"metallic: expected a finite number, got 1000"),
        (lambda h: h["mesh"][0]["xyz"].__setitem__(0, 10**400), r"floor-1\)\.xyz: not a list of numbers"),
        # duplicated ids would replace or mix objects
        (lambda h: h["material"].append(dict(h["material"][0])), r"material\[2\] \(m-floor\): uid 'm-floor' "
                                                                   r"repeats material\[0\]'s"),
        (lambda h: h["mesh"].append(dict(h["mesh"][0])), r"mesh\[2\] \(floor-1\): uid 'floor-1' repeats mesh\[0\]'s"),
        (lambda h: h["scene"]["room"].append(copy.deepcopy(h["scene"]["room"][0])),
         r"scene\.room\[1\] \(Bedroom-1\): instanceid 'Bedroom-1' repeats scene\.room\[0\]'s"),
        (lambda h: h["scene"]["room"][0]["children"][3].__setitem__("instanceid", "c2"),
         r"children\[3\]: instanceid 'c2' repeats .*children\[2\]'s"),
        # files named outside the models and textures roots
        (lambda h: h["furniture"][0].__setitem__("jid", "../outside"), r"furniture \(f-cab\)\.jid: '\.\./outside' "
                                                                        r"is not a plain name"),
        (lambda h: h["furniture"][0].__setitem__("jid", "/etc"), r"jid: '/etc' is not a plain name"),
        (lambda h: h["material"][0].update(texture="t.png", jid="../../x"), r"material\[0\] \(m-floor\)\.jid: "
                                                                           r"'\.\./\.\./x' is not a plain name"),
        # geometry beyond any house
        (lambda h: h["scene"]["room"][0]["children"][2].__setitem__("scale", [1e308] * 3),
         r"children\[2\]: its scale .* more than 1e\+05 m from the origin"),
        (lambda h: h["mesh"][0].__setitem__("xyz", [v * 1e200 for v in h["mesh"][0]["xyz"]]),
         r"floor-1\)\.xyz: a vertex lies 4e\+200 m from the origin"),
        (lambda h: h["mesh"][0].update(xyz=_flat([(x, 0, 0) for x in range(6)] + [(0, 0, 1e-5)])[:18]),
         r"zero-area room"),
    ],
)
def test_error_paths_name_file_entry_and_problem(tmp_path, mutate, match):
    house, root = make_house(tmp_path)
    house = copy.deepcopy(house)
    mutate(house)
    _expect_error(root, house, match)


def test_missing_model_and_texture_are_listed_and_skippable(tmp_path):
    house, root = make_house(tmp_path)
    house["material"][0]["texture"] = "https://example.invalid/tex-floor/texture.png"
    (root / "models" / "model-lamp" / "raw_model.obj").unlink()
    path = write(root, house)
    with pytest.raises(Front3DError, match=r"2 missing item\(s\)") as info:
        load_house(path)
    message = str(info.value)
    assert "model 'model-lamp'" in message and "texture of material[0] (m-floor)" in message
    scene = load_house(path, LoadOptions(allow_missing=True))
    assert "Bedroom-1/c3" not in {o.name for o in scene.objects}
    assert scene.room().floor_area() == pytest.approx(10.0, abs=1e-3)
    # the texture is found once it exists where 3D-FRONT-texture keeps it
    (root / "textures" / "tex-floor").mkdir(parents=True)
    from PIL import Image

    Image.new("RGB", (4, 4)).save(root / "textures" / "tex-floor" / "texture.png")
    scene = load_house(path, LoadOptions(allow_missing=True))
    assert scene.objects[0].material.texture == root / "textures" / "tex-floor" / "texture.png"


def test_uv_transform_applied(tmp_path):
    house, root = make_house(tmp_path)
    house["material"][0]["UVTransform"] = [2, 0, 0.5, 0, 3, 0, 0, 0, 1]
    scene = load_house(write(root, house))
    floor = next(o for o in scene.objects if o.name == "floor-1")
    np.testing.assert_allclose(floor.uvs[1], [2 * 4 + 0.5, 0.0])
    np.testing.assert_allclose(floor.uvs[5], [0.5, 9.0])


def test_bad_model_files_and_textures_name_the_file(tmp_path):
    """An MTL line with a non-finite or short value, a map_Kd leaving the model's folder and a texture that does not
    decode (Blender would render it magenta) are each one line naming the file."""
    house, root = make_house(tmp_path)
    mtl = root / "models" / "model-cab" / "model.mtl"
    for text, match in (("newmtl m\nPr nan\n", r"model\.mtl: line 2: Pr must be finite"),
                        ("newmtl m\nKd 0.5\n", r"model\.mtl: line 2: cannot parse 'Kd 0\.5'"),
                        ("newmtl m\nKd 0.5 0.5 inf\n", r"model\.mtl: line 2: Kd must be finite"),
                        ("newmtl m\nmap_Kd ../../tex.png\n", r"line 2: map_Kd '\.\./\.\./tex\.png' leaves the "
                                                            r"model's folder")):
        mtl.write_text(text)
        with pytest.raises(Front3DError, match=match):
            load_house(write(root, house))
    mtl.write_text(MTL)
    (root / "models" / "model-cab" / "texture.png").write_bytes(b"this is not a png")
    with pytest.raises(Front3DError, match=r"model-cab/texture\.png: texture does not decode as an image"):
        load_house(write(root, house))


def test_a_room_the_camera_path_does_not_fit_is_named(tmp_path):
    """The trajectory's refusals (a room too small for the camera's margin) name the house file and the room."""
    from simulator.render_pipeline import RenderConfig, plan_poses
    from spotlessgs.io.errors import InputError

    house, root = make_house(tmp_path, lamp=True)
    for mesh in house["mesh"]:  # the L-shaped room shrunk to 0.8 m x 0.6 m (the ceiling stays 2.8 m up)
        mesh["xyz"] = [v * 0.2 if axis != 1 else v for v, axis in zip(mesh["xyz"], [0, 1, 2] * 6)]
    house["scene"]["room"][0]["children"] = house["scene"]["room"][0]["children"][:2]
    path = write(root, house)
    with pytest.raises(InputError, match=rf"{re.escape(str(path))} room Bedroom-1: .*too small"):
        plan_poses(path, RenderConfig(frames=4, width=16, height=12, samples=1), LoadOptions())
