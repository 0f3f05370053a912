"""The monotone angular profile (models.angular_profile): interpolation, ordering, its setting and learning rate."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest
import torch

from spotlessgs.models.angular_profile import PROFILE_MAX_ANGLE, MonotoneProfile
from spotlessgs.models.light import SpotLight, cone_profile
from spotlessgs.models.shading import MODEL_VARIANTS, build_appearance_models


def _random_profile(knots: int, seed: int) -> MonotoneProfile:
    """A profile with seeded random parameters (drops of very different sizes, some near zero)."""
    profile = MonotoneProfile(knots)
    gen = torch.Generator().manual_seed(seed)
    with torch.no_grad():
        profile.log_peak.copy_(torch.randn((), generator=gen))
        profile.decrement_logits.copy_(4.0 * torch.randn(knots - 1, generator=gen))
    return profile.double()


@pytest.mark.parametrize("knots, seed", [(2, 0), (7, 1), (48, 2)])
def test_the_profile_interpolates_its_knots_and_never_rises(knots, seed):
    """Φ at the k-th knot angle is v_k, halfway between two knots their mean, beyond 90° the last value; the knots
    are positive and non-increasing whatever the parameters, and v_0 = exp(log_peak), v_k / v_{k-1} =
    exp(-softplus(c_k)) by hand."""
    profile = _random_profile(knots, seed)
    values = profile.knot_values().detach().numpy()
    peak = math.exp(float(profile.log_peak.detach()))
    logits = profile.decrement_logits.detach().numpy()
    by_hand = peak * np.exp(-np.cumsum(np.log1p(np.exp(logits))))
    np.testing.assert_allclose(values, np.concatenate([[peak], by_hand]), rtol=1e-12)
    assert (values > 0).all() and (np.diff(values) <= 0).all()
    step = PROFILE_MAX_ANGLE / (knots - 1)
    at_knots = profile(torch.arange(knots, dtype=torch.float64)[:, None] * step).detach().numpy()[:, 0]
    np.testing.assert_allclose(at_knots, values, rtol=1e-12)
    halfway = profile((torch.arange(knots - 1, dtype=torch.float64)[:, None] + 0.5) * step).detach().numpy()[:, 0]
    np.testing.assert_allclose(halfway, 0.5 * (values[:-1] + values[1:]), rtol=1e-12)
    beyond = profile(torch.tensor([[2.0], [math.pi]], dtype=torch.float64)).detach().numpy()[:, 0]
    np.testing.assert_allclose(beyond, values[-1], rtol=1e-12)
    dense = profile(torch.linspace(0, math.pi, 2001, dtype=torch.float64)[:, None]).detach().numpy()[:, 0]
    assert (np.diff(dense) <= 1e-15).all()


def test_the_angle_gets_the_profiles_slope_as_its_gradient():
    """dΦ/dθ between two knots is (v_{k+1} - v_k) / Δθ: the lamp's pose learns from the profile's edge."""
    profile = _random_profile(12, 3)
    step = PROFILE_MAX_ANGLE / 11
    theta = torch.tensor([[4.3 * step]], dtype=torch.float64, requires_grad=True)
    profile(theta).sum().backward()
    values = profile.knot_values().detach()
    assert float(theta.grad) == pytest.approx(float(values[5] - values[4]) / step, rel=1e-9)
    assert theta.grad < 0 or values[5] == values[4]


def test_the_monotone_rid_fits_a_spot_lamps_cone():
    """Fitted to Blender's cone of the shipped rooms (65°, blend 0.35) and a narrower one, the profile is within
    piecewise-linear interpolation error of it: a 1.9° knot spacing across an edge 6.4° and 4.6° wide."""
    for half_deg, blend, tol in ((32.5, 0.35, 0.05), (30.0, 0.3, 0.06)):
        light = SpotLight(rid_model="monotone")
        max_err = light.fit_rid_to_cone(math.radians(half_deg), blend)
        thetas = torch.linspace(0, math.pi, 1001)
        err = (light.rid_curve(thetas) - cone_profile(thetas, math.radians(half_deg), blend)).abs()
        assert max_err < tol and float(err.max()) < tol and float(err.pow(2).mean().sqrt()) < 0.01


def test_rid_model_setting_reaches_the_light_and_its_own_learning_rate():
    """TrainConfig.rid_model reaches the spotlight through model_config; the profile learns at lr_rid_profile and
    the fall-off at lr_light; the MLP is the default; an unknown form is refused where it is named."""
    from spotlessgs.models.relightable import RelightableScene
    from spotlessgs.training.config import TrainConfig
    from spotlessgs.training.trainer import build_optimizers, model_config
    from test_models_shading import _scene

    train = TrainConfig(rid_model="monotone", brdf_hidden=8, lr_light=2e-3, lr_rid_profile=3e-2)
    scene = RelightableScene.create(model_config("spotless", train), _scene(), seed=0)
    light = scene.appearance.light
    assert isinstance(light.rid, MonotoneProfile)
    groups = build_optimizers(scene, train, extent=1.0)["appearance"].param_groups
    lr_of = {id(p): group["lr"] for group in groups for p in group["params"]}
    assert lr_of[id(light.rid.log_peak)] == lr_of[id(light.rid.decrement_logits)] == 3e-2
    assert lr_of[id(light.log_tau)] == lr_of[id(light.log_gamma)] == 2e-3
    assert isinstance(build_appearance_models("spotless").light.rid, torch.nn.Sequential)
    with pytest.raises(ValueError, match="rid_model must be one of"):
        dataclasses.replace(MODEL_VARIANTS["spotless"], rid_model="spline")
    with pytest.raises(ValueError, match="rid_model must be one of"):
        SpotLight(rid_model="spline")
    with pytest.raises(ValueError, match="need knots >= 2"):
        MonotoneProfile(1)


def test_a_run_with_the_monotone_profile_reloads_it(tmp_path, tmp_path_factory, one_torch_thread):
    """A run trained with rid_model=monotone comes back with the profile it learned (config.json carries the
    setting; the checkpoint the knots), and relights."""
    from conftest import synthetic_box_dataset
    from spotlessgs.run import RunSpec, train
    from spotlessgs.training.checkpoint import load_checkpoint
    from spotlessgs.training.trainer import load_run
    from test_run_api import SMALL

    box = synthetic_box_dataset(tmp_path_factory, "profile", seed=4)
    run = train(RunSpec(data=box, model="spotless", preset="tiny", overrides=(*SMALL, ("rid_model", "monotone"))),
                tmp_path / "run", progress=False)
    scene, _views, config, _info = load_run(run.dir, device="cpu")
    assert config.rid_model == "monotone" and isinstance(scene.appearance.light.rid, MonotoneProfile)
    saved = load_checkpoint(run.dir)["appearance"]
    torch.testing.assert_close(scene.appearance.light.rid.decrement_logits.detach(),
                               saved["light.rid.decrement_logits"], rtol=0, atol=0)
    assert not torch.equal(saved["light.rid.decrement_logits"], MonotoneProfile().decrement_logits.detach())  # learned
    assert run.relight("test", tmp_path / "relit", progress=False, device="cpu")["count"] > 0
