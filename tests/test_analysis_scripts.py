"""The analysis scripts under scripts/ that docs/results.md quotes: relit_error_vs_lamps.py (how much of a relighting's
error looks like the room lamps' light field), indirect_light_by_height.py (a run's low-frequency light against
the true indirect light by height), normal_pull_by_height.py (which way the loss turns wall normals), and
io.lens.camera_points, which the first two back-project with."""

from __future__ import annotations

import importlib.util
import math
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
import torch

from evaluation.alignment import apply_gain, exposure_gain
from evaluation.lamp_light import true_direct_light
from spotlessgs.io.cameras import Intrinsics
from spotlessgs.io.colorspace import linear_to_srgb
from spotlessgs.io.lens import camera_points, distort

SCRIPTS = Path(__file__).resolve().parents[1] / "scripts"


def load_script(name: str):
    """The module of scripts/NAME.py."""
    spec = importlib.util.spec_from_file_location(name, SCRIPTS / f"{name}.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def tiny_config(iterations: int = 30, **overrides):
    """The tiny preset these tests train with: ``iterations`` steps on 40-pixel-wide images, one thread, no
    densification, at most 300 Gaussians (``overrides``: further TrainConfig fields)."""
    from spotlessgs.training.config import preset

    return preset("tiny", iterations=iterations, image_width=40, num_threads=1, densify_from=1000, log_every=10,
                  checkpoint_every=1000, init_points=200, max_gaussians=300, **overrides)


def tiny_runs(tmp_path_factory, name: str, seed: int, models, iterations: int = 30, **overrides) -> Path:
    """Tiny runs of ``models`` (seed 0, :func:`tiny_config`) on a synthetic box dataset drawn with ``seed``, each in
    ROOT/MODEL beside the dataset; returns the dataset's folder (ROOT is its parent)."""
    from conftest import synthetic_box_dataset
    from spotlessgs.training.trainer import train

    data = synthetic_box_dataset(tmp_path_factory, name, seed=seed)
    config = tiny_config(iterations, **overrides)
    for model in models:
        train(data, data.parent / model, model, config, seed=0, progress=False)
    return data


def scene(rng: np.random.Generator, shape=(3, 24, 32)):
    """Linear albedo (N, H, W, 3), the lamps' field F (N, H, W), depth, walls and emitters."""
    albedo = rng.uniform(0.1, 0.6, size=shape + (3,))
    field = np.exp(rng.uniform(-0.8, 0.4, size=shape))
    depth = rng.uniform(1.0, 4.0, size=shape)
    side = rng.uniform(size=shape) < 0.7
    emitter = np.zeros(shape, bool)
    emitter[:, :2] = True
    return albedo, field, depth, side, emitter


def aligned_psnr(pred_srgb: np.ndarray, gt_srgb: np.ndarray) -> float:
    p, g = torch.from_numpy(pred_srgb), torch.from_numpy(gt_srgb)
    return float(-10 * torch.log10(((apply_gain(p, exposure_gain(p, g)) - g) ** 2).mean()))


def test_an_error_that_is_the_lamps_field_to_a_power_is_found_and_removed():
    """A relighting that is the albedo × F^0.3: slope 0.3 on log F, none on depth or albedo, correlation 1; with that
    part removed it is the albedo itself, so its lamps-on PSNR becomes the uniform ground truth's own against the
    lamps-on one; the brightest third of F is relit brightest."""
    module = load_script("relit_error_vs_lamps")
    albedo, field, depth, side, emitter = scene(np.random.default_rng(0))
    emitter[:] = False  # every pixel counts, so that the part removed leaves exactly the albedo × a constant
    uniform = linear_to_srgb(albedo)
    lamps = linear_to_srgb(albedo * field[..., None])
    pred = linear_to_srgb(albedo * field[..., None] ** 0.3)
    r = module.lamps_like_error(pred, lamps, uniform, depth, side, emitter)
    assert r["slopes"][0] == pytest.approx(0.3, abs=1e-3)
    assert r["slopes"][1] == pytest.approx(0.0, abs=1e-3) and r["slopes"][2] == pytest.approx(0.0, abs=1e-3)
    assert r["corr"] == pytest.approx(1.0, abs=1e-4)
    assert r["psnr_lamps_removed"] == pytest.approx(aligned_psnr(uniform, lamps), abs=0.05)
    assert r["psnr_lamps_removed"] < r["psnr_lamps"]
    assert r["psnr_uniform"] == pytest.approx(aligned_psnr(pred, uniform), abs=1e-9)
    darkest, _, brightest = r["thirds"]
    assert darkest[0] < 0 < brightest[0]


def test_an_error_unrelated_to_the_lamps_leaves_the_score_as_it_is():
    """A relighting off by a depth term only: its slope goes to depth, none to F, and removing nothing changes
    nothing."""
    module = load_script("relit_error_vs_lamps")
    albedo, field, depth, side, emitter = scene(np.random.default_rng(1))
    uniform = linear_to_srgb(albedo)
    lamps = linear_to_srgb(albedo * field[..., None])
    pred = linear_to_srgb(albedo * depth[..., None] ** -0.2)
    r = module.lamps_like_error(pred, lamps, uniform, depth, side, emitter)
    assert r["slopes"][1] == pytest.approx(-0.2, abs=1e-3)
    assert r["slopes"][0] == pytest.approx(0.0, abs=1e-3)
    assert r["psnr_lamps_removed"] == pytest.approx(r["psnr_lamps"], abs=0.01)


def test_world_height_of_a_level_camera_and_an_error_that_grows_with_height():
    """A level camera 1.5 m up, looking along +y at a wall 2 m away: each pixel row's height is 1.5 - 2 (v - cy) / fy
    (the image's y axis points down). A relighting off by exp(0.2 height) on walls: slope 0.2 per metre on height,
    none on F, and the height bands' mean error rises with height."""
    module = load_script("relit_error_vs_lamps")
    camera = Intrinsics(fx=50.0, fy=50.0, cx=16.0, cy=12.0, width=32, height=24)
    c2w = np.eye(4)
    c2w[:3, :3] = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, -1.0, 0.0]])  # columns: x right, y down, z ahead
    c2w[:3, 3] = [0.0, 0.0, 1.5]
    dataset = SimpleNamespace(cameras=[camera], c2w_opencv=np.stack([c2w]))
    depth = np.full((24, 32), 2.0)
    rows = np.arange(24)[:, None] + 0.5
    assert module.world_height(dataset, 0, depth) == pytest.approx(np.broadcast_to(1.5 - 2.0 * (rows - 12) / 50, (24, 32)))

    albedo, field, depth, side, emitter = scene(np.random.default_rng(2))
    height = np.broadcast_to(np.linspace(0.0, 2.4, 24)[None, :, None], depth.shape)
    side[:] = True
    pred = linear_to_srgb(albedo * np.exp(0.2 * height)[..., None])
    r = module.lamps_like_error(pred, linear_to_srgb(albedo * field[..., None]), linear_to_srgb(albedo), depth, side,
                                emitter, height)
    assert r["wall_slopes"][1] == pytest.approx(0.2, abs=1e-3)
    assert r["wall_slopes"][0] == pytest.approx(0.0, abs=0.01)
    band_errors = [e for _, e, _ in r["bands"]]
    assert band_errors == sorted(band_errors) and len(band_errors) >= 4


def test_camera_points_of_a_pinhole_and_through_a_lens():
    """A pinhole's pixel (u, v) at planar depth d lies at ((u + 0.5 - cx) d / fx, (v + 0.5 - cy) d / fy, d); through
    a distorted lens the points project back (io.lens.distort) to their pixel centres, at their depths."""
    depth = np.linspace(1.0, 3.0, 6 * 8).reshape(6, 8)
    pinhole = Intrinsics(fx=10.0, fy=12.0, cx=4.0, cy=3.0, width=8, height=6)
    points = camera_points(pinhole, depth)
    assert points[2, 5] == pytest.approx([(5.5 - 4.0) * depth[2, 5] / 10.0, (2.5 - 3.0) * depth[2, 5] / 12.0,
                                          depth[2, 5]])
    lens = Intrinsics(fx=10.0, fy=10.0, cx=4.0, cy=3.0, width=8, height=6, lens="opencv",
                      distortion=(-0.2, 0.03, 0.0, 0.0))
    points = camera_points(lens, depth).reshape(-1, 3)
    rows, cols = np.mgrid[:6, :8]
    assert points[:, 2] == pytest.approx(depth.ravel())
    assert distort(lens, points[:, :2] / points[:, 2:]) == pytest.approx(
        np.stack([cols.ravel() + 0.5, rows.ravel() + 0.5], 1), abs=1e-4)
    assert not np.allclose(camera_points(lens, depth), camera_points(Intrinsics(10.0, 10.0, 4.0, 3.0, 8, 6), depth))
    with pytest.raises(ValueError, match="does not match"):
        camera_points(pinhole, depth[:, :4])


def test_true_direct_light_of_a_lamp_facing_a_wall():
    """A lamp at the camera looking along +z at a wall 2 m ahead: on the axis diffuse / 4; a point at 20° off the
    axis gets the cone's profile × cos 20° / (2 / cos 20°)², the cosine of incidence being cos 20° too; outside the
    cone nothing; a wall facing away nothing."""
    light = SimpleNamespace(position_in_camera=np.zeros(3), rotation_in_camera=np.eye(3), cone_angle_deg=65.0,
                            blend=0.35)
    angles = np.radians([0.0, 20.0, 30.0, 40.0])
    points = np.stack([2.0 * np.tan(angles), np.zeros(4), np.full(4, 2.0)], -1)[None]
    normals = np.tile([0.0, 0.0, -1.0], (1, 4, 1))
    direct = true_direct_light(points, normals, np.full((1, 4), 0.5), light)[0]
    cos_c = math.cos(math.radians(32.5))

    def cone(theta):
        s = min(max((math.cos(theta) - cos_c) / (0.35 * (1 - cos_c)), 0.0), 1.0)
        return s * s * (3 - 2 * s)

    expected = [0.5 * cone(a) * math.cos(a) / (2.0 / math.cos(a)) ** 2 for a in angles]
    assert direct == pytest.approx(expected)
    assert direct[0] == pytest.approx(0.5 / 4) and direct[3] == 0.0 and 0 < direct[2] < direct[1]
    assert true_direct_light(points, -normals, np.full((1, 4), 0.5), light).max() == 0.0


def test_bands_find_an_indirect_light_that_rises_and_a_model_that_is_flat():
    """Indirect light rising with height, a flat model light, direct light known exactly: the gain is recovered, the
    true indirect irradiance rises and the model's stays at 1, and an albedo darkened by the model's excess where
    the true indirect light is low shows in the lowest band."""
    module = load_script("indirect_light_by_height")
    rng = np.random.default_rng(0)
    n = 20000
    height = rng.uniform(0.0, 2.8, n)
    albedo = rng.uniform(0.2, 0.8, n)
    direct = albedo * np.exp(rng.uniform(math.log(0.01), math.log(2.0), n))  # the lamp's light, unscaled
    indirect_irradiance = 0.003 * (0.5 + height / 2.8)  # rises 3x over the room, small where the lamp is bright
    observed = 3.0 * direct + albedo * indirect_irradiance
    model_low_irradiance = np.full(n, indirect_irradiance.mean())
    learned = observed / (3.0 * direct / albedo + model_low_irradiance)  # what the images then ask of the albedo
    rows = module.band_table(height, observed, direct, albedo, learned * 3.0 * direct / albedo,
                             learned * model_low_irradiance, learned)
    assert [r["low"] for r in rows] == pytest.approx([0.0, 0.4, 0.8, 1.2, 1.6, 2.0, 2.4])
    assert [r["indirect_true"] for r in rows] == sorted(r["indirect_true"] for r in rows)
    assert rows[-1]["indirect_true"] / rows[0]["indirect_true"] > 2.0
    assert all(r["low_model"] == pytest.approx(1.0, rel=0.05) for r in rows)
    assert rows[0]["albedo_log_ratio"] < 0 < rows[-1]["albedo_log_ratio"]
    assert rows[0]["share_model"] > rows[0]["share_true"] and rows[-1]["share_model"] < rows[-1]["share_true"]
    # the optional columns: a one-bounce irradiance comes out relative to its mean, the normals' z as it is
    with_columns = module.band_table(height, observed, direct, albedo, learned * 3.0 * direct / albedo,
                                     learned * model_low_irradiance, learned, bounce_true=5.0 * indirect_irradiance,
                                     normal_z=0.1 * (1.4 - height))
    relative = indirect_irradiance / indirect_irradiance.mean()
    assert [r["bounce_true"] for r in with_columns] == pytest.approx(
        [relative[(height >= r["low"]) & (height < r["low"] + 0.4)].mean() for r in rows], rel=1e-9)
    assert [r["normal_z"] for r in with_columns] == pytest.approx([0.1 * (1.4 - (r["low"] + 0.2)) for r in rows],
                                                                  abs=0.01)


def test_normal_pull_sums_the_tangent_descent_per_band_on_walls_only():
    """Horizontal normals whose loss gradient points down low in the room and up high (plus a component along the
    normal, which cannot turn it): the descent's z is positive low and negative high; floor normals are left out."""
    module = load_script("normal_pull_by_height")
    rng = np.random.default_rng(1)
    n = 3000
    angle = rng.uniform(0.0, 2.0 * math.pi, n)
    normals = np.stack([np.cos(angle), np.sin(angle), np.zeros(n)], -1)
    heights = rng.uniform(0.0, 2.8, n)
    pull = 1.4 - heights  # the descent wants the normal up below 1.4 m and down above
    gradient = -pull[:, None] * np.array([0.0, 0.0, 1.0]) + 5.0 * normals  # along the normal: projected away
    floor = rng.uniform(0.0, 2.8, 500)
    rows = module.descent_z_by_band(np.concatenate([gradient, np.tile([0.0, 0.0, -9.0], (500, 1))]),
                                    np.concatenate([normals, np.tile([0.0, 0.0, 1.0], (500, 1))]),
                                    np.concatenate([heights, floor]))
    assert [low for low, _ in rows] == pytest.approx([0.0, 0.4, 0.8, 1.2, 1.6, 2.0, 2.4])
    for low, total in rows:
        chosen = (heights >= low) & (heights < low + 0.4)
        assert total == pytest.approx(pull[chosen].sum(), rel=1e-9)
    assert rows[0][1] > 0 > rows[-1][1]


def test_reflectance_by_cosine_is_one_for_a_lambertian_room_and_rises_for_a_retro_reflective_one():
    module = load_script("reflectance_vs_incidence")
    rng = np.random.default_rng(2)
    cosine = rng.uniform(0.2, 1.0, 20000)
    lambertian = module.ratio_by_cosine(cosine, 0.37 * np.exp(rng.normal(0.0, 0.01, 20000)))
    assert [low for low, _, _ in lambertian] == pytest.approx(np.arange(0.2, 1.0, 0.1))
    assert all(ratio == pytest.approx(1.0, abs=0.01) for _, ratio, _ in lambertian)
    brighter_at_grazing = module.ratio_by_cosine(cosine, 0.37 / np.sqrt(cosine))  # falls as sqrt(cos), not cos
    assert brighter_at_grazing[0][1] == pytest.approx(1.0 / math.sqrt(0.25), rel=0.05)
    assert [r for _, r, _ in brighter_at_grazing] == sorted((r for _, r, _ in brighter_at_grazing), reverse=True)


def test_surface_labels_and_each_surfaces_share_of_the_error():
    module = load_script("relit_error_by_material")
    normals = np.zeros((2, 4, 3))
    normals[0, :2] = [0.0, 0.0, 1.0]  # floor
    normals[0, 2:] = [0.0, 0.3, -0.95]  # ceiling, a little tilted
    normals[1] = [1.0, 0.0, 0.0]  # a wall
    labels = module.surface_labels(normals / np.linalg.norm(normals, axis=-1, keepdims=True))
    assert labels.tolist() == [[0, 0, 1, 1], [2, 2, 2, 2]]
    error = np.array([[1.0, 3.0, 0.0, 0.0], [1.0, 1.0, 1.0, 1.0]])
    gt = np.full((2, 4, 3), 0.5)
    aligned = gt.copy()
    aligned[0, :2] = 0.6  # the floor relit brighter
    aligned[1, 0] = 0.3  # one wall pixel darker
    shares = module.region_shares(error, labels, module.SURFACES, aligned, gt)
    assert [name for name, *_ in shares] == ["floor", "ceiling", "walls and sides"]
    assert [pixels for _, pixels, _, _, _ in shares] == pytest.approx([0.25, 0.25, 0.5])
    assert [share for _, _, share, _, _ in shares] == pytest.approx([0.5, 0.0, 0.5])
    assert [mse for *_, mse, _ in shares] == pytest.approx([2.0, 0.0, 1.0])
    assert [ratio for *_, ratio in shares] == pytest.approx([1.2, 1.0, (0.3 + 3 * 0.5) / 4 / 0.5])


def test_cone_labels_from_the_true_lamp_and_the_planar_depth():
    """A pixel is inside the cone where the surface it sees lies within half the cone angle of the lamp's axis, measured
    from the lamp's own position; no surface (infinite depth) is no region."""
    from spotlessgs.io.cameras import Intrinsics
    from spotlessgs.io.transforms import LightTruth
    module = load_script("relit_error_by_material")
    intrinsics = Intrinsics(fx=10.0, fy=10.0, cx=10.5, cy=10.5, width=21, height=21)  # pixel i sees x/z = (i - 10) / 10
    depth = np.full((21, 21), 2.0)
    depth[0, 0] = np.inf
    at_camera = LightTruth(position_in_camera=np.zeros(3), rotation_in_camera=np.eye(3), cone_angle_deg=91.0,
                           blend=0.1, power_w=1.0)
    labels = module.cone_labels(depth, intrinsics, at_camera)
    offsets = np.hypot(*np.mgrid[-10:11, -10:11]) / 10.0  # tan of the angle off the axis
    expected = np.where(offsets < math.tan(math.radians(45.5)), 0, 1)
    expected[0, 0] = -1
    assert (labels == expected).all()
    # the lamp 1 m to the right, along +z with a 20° cone: only what lies near x = 1 m is inside (at depth 2, column 15)
    beside = LightTruth(position_in_camera=np.array([1.0, 0.0, 0.0]), rotation_in_camera=np.eye(3),
                        cone_angle_deg=20.0, blend=0.1, power_w=1.0)
    labels = module.cone_labels(depth, intrinsics, beside)
    inside = np.argwhere(labels == 0)
    assert labels[10, 15] == 0 and labels[10, 10] == 1
    assert np.abs(inside - [10, 15]).max() <= 2


def test_depth_map_normals_of_a_tilted_plane_and_angles_of_either_sign():
    """The depth map of a plane n·X = d seen by a pinhole camera gives back n (turned to face the camera) at every inner
    pixel (NaN on the border), as normal_error.py computes a model's depth map's normals; the angle between normals
    ignores their sign."""
    from spotlessgs.prepare.depth_points import surface_normals

    module = load_script("normal_error")
    camera = Intrinsics(60.0, 55.0, 20.5, 14.0, 40, 30)
    n = np.array([0.3, -0.5, -1.0]) / np.linalg.norm([0.3, -0.5, -1.0])  # faces the camera
    u, v = np.meshgrid(np.arange(40) + 0.5, np.arange(30) + 0.5)
    rays = np.stack([(u - camera.cx) / camera.fx, (v - camera.cy) / camera.fy, np.ones_like(u)], -1)
    depth = -2.0 / (rays @ n)  # n·X = -2 with X = z · ray: the plane lies in front of the camera
    assert bool((depth > 0).all())
    normals = surface_normals(camera_points(camera, depth))
    assert normals.shape == (30, 40, 3)
    np.testing.assert_allclose(normals[1:-1, 1:-1], np.broadcast_to(n, (28, 38, 3)), atol=1e-9, rtol=0)
    border = np.ones((30, 40), bool)
    border[1:-1, 1:-1] = False
    assert np.isnan(normals[border]).all()
    inner = normals[1:-1, 1:-1]
    keep = np.ones((28, 38), bool)
    assert np.allclose(module._angles(inner, -inner, keep), 0.0, atol=1e-4)
    side = np.zeros((1, 1, 3))
    side[..., 0] = 1.0
    up = np.zeros((1, 1, 3))
    up[..., 2] = 1.0
    assert np.allclose(module._angles(side, up, np.ones((1, 1), bool)), 90.0)


def test_relight_radiance_sweep_relights_at_each_l0_and_scores_both_ground_truths(tmp_path_factory, monkeypatch):
    """relight_radiance_sweep.py on tiny trained runs: a constant ambient (DarkGS) relights to one image up to a gain,
    so every L0 scores the same; the SH light's run relit with L0 = 0 (its low-frequency light alone) scores
    differently from L0 = 1, and its rows are what `spotless relight --l0 L L L` scores; a dataset with a uniform
    ground truth (here the spotlit inputs) is scored against it too, one without it not; the L0 `spotless relight`
    chose is read only from an automatic relighting; a folder that is no run, or a run whose relit.json is damaged,
    stops the script with one line naming it."""
    import json
    import shutil

    from click.testing import CliRunner

    from evaluation.runner import score_test_views
    from spotlessgs.cli import main

    def relight(run: Path, *options: str) -> None:
        res = CliRunner().invoke(main, ["relight", str(run), "-q", "--device", "cpu", *options])
        assert res.exit_code == 0, res.output

    module = load_script("relight_radiance_sweep")
    data = tiny_runs(tmp_path_factory, "sweep-data", 3, ("darkgs", "darkgs+sh"), brdf_hidden=8)
    root = data.parent
    levels = [0.0, 0.3, 1.0]

    darkgs = module.sweep(root / "darkgs", levels, root / "sweep-darkgs")
    assert [r["l0"] for r in darkgs] == levels and all(r["uniform"] is None for r in darkgs)
    assert max(r["lamps"] for r in darkgs) - min(r["lamps"] for r in darkgs) < 0.05  # 8-bit rounding only

    sh = module.sweep(root / "darkgs+sh", levels, root / "sweep-sh")
    assert abs(sh[0]["lamps"] - sh[2]["lamps"]) > 1.0
    for row, level in ((sh[0], "0"), (sh[2], "1")):
        relight(root / "darkgs+sh", "--views", "test", "--l0", level, level, level, "--out", str(root / f"cli-{level}"))
        assert row["lamps"] == pytest.approx(score_test_views(data, root / f"cli-{level}", 1)["psnr_aligned"], abs=1e-9)

    shutil.copytree(data / "images", data / "gt_uniform")  # the spotlit inputs as a second ground truth, far off
    transforms = json.loads((data / "transforms.json").read_text())
    transforms["spotless"]["renderer"] = {"ground_truths": {"lamps": "gt", "uniform": "gt_uniform"}}
    (data / "transforms.json").write_text(json.dumps(transforms))
    both = module.sweep(root / "darkgs+sh", levels, root / "sweep-both")
    assert [r["lamps"] for r in both] == pytest.approx([r["lamps"] for r in sh], abs=1e-9)
    for row, level in zip(both, levels):
        folder = root / "sweep-both" / f"l0-{level:g}"
        assert row["uniform"] == pytest.approx(score_test_views(data, folder, 1, "uniform")["psnr_aligned"], abs=1e-9)
        assert abs(row["uniform"] - row["lamps"]) > 0.5

    assert module.chosen_l0(root / "darkgs+sh") is None  # never relit into RUN/relit
    relight(root / "darkgs+sh")
    auto = json.loads((root / "darkgs+sh" / "relit.json").read_text())["l0"][0]
    assert auto > 0 and module.chosen_l0(root / "darkgs+sh") == auto
    relight(root / "darkgs+sh", "--l0", "1", "1", "1")
    assert module.chosen_l0(root / "darkgs+sh") is None  # a given L0 is not a choice

    monkeypatch.setattr("sys.argv", ["relight_radiance_sweep.py", str(root / "sweep-sh")])
    with pytest.raises(SystemExit, match=r"^error: .*sweep-sh: not a training run"):
        module.main()
    (root / "darkgs" / "relit.json").write_text('{"l0": "auto", "l0_mode": "auto"}')
    monkeypatch.setattr("sys.argv", ["relight_radiance_sweep.py", str(root / "darkgs"), "--l0", "0.5"])
    with pytest.raises(SystemExit, match=r"^error: .*relit.json: l0 must be three numbers"):
        module.main()
    monkeypatch.setattr("sys.argv", ["relight_radiance_sweep.py", str(root / "darkgs"), str(root / "darkgs")])
    with pytest.raises(SystemExit) as stopped:  # two curves of one name
        module.main()
    assert stopped.value.code == 2


def test_lamp_l0_is_the_irradiance_training_shades_a_white_surface_with(tmp_path_factory, monkeypatch, capsys):
    """The lamp-matched L0 (rendering.lamp_irradiance) on a tiny DarkGS run: with every albedo white, the coverage-
    weighted mean of the spotlight half of training's own shading (shade(..., split_lights=True): f̃ · cos · L_spot,
    f̃ = 1) over the same views; it doubles with the lamp's radiance. `spotless relight --lamp-l0` writes the view at
    that L0 with its low-frequency light, scaled as a whole (the relit view at --l0 E E E times its recorded gain, the
    99th percentile of luminance at the exposure target); with --l0 too it is refused. relight_radiance_sweep.py
    --lamp scores that relighting beside the given L0 and says so; a 3DGS run, which has no lamp, relights as ever."""
    import json

    import numpy as np
    import torch
    from click.testing import CliRunner

    from spotlessgs.cli import main
    from spotlessgs.io.exr import read_exr
    from spotlessgs.models.shading import shade
    from spotlessgs.rasterizer import rasterize
    from spotlessgs.rendering import AUTO_L0_PERCENTILE, AUTO_L0_TARGET, evenly_spaced, lamp_irradiance
    from spotlessgs.training.trainer import load_run

    module = load_script("relight_radiance_sweep")
    data = tiny_runs(tmp_path_factory, "lamp-l0-data", 4, ("darkgs", "3dgs"))
    root = data.parent
    scene, views, run_config, _ = load_run(root / "darkgs", device="cpu")
    lamp = lamp_irradiance(scene, views.cameras, views.train, run_config, count=3)
    assert np.isfinite(lamp) and lamp > 0

    g, app = scene.gaussians, scene.appearance
    with torch.no_grad():
        g.params["albedo_raw"].fill_(40.0)  # sigmoid: 1 in float32
        weighted, coverage = 0.0, 0.0
        for k in evenly_spaced(views.train, 3):
            camera = views.cameras[k]
            spot_half = shade(scene.config, g, app.light, app.lf_light, app.brdf, camera.c2w, split_lights=True)[:, :3]
            lit = rasterize(g.means, g.quats, g.scales, g.opacities, spot_half, camera.viewmat, camera.K,
                            camera.width, camera.height).image
            cover = rasterize(g.means, g.quats, g.scales, g.opacities, torch.ones_like(spot_half), camera.viewmat,
                              camera.K, camera.width, camera.height).image
            weighted += float(lit[..., 0].sum())  # white: every channel alike
            coverage += float(cover[..., 0].sum())
        assert lamp == pytest.approx(weighted / coverage, rel=1e-5)
        app.light.radiance_scale.mul_(2.0)
        assert lamp_irradiance(scene, views.cameras, views.train, run_config, count=3) == pytest.approx(2 * lamp,
                                                                                                        rel=1e-5)

    scene, views, run_config, _ = load_run(root / "darkgs", device="cpu")
    at = lamp_irradiance(scene, views.cameras, views.train, run_config)  # the default 16 views
    runner = CliRunner()
    res = runner.invoke(main, ["relight", str(root / "darkgs"), "-q", "--device", "cpu", "--views", "test", "--exr",
                               "--lamp-l0", "--out", str(root / "lamp")])
    assert res.exit_code == 0, res.output
    summary = json.loads(res.output)
    assert summary["l0_mode"] == "lamp" and summary["lamp_irradiance"] == pytest.approx(at, rel=1e-9)
    gain = summary["low_frequency_gain"]
    assert summary["l0"] == pytest.approx([gain * at] * 3, rel=1e-9)
    given = f"{at!r}"
    res = runner.invoke(main, ["relight", str(root / "darkgs"), "-q", "--device", "cpu", "--views", "test", "--exr",
                               "--l0", given, given, given, "--out", str(root / "given")])
    assert res.exit_code == 0, res.output
    names = sorted(p.name for p in (root / "lamp").glob("*.exr"))
    assert names and names == sorted(p.name for p in (root / "given").glob("*.exr"))
    lamp_images = [np.stack([read_exr(root / "lamp" / n)[c] for c in "RGB"], -1) for n in names]
    for name, image in zip(names, lamp_images):
        at_given = np.stack([read_exr(root / "given" / name)[c] for c in "RGB"], -1)
        np.testing.assert_allclose(image, gain * at_given, rtol=1e-5, atol=1e-7)
    luminance = np.concatenate([im.mean(axis=2).ravel() for im in lamp_images])
    assert np.percentile(luminance, AUTO_L0_PERCENTILE) == pytest.approx(AUTO_L0_TARGET, rel=1e-4)
    res = runner.invoke(main, ["relight", str(root / "darkgs"), "--lamp-l0", "--l0", "1", "1", "1"])
    assert res.exit_code == 2 and "give --l0 or --lamp-l0, not both" in res.output

    from evaluation.runner import score_test_views

    rows = module.sweep(root / "darkgs", [0.5], root / "sweep", lamp=True)
    assert [r["l0"] for r in rows] == [0.5, "lamp"]
    assert rows[1]["lamp_irradiance"] == pytest.approx(at, rel=1e-9) and rows[1]["gain"] == pytest.approx(gain)
    assert rows[1]["lamps"] == pytest.approx(score_test_views(data, root / "lamp", 1)["psnr_aligned"], abs=1e-9)
    monkeypatch.setattr("sys.argv", ["relight_radiance_sweep.py", str(root / "darkgs"), "--l0", "0.5", "--lamp"])
    module.main()
    printed = capsys.readouterr().out
    assert "L0 0.5   lamps-on" in printed and f"--lamp-l0 (L0 {at:.3f}, the view x {gain:.2f})  lamps-on" in printed
    assert module.sweep(root / "3dgs", [0.5], root / "sweep-3dgs", lamp=True)[1]["lamp_irradiance"] is None


def test_shading_cost_times_the_runs_shading_and_variants_that_shade_alike(tmp_path_factory):
    """shading_cost.py on a tiny SpotlessGS run: the network without its input gradients shades the same colours as
    the run's own BRDF (so the two times compare like with like); the Disney-only BRDF is the learned one with its
    network's output at zero; the Lambertian variants shade with the albedo; a DarkGS run is refused. Times are only checked to be positive (tests never assert a time)."""
    import torch

    from spotlessgs.models.shading import shade
    from spotlessgs.training.trainer import load_run

    module = load_script("shading_cost")
    root = tiny_runs(tmp_path_factory, "shading-cost-data", 5, ("spotless", "darkgs"), iterations=20,
                     brdf_hidden=8).parent
    scene, views, _, _ = load_run(root / "spotless", device="cpu")
    app, g = scene.appearance, scene.gaussians
    with torch.no_grad():  # a residual the network's input gradient would show in
        app.brdf.mlp[-1].weight.fill_(0.3)
    rows = module.variants(scene.config, app.brdf, app.lf_light, app.bounce_light)
    c2w = views.cameras.c2w[views.train[0]]

    def colours(config, brdf, lf_light, bounce_light=app.bounce_light):
        return shade(config, g, app.light, lf_light, brdf, c2w, bounce_light=bounce_light)

    own, detached, disney, lambert, darkgs = [colours(*row[1:]) for row in rows]
    torch.testing.assert_close(detached, own, rtol=0, atol=0)
    with torch.no_grad():
        app.brdf.mlp[-1].weight.zero_()
        app.brdf.mlp[-1].bias.zero_()
    torch.testing.assert_close(disney, colours(scene.config, app.brdf, app.lf_light), rtol=0, atol=0)
    assert not torch.allclose(disney, own)
    assert rows[3][1].brdf == "lambert" and rows[4][1].ambient == "constant" and rows[4][1].brdf == "lambert"
    assert not torch.allclose(lambert, darkgs)
    count, timed = module.shading_cost(root / "spotless", views=2, repeats=1)
    assert count == len(g) and [name for name, _ in timed] == [name for name, *_ in rows]
    assert all(ms > 0 for _, ms in timed)
    darkgs_scene, *_ = load_run(root / "darkgs", device="cpu")
    with pytest.raises(ValueError, match="SpotlessGS run"):
        module.variants(darkgs_scene.config, darkgs_scene.appearance.brdf, darkgs_scene.appearance.lf_light, None)
    # --parts times the BRDF on the inputs shade gives it: f̃ · cos · L_spot is shade's spotlight half
    from spotlessgs.models.shading import lambert_cosine

    inputs, spot = module.brdf_inputs(scene, c2w)
    halves = shade(scene.config, g, app.light, app.lf_light, app.brdf, c2w, split_lights=True,
                   bounce_light=app.bounce_light)
    torch.testing.assert_close(app.brdf(*inputs) * lambert_cosine(inputs[3], inputs[5]) * spot, halves[:, :3])
    count, parts = module.brdf_parts(root / "spotless", repeats=1)
    assert count == len(g) and len(parts) == 6 and parts[-1][0] == "the whole learned BRDF"
    assert all(ms > 0 for _, ms in parts)
    with pytest.raises(ValueError, match="learned BRDF"):
        module.brdf_parts(root / "darkgs", repeats=1)


def test_step_profile_counts_every_profiled_step_and_ranks_operators_by_self_time(tmp_path_factory, tmp_path):
    """step_profile.py on a tiny SpotlessGS run: the rasterizer's compositing runs forward and backward in every
    profiled step; the rows are ranked by self time and add up to the total; the run stopped after the profiled steps
    with a checkpoint a resumed run starts from. Times are only checked to be positive (tests never assert a time)."""
    from spotlessgs.training.trainer import train

    module = load_script("step_profile")
    data = tiny_runs(tmp_path_factory, "step-profile-data", 6, ())
    config = tiny_config()
    steps = 4
    ms_per_step, total, rows = module.profile_steps(data, tmp_path / "run", "spotless", config, steps)
    assert ms_per_step > 0 and total > 0
    calls = {name: count for name, _, count in rows}
    assert calls["_CompositeFunction"] >= steps and calls["_CompositeFunctionBackward"] == steps
    assert [ms for _, ms, _ in rows] == sorted((ms for _, ms, _ in rows), reverse=True)
    assert sum(ms for _, ms, _ in rows) == pytest.approx(total)
    assert (tmp_path / "run" / "checkpoints" / "last.safetensors").is_file()
    resumed = train(data, tmp_path / "run", "spotless", config, seed=0, resume=True, progress=False,
                    stop_after=steps + 2)
    assert resumed.steps == steps + 2
