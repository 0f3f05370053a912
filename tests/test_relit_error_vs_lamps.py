"""scripts/relit_error_vs_lamps.py: how much of a relighting's error looks like the room lamps' light field."""

from __future__ import annotations

import importlib.util
from pathlib import Path

import numpy as np
import pytest
import torch

from evaluation.alignment import apply_gain, exposure_gain
from spotlessgs.io.colorspace import linear_to_srgb

SCRIPT = Path(__file__).resolve().parents[1] / "scripts" / "relit_error_vs_lamps.py"


def load_script():
    spec = importlib.util.spec_from_file_location("relit_error_vs_lamps", SCRIPT)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


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
    module = load_script()
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
    module = load_script()
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
    from types import SimpleNamespace

    from spotlessgs.io.cameras import Intrinsics

    module = load_script()
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
