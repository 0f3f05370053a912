"""scripts/indirect_light_by_height.py and io.lens.camera_points: the true direct light of a lamp and the per-band
comparison of the indirect light with a model's low-frequency light."""

from __future__ import annotations

import importlib.util
import math
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

from spotlessgs.io.cameras import Intrinsics
from spotlessgs.io.lens import camera_points

SCRIPT = Path(__file__).resolve().parents[1] / "scripts" / "indirect_light_by_height.py"


def load_script():
    spec = importlib.util.spec_from_file_location("indirect_light_by_height", SCRIPT)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_camera_points_of_a_pinhole_and_through_a_lens():
    """A pinhole's pixel (u, v) at planar depth d lies at ((u + 0.5 - cx) d / fx, (v + 0.5 - cy) d / fy, d); through
    a distorted lens the points project back (io.lens.distort) to their pixel centres, at their depths."""
    from spotlessgs.io.lens import distort

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
    module = load_script()
    light = SimpleNamespace(position_in_camera=np.zeros(3), rotation_in_camera=np.eye(3), cone_angle_deg=65.0,
                            blend=0.35)
    angles = np.radians([0.0, 20.0, 30.0, 40.0])
    points = np.stack([2.0 * np.tan(angles), np.zeros(4), np.full(4, 2.0)], -1)[None]
    normals = np.tile([0.0, 0.0, -1.0], (1, 4, 1))
    direct = module.true_direct(points, normals, np.full((1, 4), 0.5), light)[0]
    cos_c = math.cos(math.radians(32.5))

    def cone(theta):
        s = min(max((math.cos(theta) - cos_c) / (0.35 * (1 - cos_c)), 0.0), 1.0)
        return s * s * (3 - 2 * s)

    expected = [0.5 * cone(a) * math.cos(a) / (2.0 / math.cos(a)) ** 2 for a in angles]
    assert direct == pytest.approx(expected)
    assert direct[0] == pytest.approx(0.5 / 4) and direct[3] == 0.0 and 0 < direct[2] < direct[1]
    assert module.true_direct(points, -normals, np.full((1, 4), 0.5), light).max() == 0.0


def test_bands_find_an_indirect_light_that_rises_and_a_model_that_is_flat():
    """Indirect light rising with height, a flat model light, direct light known exactly: the gain is recovered, the
    true indirect irradiance rises and the model's stays at 1, and an albedo darkened by the model's excess where
    the true indirect light is low shows in the lowest band."""
    module = load_script()
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
