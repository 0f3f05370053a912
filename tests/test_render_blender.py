"""A tiny paired render of a shipped room with Blender: image statistics, geometric and light-pose consistency, resume.

Marked `blender`; it stays in the default suite because the renders are tiny (64x48, 4 samples, 6 frames).
"""

from __future__ import annotations

import json
import os
import shutil
import subprocess
from pathlib import Path

import numpy as np
import pytest

pytestmark = pytest.mark.blender

ROOT = Path(__file__).resolve().parents[1]
SCENE = ROOT / "scenes" / "bedroom" / "house.json"
TINY = dict(frames=6, width=64, height=48, samples=4, seed=3)


def _render(out, **overrides):
    from simulator.render_pipeline import ExecutionOptions, RenderConfig, render_dataset

    kwargs = {**TINY, **overrides}
    shard = kwargs.pop("shard", (0, 1))
    preset = kwargs.pop("preset", "uneven")
    config = RenderConfig.from_preset(preset, **kwargs)
    return render_dataset(SCENE, out, config, execution=ExecutionOptions(shard=shard, progress=False))


@pytest.fixture(scope="module")
def dataset(tmp_path_factory):
    out = tmp_path_factory.mktemp("render") / "bedroom"
    summary = _render(out)
    assert summary == {**summary, "rendered": 6, "skipped": 0, "complete": True,
                       "dark_frames": {"gt": [], "images": [], "empty": []}}
    return out


def _load(dataset):
    from spotlessgs.io.transforms import read_transforms

    return read_transforms(dataset / "transforms.json")


def test_dataset_files_and_split(dataset):
    desc = _load(dataset)
    assert desc.n_frames == 6
    assert list(desc.split.test) == [0] and list(desc.split.train) == [1, 2, 3, 4, 5]
    for k in range(6):
        for sub, ext in (("images", "png"), ("gt", "png"), ("exr", "exr")):
            assert (dataset / sub / f"frame_{k:05d}.{ext}").is_file()
    assert (dataset / "points3d.ply").is_file()
    meta = json.loads((dataset / "transforms.json").read_text())["spotless"]
    assert meta["seed"] == 3 and meta["preset"] == "uneven"
    assert meta["provenance"]["blender_version"].startswith("5.0")


def test_uneven_images_are_less_uniform_than_ground_truth(dataset):
    from spotlessgs.io.images import read_image

    def variation(img):
        lum = img.mean(axis=2)
        return lum.std() / max(lum.mean(), 1e-6)

    cv_uneven = np.mean([variation(read_image(p)) for p in sorted((dataset / "images").glob("*.png"))])
    cv_gt = np.mean([variation(read_image(p)) for p in sorted((dataset / "gt").glob("*.png"))])
    assert cv_uneven > 1.5 * cv_gt, (cv_uneven, cv_gt)
    # the spotlight leaves the image corners darker than the centre
    img = np.mean([read_image(p).mean(axis=2) for p in sorted((dataset / "images").glob("*.png"))], axis=0)
    h, w = img.shape
    centre = img[h // 3: 2 * h // 3, w // 3: 2 * w // 3].mean()
    corners = np.mean([img[:6, :8].mean(), img[:6, -8:].mean(), img[-6:, :8].mean(), img[-6:, -8:].mean()])
    assert centre > 2.0 * corners, (centre, corners)


def _world_points(desc, k, exr):
    """Back-project frame k's depth with independent pinhole maths: (H, W, 3) world points (OpenCV pose)."""
    intr = desc.intrinsics
    h, w = exr.depth.shape
    u, v = np.meshgrid(np.arange(w) + 0.5, np.arange(h) + 0.5)
    cam = np.stack([(u - intr.cx) / intr.fx, (v - intr.cy) / intr.fy, np.ones_like(u)], -1) * exr.depth[..., None]
    c2w = desc.c2w_opencv[k]
    return cam @ c2w[:3, :3].T + c2w[:3, 3]


def test_poses_intrinsics_and_depth_agree_with_the_room_geometry(dataset):
    """Pixels whose normal points up are floor pixels: back-projected, they must lie on the floor plane z = 0."""
    from simulator.front3d import load_house
    from spotlessgs.io.exr import read_frame_exr

    desc = _load(dataset)
    room = load_house(SCENE).room()
    checked = 0
    for k in range(desc.n_frames):
        exr = read_frame_exr(dataset / "exr" / f"frame_{k:05d}.exr")
        pts = _world_points(desc, k, exr)
        floor = (exr.normal[..., 2] > 0.95) & np.isfinite(exr.depth)
        # exclude pixels within a pixel of a depth edge (tops of furniture also face up, but sit higher)
        low = floor & (pts[..., 2] < room.floor_z + 0.05)
        if low.sum() < 20:
            continue
        checked += 1
        assert np.median(np.abs(pts[low][:, 2] - room.floor_z)) < 0.01
        # and floor points lie inside the room outline
        from shapely.geometry import Point, Polygon

        outline = Polygon(room.floor_polygon).buffer(0.05)
        assert all(outline.contains(Point(p[0], p[1])) for p in pts[low][::7])
    assert checked >= 3


def test_light_pose_in_transforms_matches_the_lit_pixels(dataset):
    """Pixels inside the recorded spotlight cone are much brighter (per unit of ground-truth albedo) than outside."""
    from spotlessgs.io.exr import read_frame_exr

    desc = _load(dataset)
    light = desc.light
    inside, outside = [], []
    for k in range(desc.n_frames):
        exr = read_frame_exr(dataset / "exr" / f"frame_{k:05d}.exr")
        pts = _world_points(desc, k, exr)
        c2w = desc.c2w_opencv[k]
        cam = (pts - c2w[:3, 3]) @ c2w[:3, :3]  # world -> camera
        x_l = (cam - light.position_in_camera) @ light.rotation_in_camera  # camera -> light: R^T (x - t)
        theta = np.degrees(np.arctan2(np.linalg.norm(x_l[..., :2], axis=-1), x_l[..., 2]))
        ok = np.isfinite(exr.depth)
        lum = exr.uneven.mean(axis=2) / np.maximum(exr.gt.mean(axis=2), 1e-3)
        inside.append(lum[ok & (theta < light.cone_angle_deg * 0.25)])
        outside.append(lum[ok & (theta > light.cone_angle_deg * 0.6)])
    inside, outside = np.concatenate(inside), np.concatenate(outside)
    assert inside.size > 50 and outside.size > 50
    assert np.median(inside) > 4.0 * np.median(outside), (np.median(inside), np.median(outside))


def test_rerun_resumes_and_renders_only_missing_frames(dataset):
    before = {p: p.stat().st_mtime_ns for p in dataset.rglob("frame_*")}
    summary = _render(dataset)
    assert summary["rendered"] == 0 and summary["skipped"] == 6 and summary["complete"]
    (dataset / "images" / "frame_00004.png").unlink()
    summary = _render(dataset)
    assert summary["rendered"] == 1 and summary["skipped"] == 5
    after = {p: p.stat().st_mtime_ns for p in dataset.rglob("frame_*")}
    changed = sorted(p.name for p in before if after.get(p) != before[p])
    assert changed == ["frame_00004.exr", "frame_00004.png", "frame_00004.png"]


def test_other_settings_in_the_same_folder_are_refused(dataset):
    from simulator.render_pipeline import DatasetFolderError

    with pytest.raises(DatasetFolderError, match="differs in: samples"):
        _render(dataset, samples=8)
    with pytest.raises(DatasetFolderError, match="differs in: lambertian"):
        _render(dataset, lambertian=True)


def test_a_dataset_resumes_from_a_copy_of_its_scene_elsewhere_and_refuses_another_scene(dataset, tmp_path):
    """The scene is identified by its content: the same house.json from another checkout resumes (nothing is
    rendered again) and the plan is brought up to date; a plan written before the content hash resumes when the file
    it names has the same content, and is refused when that file is gone; an edited scene is refused, naming it."""
    from simulator.render_pipeline import DatasetFolderError, ExecutionOptions, RenderConfig, render_dataset

    copy = shutil.copytree(dataset, tmp_path / "copy")
    moved_scene = shutil.copytree(SCENE.parent, tmp_path / "checkout" / "bedroom") / "house.json"

    def render(scene):
        config = RenderConfig.from_preset("uneven", **TINY)
        return render_dataset(scene, copy, config, execution=ExecutionOptions(progress=False))

    assert render(moved_scene)["rendered"] == 0
    plan = json.loads((copy / "plan.json").read_text())
    assert plan["fingerprint"]["scene"] == str(moved_scene.resolve())
    old = {**plan, "fingerprint": {k: v for k, v in plan["fingerprint"].items() if k != "scene_sha256"}}
    (copy / "plan.json").write_text(json.dumps(old))  # an older plan, naming the moved copy
    assert render(SCENE)["rendered"] == 0
    assert "scene_sha256" in json.loads((copy / "plan.json").read_text())["fingerprint"]
    old["fingerprint"]["scene"] = str(tmp_path / "gone" / "house.json")  # ... from a checkout since removed
    (copy / "plan.json").write_text(json.dumps(old))
    with pytest.raises(DatasetFolderError, match=r"scene: .*gone/house\.json then, .* cannot be compared"):
        render(SCENE)
    (copy / "plan.json").write_text(json.dumps(plan))  # the plan with the content hash
    # the same house.json with other textures: another room as loaded, refused; a plan from before the room's hash
    # resumes and records it
    from PIL import Image

    textures = sorted((moved_scene.parent / "textures").rglob("*.png"))
    kept = {t: t.read_bytes() for t in textures}
    for texture in textures:
        pixels = np.asarray(Image.open(texture).convert("RGB")).copy()
        pixels[0, 0] = 255 - pixels[0, 0]
        Image.fromarray(pixels).save(texture)
    with pytest.raises(DatasetFolderError, match=r"differs in: the room's models or textures"):
        render(moved_scene)
    for texture, data in kept.items():
        texture.write_bytes(data)
    stripped = {**plan, "fingerprint": {k: v for k, v in plan["fingerprint"].items() if k != "room_sha256"}}
    (copy / "plan.json").write_text(json.dumps(stripped))
    assert render(moved_scene)["rendered"] == 0
    assert json.loads((copy / "plan.json").read_text())["fingerprint"]["room_sha256"] == plan["fingerprint"]["room_sha256"]
    edited = json.loads(moved_scene.read_text())
    edited["uid"] = "another"
    moved_scene.write_text(json.dumps(edited))
    with pytest.raises(DatasetFolderError, match=r"differs in: scene: .*another file content"):
        render(moved_scene)


def test_shards_render_disjoint_parts_and_complete_together(tmp_path):
    out = tmp_path / "sharded"
    first = _render(out, frames=3, shard=(0, 2))
    assert first["rendered"] == 2 and not first["complete"]
    assert not (out / "transforms.json").exists()
    second = _render(out, frames=3, shard=(1, 2))
    assert second["rendered"] == 1 and second["complete"]
    assert (out / "transforms.json").is_file()
    import pycolmap

    rec = pycolmap.Reconstruction(str(out / "sparse" / "0"))
    assert rec.num_images() == 3
    assert os.path.getsize(out / "points3d.ply") > 0


def _look_at_blender(eye, target) -> np.ndarray:
    """(4, 4) camera-to-world in the Blender convention (camera looks along -z, y up) from ``eye`` to ``target``."""
    eye, target = np.asarray(eye, float), np.asarray(target, float)
    back = eye - target
    back /= np.linalg.norm(back)
    right = np.cross([0.0, 1.0, 0.0] if abs(back[2]) > 0.99 else [0.0, 0.0, 1.0], back)
    right /= np.linalg.norm(right)
    up = np.cross(back, right)
    c2w = np.eye(4)
    c2w[:3, 0], c2w[:3, 1], c2w[:3, 2], c2w[:3, 3] = right, up, back, eye
    return c2w


def _floor_radiance_from_two_directions(lambertian: bool) -> tuple[float, float, np.ndarray, np.ndarray]:
    """Lamp-lit radiance of one floor point seen from straight above and from a grazing 20 deg elevation, and the
    albedo (diffuse colour) pass at that point seen from above.

    The floor is a glossy metal (roughness 0.3, metallic 1) and there is no bounce light, so only the material model
    decides whether the two radiances agree.
    """
    from simulator.blender import renderer, scene_builder
    from simulator.lighting import SpotlightConfig
    from simulator.scene_model import LightFixture, Material, MeshObject, Scene
    from spotlessgs.io.cameras import Intrinsics

    scene_builder.reset_blender()
    settings = renderer.CyclesSettings(width=24, height=18, samples=64, denoise=False, max_bounces=0, threads=2)
    renderer.configure(settings)
    floor = MeshObject(
        name="floor", source="test", category="Floor",
        vertices=np.array([[-5, -5, 0], [5, -5, 0], [5, 5, 0], [-5, 5, 0]], float),
        faces=np.array([[0, 1, 2], [0, 2, 3]]),
        material=Material(name="brushed_steel", base_color=(0.6, 0.6, 0.6), roughness=0.3, metallic=1.0),
    )
    scene = Scene(scene_id="plane", source=Path("plane"), objects=[floor],
                  lights=[LightFixture(name="lamp", kind="point", position=(0.0, 0.0, 1.0), power_w=60.0, size=0.05)],
                  rooms=[])
    built = scene_builder.build_scene(scene, SpotlightConfig(), 0.0, Intrinsics.from_fov(30.0, 24, 18),
                                      lambertian=lambertian)
    target = np.array([0.4, 0.0, 0.0])
    radiance, albedo, glossy = [], [], []
    for eye in (target + [0.0, 0.0, 2.0], target + 2.0 * np.array([np.cos(np.radians(20)), 0.0,
                                                                    np.sin(np.radians(20))])):
        pair = renderer.render_pair(built, _look_at_blender(eye, target), settings, seed=0)
        radiance.append(float(pair.gt[7:11, 10:14].mean()))  # the pixels around the image centre = the target
        albedo.append(pair.albedo[7:11, 10:14].reshape(-1, 3).mean(0))
        glossy.append(pair.glossy[7:11, 10:14].reshape(-1, 3).mean(0))
    return radiance[0], radiance[1], albedo[0], glossy[0]


def test_lambertian_option_makes_radiance_independent_of_the_view_direction():
    """An ideal diffuse reflector has the same radiance in every direction; Blender's metal does not."""
    top, grazing, albedo, glossy = _floor_radiance_from_two_directions(lambertian=True)
    assert top > 0.05 and abs(grazing / top - 1.0) < 0.05, (top, grazing)
    # the albedo pass is the base colour 0.6 of the (now diffuse) floor, which has no specular layer; a metal has no
    # diffuse colour, and its glossy colour is its specular reflectance: about its base colour, seen from above
    np.testing.assert_allclose(albedo, 0.6, atol=0.01)
    np.testing.assert_allclose(glossy, 0.0, atol=0.01)
    top, grazing, albedo, glossy = _floor_radiance_from_two_directions(lambertian=False)
    assert abs(grazing / top - 1.0) > 0.3, (top, grazing)
    np.testing.assert_allclose(albedo, 0.0, atol=0.01)
    assert np.all((glossy > 0.45) & (glossy < 0.7)), glossy


def test_every_frame_stores_the_albedo_and_the_glowing_lamps_of_the_ground_truth(dataset):
    """The EXR of each frame holds the albedo pass (in [0, 1]) and the ground truth's emission; the lamps it marks
    (FrameEXR.emitters) cover 0.5-10 % of a frame of the bedroom and are the brightest part of its ground truth."""
    from spotlessgs.io.exr import read_frame_exr

    shares = []
    for path in sorted((dataset / "exr").glob("*.exr")):
        frame = read_frame_exr(path)
        assert frame.albedo is not None and frame.emission is not None
        assert frame.albedo.min() >= 0.0 and frame.albedo.max() <= 1.0 + 1e-6
        lamps = frame.emitters()
        shares.append(float(lamps.mean()))
        if lamps.any():
            luminance = frame.gt.mean(-1)
            assert np.median(luminance[lamps]) > 2.0 * np.percentile(luminance[~lamps], 90)
    assert 0.005 < np.mean(shares) < 0.10, shares


# ---------------------------------------------------------------------------------------------------------------------
# Degenerate rooms, quiet output, outputs that overlap the inputs


def _box_room(folder: Path, ceiling: bool = False, band_below_floor: bool = False) -> Path:
    """A 4 m x 4 m room of a floor and four walls (3D-FRONT format, y up, no furniture) in ``folder``.

    ``ceiling``: add a ceiling mesh; ``band_below_floor``: add a LightBand strip 30 cm *under* the floor, so that the
    room has a light for the ground truth that lights nothing the camera sees. Returns the house file.
    """
    quads = {
        "floor": ("Floor", [0, 0, 0, 4, 0, 0, 4, 0, 4, 0, 0, 4]),
        "wall-a": ("WallInner", [0, 0, 0, 4, 0, 0, 4, 2.6, 0, 0, 2.6, 0]),
        "wall-b": ("WallInner", [0, 0, 4, 4, 0, 4, 4, 2.6, 4, 0, 2.6, 4]),
        "wall-c": ("WallInner", [0, 0, 0, 0, 0, 4, 0, 2.6, 4, 0, 2.6, 0]),
        "wall-d": ("WallInner", [4, 0, 0, 4, 0, 4, 4, 2.6, 4, 4, 2.6, 0]),
    }
    if ceiling:
        quads["ceiling"] = ("Ceiling", [0, 2.6, 0, 4, 2.6, 0, 4, 2.6, 4, 0, 2.6, 4])
    if band_below_floor:
        quads["band"] = ("LightBand", [1.5, -0.3, 1.5, 2.5, -0.3, 1.5, 2.5, -0.3, 2.5, 1.5, -0.3, 2.5])
    house = {
        "uid": "box-room",
        "material": [{"uid": "plaster", "color": [200, 200, 200, 255], "roughness": 0.9}],
        "mesh": [{"uid": uid, "type": kind, "material": "plaster", "xyz": xyz, "faces": [0, 1, 2, 0, 2, 3]}
                 for uid, (kind, xyz) in quads.items()],
        "furniture": [],
        "scene": {"room": [{"type": "Bedroom", "instanceid": "Box-1",
                            "children": [{"ref": uid, "instanceid": uid} for uid in quads]}]},
    }
    folder.mkdir(parents=True, exist_ok=True)
    path = folder / "house.json"
    path.write_text(json.dumps(house))
    return path


@pytest.mark.parametrize("ceiling", [False, True], ids=["floor-and-walls", "ceiling-without-glow"])
def test_a_room_without_light_for_the_ground_truth_is_refused_before_anything_is_written(tmp_path, ceiling):
    """A room of only a floor and walls (or with a ceiling but the ceiling glow off) would render 100 % black ground
    truth: refused with the scene file named, before the output folder is created."""
    import dataclasses

    from simulator.lighting import GroundTruthLighting
    from simulator.render_pipeline import ExecutionOptions, RenderConfig, render_dataset
    from spotlessgs.io.errors import InputError

    scene = _box_room(tmp_path / "scene", ceiling=ceiling)
    config = RenderConfig(**{**TINY, "frames": 2})
    if ceiling:
        config = dataclasses.replace(config, ground_truth=GroundTruthLighting(ceiling_glow=0.0))
    out = tmp_path / "out"
    with pytest.raises(InputError, match="has no light for the ground-truth render") as err:
        render_dataset(scene, out, config, execution=ExecutionOptions(progress=False))
    assert str(scene) in str(err.value) and "Box-1" in str(err.value)
    assert not out.exists()


def test_a_room_without_visible_geometry_is_refused():
    from simulator.render_pipeline import RenderConfig, check_scene
    from simulator.scene_model import LightFixture, Room
    from spotlessgs.io.errors import InputError

    room = Room("Empty-1", "Bedroom", np.array([[0, 0], [4, 0], [4, 4], [0, 4]], float), 0.0, 2.6)
    lamp = LightFixture("lamp", "point", (2.0, 2.0, 2.0), 60.0)
    with pytest.raises(InputError, match=r"scene.json: room 'Empty-1' has no visible geometry"):
        check_scene(Path("scene.json"), room, [], [lamp], RenderConfig())


def test_black_ground_truth_in_every_frame_is_an_error_and_the_dataset_is_not_finished(tmp_path):
    """The room has a light, but it lights nothing the camera sees: the frames are rendered (and kept), then the
    dataset is refused, without transforms.json, also when the command is run again."""
    from simulator.render_pipeline import ExecutionOptions, RenderConfig, render_dataset
    from spotlessgs.io.errors import InputError

    scene = _box_room(tmp_path / "scene", band_below_floor=True)
    out = tmp_path / "out"
    config = RenderConfig(**{**TINY, "frames": 2})
    for _ in range(2):
        with pytest.raises(InputError, match=r"ground truth \(evenly lit render\) of every frame is \(almost\) all "
                                             "black") as err:
            render_dataset(scene, out, config, execution=ExecutionOptions(progress=False))
        assert str(scene) in str(err.value) and "no transforms.json" in str(err.value)
        assert sorted(p.name for p in (out / "gt").iterdir()) == ["frame_00000.png", "frame_00001.png"]
        for name in ("transforms.json", "points3d.ply", "sparse"):
            assert not (out / name).exists()


def test_frame_checks_name_black_frames_in_one_warning_line_each(caplog):
    from simulator.render_pipeline import dark_frames, frame_check, warn_dark_frames

    lit = np.full((12, 16, 3), 0.2, np.float32)
    black = np.zeros_like(lit)
    specks = black.copy()
    specks[0, 0] = 1.0  # 1 lit pixel of 192: still (almost) all black
    depth = np.ones((12, 16), np.float32)
    checks = {
        0: frame_check(lit, lit, depth),
        1: frame_check(lit, black, depth),
        2: frame_check(specks, specks, np.full_like(depth, np.inf)),
    }
    assert checks[0] == {"gt_dark": False, "image_dark": False, "empty": False}
    assert checks[2] == {"gt_dark": True, "image_dark": True, "empty": True}
    report = dark_frames(checks)
    assert report == {"gt": ["frame_00001", "frame_00002"], "images": ["frame_00002"], "empty": ["frame_00002"]}
    with caplog.at_level("WARNING"):
        warn_dark_frames(report, "OUT", 3)
    lines = [r.getMessage() for r in caplog.records]
    assert lines == [
        "OUT: 2 of 3 frame(s) with an (almost) all-black ground truth (evenly lit render): frame_00001, frame_00002",
        "OUT: 1 of 3 frame(s) with an (almost) all-black spotlight-only image: frame_00002",
        "OUT: 1 of 3 frame(s) with no geometry in view: frame_00002",
    ]


def _cli(*args: str, timeout: float = 300) -> subprocess.CompletedProcess[str]:
    import sys

    return subprocess.run([sys.executable, "-m", "simulator.cli", *args], capture_output=True, text=True,
                          timeout=timeout, cwd=ROOT)


def test_quiet_render_prints_nothing_from_blender(tmp_path):
    """`-q` silences what Blender's C code prints while probing the devices ("... cycles | WARNING CUEW
    initialization failed" on a machine without CUDA): stdout is the summary line, stderr has only the project's own
    log lines (none on a machine without a GPU)."""
    out = tmp_path / "quiet"
    proc = _cli("render", "--scene", str(SCENE), "--out", str(out), "--frames", "2", "--width", "64", "--height", "48",
                "--samples", "4", "--device", "auto", "-q")
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout.splitlines() == [f"{out}: rendered 2, skipped 0 finished frame(s); dataset complete"]
    assert all(line.startswith("INFO simulator.") for line in proc.stderr.splitlines()), proc.stderr


def test_render_refuses_an_output_that_holds_the_scene(tmp_path):
    """OUT equal to the scene's folder, containing the scene file or inside its model folder is refused (exit 2)
    before anything is written; a folder inside the scene's folder is fine (here it stops at the missing light)."""
    scene = _box_room(tmp_path / "rooms" / "box")
    (scene.parent / "models").mkdir()
    before = sorted(p.relative_to(tmp_path) for p in tmp_path.rglob("*"))
    common = ["--frames", "2", "--width", "64", "--height", "48", "--samples", "4", "-q"]
    for out, words in ((scene.parent, "contains the input --scene"), (tmp_path / "rooms", "contains the input --scene"),
                       (scene.parent / "models" / "data", "inside the input --future-dir")):
        proc = _cli("render", "--scene", str(scene), "--out", str(out), *common)
        assert proc.returncode == 2, (out, proc.stdout, proc.stderr)
        assert words in proc.stderr and len(proc.stderr.strip().splitlines()) == 1, proc.stderr
        assert sorted(p.relative_to(tmp_path) for p in tmp_path.rglob("*")) == before
    proc = _cli("render", "--scene", str(scene), "--out", str(scene.parent / "renders"), *common)
    assert proc.returncode == 2 and "has no light for the ground-truth render" in proc.stderr, proc.stderr


def test_motion_blur_blurs_the_input_and_leaves_the_ground_truth_and_geometry_sharp(tmp_path):
    """Four frames of the paper loop (a quarter turn between frames): with the shutter open the whole time between
    two frames the spotlit inputs lose detail (less gradient energy), while the ground truth, depth and normals are
    those of the sharp render."""
    from spotlessgs.io.exr import read_frame_exr
    from spotlessgs.io.images import read_image

    sharp, blurred = tmp_path / "sharp", tmp_path / "blurred"
    _render(sharp, frames=4)
    _render(blurred, frames=4, motion_blur=1.0)
    energy = {}
    for name, folder in (("sharp", sharp), ("blurred", blurred)):
        images = np.stack([read_image(p) for p in sorted((folder / "images").glob("*.png"))])
        energy[name] = float((np.diff(images, axis=2) ** 2).mean() + (np.diff(images, axis=1) ** 2).mean())
    assert energy["blurred"] < 0.8 * energy["sharp"], energy
    for k in range(4):
        a = read_frame_exr(sharp / "exr" / f"frame_{k:05d}.exr")
        b = read_frame_exr(blurred / "exr" / f"frame_{k:05d}.exr")
        np.testing.assert_allclose(b.gt, a.gt, atol=1e-5)
        np.testing.assert_array_equal(b.depth, a.depth)
        np.testing.assert_allclose(b.normal, a.normal, atol=1e-6)
    renderer = json.loads((blurred / "transforms.json").read_text())["spotless"]["renderer"]
    assert renderer["motion_blur"] == 1.0
    assert "motion_blur" not in json.loads((sharp / "transforms.json").read_text())["spotless"]["renderer"]


def test_the_uniform_ground_truth_is_the_albedo_without_shadows_and_restores_the_scene():
    """A Lambertian floor (albedo 0.6) under a ceiling that closes it off from the world: the lamps-on render sees
    only the lamp; the uniform ground truth is the albedo times the environment's radiance 1 everywhere, as if the
    ceiling cast no shadow and the lamp were off. Afterwards every setting the uniform render changed is back."""
    import bpy

    from simulator.blender import renderer, scene_builder
    from simulator.lighting import SpotlightConfig
    from simulator.scene_model import LightFixture, Material, MeshObject, Scene
    from spotlessgs.io.cameras import Intrinsics

    scene_builder.reset_blender()
    settings = renderer.CyclesSettings(width=24, height=18, samples=64, denoise=False, max_bounces=3, threads=2,
                                       uniform_gt=True)
    renderer.configure(settings)

    def plane(name: str, z: float, half: float, material: Material) -> MeshObject:
        return MeshObject(name=name, source="test", category=name,
                          vertices=np.array([[-half, -half, z], [half, -half, z], [half, half, z], [-half, half, z]],
                                            float), faces=np.array([[0, 1, 2], [0, 2, 3]]), material=material)

    grey = Material(name="grey", base_color=(0.6, 0.6, 0.6), roughness=0.9)
    glowing = Material(name="lamp", base_color=(1.0, 1.0, 1.0), emission=5.0, emission_color=(1.0, 1.0, 1.0))
    scene = Scene(scene_id="closed", source=Path("closed"), rooms=[],
                  objects=[plane("Floor", 0.0, 5.0, grey), plane("Ceiling", 2.0, 5.0, grey),
                           plane("lamp", 1.9, 0.05, glowing)],
                  lights=[LightFixture(name="bulb", kind="point", position=(2.0, 0.0, 1.5), power_w=30.0, size=0.05)])
    built = scene_builder.build_scene(scene, SpotlightConfig(), 0.0, Intrinsics.from_fov(30.0, 24, 18),
                                      lambertian=True)
    pair = renderer.render_pair(built, _look_at_blender([0.0, 0.0, 1.0], [0.0, 0.0, 0.0]), settings, seed=0)
    assert pair.gt_uniform is not None and pair.gt_uniform.shape == pair.gt.shape
    np.testing.assert_allclose(pair.gt_uniform.mean(axis=(0, 1)), 0.6, atol=0.02)  # albedo x 1, no shadow
    assert pair.gt_uniform.std() < 0.03  # even: no fall-off, no hot spot
    np.testing.assert_allclose(pair.albedo, 0.6, atol=0.01)
    assert pair.gt.max() > 0.05 and pair.gt.std() > 0.01  # the lamps-on render: lit by the bulb, uneven
    scene_state = bpy.context.scene
    assert all(ob.visible_shadow and ob.visible_diffuse and ob.visible_glossy for ob in built.meshes)
    background = scene_state.world.node_tree.nodes["Background"].inputs["Strength"].default_value
    assert background == 0.0


def test_the_uniform_ground_truth_of_a_metal_is_its_diffuse_plus_glossy_colour():
    """What a surface reflects of the uniform ground truth's even light is the sum of the renderer's diffuse and glossy
    colour passes (FrameEXR.reflectance, the ceiling's oracle), for a metal too, whose diffuse colour is zero."""
    from simulator.blender import renderer, scene_builder
    from simulator.lighting import SpotlightConfig
    from simulator.scene_model import LightFixture, Material, MeshObject, Scene
    from spotlessgs.io.cameras import Intrinsics

    scene_builder.reset_blender()
    settings = renderer.CyclesSettings(width=24, height=18, samples=64, denoise=False, max_bounces=3, threads=2,
                                       uniform_gt=True)
    renderer.configure(settings)
    metal = Material(name="gold", base_color=(0.9, 0.6, 0.2), roughness=0.4, metallic=1.0)
    floor = MeshObject(name="Floor", source="test", category="Floor",
                       vertices=np.array([[-5, -5, 0], [5, -5, 0], [5, 5, 0], [-5, 5, 0]], float),
                       faces=np.array([[0, 1, 2], [0, 2, 3]]), material=metal)
    scene = Scene(scene_id="metal", source=Path("metal"), objects=[floor], rooms=[],
                  lights=[LightFixture(name="bulb", kind="point", position=(0.0, 0.0, 1.5), power_w=30.0, size=0.05)])
    built = scene_builder.build_scene(scene, SpotlightConfig(), 0.0, Intrinsics.from_fov(30.0, 24, 18),
                                      lambertian=False)
    pair = renderer.render_pair(built, _look_at_blender([0.0, -1.0, 1.5], [0.0, 0.5, 0.0]), settings, seed=0)
    np.testing.assert_allclose(pair.albedo, 0.0, atol=0.01)
    assert pair.glossy.mean(axis=(0, 1))[0] > 0.6  # the gold's colour, red above blue
    assert pair.glossy.mean(axis=(0, 1))[0] > 2 * pair.glossy.mean(axis=(0, 1))[2]
    reflectance = pair.albedo + pair.glossy
    np.testing.assert_allclose(pair.gt_uniform.mean(axis=(0, 1)), reflectance.mean(axis=(0, 1)), rtol=0.05)


def test_a_dataset_with_the_uniform_ground_truth_keeps_the_other_renders_bit_for_bit(dataset, tmp_path):
    """``--gt uniform`` adds gt_uniform/ and the EXR channels; the inputs and the lamps-on ground truth are those of
    the same render without it, the transforms name both ground truths, and a rerun without the option is refused."""
    from simulator.render_pipeline import DatasetFolderError
    from spotlessgs.io.exr import read_frame_exr
    from spotlessgs.io.images import read_image

    out = tmp_path / "uniform"
    summary = _render(out, uniform_gt=True)
    assert summary["complete"] and summary["rendered"] == 6
    for k in range(6):
        name = f"frame_{k:05d}"
        for sub in ("images", "gt"):
            assert (out / sub / f"{name}.png").read_bytes() == (dataset / sub / f"{name}.png").read_bytes()
        frame = read_frame_exr(out / "exr" / f"{name}.exr")
        assert frame.gt_uniform is not None
        uniform = read_image(out / "gt_uniform" / f"{name}.png")
        assert uniform.shape == (48, 64, 3)
        surface = np.isfinite(frame.depth) & ~frame.emitters() & (frame.albedo.mean(-1) > 0.05)
        ratio = frame.gt_uniform[surface].mean(-1) / frame.albedo[surface].mean(-1)
        # the directional albedo: the albedo plus the 4 % specular layer of Blender's dielectrics (measured: median
        # 1.04-1.06); no pixel in shadow (measured: 5th percentile 0.98-1.01)
        assert 1.0 < float(np.median(ratio)) < 1.1 and float(np.percentile(ratio, 5)) > 0.95
    renderer = json.loads((out / "transforms.json").read_text())["spotless"]["renderer"]
    assert renderer["ground_truths"] == {"lamps": "gt", "uniform": "gt_uniform"}
    assert "ground_truths" not in json.loads((dataset / "transforms.json").read_text())["spotless"]["renderer"]
    with pytest.raises(DatasetFolderError, match="differs in: uniform_gt"):
        _render(out)


def test_residual_light_adds_the_dimmed_lamps_to_the_spotlit_input_only(dataset, tmp_path):
    """``--residual-light 0.2`` leaves the room's lamps on at a fifth of their power in the spotlit input: light
    adds up, so the input gains about 0.2 × the lamps-on ground truth (mean over each frame, within render noise);
    the ground truth itself is byte-identical, and the setting is recorded."""
    from spotlessgs.io.exr import read_frame_exr

    out = tmp_path / "residual"
    _render(out, residual_light=0.2)
    for k in range(6):
        name = f"frame_{k:05d}"
        assert (out / "gt" / f"{name}.png").read_bytes() == (dataset / "gt" / f"{name}.png").read_bytes()
        lit, plain = read_frame_exr(out / "exr" / f"{name}.exr"), read_frame_exr(dataset / "exr" / f"{name}.exr")
        added = float(lit.uneven.mean() - plain.uneven.mean())
        assert added == pytest.approx(0.2 * float(plain.gt.mean()), rel=0.15), (k, added, float(plain.gt.mean()))
    renderer = json.loads((out / "transforms.json").read_text())["spotless"]["renderer"]
    assert renderer["residual_light"] == 0.2
    assert "residual_light" not in json.loads((dataset / "transforms.json").read_text())["spotless"]["renderer"]


def test_the_renderers_light_response_is_what_the_light_models_assume():
    """The simulator's materials (Principled BSDF, specular layer off) lit and seen from one direction reflect exactly
    cos θ at every roughness: their diffuse lobe is Lambertian, where the learned BRDF's Disney lobe would be
    (1 + 1.5 (1 - cos 75°)⁵)² = 1.78 times brighter at 75° for ρ = 1 (brdf_burley_diffuse). The simulator's spotlight
    has the profile that the calibrated DarkGS fits (light.cone_profile) within its 2 cm emitter's soft edge."""
    import math
    import sys

    result = subprocess.run([sys.executable, "-m", "simulator.blender.light_response", "--samples", "8",
                             "--threads", "1", "--json"], cwd=ROOT, capture_output=True, text=True, timeout=300,
                            check=True)
    report = json.loads(result.stdout.strip().splitlines()[-1])
    assert len(report["diffuse_lobe"]) == 15
    for row in report["diffuse_lobe"]:
        assert abs(row["measured"] - 1.0) < 0.01, row
    steep = next(r for r in report["diffuse_lobe"] if r["roughness"] == 1.0 and r["angle_deg"] == 75.0)
    assert steep["burley"] == pytest.approx((1.0 + 1.5 * (1.0 - math.cos(math.radians(75.0))) ** 5) ** 2, abs=1e-6)
    profile = report["spot_profile"]
    assert profile[0]["angle_deg"] == pytest.approx(0.0, abs=0.3) and profile[-1]["angle_deg"] > 40.0
    assert max(abs(r["measured"] - r["cone_profile"]) for r in profile) < 0.03
    assert any(0.1 < r["measured"] < 0.9 for r in profile)  # the row crosses the cone's edge
