"""The trainer: losses on hard cases, the densification strategy, and (with Blender data) a tiny end-to-end run that
must do real work, resume equality and the NaN guard."""

from __future__ import annotations

import dataclasses

import json
import math
import shutil
from pathlib import Path

import numpy as np
import pytest
import torch

from spotlessgs.io.dataset import read_dataset
from spotlessgs.models.gaussians import GaussianParams
from spotlessgs.training.losses import clipped_l1, depth_spread_loss, photometric_loss
from spotlessgs.training.strategy import DensifyConfig, DensifyStrategy

ROOT = Path(__file__).resolve().parents[1]


# ---- losses ---------------------------------------------------------------------------------------------------------


def test_clipped_pixels_only_penalise_darker_predictions():
    target = torch.full((4, 4, 3), 1.0)
    sat = torch.ones(4, 4, dtype=torch.bool)
    brighter = torch.full((4, 4, 3), 3.0, requires_grad=True)
    loss = clipped_l1(brighter, target, sat)
    loss.backward()
    assert float(loss.detach()) == 0.0 and float(brighter.grad.abs().sum()) == 0.0  # no pull towards the clipped value
    darker = torch.full((4, 4, 3), 0.5, requires_grad=True)
    loss = clipped_l1(darker, target, sat)
    loss.backward()
    assert float(loss.detach()) == pytest.approx(0.5)
    assert torch.all(darker.grad < 0)  # pushed up towards at least the observation
    # unclipped pixels: plain L1 both ways
    assert float(clipped_l1(brighter.detach(), target, ~sat)) == pytest.approx(2.0)


@pytest.mark.parametrize("space", ["linear", "srgb"])
@pytest.mark.parametrize("frame", ["black", "saturated"])
def test_photometric_loss_is_finite_on_black_and_saturated_frames(frame, space):
    value = 0.0 if frame == "black" else 1.0
    target = torch.full((16, 16, 3), value)
    sat = torch.full((16, 16), frame == "saturated")
    pred = torch.rand(16, 16, 3, generator=torch.Generator().manual_seed(0)).requires_grad_(True)
    loss, parts = photometric_loss(pred, target, sat, 0.2, space)
    loss.backward()
    assert math.isfinite(float(loss.detach())) and torch.isfinite(pred.grad).all()
    assert 0.0 <= parts["l1"] <= 1.0


def test_srgb_loss_weighs_dim_pixels_as_they_show():
    """In sRGB space an error of 0.01 on a dim pixel (linear 0.02) costs several times one on a bright pixel (0.8),
    in linear light the same; above 1 the encoding continues with its slope at 1 (1.055 / 2.4), so an overshooting
    render keeps a gradient; clipped pixels stay one-sided."""
    from spotlessgs.training.losses import srgb_encoded

    def l1(pred, target, space):
        return float(photometric_loss(torch.tensor([[pred]]), torch.tensor([[target]]), torch.tensor([[False]]),
                                      0.0, space)[0])

    dim, bright = [0.02] * 3, [0.8] * 3
    plus = [0.03] * 3, [0.81] * 3
    assert l1(plus[0], dim, "linear") == pytest.approx(l1(plus[1], bright, "linear"), rel=1e-4)
    ratio = l1(plus[0], dim, "srgb") / l1(plus[1], bright, "srgb")
    srgb = lambda v: 1.055 * v ** (1 / 2.4) - 0.055  # noqa: E731 - the encoding by hand
    assert ratio == pytest.approx((srgb(0.03) - srgb(0.02)) / (srgb(0.81) - srgb(0.8)), rel=1e-3) and ratio > 5
    x = torch.tensor([0.5, 1.0, 1.5], requires_grad=True)
    y = srgb_encoded(x)
    assert float(y[2].detach()) == pytest.approx(1.0 + 0.5 * 1.055 / 2.4)
    y.sum().backward()
    assert float(x.grad[2]) == pytest.approx(1.055 / 2.4)
    sat = torch.tensor([[True]])
    over = photometric_loss(torch.tensor([[[1.4] * 3]]), torch.tensor([[[1.0] * 3]]), sat, 0.0, "srgb")[0]
    assert float(over) == 0.0
    with pytest.raises(ValueError, match="unknown loss space 'log'"):
        photometric_loss(torch.zeros(2, 2, 3), torch.zeros(2, 2, 3), torch.zeros(2, 2, dtype=torch.bool), 0.2, "log")


# ---- densification strategy -----------------------------------------------------------------------------------------


def _gaussians(n=6, scale=0.001):
    xyz = np.stack([np.linspace(0, 1, n), np.zeros(n), np.full(n, 2.0)], 1)
    g = GaussianParams.from_point_cloud(xyz, np.full((n, 3), 128, np.uint8))
    with torch.no_grad():
        g.params["log_scales"].fill_(math.log(scale))
    return g


def _optimizers(g):
    opts = {k: torch.optim.Adam([p], lr=1e-3) for k, p in g.params.items()}
    loss = sum(p.sum() for p in g.params.values())
    loss.backward()
    for o in opts.values():
        o.step()
    return opts


def test_strategy_clones_small_and_splits_large_gaussians_with_their_optimizer_state():
    g = _gaussians(6)
    with torch.no_grad():
        g.params["log_scales"][3:] = math.log(0.5)  # large ones: split
    opts = _optimizers(g)
    cfg = DensifyConfig(densify_from=1, densify_until=100, densify_every=1, grad_threshold=1e-3, percent_dense=0.01,
                        prune_opacity=0.0, opacity_reset_every=0)
    strat = DensifyStrategy(cfg, scene_extent=1.0, generator=torch.Generator().manual_seed(0))
    grad = torch.zeros(6, 2)
    grad[[0, 4]] = 1.0  # high gradient for one small (0) and one large (4) Gaussian
    parent_scale = g.scales.detach()[4].clone()
    parent_mean = g.means.detach()[4].clone()
    changes = strat.step_post_backward(0, g, opts, grad, torch.ones(6, dtype=torch.int32), 64, 48)
    assert changes["cloned"] == 1 and changes["split"] == 1
    assert len(g) == 6 + 1 + 1  # clone adds one; split replaces one by two
    for name, p in g.params.items():
        state = opts[name].state[p]
        assert state["exp_avg"].shape == p.shape and state["exp_avg_sq"].shape == p.shape
        assert opts[name].param_groups[0]["params"][0] is p
    # split children (appended last) are 1.6 times smaller than the parent and sampled around it
    torch.testing.assert_close(g.scales.detach()[-2:], (parent_scale / 1.6).expand(2, 3), rtol=1e-5, atol=0)
    assert torch.all((g.means.detach()[-2:] - parent_mean).abs() < 5 * parent_scale)
    assert not torch.any(torch.all(g.means.detach()[:-2] == parent_mean, dim=1))  # the parent itself is gone


def test_strategy_respects_the_gaussian_cap_and_prunes_transparent_ones():
    g = _gaussians(6)
    with torch.no_grad():
        g.params["opacity_logits"][5] = -10.0  # transparent: pruned
    opts = _optimizers(g)
    cfg = DensifyConfig(densify_from=1, densify_until=100, densify_every=1, grad_threshold=1e-3, prune_opacity=0.005,
                        opacity_reset_every=0, max_gaussians=7)
    strat = DensifyStrategy(cfg, scene_extent=1.0, generator=torch.Generator().manual_seed(0))
    grad = torch.ones(6, 2)
    changes = strat.step_post_backward(0, g, opts, grad, torch.ones(6, dtype=torch.int32), 64, 48)
    assert changes["cloned"] + changes["split"] == 1  # only one slot under the cap
    assert changes["pruned"] == 1
    assert len(g) <= 7


def test_opacity_reset_caps_opacities_and_clears_their_moments():
    g = _gaussians(4)
    opts = _optimizers(g)
    cfg = DensifyConfig(densify_from=1000, densify_until=2000, opacity_reset_every=5, reset_opacity_value=0.01)
    strat = DensifyStrategy(cfg, scene_extent=1.0, generator=torch.Generator().manual_seed(0))
    for step in range(5):
        strat.step_post_backward(step, g, opts, torch.zeros(4, 2), torch.ones(4, dtype=torch.int32), 64, 48)
    assert float(g.opacities.detach().max()) <= 0.01 + 1e-6
    p = g.params["opacity_logits"]
    assert float(opts["opacity_logits"].state[p]["exp_avg"].abs().sum().detach()) == 0.0


# ---- end to end with a Blender-rendered scene --------------------------------------------------------------------------


@pytest.fixture(scope="module")
def bedroom(tmp_path_factory):
    pytest.importorskip("bpy")
    from simulator.render_pipeline import ExecutionOptions, RenderConfig, render_dataset

    out = tmp_path_factory.mktemp("train-data") / "bedroom"
    config = RenderConfig.from_preset("uneven", frames=12, width=80, height=60, samples=8, seed=1)
    render_dataset(ROOT / "scenes" / "bedroom" / "house.json", out, config,
                   execution=ExecutionOptions(progress=False))
    return out


def _tiny(**overrides):
    from spotlessgs.training.config import preset

    base = dict(iterations=300, image_width=80, num_threads=2, densify_from=100, densify_until=250, densify_every=50,
                log_every=25, checkpoint_every=100)
    base.update(overrides)
    return preset("tiny", **base)


@pytest.mark.blender
def test_tiny_training_does_real_work(bedroom, tmp_path):
    from evaluation.alignment import apply_gain, exposure_gain
    from spotlessgs.metrics import psnr
    from spotlessgs.io.images import read_image
    from spotlessgs.rendering import render_run
    from spotlessgs.training.trainer import train

    run = tmp_path / "run"
    # every parameter learned, the normals too: a dense start's normals held (trust_start_geometry=auto) fit these 300
    # steps' training views 0.7 dB less (23.86 dB) and its held-out views 4.8 dB better
    result = train(bedroom, run, "spotless", _tiny(trust_start_geometry="off"), seed=0, progress=False)
    log = [json.loads(line) for line in (run / "metrics.jsonl").read_text().splitlines()]
    first, last = np.mean([r["loss"] for r in log[:2]]), np.mean([r["loss"] for r in log[-2:]])
    assert last < 0.6 * first, (first, last)
    assert np.mean([r["psnr"] for r in log[-4:]]) > 24.0  # training-view reconstruction (linear) PSNR
    assert result.test_psnr is not None and math.isfinite(result.test_psnr)  # held-out views are reported

    light = json.loads((run / "light.json").read_text())
    assert light["errors"]["axis_error_deg"] < 5.0
    assert (run / "light_path.png").stat().st_size > 0  # the lamp's learned position over the steps

    render_run(run, "relit", "test", progress=False)
    meta = json.loads((bedroom / "transforms.json").read_text())
    test = meta["spotless"]["split"]["test"]
    names = [Path(meta["frames"][k]["file_path"]).name for k in test]

    def stack(folder):
        return torch.stack([torch.from_numpy(read_image(folder / n)).permute(2, 0, 1) for n in names])

    relit, inputs, gt = stack(run / "relit"), stack(bedroom / "images"), stack(bedroom / "gt")

    def variation(x):
        lum = x.mean(1)
        return float((lum.std(dim=(1, 2)) / lum.mean(dim=(1, 2)).clamp(min=1e-6)).mean())

    assert variation(relit) < variation(inputs)

    def aligned_psnr(pred):
        return float(psnr(apply_gain(pred, exposure_gain(pred, gt)).clamp(0, 1), gt).mean())

    assert aligned_psnr(relit) > aligned_psnr(inputs) + 1.0

    # Relit image = R·L0 + R·L_lf: leaving the low-frequency light out removes exactly the L0 = 0 image.
    from spotlessgs.io.exr import read_exr

    def linear(l0, low_frequency, name):
        out = tmp_path / name
        summary = render_run(run, "relit", "test", out, l0=l0, exr=True, progress=False, low_frequency=low_frequency)
        assert summary["low_frequency"] is low_frequency
        return np.stack([np.stack([read_exr(out / (Path(n).stem + ".exr"))[c] for c in "RGB"], -1) for n in names])

    full, reflectance = linear([1.0, 1.0, 1.0], True, "full"), linear([1.0, 1.0, 1.0], False, "no_lf")
    low_only = linear([0.0, 0.0, 0.0], True, "low_only")
    assert low_only.mean() > 1e-3 * full.mean()  # the SH light learned something
    np.testing.assert_allclose(full, reflectance + low_only, atol=1e-5)
    with pytest.raises(ValueError, match="only applies to relit"):
        render_run(run, "spot", "test", tmp_path / "spot", low_frequency=False, progress=False)


def _changed_copy(data, where):
    """A copy of the dataset ``data`` at ``where`` with one pixel of its first frame changed."""
    from spotlessgs.io.images import read_image, write_png

    shutil.copytree(data, where)
    frame = where / read_dataset(where).file_paths[0]
    image = read_image(frame)
    image[0, 0] = 1.0 - image[0, 0]
    write_png(frame, image)
    return where


@pytest.mark.blender
def test_resume_equals_an_uninterrupted_run(bedroom, tmp_path):
    from spotlessgs.io.dataset_fingerprint import dataset_fingerprint
    from spotlessgs.io.errors import InputError
    from spotlessgs.training.checkpoint import checkpoint_path, load_checkpoint
    from spotlessgs.training.trainer import train

    cfg = _tiny(iterations=60, image_width=40, densify_from=20, densify_until=50, densify_every=10,
                checkpoint_every=30)
    train(bedroom, tmp_path / "full", "darkgs+sh", cfg, seed=3, progress=False)
    train(bedroom, tmp_path / "split", "darkgs+sh", cfg, seed=3, progress=False, stop_after=30)
    with pytest.raises(FileExistsError, match="--resume"):
        train(bedroom, tmp_path / "split", "darkgs+sh", cfg, seed=3, progress=False)
    with pytest.raises(ValueError, match=r"other settings .*\(lr_albedo: run 0\.\d+, now 0\.01\)"):
        train(bedroom, tmp_path / "split", "darkgs+sh", cfg.replace(lr_albedo=0.01), seed=3, resume=True,
              progress=False)
    # the same settings on other files (one pixel of one frame changed): refused, the run left as it was
    changed = _changed_copy(bedroom, tmp_path / "changed")
    stamp = (tmp_path / "split" / "run.json").read_bytes(), checkpoint_path(tmp_path / "split").stat().st_mtime_ns
    with pytest.raises(InputError, match=r"split: --resume on another dataset: the files of .*changed differ from "
                                         r"those the run was trained on"):
        train(changed, tmp_path / "split", "darkgs+sh", cfg, seed=3, resume=True, progress=False)
    assert stamp == ((tmp_path / "split" / "run.json").read_bytes(),
                     checkpoint_path(tmp_path / "split").stat().st_mtime_ns)
    assert json.loads(stamp[0])["data_fingerprint"] == dataset_fingerprint(read_dataset(bedroom))
    moved = tmp_path / "moved" / "bedroom"  # the same files elsewhere: the run resumes on them
    shutil.copytree(bedroom, moved)
    train(moved, tmp_path / "split", "darkgs+sh", cfg, seed=3, progress=False, resume=True)
    assert json.loads((tmp_path / "split" / "run.json").read_text())["data_dir"] == str(moved.resolve())
    # a run saved before the fingerprint existed is not compared, and records one when resumed
    info = json.loads((tmp_path / "split" / "run.json").read_text())
    (tmp_path / "split" / "run.json").write_text(json.dumps({k: v for k, v in info.items() if k != "data_fingerprint"}))
    train(bedroom, tmp_path / "split", "darkgs+sh", cfg, seed=3, progress=False, resume=True)
    assert json.loads((tmp_path / "split" / "run.json").read_text())["data_fingerprint"] == info["data_fingerprint"]
    # resuming the finished run trains nothing and reports the time per step and last loss of the session that
    # trained it, as its last step logged them (not the time of a session without steps)
    summary = json.loads((tmp_path / "full" / "train_summary.json").read_text())
    logged = json.loads((tmp_path / "full" / "metrics.jsonl").read_text().splitlines()[-1])
    again = train(bedroom, tmp_path / "full", "darkgs+sh", cfg, seed=3, progress=False, resume=True)
    assert again.steps == logged["step"] == 60 and again.ms_per_step == logged["ms_per_step"] > 1.0
    assert again.ms_per_step == pytest.approx(summary["ms_per_step"], rel=0.5)
    assert again.final_loss == logged["loss"] == summary["final_loss"]
    resumed = json.loads((tmp_path / "full" / "train_summary.json").read_text())
    assert (resumed["ms_per_step"], resumed["final_loss"]) == (logged["ms_per_step"], logged["loss"])
    a, b = load_checkpoint(tmp_path / "full"), load_checkpoint(tmp_path / "split")
    assert a["step"] == b["step"] == 60
    for name, tensor in a["gaussians"].items():
        torch.testing.assert_close(b["gaussians"][name], tensor, rtol=1e-5, atol=1e-6, msg=name)
    for name, tensor in a["appearance"].items():
        torch.testing.assert_close(b["appearance"][name], tensor, rtol=1e-5, atol=1e-6, msg=name)


@pytest.mark.blender
def test_resume_with_spot_shadows_reuses_the_checkpointed_maps(bedroom, tmp_path):
    """The shadow maps and the lamp bounce's irradiance go into the checkpoint: a run stopped while its views reuse
    them resumes as if never stopped."""
    from spotlessgs.training.checkpoint import load_checkpoint
    from spotlessgs.training.trainer import train

    cfg = _tiny(iterations=40, image_width=40, densify_from=1000, checkpoint_every=20, spot_shadows=True,
                shadow_map_every=30, lamp_bounce=True, lamp_bounce_every=30)
    train(bedroom, tmp_path / "full", "darkgs", cfg, seed=3, progress=False)
    train(bedroom, tmp_path / "split", "darkgs", cfg, seed=3, progress=False, stop_after=20)
    stopped = load_checkpoint(tmp_path / "split")
    assert stopped["shadow_maps"] and stopped["lamp_bounces"]  # what steps < 20 rendered, still in use after it
    train(bedroom, tmp_path / "split", "darkgs", cfg, seed=3, progress=False, resume=True)
    a, b = load_checkpoint(tmp_path / "full"), load_checkpoint(tmp_path / "split")
    for name, tensor in a["gaussians"].items():
        torch.testing.assert_close(b["gaussians"][name], tensor, rtol=1e-5, atol=1e-6, msg=name)
    torch.testing.assert_close(b["appearance"]["light.translation"], a["appearance"]["light.translation"])
    torch.testing.assert_close(b["appearance"]["lamp_bounce.log_gain"], a["appearance"]["lamp_bounce.log_gain"])


def test_recorded_model_settings_complete_an_older_record_from_the_saved_config():
    """A checkpoint's model settings as recorded; what an older record lacks, as the run's saved config set it (a
    checkpoint without any record: the bounce as its modules show); a record of the wrong form names the file."""
    from pathlib import Path

    from spotlessgs.io.errors import InputError
    from spotlessgs.training.config import TrainConfig
    from spotlessgs.training.trainer import recorded_model_settings

    saved = TrainConfig(rid_model="mlp")  # as the versions that wrote records without the profile saved it
    where = Path("run/checkpoints/last.safetensors")
    full = {"lamp_bounce": True, "brdf_upper_clamp": False, "spot_shadows": True, "rid_model": "monotone",
            "low_frequency_shading": "irradiance", "bounce_light_degree": -1}
    assert recorded_model_settings({"model_settings": full, "appearance": {}}, saved, where) == full
    # a record written before the camera-frame bounce left the trusted start: the degree its saved config holds
    of_2026_12_06 = {"model_settings": {k: v for k, v in full.items() if k != "bounce_light_degree"}}
    assert saved.bounce_light_degree == 2
    assert recorded_model_settings(of_2026_12_06, saved, where) == {**full, "bounce_light_degree": 2}
    of_2026_11_27 = {"model_settings": {"lamp_bounce": True, "brdf_upper_clamp": False}, "appearance": {}}
    assert recorded_model_settings(of_2026_11_27, saved, where) == {**full, "spot_shadows": False, "rid_model": "mlp",
                                                                    "low_frequency_shading": "spot_cosine",
                                                                    "bounce_light_degree": 2}
    unrecorded = {"appearance": {"lamp_bounce.log_gain": 0.0}}
    assert recorded_model_settings(unrecorded, saved.replace(rid_model="monotone"), where) == {
        "lamp_bounce": True, "brdf_upper_clamp": True, "spot_shadows": False, "rid_model": "monotone",
        "low_frequency_shading": "spot_cosine", "bounce_light_degree": 2}
    assert recorded_model_settings({"appearance": {}}, saved, where)["lamp_bounce"] is False
    with pytest.raises(InputError, match=r"last.safetensors: model_settings must give rid_model as one of "
                                         r"\"mlp\", \"monotone\", got 'cubic'"):
        recorded_model_settings({"model_settings": {**full, "rid_model": "cubic"}}, saved, where)
    with pytest.raises(InputError, match="spot_shadows as one of true, false, got 1"):
        recorded_model_settings({"model_settings": {**full, "spot_shadows": 1}}, saved, where)
    with pytest.raises(InputError, match=r"bounce_light_degree as one of -1, 0, 1, 2, 3, got 4"):
        recorded_model_settings({"model_settings": {**full, "bounce_light_degree": 4}}, saved, where)
    with pytest.raises(InputError, match=r"bounce_light_degree as one of -1, 0, 1, 2, 3, got 2.0"):
        recorded_model_settings({"model_settings": {**full, "bounce_light_degree": 2.0}}, saved, where)
    with pytest.raises(InputError, match="model_settings must be a table"):
        recorded_model_settings({"model_settings": ["lamp_bounce"]}, saved, where)


def test_the_angular_profile_auto_is_monotone_for_spotlessgs_only():
    """rid_model "auto" resolves to the monotone profile for a model with an SH light and a learned BRDF, on any start,
    and to the paper's MLP for the DarkGS variants; a profile given is kept; a run saved before the setting existed
    trained with the MLP profile."""
    from spotlessgs.training.config import TrainConfig, with_defaults
    from spotlessgs.training.selection import candidate_model
    from spotlessgs.training.trainer import model_config

    auto = TrainConfig()
    assert auto.rid_model == "auto"
    resolved = {name: model_config(name, auto).rid_model for name in ("spotless", "darkgs", "darkgs+sh",
                                                                       "darkgs+brdf", "darkgs-calibrated")}
    assert resolved == {"spotless": "monotone", "darkgs": "mlp", "darkgs+sh": "mlp", "darkgs+brdf": "mlp",
                        "darkgs-calibrated": "mlp"}
    assert model_config(candidate_model(0, "mlp"), auto).rid_model == "monotone"  # what counts: the model's parts
    assert model_config(candidate_model(3, "lambert"), auto).rid_model == "mlp"
    assert model_config("spotless", auto.replace(rid_model="mlp")).rid_model == "mlp"
    assert model_config("darkgs", auto.replace(rid_model="monotone")).rid_model == "monotone"
    assert with_defaults(TrainConfig, {})["rid_model"] == "mlp"


def test_a_run_begun_with_the_mlp_profile_resumes_with_it_under_auto(tmp_path_factory):
    """A SpotlessGS run on a start that is not trusted, begun with rid_model "mlp" (in its settings and its
    checkpoint's record), resumes under "auto" with the profile it began with; a fresh run under "auto" has the
    monotone one."""
    from conftest import synthetic_box_dataset

    from spotlessgs.models.angular_profile import MonotoneProfile
    from spotlessgs.training.checkpoint import load_checkpoint
    from spotlessgs.training.trainer import load_run, train

    data = synthetic_box_dataset(tmp_path_factory, "auto-profile", seed=5)
    run = tmp_path_factory.mktemp("auto-profile-run") / "run"
    cfg = _tiny(iterations=20, image_width=40, densify_from=1000, checkpoint_every=10, num_threads=1, rid_model="auto")
    train(data, run, "spotless", cfg.replace(rid_model="mlp"), seed=0, progress=False, stop_after=10)
    assert load_checkpoint(run)["model_settings"]["rid_model"] == "mlp"
    assert load_checkpoint(run)["depth_spread_weight"] == cfg.depth_spread_weight > 0  # SpotlessGS: on any dataset
    result = train(data, run, "spotless", cfg, seed=0, progress=False, resume=True)
    assert result.steps == 20 and load_checkpoint(run)["model_settings"]["rid_model"] == "mlp"
    scene, _views, _config, _info = load_run(run, device="cpu")
    assert not isinstance(scene.appearance.light.rid, MonotoneProfile)
    fresh = tmp_path_factory.mktemp("auto-profile-fresh") / "run"
    train(data, fresh, "spotless", cfg, seed=0, progress=False)
    assert isinstance(load_run(fresh, device="cpu")[0].appearance.light.rid, MonotoneProfile)


@pytest.mark.blender
def test_a_trusted_run_begun_by_the_previous_version_resumes_with_its_own_lamp_model(bedroom, tmp_path):
    """A run that the previous version began on a trusted start (its record: the bounce and the clamp; its lamp: the
    MLP profile, the paper's shading of the room light, the camera-frame bounce SH) resumes with this version, whose
    trust adds the monotone profile and the irradiance shading and drops the camera-frame light: the model keeps the
    structure and shading its checkpoint records, and its saved config the rest."""
    from spotlessgs.models.angular_profile import MonotoneProfile
    from spotlessgs.training.checkpoint import load_checkpoint, save_checkpoint
    from spotlessgs.training.trainer import load_run, train

    cfg = _tiny(iterations=30, image_width=40, densify_from=1000, checkpoint_every=15, trust_start_geometry="auto")
    as_trusted_then = cfg.replace(trust_start_geometry="off", lr_normals=0.0, lamp_bounce=True, brdf_upper_clamp=False,
                                  rid_model="mlp")
    train(bedroom, tmp_path / "run", "spotless", as_trusted_then, seed=1, progress=False, stop_after=15)
    path = tmp_path / "run" / "config.json"
    written = json.loads(path.read_text())
    written["train"] = {**written["train"], "trust_start_geometry": "auto", "lr_normals": cfg.lr_normals,
                        "lamp_bounce": False, "brdf_upper_clamp": True, "rid_model": "mlp"}  # as that version wrote
    # it: the settings given, its default profile
    path.write_text(json.dumps(written))
    ckpt = load_checkpoint(tmp_path / "run")
    save_checkpoint(tmp_path / "run", {**ckpt, "model_settings": {"lamp_bounce": True, "brdf_upper_clamp": False}})
    result = train(bedroom, tmp_path / "run", "spotless", cfg, seed=1, progress=False, resume=True)
    assert result.steps == 30
    assert load_checkpoint(tmp_path / "run")["model_settings"] == {"lamp_bounce": True, "brdf_upper_clamp": False,
                                                                   "spot_shadows": False, "rid_model": "mlp",
                                                                   "low_frequency_shading": "spot_cosine",
                                                                   "bounce_light_degree": 2}
    scene, _views, config, _info = load_run(tmp_path / "run")
    assert not isinstance(scene.appearance.light.rid, MonotoneProfile)
    assert scene.appearance.bounce_light.degree == config.bounce_light_degree == 2  # its camera-frame light kept
    assert config.low_frequency_shading == scene.config.low_frequency_shading == "spot_cosine"
    assert scene.appearance.lamp_bounce is not None and config.lr_normals == 0.0


@pytest.mark.blender
def test_a_run_from_before_a_setting_existed_resumes_with_its_default(bedroom, tmp_path):
    """A run whose config.json predates a TrainConfig field and a ModelConfig switch (both absent from the file)
    resumes: the missing settings take what the run trained with, their PREDATING_VALUES where listed, else their
    defaults. (A custom ModelConfig's switches, kept in run.json, are completed the same way.)"""
    from spotlessgs.training.config import TrainConfig
    from spotlessgs.training.trainer import load_run, train

    # a run from before the bounce light, the camera-relative shadows and the depth-spread term: it trained with none
    # of them (its shadows, had it turned them on, the lamp's map alone), whatever today's defaults
    cfg = _tiny(iterations=40, image_width=40, densify_from=1000, checkpoint_every=20, bounce_light_degree=-1,
                shadow_camera_relative=False, depth_spread_weight=0.0, depth_spread="on", depth_spread_every=1)
    train(bedroom, tmp_path / "run", "darkgs+sh", cfg, seed=0, progress=False, stop_after=20)
    path = tmp_path / "run" / "config.json"
    saved = json.loads(path.read_text())
    for name in ("low_frequency_shading", "bounce_light_degree", "shadow_camera_relative"):
        del saved["train"][name]
        del saved["model_config"][name]
    for name in ("depth_spread_weight", "depth_spread", "depth_spread_every"):  # TrainConfig fields only
        del saved["train"][name]
    path.write_text(json.dumps(saved))
    scene, _, config, _ = load_run(tmp_path / "run", device="cpu")
    assert scene.appearance.bounce_light is None  # absent: the value before it
    assert not scene.config.shadow_camera_relative
    # absent: weight 0, not today's 0.1, and a weight that applies to every model, as the term did before "auto"
    assert (config.depth_spread_weight, config.depth_spread, config.depth_spread_every) == (0.0, "on", 1)
    assert TrainConfig().depth_spread_weight == 0.4 and TrainConfig().depth_spread == "auto"
    result = train(bedroom, tmp_path / "run", "darkgs+sh", cfg, seed=0, progress=False, resume=True)
    assert result.steps == 40
    with pytest.raises(ValueError, match="other settings"):  # a setting that differs from its default still counts
        train(bedroom, tmp_path / "run", "darkgs+sh", cfg.replace(low_frequency_shading="irradiance"), seed=0,
              progress=False, resume=True)
    with pytest.raises(ValueError, match=r"bounce_light_degree: run -1, now 2"):  # ... and names itself
        train(bedroom, tmp_path / "run", "darkgs+sh", cfg.replace(bounce_light_degree=2), seed=0,
              progress=False, resume=True)
    with pytest.raises(ValueError, match=r"depth_spread_weight: run 0.0, now 0.4"):
        train(bedroom, tmp_path / "run", "darkgs+sh", cfg.replace(depth_spread_weight=0.4), seed=0,
              progress=False, resume=True)


@pytest.mark.blender
def test_a_bounce_light_trains_is_reported_reloads_and_stays_out_of_relighting(bedroom, tmp_path):
    """``bounce_light_degree``: the camera-frame SH light learns, is written to light.json and the checkpoint, comes
    back with the run, and the relit images are those of the same model with the bounce light set to zero."""
    from spotlessgs.rendering import render_run
    from spotlessgs.training.trainer import load_run, train

    cfg = _tiny(iterations=40, image_width=40, densify_from=1000, checkpoint_every=40, bounce_light_degree=1)
    run = tmp_path / "run"
    train(bedroom, run, "darkgs+sh", cfg, seed=0, progress=False)
    coeffs = np.asarray(json.loads((run / "light.json").read_text())["estimate"]["bounce_sh_coefficients_camera_frame"])
    assert coeffs.shape == (4, 3) and np.abs(coeffs).max() > 1e-4
    scene = load_run(run, device="cpu")[0]
    np.testing.assert_allclose(scene.appearance.bounce_light.coeffs.detach().numpy(), coeffs, rtol=1e-6, atol=1e-9)
    c2w = torch.eye(4)
    with torch.no_grad():
        lit = scene.colours(c2w, relight_l0=None)
        relit = scene.colours(c2w, relight_l0=[1.0, 1.0, 1.0])
        scene.appearance.bounce_light.coeffs.zero_()
        assert float((scene.colours(c2w, relight_l0=None) - lit).abs().max()) > 0  # it lit the spotlit images
        torch.testing.assert_close(scene.colours(c2w, relight_l0=[1.0, 1.0, 1.0]), relit)
    summary = render_run(run, "relit", "test", tmp_path / "relit", progress=False)
    assert summary["count"] > 0 and len(list((tmp_path / "relit").glob("*.png"))) == summary["count"]


@pytest.mark.blender
def test_spot_shadows_train_reload_and_leave_relighting_alone(bedroom, tmp_path):
    """``spot_shadows``: a run trains with the lamp's shadow map, logs the lamp's position as it learns, comes back
    with its shadows (its spotlit render differs from the same model's without them), and relights as without."""
    from spotlessgs.io.camera_batch import Cameras
    from spotlessgs.training.trainer import load_run, train

    cfg = _tiny(iterations=30, image_width=40, densify_from=1000, checkpoint_every=30, spot_shadows=True)
    run = tmp_path / "run"
    train(bedroom, run, "darkgs", cfg, seed=0, progress=False)
    rows = [json.loads(line) for line in (run / "metrics.jsonl").read_text().splitlines()]
    positions = np.array([r["light_translation_m"] for r in rows])
    assert positions.shape == (len(rows), 3) and np.abs(positions[-1] - positions[0]).max() > 0
    scene, views, config, _ = load_run(run, device="cpu")
    assert config.spot_shadows and scene.config.spot_shadows and scene.config.shadow_map_scale == 0.5
    camera: Cameras = views.cameras[views.train[0]]
    with torch.no_grad():
        shadowed = scene.render(camera).image
        relit = scene.render(camera, relight_l0=[1.0, 1.0, 1.0]).image
        scene.config = dataclasses.replace(scene.config, spot_shadows=False)
        assert float((scene.render(camera).image - shadowed).abs().max()) > 1e-4
        torch.testing.assert_close(scene.render(camera, relight_l0=[1.0, 1.0, 1.0]).image, relit)


@pytest.mark.blender
def test_the_depth_spread_term_trains_and_is_saved_and_auto_leaves_simulator_renders_alone(bedroom, tmp_path):
    """"on": the term changes a relightable model's training and is saved with the run; "auto" trains DarkGS on the
    simulator's bedroom (no camera effects) exactly as without the term."""
    from spotlessgs.training.trainer import load_run, train

    cfg = _tiny(iterations=30, image_width=40, densify_from=1000, checkpoint_every=30, log_every=10)

    def l1_curve(mode: str, weight: float) -> list[float]:
        run = tmp_path / f"{mode}-{weight}"
        train(bedroom, run, "darkgs", cfg.replace(depth_spread=mode, depth_spread_weight=weight), seed=0,
              progress=False)
        saved = load_run(run, device="cpu")[2]
        assert (saved.depth_spread, saved.depth_spread_weight) == (mode, weight)
        assert json.loads((run / "train_summary.json").read_text())["depth_spread_weight"] == (
            0.0 if mode != "on" else weight)
        # the photometric L1 (the logged loss would differ by the term itself even if it trained nothing)
        return [json.loads(line)["l1"] for line in (run / "metrics.jsonl").read_text().splitlines()]

    with_term = l1_curve("on", 1.0)
    without = l1_curve("off", 1.0)
    assert with_term and all(math.isfinite(v) for v in with_term)
    assert with_term != without
    assert l1_curve("auto", 1.0) == without


@pytest.mark.parametrize("every, steps", [(1, [0, 1, 2, 3, 4, 5, 6]), (3, [0, 3, 6])])
def test_the_depth_spread_term_trains_on_every_kth_step_only(tmp_path_factory, tmp_path, monkeypatch, every, steps):
    """``depth_spread_every``: the depth moments are rendered, and the term trained, on steps 0, k, 2k, ... only."""
    from conftest import synthetic_box_dataset
    from spotlessgs.models.relightable import RelightableScene
    from spotlessgs.training import trainer

    box = synthetic_box_dataset(tmp_path_factory, f"every-{every}", seed=3)
    step_of_render, with_moments = [], []
    real_view = trainer.fitted_view

    def fitted_view(seed, step, *args, **kwargs):  # the step whose render comes next
        step_of_render.append(step)
        return real_view(seed, step, *args, **kwargs)

    real = RelightableScene.render_with_depth_moments

    def counted(self, camera, **options):
        with_moments.append(step_of_render[-1])
        return real(self, camera, **options)

    monkeypatch.setattr(trainer, "fitted_view", fitted_view)
    monkeypatch.setattr(RelightableScene, "render_with_depth_moments", counted)
    cfg = _tiny(iterations=7, image_width=40, num_threads=1, densify_from=1000, checkpoint_every=7, log_every=7,
                validation_blocks=0, depth_spread="on", depth_spread_every=every)
    trainer.train(box, tmp_path / "run", "darkgs", cfg, seed=0, progress=False)
    assert step_of_render == list(range(7)) and with_moments == steps


@pytest.mark.parametrize("meta, variant, mode, expected", [
    ({}, "spotless", "auto", 0.1),                                              # a real camera
    ({}, "darkgs", "auto", 0.1),
    ({}, "3dgs", "auto", 0.0),                                                  # no light to relight with
    ({"scene_id": "bedroom"}, "spotless", "auto", 0.1),                         # our simulator's render: SpotlessGS
    ({"scene_id": "bedroom"}, "darkgs", "auto", 0.0),                           # ... not the DarkGS variants
    ({"scene_id": "bedroom"}, "darkgs+brdf", "auto", 0.0),
    ({"scene_id": "bedroom"}, "darkgs+sh", "auto", 0.0),
    ({"scene_id": "bedroom", "camera_effects": {"noise": 1}}, "spotless", "auto", 0.1),  # ... imitating a camera
    ({"scene_id": "bedroom"}, "3dgs", "on", 0.1),                               # "on": every model, any data
    ({}, "spotless", "off", 0.0),
])
def test_when_the_depth_spread_term_trains(meta, variant, mode, expected):
    from types import SimpleNamespace

    from spotlessgs.models.shading import MODEL_VARIANTS
    from spotlessgs.training.config import TrainConfig
    from spotlessgs.training.trainer import depth_spread_weight_for

    views = SimpleNamespace(dataset=SimpleNamespace(meta=meta))
    config = TrainConfig(depth_spread=mode, depth_spread_weight=0.1)
    assert depth_spread_weight_for(config, views, MODEL_VARIANTS[variant]) == expected


def test_a_resume_trains_the_depth_spread_weight_its_checkpoint_records():
    """On a resume the weight comes from the checkpoint; one written before the record resolves "auto" as its version
    did (real cameras only: SpotlessGS on our simulator's render without the term); a damaged record is refused."""
    from types import SimpleNamespace

    from spotlessgs.io.errors import InputError
    from spotlessgs.models.shading import MODEL_VARIANTS
    from spotlessgs.training.config import TrainConfig
    from spotlessgs.training.trainer import trained_depth_spread_weight

    render, camera = (SimpleNamespace(dataset=SimpleNamespace(meta=meta)) for meta in ({"scene_id": "bedroom"}, {}))
    config, spotless, where = TrainConfig(depth_spread_weight=0.4), MODEL_VARIANTS["spotless"], Path("last.safetensors")
    assert trained_depth_spread_weight(config, render, spotless, None, where) == 0.4  # a fresh run
    assert trained_depth_spread_weight(config, render, spotless, {"step": 5}, where) == 0.0  # before the record
    assert trained_depth_spread_weight(config, camera, spotless, {"step": 5}, where) == 0.4
    assert trained_depth_spread_weight(config, render, spotless, {"depth_spread_weight": 0.1}, where) == 0.1
    for damaged in (-1.0, float("nan"), "0.4", True):
        with pytest.raises(InputError, match="last.safetensors: depth_spread_weight must be a finite number"):
            trained_depth_spread_weight(config, render, spotless, {"depth_spread_weight": damaged}, where)


def test_a_run_from_before_the_depth_spread_switch_keeps_its_weight_for_every_model():
    """Runs saved while ``depth_spread_weight`` existed without ``depth_spread`` trained with that weight for every
    model, 3DGS included: they come back as "on" with their weight."""
    from spotlessgs.training.config import TrainConfig, with_defaults

    saved = {k: v for k, v in dataclasses.asdict(TrainConfig(depth_spread_weight=1.0)).items()
             if k not in ("depth_spread", "depth_spread_every")}
    config = TrainConfig(**with_defaults(TrainConfig, saved))
    assert (config.depth_spread, config.depth_spread_weight, config.depth_spread_every) == ("on", 1.0, 1)
    # runs saved before depth_spread_every trained the term on every step, whatever today's default (4)
    assert TrainConfig().depth_spread_every == 4


@pytest.mark.parametrize("kwargs, match", [({"depth_spread": "always"}, "depth_spread must be 'auto', 'on' or 'off'"),
                                           ({"depth_spread_weight": -0.1}, "depth_spread_weight must be >= 0"),
                                           ({"depth_spread_weight": float("nan")}, "depth_spread_weight must be finite"),
                                           ({"depth_spread_every": 0}, "depth_spread_every must be >= 1")])
def test_train_config_rejects_bad_depth_spread_settings(kwargs, match):
    from spotlessgs.training.config import TrainConfig

    with pytest.raises(ValueError, match=match):
        TrainConfig(**kwargs)


@pytest.mark.blender
def test_nan_stops_training_and_keeps_the_last_good_checkpoint(bedroom, tmp_path, monkeypatch):
    import spotlessgs.training.trainer as trainer_mod

    real = trainer_mod.photometric_loss
    calls = {"n": 0}

    def poisoned(pred, target, saturated, lam, space):
        calls["n"] += 1
        loss, parts = real(pred, target, saturated, lam, space)
        return (loss * float("nan") if calls["n"] == 25 else loss), parts

    monkeypatch.setattr(trainer_mod, "photometric_loss", poisoned)
    _assert_diverges_and_keeps_step_20(bedroom, tmp_path, r"step 24: loss is nan.*last good checkpoint")


def _assert_diverges_and_keeps_step_20(bedroom, tmp_path, match):
    """A 40-step darkgs run with checkpoints every 20 steps stops with ``match`` and leaves the step-20 checkpoint,
    finite."""
    import spotlessgs.training.trainer as trainer_mod
    from spotlessgs.training.checkpoint import load_checkpoint

    cfg = _tiny(iterations=40, image_width=40, checkpoint_every=20, densify_from=1000)
    with pytest.raises(trainer_mod.TrainingDivergedError, match=match):
        trainer_mod.train(bedroom, tmp_path / "run", "darkgs", cfg, seed=0, progress=False)
    ckpt = load_checkpoint(tmp_path / "run")
    assert ckpt["step"] == 20
    assert all(torch.isfinite(t).all() for t in ckpt["gaussians"].values())


@pytest.mark.blender
def test_a_nan_parameter_never_reaches_a_checkpoint(bedroom, tmp_path, monkeypatch):
    """A NaN in a parameter no render uses (darkgs ignores the vanilla SH colour) is caught before the next save."""
    import spotlessgs.training.trainer as trainer_mod

    scenes = []
    real_build, real_loss = trainer_mod.build_optimizers, trainer_mod.photometric_loss

    def capture(scene, config, extent, photometric=None):
        scenes.append(scene)
        return real_build(scene, config, extent, photometric)

    calls = {"n": 0}

    def poison_after_step_24(pred, target, saturated, lam, space):
        calls["n"] += 1
        if calls["n"] == 25:
            with torch.no_grad():
                scenes[0].gaussians.params["shN"][0, 0, 0] = float("nan")
        return real_loss(pred, target, saturated, lam, space)

    monkeypatch.setattr(trainer_mod, "build_optimizers", capture)
    monkeypatch.setattr(trainer_mod, "photometric_loss", poison_after_step_24)
    _assert_diverges_and_keeps_step_20(bedroom, tmp_path, r"step 39: parameter 'shN'.*last good checkpoint")


@pytest.mark.blender
def test_calibrated_darkgs_uses_the_true_light_and_export_writes_a_3dgs_ply(bedroom, tmp_path):
    from plyfile import PlyData

    from spotlessgs.export import export_ply
    from spotlessgs.training.trainer import train

    run = tmp_path / "cal"
    train(bedroom, run, "darkgs-calibrated", _tiny(iterations=20, image_width=40, densify_from=1000), seed=0,
          progress=False)
    light = json.loads((run / "light.json").read_text())
    assert light["errors"]["axis_error_deg"] < 1e-3 and light["errors"]["translation_error_m"] < 1e-6
    assert light["estimate"]["pose_trainable"] is False
    ply = PlyData.read(str(export_ply(run, tmp_path / "model.ply")))
    names = [p.name for p in ply["vertex"].properties]
    assert names[:3] == ["x", "y", "z"] and "f_dc_0" in names and "f_rest_44" in names and "rot_3" in names
    assert len(names) == 3 + 3 + 3 + 45 + 1 + 3 + 4
    assert np.isfinite(np.stack([ply["vertex"][n] for n in names])).all()


# ---- relit rendering ------------------------------------------------------------------------------------------------


@pytest.mark.parametrize("variant", ["darkgs", "spotless"])
def test_cached_relit_colours_equal_per_view_shading(variant):
    """RelitColours (one reflectance evaluation for all views) reproduces shade(..., relight_l0) view by view,
    including Gaussians seen from behind (two-sided normals)."""
    from spotlessgs.models.relightable import RelightableScene
    from spotlessgs.rendering import RelitColours

    rng = np.random.default_rng(0)
    xyz = rng.uniform(-1, 1, (50, 3))
    normals = rng.normal(size=(50, 3))  # half of them face away from any given camera
    g = GaussianParams.from_point_cloud(xyz, rng.integers(0, 256, (50, 3)).astype(np.uint8), normals)
    scene = RelightableScene.create(variant, g, seed=0)
    with torch.no_grad():
        if scene.appearance.lf_light is not None and hasattr(scene.appearance.lf_light, "coeffs"):
            scene.appearance.lf_light.coeffs.normal_(0.0, 0.3, generator=torch.Generator().manual_seed(1))
    cams = []
    for eye in ([0.0, 0.0, -4.0], [3.0, 1.0, 2.0]):
        z = -torch.tensor(eye) / torch.linalg.norm(torch.tensor(eye))
        x = torch.linalg.cross(torch.tensor([0.0, 1.0, 0.0]), z)
        x = x / torch.linalg.norm(x)
        c2w = torch.eye(4)
        c2w[:3, 0], c2w[:3, 1], c2w[:3, 2], c2w[:3, 3] = x, torch.linalg.cross(z, x), z, torch.tensor(eye)
        cams.append(c2w)
    with torch.no_grad():
        cached = RelitColours(scene, cams[0])
        for c2w in cams:
            feats = cached.features(c2w)
            l0 = torch.tensor([0.7, 0.8, 0.9])
            expected = scene.colours(c2w, relight_l0=l0.tolist())
            torch.testing.assert_close(feats[:, :3] * l0 + feats[:, 3:], expected, rtol=1e-5, atol=1e-6)


def test_auto_l0_puts_the_chosen_percentile_at_the_target():
    from spotlessgs.rendering import AUTO_L0_PERCENTILE, AUTO_L0_TARGET, auto_l0

    rng = np.random.default_rng(0)
    r = [rng.uniform(0.0, 0.5, (20, 30, 3)).astype(np.float32) for _ in range(3)]
    low = [np.full((20, 30, 3), 0.05, np.float32) for _ in range(3)]
    s = auto_l0(r, low)[0]
    lum = np.concatenate([(s * a + b).mean(axis=2).ravel() for a, b in zip(r, low)])
    assert np.percentile(lum, AUTO_L0_PERCENTILE) == pytest.approx(AUTO_L0_TARGET, rel=1e-6)
    # the low-frequency light alone already exceeds the target: no spotlight replacement is needed
    assert auto_l0(r, [np.full((20, 30, 3), 2.0, np.float32)] * 3) == [0.0, 0.0, 0.0]


@pytest.mark.parametrize("variant", ["3dgs", "darkgs", "spotless"])
def test_a_view_with_no_visible_gaussian_renders_black_with_finite_gradients(variant):
    from spotlessgs.io.camera_batch import Cameras
    from spotlessgs.io.cameras import Intrinsics
    from spotlessgs.models.relightable import RelightableScene

    rng = np.random.default_rng(0)
    g = GaussianParams.from_point_cloud(rng.uniform(-1, 1, (20, 3)), rng.integers(0, 256, (20, 3)).astype(np.uint8))
    scene = RelightableScene.create(variant, g, seed=0)
    c2w = torch.eye(4)
    c2w[2, 3] = 5.0  # at z = 5 looking along +z: every Gaussian is behind the camera
    out = scene.render(Cameras(c2w, Intrinsics(50.0, 50.0, 16.0, 12.0, 32, 24)))
    assert float(out.image.detach().abs().sum()) == 0.0 and int(out.visible.sum()) == 0
    loss, _ = photometric_loss(out.image, torch.full((24, 32, 3), 0.2), torch.zeros(24, 32, dtype=torch.bool))
    loss.backward()
    assert all(torch.isfinite(p.grad).all() for p in scene.parameters() if p.grad is not None)


def test_depth_spread_loss_is_the_relative_depth_variance_of_covered_pixels():
    # Pixel 0: weights 0.6 at z = 2 and 0.3 at z = 4: A = 0.9, mean = (1.2 + 1.2) / 0.9 = 8/3, E[z²] = (2.4 + 4.8) / 0.9
    # = 8, variance 8 - 64/9 = 8/9, relative 8/9 / (64/9) = 1/8. Pixel 1: one opaque Gaussian at z = 3: 0.
    # Pixel 2: A = 0.2 < 0.5, left out whatever its moments.
    alpha = torch.tensor([[0.9, 1.0, 0.2]])
    moments = torch.tensor([[[0.6 * 2 + 0.3 * 4, 0.6 * 4 + 0.3 * 16], [3.0, 9.0], [0.1, 5.0]]], requires_grad=True)
    loss = depth_spread_loss(moments, alpha)
    assert float(loss.detach()) == pytest.approx((1 / 8 + 0) / 2, rel=1e-5)
    loss.backward()
    assert float(moments.grad[0, 2].abs().sum()) == 0.0 and float(moments.grad[0, 0].abs().sum()) > 0
    # Scale-free: the same slab twice as far costs the same.
    far = moments.detach() * torch.tensor([2.0, 4.0])
    assert float(depth_spread_loss(far, alpha)) == pytest.approx(float(loss.detach()), rel=1e-5)
    empty = torch.zeros(1, 2, 2, requires_grad=True)
    none = depth_spread_loss(empty, torch.zeros(1, 2))
    none.backward()
    assert float(none.detach()) == 0.0 and empty.grad is not None


def test_render_with_depth_moments_matches_the_rasterizers_depth_and_image():
    """The two extra channels are Σ w z and Σ w z² of the same compositing: Σ w z / A is the rasterizer's own
    depth output, Σ w z² ≥ (Σ w z)² / A, and the colour image is the plain render's."""
    from spotlessgs.io.camera_batch import Cameras
    from spotlessgs.io.cameras import Intrinsics
    from spotlessgs.models.relightable import RelightableScene

    rng = np.random.default_rng(3)
    points = np.column_stack([rng.uniform(-0.5, 0.5, (200, 2)), rng.uniform(1.5, 3.0, 200)])
    g = GaussianParams.from_point_cloud(points, rng.integers(0, 256, (200, 3)).astype(np.uint8))
    scene = RelightableScene.create("darkgs", g, seed=0)
    camera = Cameras(torch.eye(4), Intrinsics(40.0, 40.0, 16.0, 12.0, 32, 24))
    out, moments = scene.render_with_depth_moments(camera)
    plain = scene.render(camera)
    assert moments.shape == (24, 32, 2) and out.image.shape == (24, 32, 3)
    torch.testing.assert_close(out.image, plain.image)
    covered = out.alpha > 0.5
    assert int(covered.sum()) > 50
    torch.testing.assert_close(moments[..., 0][covered] / out.alpha[covered], out.depth[covered], rtol=1e-4, atol=1e-4)
    assert bool((moments[..., 1][covered] * out.alpha[covered] >= moments[..., 0][covered] ** 2 * (1 - 1e-4)).all())
    depth_spread_loss(moments, out.alpha).backward()
    assert g.params["means"].grad is not None and float(g.params["means"].grad.abs().sum()) > 0


def test_random_initialisation_in_the_frusta_when_a_dataset_has_no_points(tmp_path, caplog):
    """A nerfstudio folder without a point cloud: Gaussians start at random depths inside the training frusta."""
    from spotlessgs.io.cameras import Intrinsics
    from spotlessgs.io.images import write_png
    from spotlessgs.io.transforms import FrameRecord, write_transforms
    from spotlessgs.training.data import initial_point_cloud, load_training_views

    intr = Intrinsics.from_fov(60.0, 32, 24)
    frames = []
    for k in range(4):
        c2w = np.eye(4)
        c2w[0, 3] = 0.3 * k
        write_png(tmp_path / "images" / f"f{k}.png", np.full((24, 32, 3), 0.3 + 0.1 * k))  # identical frames are refused
        frames.append(FrameRecord(f"images/f{k}.png", c2w))
    write_transforms(tmp_path / "transforms.json", intr, frames, None)
    views = load_training_views(tmp_path)
    with caplog.at_level("WARNING"):
        cloud = initial_point_cloud(views, np.random.default_rng(0), n_random=300)
    assert "no point cloud" in caplog.text
    assert len(cloud.xyz) >= 200 and np.isfinite(cloud.xyz).all()
    # every point lies in front of some training camera and projects inside its image
    inside_any = np.zeros(len(cloud.xyz), dtype=bool)
    for k in views.train:
        w2c = np.linalg.inv(views.cameras.c2w[k].double().numpy())
        cam = cloud.xyz @ w2c[:3, :3].T + w2c[:3, 3]
        u = intr.fx * cam[:, 0] / cam[:, 2] + intr.cx
        v = intr.fy * cam[:, 1] / cam[:, 2] + intr.cy
        inside_any |= (cam[:, 2] > 0) & (u >= 0) & (u <= 32) & (v >= 0) & (v <= 24)
    assert inside_any.all()


def test_overriding_iterations_scales_the_densification_schedule():
    from spotlessgs.training.config import PRESETS, preset

    quick = PRESETS["quick"]
    short = preset("quick", iterations=1000)
    assert short.densify_until == round(quick.densify_until / 3) < 1000
    assert short.opacity_reset_every == round(quick.opacity_reset_every / 3)
    assert short.densify_every == round(quick.densify_every / 3)
    # an explicitly given schedule field is kept as given
    assert preset("quick", iterations=1000, densify_until=900).densify_until == 900
    assert preset("quick").densify_until == quick.densify_until


def test_the_densification_strategy_is_a_named_config_choice():
    from spotlessgs.training.config import STRATEGIES, preset

    default, budget = preset("tiny"), preset("tiny", strategy="budget")
    assert not default.gaussian_budget and budget.gaussian_budget and budget.validation_every == 8
    assert budget == default.replace(**STRATEGIES["budget"])  # nothing else differs
    assert preset("tiny", strategy="budget", validation_every=4).validation_every == 4  # overrides win
    with pytest.raises(ValueError, match="unknown densification strategy 'greedy'"):
        preset("tiny", strategy="greedy")


def test_sfm_points_get_normals_facing_the_cameras():
    from spotlessgs.training.data import estimate_normals

    rng = np.random.default_rng(0)
    # a tilted plane seen from above, and a sphere seen from its centre (normals point inwards, at the camera)
    xy = rng.uniform(-1, 1, (400, 2))
    plane = np.c_[xy, 0.3 * xy[:, 0] + rng.normal(0, 0.002, 400)]
    truth = np.array([-0.3, 0.0, 1.0]) / np.linalg.norm([-0.3, 0.0, 1.0])
    normals = estimate_normals(plane, np.array([[0.0, 0.0, 3.0], [1.0, 0.5, 2.5]]))
    assert np.abs(np.linalg.norm(normals, axis=1) - 1).max() < 1e-9
    assert np.median(normals @ truth) > 0.99 and (normals @ truth > 0.9).mean() > 0.95
    sphere = rng.normal(size=(500, 3))
    sphere /= np.linalg.norm(sphere, axis=1, keepdims=True)
    inwards = estimate_normals(sphere, np.zeros((1, 3)))
    assert np.median(np.einsum("ni,ni->n", inwards, -sphere)) > 0.99
    assert estimate_normals(plane[:2], np.zeros((1, 3))).shape == (2, 3)  # too few points: zero normals


@pytest.mark.blender
def test_lamp_self_consistency_script_renders_the_run_with_the_lamp_at_the_truth(bedroom, tmp_path):
    """scripts/lamp_self_consistency.py: the copy's frames are the run's renders with the lamp moved to the light
    truth (to 8 bits), not the renders with its learned lamp; the source dataset is untouched; a second call into the
    same folder fails without touching it."""
    import subprocess
    import sys

    from PIL import Image

    from spotlessgs.io.colorspace import linear_to_srgb, to_uint8
    from spotlessgs.models.geometry import so3_log
    from spotlessgs.training.trainer import load_run, train

    run, copy = tmp_path / "run", tmp_path / "consistent"
    # the lamp starts half a metre behind the camera, so the run's own lamp is far from the truth
    train(bedroom, run, "darkgs", _tiny(iterations=10, image_width=80, densify_from=1000), seed=0, progress=False,
          light_prior=(0.06, -0.04, -0.5))
    before = {p.name: p.read_bytes() for p in sorted((bedroom / "images").iterdir())}
    script = [sys.executable, str(ROOT / "scripts" / "lamp_self_consistency.py"), str(run), str(copy)]
    subprocess.run(script, check=True, capture_output=True)
    assert {p.name: p.read_bytes() for p in sorted((bedroom / "images").iterdir())} == before
    assert sorted(p.name for p in (copy / "images").iterdir()) == sorted(before)
    record = json.loads((copy / "self_consistency.json").read_text())
    scene, views, _, _ = load_run(run, device="cpu")
    np.testing.assert_allclose(record["lamp"]["position_in_camera_m"], views.light.position_in_camera, atol=1e-6)
    index = views.train[0]
    written = np.asarray(Image.open(copy / "images" / views.names[index]).convert("RGB")).astype(int)
    with torch.no_grad():
        learned = to_uint8(linear_to_srgb(scene.render(views.cameras[index]).image.clamp_min(0).numpy())).astype(int)
        light = scene.appearance.light
        light.translation.copy_(torch.tensor(np.array(views.light.position_in_camera), dtype=torch.float32))
        light.rotvec.copy_(torch.tensor(so3_log(views.light.rotation_in_camera), dtype=torch.float32))
        at_truth = to_uint8(linear_to_srgb(scene.render(views.cameras[index]).image.clamp_min(0).numpy())).astype(int)
    assert np.abs(written - at_truth).max() <= 1
    assert np.abs(written - learned).mean() > 1.0  # 3.5 levels; moved lamp: all within 1
    stamp = (copy / "self_consistency.json").read_bytes()
    again = subprocess.run(script, capture_output=True, text=True)
    assert again.returncode != 0 and "exists" in again.stderr
    assert (copy / "self_consistency.json").read_bytes() == stamp
    # a run trained below the dataset's size is refused before anything is copied
    small = tmp_path / "small"
    train(bedroom, small, "darkgs", _tiny(iterations=2, image_width=40, densify_from=1000), seed=0, progress=False)
    refused = subprocess.run(script[:2] + [str(small), str(tmp_path / "other")], capture_output=True, text=True)
    assert refused.returncode != 0 and "trained at 40x30, the dataset's frames are 80x60" in refused.stderr
    assert not (tmp_path / "other").exists() and not (tmp_path / "other.partial").exists()


def test_normal_gravity_prior_pulls_to_the_nearer_of_horizontal_and_vertical():
    """normal_gravity_loss: zero for walls and floors, (1 − |c|)² or c² for tilted ones, gradients turning a tilted wall
    back to horizontal and a tilted ceiling back to vertical; camera_up of level cameras is their −y axis."""
    from spotlessgs.training.losses import camera_up, normal_gravity_loss

    up = torch.tensor([0.0, 0.0, 1.0])
    tilt = math.radians(10.0)
    normals = torch.tensor([[1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [math.cos(tilt), 0.0, math.sin(tilt)],
                            [math.sin(tilt), 0.0, -math.cos(tilt)]], requires_grad=True)
    visible = torch.tensor([True, True, False, False])
    assert float(normal_gravity_loss(normals, up, visible).detach()) == pytest.approx(0.0, abs=1e-12)
    loss = normal_gravity_loss(normals, up, torch.tensor([False, False, True, True]))
    expected = (math.sin(tilt) ** 2 + (1.0 - math.cos(tilt)) ** 2) / 2
    assert float(loss.detach()) == pytest.approx(expected, rel=1e-5)
    loss.backward()
    assert float(normals.grad[2, 2]) > 0  # descent lowers the tilted wall's z towards 0
    assert float(normals.grad[3, 2]) > 0  # ... and the tilted ceiling's z towards -1
    assert float(normal_gravity_loss(normals, up, torch.zeros(4, dtype=torch.bool)).detach()) == 0.0
    # level cameras looking along +x and +y (OpenCV: y down) → up is world +z
    look_x = torch.tensor([[0.0, 0.0, 1.0, 0.0], [-1.0, 0.0, 0.0, 0.0], [0.0, -1.0, 0.0, 1.5], [0.0, 0.0, 0.0, 1.0]])
    look_y = torch.tensor([[1.0, 0.0, 0.0, 0.0], [0.0, 0.0, 1.0, 0.0], [0.0, -1.0, 0.0, 1.5], [0.0, 0.0, 0.0, 1.0]])
    torch.testing.assert_close(camera_up(torch.stack([look_x, look_y])), up)


@pytest.mark.blender
def test_the_start_point_cloud_is_read_once_at_start_up(bedroom, monkeypatch):
    """The start-up decisions (a sparse start's schedule, a trusted dense start) and the initial Gaussians share one
    read of the dataset's point cloud."""
    import spotlessgs.io.dataset as dataset_io
    from spotlessgs.training.data import load_training_views
    from spotlessgs.training.trainer import build_scene, sparse_start_schedule, start_geometry_settings

    reads = []
    original = dataset_io.read_point_cloud
    monkeypatch.setattr(dataset_io, "read_point_cloud",
                        lambda path, origin=None: reads.append(path) or original(path, origin))
    cfg = _tiny(image_width=40, trust_start_geometry="auto")
    views = load_training_views(bedroom, cfg.image_width)
    cfg = start_geometry_settings(sparse_start_schedule(cfg, views), views, "spotless")
    assert cfg.lamp_bounce and cfg.lr_normals == 0.0  # the shipped bedroom's dense start is trusted
    build_scene(views, "spotless", cfg, seed=0)
    assert len(reads) == 1


def test_a_trusted_dense_start_keeps_its_normals_and_trains_the_bounce(bedroom, tmp_path):
    """trust_start_geometry=auto on the simulator's dense cloud: the normals stay the start's, the bounce's gain
    learns and the camera-frame bounce SH is left out (a Lambertian model keeps it), the BRDF is unclamped, the lamp's
    profile is monotone, the room light is shaded as relit, and the run loads as it trained (its checkpoint records
    the model's settings), also after its dataset's cloud changed, and from a checkpoint that predates the record."""
    from spotlessgs.io.errors import InputError
    from spotlessgs.io.ply import read_point_cloud, write_point_cloud
    from spotlessgs.models.angular_profile import MonotoneProfile
    from spotlessgs.training.checkpoint import load_checkpoint, save_checkpoint
    from spotlessgs.training.data import load_training_views
    from spotlessgs.training.trainer import build_scene, load_run, start_geometry_settings, train

    cfg = _tiny(iterations=30, image_width=40, densify_from=1000, checkpoint_every=30, trust_start_geometry="auto")
    train(bedroom, tmp_path / "run", "spotless", cfg, seed=3, progress=False)
    train(bedroom, tmp_path / "lambert", "darkgs+sh", cfg, seed=3, progress=False)  # Lambertian: not trusted
    lambert = load_checkpoint(tmp_path / "lambert")["appearance"]
    assert "lamp_bounce.log_gain" not in lambert and "bounce_light.coeffs" in lambert  # its camera-frame bounce kept
    saved = load_checkpoint(tmp_path / "run")
    assert saved["model_settings"] == {"lamp_bounce": True, "brdf_upper_clamp": False, "spot_shadows": False,
                                       "rid_model": "monotone", "low_frequency_shading": "irradiance",
                                       "bounce_light_degree": -1}
    assert not any(name.startswith("bounce_light.") for name in saved["appearance"])  # the geometric bounce alone
    views = load_training_views(bedroom, cfg.image_width)
    start = build_scene(views, "spotless", start_geometry_settings(cfg, views, "spotless"), 3)
    torch.testing.assert_close(saved["gaussians"]["normals_raw"], start.gaussians.params["normals_raw"], rtol=0, atol=0)
    assert saved["optimizers"]["normals_raw"]["state"] == {}  # held: no gradient computed, no moments kept
    assert float(saved["appearance"]["lamp_bounce.log_gain"]) != 0.0  # learned from its start at 0
    scene, _views, config, _info = load_run(tmp_path / "run")
    assert scene.appearance.lamp_bounce is not None and config.lr_normals == 0.0
    assert scene.appearance.brdf.upper_clamp is False and config.brdf_upper_clamp is False
    assert scene.appearance.bounce_light is None and config.bounce_light_degree == -1
    assert float(scene.appearance.lamp_bounce.log_gain.detach()) == float(saved["appearance"]["lamp_bounce.log_gain"])
    # the dataset moved and its point cloud became a sparse one: the run still loads as it trained
    moved = tmp_path / "moved"
    shutil.copytree(bedroom, moved)
    cloud = read_point_cloud(moved / "points3d.ply")
    write_point_cloud(moved / "points3d.ply", cloud.xyz[:20], cloud.rgb[:20])
    assert start_geometry_settings(cfg, load_training_views(moved, cfg.image_width), "spotless") == cfg
    scene, _views, config, _info = load_run(tmp_path / "run", data_dir=moved)
    assert float(scene.appearance.lamp_bounce.log_gain.detach()) == float(saved["appearance"]["lamp_bounce.log_gain"])
    assert scene.appearance.brdf.upper_clamp is False
    assert isinstance(scene.appearance.light.rid, MonotoneProfile)
    assert config.low_frequency_shading == scene.config.low_frequency_shading == "irradiance"
    # a checkpoint without the record (before 2026-11-27), of a run that trusted nothing: the bounce as its modules
    # show, the clamp and the profile as configured
    cfg_off = cfg.replace(trust_start_geometry="off", lamp_bounce=True, rid_model="mlp")  # that version's profile
    train(bedroom, tmp_path / "old", "spotless", cfg_off, seed=3, progress=False)
    older = {k: v for k, v in load_checkpoint(tmp_path / "old").items() if k not in ("version", "model_settings")}
    save_checkpoint(tmp_path / "old", older)
    scene, _views, _config, _info = load_run(tmp_path / "old", data_dir=moved)
    assert scene.appearance.lamp_bounce is not None and scene.appearance.brdf.upper_clamp is True
    assert not isinstance(scene.appearance.light.rid, MonotoneProfile)
    save_checkpoint(tmp_path / "old", {**older, "model_settings": {"lamp_bounce": "yes", "brdf_upper_clamp": False}})
    with pytest.raises(InputError, match="last.safetensors: model_settings must give lamp_bounce as one of true, "
                                         "false, got 'yes'"):
        load_run(tmp_path / "old")
