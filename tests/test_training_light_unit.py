"""The spotlight's radiance unit (training.light_unit, SpotLight.radiance_scale): the scene's median depth, the
factor, its place in the light's state and in a trained run."""

from __future__ import annotations

import json
import math

import pytest
import torch

from spotlessgs.io.camera_batch import Cameras
from spotlessgs.io.cameras import Intrinsics
from spotlessgs.models.light import SpotLight
from spotlessgs.training.config import TrainConfig
from spotlessgs.training.light_unit import median_view_depth, spot_radiance_scale

# a 100 x 80 pinhole camera, f = 100 px: a point at (x, y, z) is in the image when |x / z| < 0.5 and |y / z| < 0.4
INTRINSICS = Intrinsics(100.0, 100.0, 50.0, 40.0, 100, 80)


def _cameras() -> Cameras:
    """Two views: the identity (looking along +z), and one 10 m along +x looking the same way."""
    c2w = torch.eye(4).repeat(2, 1, 1)
    c2w[1, 0, 3] = 10.0
    return Cameras(c2w, INTRINSICS)


def test_the_median_depth_counts_only_points_each_view_sees():
    """View 0 sees the points at depths 1, 2, 6 (median 2) and neither the one behind it nor the ones off its image;
    view 1 sees 3, 4, 5, 7 (median 4.5, torch's lower median: 4). The median of the two medians (lower): 2."""
    seen_by_0 = [[0.0, 0.0, 1.0], [0.1, 0.1, 2.0], [-0.2, 0.0, 6.0]]
    seen_by_1 = [[10.0, 0.0, 3.0], [10.5, 0.0, 4.0], [9.5, 1.0, 5.0], [10.0, -1.0, 7.0]]
    unseen = [[0.0, 0.0, -2.0], [0.0, 0.0, 0.005], [3.0, 0.0, 2.0], [0.0, 1.5, 3.0], [5.0, 0.0, 8.0]]
    points = torch.tensor(seen_by_0 + seen_by_1 + unseen)
    cameras = _cameras()
    assert median_view_depth(points, cameras, [0]) == pytest.approx(2.0)
    assert median_view_depth(points, cameras, [1]) == pytest.approx(4.0)
    assert median_view_depth(points, cameras, [0, 1]) == pytest.approx(2.0)
    with pytest.raises(ValueError, match="no point"):
        median_view_depth(torch.tensor(unseen[:2]), cameras, [0, 1])


def test_the_unit_is_the_initial_falloff_at_the_median_depth():
    """"median_depth": s = (τ + z²)^γ, so that s (τ + z²)^(-γ) = 1 at the median depth z; "fixed": 1."""
    points = torch.tensor([[0.0, 0.0, 2.0], [0.0, 0.0, 3.0], [0.1, 0.0, 4.0]])
    cameras = _cameras()
    assert spot_radiance_scale("fixed", points, cameras, [0], 0.3, 1.0) == 1.0
    assert spot_radiance_scale("median_depth", points, cameras, [0], 0.3, 1.0) == pytest.approx(9.3)
    assert spot_radiance_scale("median_depth", points, cameras, [0], 0.5, 0.8) == pytest.approx(9.5**0.8)
    with pytest.raises(ValueError, match="spot_radiance_unit"):
        spot_radiance_scale("metres", points, cameras, [0], 0.3, 1.0)
    with pytest.raises(ValueError, match="spot_radiance_unit"):
        TrainConfig(spot_radiance_unit="metres")


def test_the_scale_multiplies_the_spotlights_radiance_and_nothing_else():
    """Same seed and pose: the radiance at any point is s times the unit light's, the direction to the lamp is
    the same; a scale that is not finite and positive is refused."""
    points = torch.tensor([[0.3, -0.2, 1.5], [0.0, 0.0, 3.0], [-1.0, 0.5, 0.8]])
    c2w = torch.eye(4)
    unit = SpotLight(translation=[0.05, -0.03, 0.0], seed=3, rid_model="mlp")
    scaled = SpotLight(translation=[0.05, -0.03, 0.0], seed=3, rid_model="mlp", radiance_scale=7.5)
    (r1, l1), (r2, l2) = unit.incident(points, c2w), scaled.incident(points, c2w)
    torch.testing.assert_close(r2, 7.5 * r1)
    torch.testing.assert_close(l2, l1)
    for bad in (0.0, -1.0, math.nan, math.inf):
        with pytest.raises(ValueError, match="radiance_scale"):
            SpotLight(radiance_scale=bad)


def test_the_scale_is_saved_with_the_light_and_an_older_state_loads_as_one():
    """The scale is part of the state dict (a run reloads in its unit); a state saved before it existed has no
    such entry and loads as 1, the unit it trained in."""
    saved = SpotLight(radiance_scale=12.25).state_dict()
    assert float(saved["radiance_scale"]) == 12.25
    restored = SpotLight()
    restored.load_state_dict(saved)
    assert float(restored.radiance_scale) == 12.25
    older = {k: v for k, v in saved.items() if k != "radiance_scale"}
    light = SpotLight(radiance_scale=3.0)
    light.load_state_dict(older)
    assert float(light.radiance_scale) == 1.0


def test_a_run_trained_in_the_median_depth_unit_records_reloads_and_relights_in_it(tmp_path_factory, tmp_path):
    """A short run with ``spot_radiance_unit=median_depth``: the scene it starts from has the unit of its initial
    Gaussians and training views (not 1), and the 3DGS variant no light; the trained run keeps that unit (a buffer,
    not learned), light.json reports it, and the run relights."""
    from conftest import synthetic_box_dataset
    from spotlessgs.run import RunSpec, train
    from spotlessgs.training.trainer import build_scene, load_run
    from test_run_api import SMALL

    box = synthetic_box_dataset(tmp_path_factory, "unit", seed=4)
    spec = RunSpec(data=box, model="spotless", preset="tiny",
                   overrides=(*SMALL, ("spot_radiance_unit", "median_depth")))
    run = train(spec, tmp_path / "run", progress=False)
    scene, views, config, _info = load_run(run.dir, device="cpu")
    start = build_scene(views, "spotless", config, seed=0)
    expected = spot_radiance_scale("median_depth", start.gaussians.means.detach(), views.cameras, views.train,
                                   config.falloff_tau, config.falloff_gamma)
    assert float(start.appearance.light.radiance_scale) == pytest.approx(expected, rel=1e-6) and expected > 1.5
    assert build_scene(views, "3dgs", config, seed=0).appearance.light is None
    assert float(scene.appearance.light.radiance_scale) == pytest.approx(expected, rel=1e-6)
    assert json.loads((run.dir / "light.json").read_text())["estimate"]["radiance_scale"] == pytest.approx(expected)
    assert run.relight("test", tmp_path / "relit", progress=False, device="cpu")["count"] > 0


def test_the_albedo_scale_script_finds_the_factor_and_what_the_cap_flattens():
    """scripts/albedo_scale.py's statistics on a learned albedo that is the truth × 1.25, capped at 1: k = 1.25, and
    the pixels whose true albedo exceeds 0.8 are the ones flattened and at the cap; pixels without a true albedo
    (below 0.02) do not count."""
    import importlib.util
    from pathlib import Path

    import numpy as np

    path = Path(__file__).resolve().parents[1] / "scripts" / "albedo_scale.py"
    spec = importlib.util.spec_from_file_location("albedo_scale", path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    rng = np.random.default_rng(0)
    true = rng.uniform(0.05, 0.95, size=(4000, 3))
    true[:500] = 0.0  # no true albedo: an emitter, a gap
    learned = np.minimum(1.25 * true, 1.0)
    stats = module.albedo_scale_stats(learned, true)
    lit = true[500:]
    assert stats["k"] == pytest.approx(1.25)
    assert stats["flattened"] == pytest.approx(float((lit.max(1) > 0.8).mean()))
    assert stats["at_cap"] == pytest.approx(float((lit.max(1) > 0.76).mean()))
    assert stats["spread"] == pytest.approx(0.0, abs=1e-12)
