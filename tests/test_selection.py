"""Automatic model selection: the decision rule, the candidates, the settings' errors, the ModelConfig round trip of a
run folder, and `spotless train --model auto` end to end on a synthetic dataset (no Blender)."""

from __future__ import annotations

import dataclasses
import json
import shutil
import math

import pytest
import torch
from click.testing import CliRunner

from conftest import synthetic_box_dataset
from spotlessgs.io.camera_batch import Cameras
from spotlessgs.io.cameras import Intrinsics
from spotlessgs.models.shading import ModelConfig
from spotlessgs.training.config import TrainConfig, preset
from spotlessgs.training.trainer import validation_steps
from spotlessgs.training.validation import held_out_score, holdout_blocks
from spotlessgs.training.selection import (
    SELECTION_FILE, SELECTION_VERSION, CandidateResult, SelectionConfig, appearance_parameters, candidate_model, choose,
    choose_light,
    cost_rank,
    format_selection_table, phase_tolerance, proxy_config, run_decisions, selection_config,
)


pytestmark = pytest.mark.usefixtures("one_torch_thread")


def _result(degree, brdf, psnr):
    return CandidateResult(f"auto-sh{degree}-{brdf}", degree, brdf, psnr, 10.0, 100, 1)


# ---- the decision rule ------------------------------------------------------------------------------------------


def test_the_cheapest_candidate_within_the_tolerance_wins():
    results = [_result(0, "lambert", 20.00), _result(1, "lambert", 20.10), _result(3, "lambert", 20.20),
               _result(0, "mlp", 20.50)]
    assert choose(results, 0.25).name == "auto-sh0-mlp"  # the best Lambert is 0.30 dB behind
    assert choose(results, 0.31).name == "auto-sh3-lambert"
    assert choose(results, 0.5).name == "auto-sh0-lambert"  # exactly at the tolerance counts as within
    assert choose(results, 0.0).name == "auto-sh0-mlp"
    with pytest.raises(ValueError, match="no candidates"):
        choose([], 0.25)


def test_cost_order_puts_lambert_before_mlp_then_lower_degree_first():
    models = [candidate_model(d, b) for b in ("mlp", "lambert") for d in (3, 0, 2, 1)]
    ranked = [m.name for m in sorted(models, key=cost_rank)]
    assert ranked == ["auto-sh0-lambert", "auto-sh1-lambert", "auto-sh2-lambert", "auto-sh3-lambert",
                      "auto-sh0-mlp", "auto-sh1-mlp", "auto-sh2-mlp", "auto-sh3-mlp"]
    # and the measured parameter counts agree with that order within each BRDF: (d+1)^2 * 3 SH coefficients
    lam = [appearance_parameters(candidate_model(d, "lambert"), 32) for d in range(4)]
    assert [b - lam[0] for b in lam] == [3 * ((d + 1) ** 2 - 1) for d in range(4)]
    # the MLP of the given width: 117·h + h + h·h + h + h + 1 weights and biases on top of the SH-0 model
    assert appearance_parameters(candidate_model(0, "mlp"), 32) - lam[0] == 117 * 32 + 32 + 32 * 32 + 32 + 32 + 1
    assert appearance_parameters(candidate_model(0, "mlp"), 8) < appearance_parameters(candidate_model(0, "mlp"), 32)


def test_candidates_are_spotlight_models_with_an_sh_light():
    m = candidate_model(2, "mlp")
    assert (m.light_model, m.ambient, m.sh_degree, m.brdf) == ("spotlight", "sh", 2, "mlp")
    with pytest.raises(ValueError, match="brdf must be one of"):
        candidate_model(1, "phong")
    with pytest.raises(ValueError, match="degree"):
        candidate_model(4, "lambert")


@pytest.mark.parametrize("kwargs, match", [
    ({"tolerance_db": -0.1}, "tolerance_db"), ({"proxy_fraction": 0.0}, "proxy_fraction"),
    ({"base_fraction": 2.0}, "base_fraction"),
    ({"proxy_fraction": 1.5}, "proxy_fraction"), ({"min_proxy_iterations": 0}, "min_proxy_iterations"),
    ({"validation_every": 1}, "validation_every"), ({"search": "random"}, "search"),
    ({"sh_degrees": (0, 5)}, "sh_degrees"), ({"sh_degrees": ()}, "sh_degrees"),
    ({"holdout": "pixels"}, "holdout must be"), ({"holdout_fraction": 1.0}, "holdout_fraction"),
    ({"min_low_frequency_share": 1.0}, "min_low_frequency_share"), ({"share_views": 0}, "share_views"),
    ({"trusted_start_reflectance": "lambert"}, "trusted_start_reflectance must be"),
])
def test_selection_config_rejects_bad_values(kwargs, match):
    with pytest.raises(ValueError, match=match):
        SelectionConfig(**kwargs)


def test_proxy_schedule_is_a_fraction_without_densification():
    full = preset("quick")
    proxy = proxy_config(full, SelectionConfig(proxy_fraction=0.1, holdout="views", validation_every=5))
    assert proxy.iterations == 300 and proxy.validation_every == 5 and not proxy.validation_rejoin
    assert proxy.validation_blocks == 0
    blocks = proxy_config(full, SelectionConfig(holdout_fraction=0.2))  # default: held-out pixel blocks
    assert blocks.validation_blocks == 0.2 and blocks.validation_every == 0
    assert proxy_config(full, SelectionConfig()).iterations == 150  # default: 5 % of 3000 per candidate
    assert proxy_config(full, SelectionConfig(), 0.1).iterations == 300  # the shared base run
    assert proxy.densify_until == 0 and proxy.opacity_reset_every == 0 and not proxy.gaussian_budget
    assert proxy_config(preset("tiny"), SelectionConfig(min_proxy_iterations=150)).iterations == 150
    assert selection_config(0.5, None) == dataclasses.replace(SelectionConfig(), tolerance_db=0.5)


def test_table_lists_every_candidate_and_marks_the_choice():
    decision = {"chosen": "auto-sh1-lambert", "best": "auto-sh1-mlp", "tolerance_db": 0.25, "phase_tolerance_db": 0.125,
                "candidates": [dataclasses.asdict(r) for r in (_result(0, "lambert", 19.0),
                                                               _result(1, "lambert", 19.9),
                                                               _result(1, "mlp", 20.0))],
                "low_frequency_light": {"dark_level": 0.0539, "low_frequency_share": 0.0834,
                                        "measured_on": "auto-sh1-lambert-light", "needed": True},
                "settings": {"selection": dataclasses.asdict(SelectionConfig())}}
    lines = format_selection_table(decision).splitlines()
    assert len(lines) == 6  # header, three candidates, the light measurements, the verdict
    assert lines[2].startswith("* auto-sh1-lambert") and "-0.10" in lines[2]
    assert lines[1].startswith("  auto-sh0-lambert") and "-1.00" in lines[1]
    assert lines[4] == ("low-frequency light needed: dark level 0.054 (min 0.01), share 8.3% of "
                        "auto-sh1-lambert-light's radiance (min 1%) -> highest SH degree (if within 0.25 dB)")
    assert lines[5].startswith("chosen: auto-sh1-lambert (SH degree by the light rule, then the cheapest within "
                               "0.125 dB")


def test_each_coordinate_phase_gets_half_the_tolerance_so_the_two_decisions_stay_within_it():
    assert phase_tolerance(SelectionConfig(tolerance_db=0.3)) == pytest.approx(0.15)
    assert phase_tolerance(SelectionConfig(tolerance_db=0.3, search="grid")) == pytest.approx(0.3)


def test_a_dark_criterion_candidate_is_compared_on_its_dark_pixels():
    light = [dataclasses.replace(_result(d, "lambert", psnr), validation_psnr_dark=dark, criterion="dark")
             for d, psnr, dark in ((0, 24.2, 29.50), (1, 24.1, 29.60), (3, 24.0, 29.70))]
    assert [r.score for r in light] == [29.50, 29.60, 29.70]
    # on all pixels degree 0 is best; on the dark ones degree 3 is, and degree 0 is 0.2 dB behind it
    assert choose(light, 0.125).name == "auto-sh1-lambert" and choose(light, 0.25).name == "auto-sh0-lambert"
    assert _result(0, "lambert", 24.2).score == 24.2  # default criterion: all held-out pixels


def _light(degree, dark):
    return dataclasses.replace(_result(degree, "lambert", 24.0), validation_psnr_dark=dark, criterion="dark")


def test_the_light_decision_follows_the_measured_need_for_a_low_frequency_light():
    cfg = SelectionConfig(tolerance_db=0.3)  # 0.15 dB per decision
    close = [_light(0, 29.70), _light(3, 29.60)]  # degree 3 0.10 dB behind: within the tolerance
    assert choose_light(close, True, cfg).sh_degree == 3  # the light is needed: the highest degree
    assert choose_light(close, False, cfg).sh_degree == 0  # not needed: the lowest degree
    # not needed, and degree 0 0.20 dB behind: still within the whole tolerance, degree 0
    assert choose_light([_light(0, 29.80), _light(3, 30.0)], False, cfg).sh_degree == 0
    # not needed, but degree 0 is 1 dB behind: the measurement and the held-out pixels disagree, the pixels decide
    assert choose_light([_light(0, 29.0), _light(3, 30.0)], False, cfg).sh_degree == 3
    # needed and 0.20 dB behind: beyond the phase's 0.15 dB but the guard allows the whole 0.3 dB (no ranking)
    assert choose_light([_light(0, 29.70), _light(3, 29.50)], True, cfg).sh_degree == 3
    # needed, but the highest degree is beyond the whole tolerance of the best: the cheapest within the phase's
    assert choose_light([_light(0, 29.70), _light(3, 29.35)], True, cfg).sh_degree == 0
    # grid: both BRDFs at both degrees; needed -> degree 3, and the cheaper BRDF within the tolerance of the best
    grid = [_light(0, 29.0), _light(3, 29.5),
            dataclasses.replace(_light(0, 29.2), name="auto-sh0-mlp", brdf="mlp"),
            dataclasses.replace(_light(3, 29.6), name="auto-sh3-mlp", brdf="mlp")]
    assert choose_light(grid, True, SelectionConfig(tolerance_db=0.2, search="grid")).name == "auto-sh3-lambert"
    assert choose_light(grid, True, SelectionConfig(tolerance_db=0.05, search="grid")).name == "auto-sh3-mlp"
    # not needed: degree 0, whose best is 0.4 dB behind: within 0.45 (then the cheaper BRDF), not within 0.05
    assert choose_light(grid, False, SelectionConfig(tolerance_db=0.45, search="grid")).name == "auto-sh0-lambert"
    assert choose_light(grid, False, SelectionConfig(tolerance_db=0.05, search="grid")).name == "auto-sh3-mlp"
    with pytest.raises(ValueError, match="no candidates"):
        choose_light([], True, cfg)


def _random_scene(model, n=60, seed=0):
    from spotlessgs.models.gaussians import GaussianParams
    from spotlessgs.models.relightable import RelightableScene

    import numpy as np

    rng = np.random.default_rng(seed)
    xyz = rng.uniform(-1, 1, (n, 3)) + np.array([0.0, 0.0, 4.0])
    g = GaussianParams.from_point_cloud(xyz, rng.integers(30, 256, (n, 3)).astype(np.uint8), rng.normal(size=(n, 3)))
    return RelightableScene.create(model, g, seed=seed)


def test_split_lights_halves_sum_to_the_spotlight_lit_colour():
    from spotlessgs.models.shading import shade

    scene = _random_scene(candidate_model(2, "mlp"))
    app = scene.appearance
    with torch.no_grad():
        app.lf_light.coeffs.normal_(0.0, 0.3, generator=torch.Generator().manual_seed(2))
        parts = shade(scene.config, scene.gaussians, app.light, app.lf_light, app.brdf, torch.eye(4),
                      split_lights=True)
        full = shade(scene.config, scene.gaussians, app.light, app.lf_light, app.brdf, torch.eye(4))
    assert parts.shape == (60, 6) and float(parts[:, 3:].abs().sum()) > 0
    torch.testing.assert_close(parts[:, :3] + parts[:, 3:], full, rtol=1e-5, atol=1e-6)
    with pytest.raises(ValueError, match="split_lights"):
        shade(scene.config, scene.gaussians, app.light, app.lf_light, app.brdf, torch.eye(4), relight_l0=[1.0] * 3,
              split_lights=True)


def test_low_frequency_share_is_what_the_light_adds_to_the_renders():
    """Independently: 1 - Σ(render without the low-frequency light) / Σ(render with it), through scene.render."""
    from spotlessgs.training.light_need import low_frequency_share

    scene = _random_scene(candidate_model(3, "lambert"))
    c2ws = torch.stack([torch.eye(4), torch.eye(4)])
    c2ws[1, 0, 3] = 0.4  # a second camera, moved sideways
    cams = Cameras(c2ws, Intrinsics(30.0, 30.0, 16.0, 12.0, 32, 24))
    lf = scene.appearance.lf_light.coeffs
    with torch.no_grad():
        lf.zero_()
        assert low_frequency_share(scene, cams, [0, 1]) == 0.0
        dark = sum(float(scene.render(cams[k]).image.double().sum()) for k in (0, 1))
        lf[0] = torch.tensor([0.8, 0.5, 0.3])
        lf[1:] = 0.1
        lit = sum(float(scene.render(cams[k]).image.double().sum()) for k in (0, 1))
        share = low_frequency_share(scene, cams, [0, 1])
    assert 0.05 < share < 0.95 and share == pytest.approx(1.0 - dark / lit, rel=1e-5)
    with pytest.raises(ValueError, match="no views"):
        low_frequency_share(scene, cams, [])


def test_dark_level_is_the_dark_end_of_each_view_over_its_bright_end():
    from spotlessgs.training.light_need import dark_level

    # one view of 10 x 10 blocks of 2 x 2 px: block brightness 0.01 * (index + 1), so the 20th-percentile block
    # (torch.quantile, linear interpolation: position 0.2 * 99 = 19.8) is 0.208 and the 99th (98.01) 0.9901
    steps = (torch.arange(100, dtype=torch.float32) + 1) * 0.01
    view = steps.reshape(10, 10).repeat_interleave(2, 0).repeat_interleave(2, 1)[..., None].expand(20, 20, 3)
    level = 0.208 / 0.9901
    assert dark_level(view[None], 2) == pytest.approx(level, rel=1e-5)
    # a strongly coloured view counts with its channel-mean brightness: pure red at three times the grey value
    red = view * torch.tensor([3.0, 0.0, 0.0])
    assert dark_level(red[None], 2) == pytest.approx(level, rel=1e-5)
    # half the view unlit: level 0, also under sensor noise clipped at 0 (two of a block's four pixels at 0 in every
    # channel; block means would make it 0.01 / 0.99 ~ 0.01); black frames are skipped; the median over views
    half = view * torch.cat([torch.zeros(10, 20), torch.ones(10, 20)])[..., None]
    clipped_noise = torch.tensor([[0.02, 0.0], [0.0, 0.02]]).repeat(10, 10)[..., None].expand(20, 20, 3)
    noisy_half = torch.where(half > 0, half, clipped_noise)
    assert dark_level(noisy_half[None], 2) == 0.0
    black = torch.zeros(20, 20, 3)
    assert dark_level(torch.stack([view, black, red, noisy_half]), 2) == pytest.approx(level, rel=1e-5)
    assert dark_level(torch.stack([noisy_half, black]), 2) == 0.0 and dark_level(black[None], 2) == 0.0
    # a block that does not divide the image: edge blocks are cut to the image (the 20 x 20 view in 3-px blocks)
    assert 0.0 < dark_level(view[None], 3) < 1.0
    # pixels without a sample (NaN: a distorted camera's working image outside the lens's view) are skipped: a
    # bright NaN-free block grid padded by two NaN block rows gives the same level
    padded = torch.cat([view, torch.full((4, 20, 3), float("nan"))])
    assert dark_level(padded[None], 2) == pytest.approx(level, rel=1e-5)
    with pytest.raises(ValueError, match="block"):
        dark_level(view[None], 0)
    with pytest.raises(ValueError, match="V, H, W, 3"):
        dark_level(view, 2)


def test_proxies_average_their_scores_and_speed_up_the_low_frequency_light():
    full = preset("quick")
    proxy = proxy_config(full, SelectionConfig())
    assert proxy.validation_average == 4 and proxy.lr_lf_light == pytest.approx(10 * full.lr_light)
    assert proxy.lr_brdf == full.lr_brdf and proxy.lr_light == full.lr_light
    assert proxy_config(full, SelectionConfig(proxy_light_lr_scale=2.0)).lr_lf_light == pytest.approx(2e-3)


def test_validation_steps_cover_the_last_third_and_end_at_the_last_step():
    assert validation_steps(150, 4) == {100, 117, 133, 150}
    assert validation_steps(3000, 1) == {3000} and validation_steps(30, 2) == {20, 30}


class _FixedRenders:
    """A stand-in scene whose render of view k is a fixed image."""

    def __init__(self, images):
        self.images = images

    def render(self, camera, backend="auto", num_threads=None):
        from types import SimpleNamespace

        return SimpleNamespace(image=self.images[int(camera.c2w[0, 3])])


def test_held_out_score_on_all_and_on_the_darkest_pixels():
    # one view, 1 x 4 pixels, grey; observed brightness 0.1, 0.2, 0.8, 0.9; errors 0.1, 0.3, 0.0, 0.2 (every channel)
    seen = torch.tensor([0.1, 0.2, 0.8, 0.9]).reshape(1, 1, 4, 1).expand(1, 1, 4, 3)
    pred = (seen[0] + torch.tensor([0.1, 0.3, 0.0, -0.2]).reshape(1, 4, 1)).clone()
    one_view = Cameras(torch.eye(4)[None], Intrinsics(4.0, 4.0, 2.0, 0.5, 4, 1))
    score = held_out_score(_FixedRenders([pred]), one_view, seen, [0])
    assert score.psnr == pytest.approx(-10 * math.log10((0.01 + 0.09 + 0.0 + 0.04) / 4))
    assert score.psnr_dark == pytest.approx(-10 * math.log10((0.01 + 0.09) / 2))  # the darker half
    masked = held_out_score(_FixedRenders([pred]), one_view, seen, [0], pixel_masks=torch.tensor([[[False, True, True, False]]]))
    assert masked.psnr == pytest.approx(-10 * math.log10(0.09 / 2)) and masked.psnr_dark == pytest.approx(
        -10 * math.log10(0.09))
    with pytest.raises(ValueError, match="dark_quantile"):
        held_out_score(_FixedRenders([pred]), one_view, seen, [0], dark_quantile=0.0)


def test_a_held_out_frame_of_unknown_exposure_is_scored_after_its_own_gain():
    """Three views of 1 x 4 pixels; view 2 is held out and its camera recorded it 2.5x brighter (auto-exposure). With
    the exposure unknown its render is scaled by the least-squares gain of its unclipped pixels first (2.5 exactly:
    the score is perfect); recorded exposures, or a fitted frame, keep the camera's own gain."""
    from spotlessgs.models.photometric import PhotometricCamera
    from spotlessgs.training.validation import frame_gain

    render = torch.tensor([0.1, 0.2, 0.3, 0.5]).reshape(1, 4, 1).expand(1, 4, 3).clone()
    observed = (2.5 * render).clamp(max=1.0)  # the last pixel clips at 1.0 and is left out of the gain
    views = Cameras(torch.eye(4)[None].repeat(3, 1, 1), Intrinsics(4.0, 4.0, 2.0, 0.5, 4, 1))
    for k in range(3):
        views.c2w[k, 0, 3] = k  # _FixedRenders picks the image by the pose's x
    images = torch.stack([render, render, observed])
    radius = torch.zeros(1, 4)
    learned = PhotometricCamera(3, [0, 1], radius, vignetting=False)
    assert learned.exposure_unknown(2) and not learned.exposure_unknown(0)
    assert frame_gain(render, observed) == pytest.approx(2.5)
    assert math.isinf(held_out_score(_FixedRenders([render] * 3), views, images, [2], photometric=learned).psnr)
    recorded = PhotometricCamera(3, [0, 1], radius, vignetting=False, log_gain_prior=torch.zeros(3))
    assert not recorded.exposure_unknown(2)
    at_reference = held_out_score(_FixedRenders([render] * 3), views, images, [2], photometric=recorded).psnr
    expected = ((render - observed) ** 2).mean()
    assert at_reference == pytest.approx(-10 * math.log10(float(expected)))
    assert frame_gain(torch.zeros(1, 4, 3), observed) == 1.0  # a black render: no gain to take


# ---- run folders ------------------------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def box_room(tmp_path_factory):
    return synthetic_box_dataset(tmp_path_factory, "selection-data", seed=4)


def _tiny(**overrides):
    base = dict(iterations=40, image_width=32, num_threads=1, densify_from=10, densify_until=30, densify_every=10,
                opacity_reset_every=0, log_every=10, checkpoint_every=40, init_points=300, max_gaussians=500,
                brdf_hidden=8)
    base.update(overrides)
    return preset("tiny", **base)


def test_a_run_of_any_model_config_is_stored_and_restored(box_room, tmp_path):
    from spotlessgs.training.trainer import load_run, train

    model = candidate_model(1, "lambert")
    result = train(box_room, tmp_path / "run", model, _tiny(validation_every=4), seed=0, progress=False)
    info = json.loads((tmp_path / "run" / "run.json").read_text())
    assert info["model"] == "auto-sh1-lambert" and info["model_config"]["sh_degree"] == 1
    scene, _views, _cfg, _info = load_run(tmp_path / "run", device="cpu")
    assert scene.config == dataclasses.replace(model, brdf_hidden=8, bounce_light_degree=2)  # the trainer's settings
    assert scene.appearance.lf_light.degree == 1 and scene.appearance.bounce_light.degree == 2
    assert result.validation_psnr is not None and result.validation_psnr > 0
    assert run_decisions(tmp_path / "run") == {"model chosen": "auto-sh1-lambert", "Gaussians": result.num_gaussians}
    with pytest.raises(FileNotFoundError, match="no run.json"):
        run_decisions(tmp_path)


def test_train_model_auto_writes_the_decision_prints_the_table_and_trains_the_choice(box_room, tmp_path):
    from spotlessgs.cli import main

    out = tmp_path / "auto"
    args = ["train", "--data", str(box_room), "--out", str(out), "--model", "auto", "--preset", "tiny",
            "--iterations", "300", "--width", "32", "--threads", "1", "--max-gaussians", "400", "-q",
            "--tolerance-db", "0.3"]
    res = CliRunner().invoke(main, args)
    assert res.exit_code == 0, res.output
    decision = json.loads((out / SELECTION_FILE).read_text())
    names = [c["name"] for c in decision["candidates"]]
    # coordinate search: Lambert and MLP at SH degree 0, then the lowest and highest degree with the winning BRDF
    phases = [c["phase"] for c in decision["candidates"]]
    assert phases == ["reflectance"] * 2 + ["light"] * 2
    assert names[:2] == ["auto-sh0-lambert", "auto-sh0-mlp"]
    reflectance, light = decision["candidates"][:2], decision["candidates"][2:]
    lam, mlp = (c["validation_psnr"] for c in reflectance)
    brdf = "lambert" if lam >= max(lam, mlp) - 0.15 else "mlp"  # each of the two decisions: half the tolerance
    assert names[2:] == [f"auto-sh{d}-{brdf}" for d in (0, 3)]
    assert decision["settings"]["proxy_iterations"] == 100 and decision["tolerance_db"] == 0.3
    assert decision["settings"]["reflectance_proxy_iterations"] == 100  # 15 % of 300 < the 100-step minimum
    assert decision["phase_tolerance_db"] == 0.15
    assert [c["criterion"] for c in decision["candidates"]] == ["all"] * 2 + ["dark"] * 2
    # the need for a low-frequency light, measured on the degree-3 proxy, decides between the two degrees
    need = decision["low_frequency_light"]
    assert need["measured_on"] == f"auto-sh3-{brdf}-light"
    assert 0 <= need["low_frequency_share"] <= 1 and 0 <= need["dark_level"] <= 1
    needed = need["dark_level"] >= 0.01 and need["low_frequency_share"] >= 0.01
    assert need["needed"] == needed
    from spotlessgs.training.data import load_training_views
    from spotlessgs.training.light_need import dark_level

    views = load_training_views(box_room, 32)  # the dark level is that of the training images at the run's width
    assert need["dark_level"] == pytest.approx(dark_level(views.images[views.train], 2), rel=1e-6)
    dark0, dark3 = (c["validation_psnr_dark"] for c in light)  # the darkest held-out pixels
    best, picked = max(dark0, dark3), dark3 if needed else dark0
    if picked >= best - 0.3:  # the light rule's degree, within the whole tolerance
        want = 3 if needed else 0
    else:  # else the held-out pixels decide: the cheapest within half of it
        want = 0 if dark0 >= best - 0.15 else 3
    assert decision["chosen"] == f"auto-sh{want}-{brdf}"
    assert decision["chosen"] in res.output and "val PSNR" in res.output and "low-frequency light" in res.output
    info = json.loads((out / "run.json").read_text())
    assert info["model"] == decision["chosen"] and ModelConfig(**info["model_config"]).name == decision["chosen"]
    summary = json.loads((out / "train_summary.json").read_text())
    assert summary["steps"] == 300 and summary["num_gaussians"] <= 400
    assert not list((out / "selection").glob("*/checkpoints"))  # proxies keep metrics, not checkpoints
    assert decision["base"]["steps"] == 100
    for name in names[:2]:  # the reflectance phase starts from the shared base run ...
        assert json.loads((out / "selection" / name / "run.json").read_text())["init_from"] == \
            str((out / "selection" / "base").resolve())
    for name in names[2:]:  # ... the light phase from its winner
        assert json.loads((out / "selection" / f"{name}-light" / "run.json").read_text())["init_from"] == \
            str((out / "selection" / f"auto-sh0-{brdf}").resolve())
    # same folder again: refused without --resume; with --resume the decision is reused
    again = CliRunner().invoke(main, args)
    assert again.exit_code == 2 and "--resume" in again.output and "Traceback" not in again.output
    resumed = CliRunner().invoke(main, [*args, "--resume"])
    assert resumed.exit_code == 0, resumed.output
    moved = tmp_path / "moved-data"  # the dataset moved: --resume with --data at its new place reuses the decision
    shutil.copytree(box_room, moved)
    args_moved = [str(moved) if a == str(box_room) else a for a in args]
    resumed = CliRunner().invoke(main, [*args_moved, "--resume"])
    assert resumed.exit_code == 0, resumed.output
    assert json.loads((out / SELECTION_FILE).read_text()) == decision
    from spotlessgs.training.selection import select_model

    # the same settings on other files (a frame changed): refused by name, the decision kept
    changed = tmp_path / "changed-data"
    shutil.copytree(box_room, changed)
    frames = sorted((changed / "images").glob("*.png"))
    shutil.copyfile(frames[1], frames[0])
    with pytest.raises(ValueError, match=r"other selection settings than the run was started with \(dataset: "
                                         r"decided on other files than .*changed-data holds\)"):
        select_model(changed, out, TrainConfig(**decision["settings"]["train"]), 0, SelectionConfig(tolerance_db=0.3),
                     resume=True)
    assert json.loads((out / SELECTION_FILE).read_text()) == decision

    with pytest.raises(ValueError, match="other selection settings"):
        select_model(box_room, out, _tiny(iterations=300, image_width=32), 0, SelectionConfig(tolerance_db=0.9),
                     resume=True)
    # other training settings under the same selection settings: refused by name (the proxies would differ)
    with pytest.raises(ValueError, match=r"other selection settings.*\(train depth_spread: run 'auto', now 'on'\)"):
        select_model(box_room, out, TrainConfig(**{**decision["settings"]["train"], "depth_spread": "on"}), 0,
                     SelectionConfig(tolerance_db=0.3), resume=True)
    assert decision["settings"]["train"]["depth_spread"] == "auto"
    # a decision written before the training settings were recorded is reused as it was
    unrecorded = {**decision, "settings": {k: v for k, v in decision["settings"].items() if k != "train"}}
    (out / SELECTION_FILE).write_text(json.dumps(unrecorded))
    assert select_model(box_room, out, _tiny(iterations=300, image_width=32), 0, SelectionConfig(tolerance_db=0.3),
                        resume=True) == unrecorded
    old = {**decision, "version": SELECTION_VERSION - 1}  # an older selection's decision: refused with what to do
    (out / SELECTION_FILE).write_text(json.dumps(old))
    with pytest.raises(ValueError, match=f"model selection version {SELECTION_VERSION - 1}, this is version "
                                         f"{SELECTION_VERSION}.*to decide again"):
        select_model(box_room, out, _tiny(iterations=300, image_width=32), 0, SelectionConfig(tolerance_db=0.3),
                     resume=True)


def test_a_trusted_start_keeps_the_learned_brdf_by_rule_and_the_base_holds_the_start_normals(box_room, tmp_path):
    """``trusted_start_reflectance="learned"`` (the default): on a start the trainer trusts, no reflectance phase; the
    shared base holds the start's normals and models the lamp and the room light as the candidates do, the light phase
    trains the learned BRDF from it (trusted: normals held, the lamp's bounce on, unclamped); elsewhere, and with
    ``"compare"``, the BRDFs compete as before."""
    from spotlessgs.training.selection import select_model, trusted_start
    from spotlessgs.training.trainer import model_config as trainer_model_config
    from spotlessgs.training.trainer import TRUSTED_START_SETTINGS, trusts_start_geometry

    cfg = _tiny(iterations=300, image_width=32, trust_start_geometry="on")
    assert trusted_start(cfg, box_room)
    assert not trusted_start(cfg.replace(trust_start_geometry="auto"), box_room)  # no point cloud: a random start
    assert not trusted_start(cfg.replace(trust_start_geometry="off"), box_room)
    out = tmp_path / "auto"
    rule = SelectionConfig(tolerance_db=0.3)
    assert rule.trusted_start_reflectance == "learned"
    decision = select_model(box_room, out, cfg, 0, rule)
    assert decision["reflectance"] == "learned by rule"
    assert [(c["name"], c["phase"]) for c in decision["candidates"]] == [("auto-sh0-mlp", "light"),
                                                                        ("auto-sh3-mlp", "light")]
    assert decision["chosen_model"]["brdf"] == "mlp"
    assert "the learned BRDF by rule" in format_selection_table(decision)
    for candidate, degree in zip(decision["candidates"], (0, 3)):  # trusted: the bounce's gain, the monotone profile
        untrusted = trainer_model_config(candidate_model(degree, "mlp"), cfg)
        trusted = trainer_model_config(candidate_model(degree, "mlp"), cfg.replace(**TRUSTED_START_SETTINGS))
        assert candidate["appearance_parameters"] == appearance_parameters(trusted, cfg.brdf_hidden)
        assert candidate["appearance_parameters"] != appearance_parameters(untrusted, cfg.brdf_hidden)

    def train_settings(folder):
        return json.loads((out / "selection" / folder / "config.json").read_text())["train"]

    assert train_settings("base")["lr_normals"] == 0.0  # the Lambertian base is not trusted: held by the rule
    # ... with the candidates' lamp profile and room-light shading, since their light starts from the base's
    assert (train_settings("base")["rid_model"], train_settings("base")["low_frequency_shading"]) == ("monotone",
                                                                                                      "irradiance")
    for degree in (0, 3):  # trusted by the trainer's own policy (normals held, bounce, unclamped: test_training)
        name = f"auto-sh{degree}-mlp-light"
        assert json.loads((out / "selection" / name / "run.json").read_text())["init_from"] == \
            str((out / "selection" / "base").resolve())
        assert train_settings(name)["trust_start_geometry"] == "on"
        assert trusts_start_geometry(candidate_model(degree, "mlp"))
    # a decision written before the setting existed compared the BRDFs: resumed under "compare", reused as it was;
    # under the default rule --resume says which setting differs
    older = json.loads((out / SELECTION_FILE).read_text())
    del older["settings"]["selection"]["trusted_start_reflectance"]
    (out / SELECTION_FILE).write_text(json.dumps(older))
    compare = SelectionConfig(tolerance_db=0.3, trusted_start_reflectance="compare")
    assert select_model(box_room, out, cfg, 0, compare, resume=True) == older
    with pytest.raises(ValueError, match="other selection settings.*trusted_start_reflectance"):
        select_model(box_room, out, cfg, 0, rule, resume=True)
    # not trusted (a start the trainer does not trust, or the "compare" rule): the reflectance phase runs
    for folder, config, selection in (("untrusted", cfg.replace(trust_start_geometry="off"), rule),
                                      ("compared", cfg, compare)):
        compared = select_model(box_room, tmp_path / folder, config, 0, selection)
        assert compared["reflectance"] == "compared"
        assert [c["phase"] for c in compared["candidates"]] == ["reflectance"] * 2 + ["light"] * 2
    untrusted_base = json.loads((tmp_path / "untrusted" / "selection" / "base" / "config.json").read_text())["train"]
    assert untrusted_base["lr_normals"] == cfg.lr_normals > 0
    # the default rid_model "auto" keeps the MLP profile for every proxy on a start that is not trusted
    assert (untrusted_base["rid_model"], untrusted_base["low_frequency_shading"]) == ("mlp", "spot_cosine")
    # compared on a trusted start: the Lambertian candidate starts from the same base, with its light
    compared_lambert = json.loads((tmp_path / "compared" / "selection" / "auto-sh0-lambert" / "config.json")
                                  .read_text())["train"]
    assert (compared_lambert["rid_model"], compared_lambert["low_frequency_shading"]) == ("monotone", "irradiance")


def test_train_auto_trains_the_chosen_model_with_the_light_model_of_its_proxies(box_room, tmp_path, monkeypatch):
    """On a trusted start every proxy has the trusted light model (TRUSTED_START_LIGHT), so the chosen model trains
    with it too, a Lambertian one as well (which trust_start_geometry itself leaves alone); elsewhere the angular
    profile is the MLP one for the default ``rid_model`` "auto", or the one given."""
    from spotlessgs.training import selection
    from spotlessgs.training.data import load_training_views
    from spotlessgs.training.trainer import start_geometry_settings

    chosen = candidate_model(3, "lambert")
    trained = []
    monkeypatch.setattr(selection, "select_model", lambda *a, **k: {"chosen_model": dataclasses.asdict(chosen)})
    monkeypatch.setattr(selection.trainer, "train", lambda data, run, model, config, **k: trained.append(config))
    cfg = _tiny(iterations=300, image_width=32, trust_start_geometry="on")
    assert start_geometry_settings(cfg, load_training_views(box_room, 32), chosen) == cfg  # not trusted itself
    selection.train_auto(box_room, tmp_path / "trusted", cfg)
    assert trained[-1] == cfg.replace(rid_model="monotone", low_frequency_shading="irradiance") != cfg
    untrusted = cfg.replace(trust_start_geometry="off", rid_model="mlp")
    selection.train_auto(box_room, tmp_path / "untrusted", untrusted)
    assert trained[-1] == untrusted
    auto = untrusted.replace(rid_model="auto")  # the MLP profile on an untrusted start, also for an MLP BRDF
    assert cfg.rid_model == "auto"  # the default
    selection.train_auto(box_room, tmp_path / "auto", auto)
    assert trained[-1] == auto.replace(rid_model="mlp")
    monotone = untrusted.replace(rid_model="monotone")  # a profile given is kept
    selection.train_auto(box_room, tmp_path / "monotone", monotone)
    assert trained[-1] == monotone


def test_selection_options_need_model_auto(box_room, tmp_path):
    from spotlessgs.cli import main

    res = CliRunner().invoke(main, ["train", "--data", str(box_room), "--out", str(tmp_path / "r"), "--model",
                                    "darkgs", "--tolerance-db", "0.5", "-q"])
    assert res.exit_code != 0 and "only apply to --model auto" in res.output


def test_warm_start_copies_gaussians_light_and_the_leading_sh_block():
    from spotlessgs.models.gaussians import GaussianParams
    from spotlessgs.models.relightable import RelightableScene
    from spotlessgs.training.warm_start import warm_start_scene

    import numpy as np

    def scene(model, n, seed):
        xyz = np.random.default_rng(seed).normal(size=(n, 3))
        return RelightableScene.create(model, GaussianParams.from_point_cloud(xyz, np.full((n, 3), 90, np.uint8)),
                                       seed=seed)

    src = scene(candidate_model(1, "lambert"), 7, 0)
    with torch.no_grad():
        src.appearance.lf_light.coeffs.copy_(torch.arange(12.0).reshape(4, 3))
        src.appearance.light.log_gamma.fill_(0.3)
    ckpt = {"gaussians": {k: v.detach() for k, v in src.gaussians.params.items()},
            "appearance": src.modules_.state_dict()}
    dst = warm_start_scene(scene(candidate_model(2, "mlp"), 3, 1), ckpt)
    assert len(dst.gaussians) == 7
    torch.testing.assert_close(dst.gaussians.means, src.gaussians.means)
    assert float(dst.appearance.light.log_gamma.detach()) == pytest.approx(0.3)
    coeffs = dst.appearance.lf_light.coeffs.detach()
    assert coeffs.shape == (9, 3)
    torch.testing.assert_close(coeffs[:4], torch.arange(12.0).reshape(4, 3))
    assert float(coeffs[4:].abs().sum()) == 0.0
    low = warm_start_scene(scene(candidate_model(0, "lambert"), 3, 2), ckpt)  # a lower degree keeps the DC row
    torch.testing.assert_close(low.appearance.lf_light.coeffs.detach(), torch.tensor([[0.0, 1.0, 2.0]]))
    # the bounce light's coefficients are carried the same way
    bounce = dataclasses.replace(candidate_model(1, "lambert"), bounce_light_degree=1)
    src_b = scene(bounce, 7, 0)
    with torch.no_grad():
        src_b.appearance.bounce_light.coeffs.copy_(torch.arange(12.0).reshape(4, 3) + 1)
    ckpt_b = {"gaussians": {k: v.detach() for k, v in src_b.gaussians.params.items()},
              "appearance": src_b.modules_.state_dict()}
    dst_b = warm_start_scene(scene(dataclasses.replace(bounce, bounce_light_degree=2), 3, 1), ckpt_b)
    torch.testing.assert_close(dst_b.appearance.bounce_light.coeffs.detach()[:4], torch.arange(12.0).reshape(4, 3) + 1)
    assert float(dst_b.appearance.bounce_light.coeffs.detach()[4:].abs().sum()) == 0.0
    with pytest.raises(ValueError, match="not a training checkpoint"):
        warm_start_scene(dst, {"gaussians": {}}, "x.pt")
    with pytest.raises(ValueError, match="needs a spotlight"):
        warm_start_scene(scene("3dgs", 3, 0), ckpt, "x.pt")
    # a learned BRDF is carried over to a model with the same network (the light phase continues its winner) ...
    mlp_src = scene(candidate_model(0, "mlp"), 5, 3)
    with torch.no_grad():
        mlp_src.appearance.brdf.mlp[-1].bias.fill_(0.7)
    mlp_ckpt = {"gaussians": {k: v.detach() for k, v in mlp_src.gaussians.params.items()},
                "appearance": mlp_src.modules_.state_dict()}
    carried = warm_start_scene(scene(candidate_model(3, "mlp"), 3, 4), mlp_ckpt)
    for (name, a), b in zip(carried.appearance.brdf.state_dict().items(), mlp_src.appearance.brdf.state_dict().values()):
        torch.testing.assert_close(a, b, msg=name)
    # ... but not to a network of another width
    narrow = scene(dataclasses.replace(candidate_model(0, "mlp"), brdf_hidden=8), 3, 5)
    fresh_bias = narrow.appearance.brdf.mlp[-1].bias.detach().clone()
    torch.testing.assert_close(warm_start_scene(narrow, mlp_ckpt).appearance.brdf.mlp[-1].bias.detach(), fresh_bias)


# ---- held-out pixel blocks ----------------------------------------------------------------------------------------


def test_holdout_blocks_are_whole_blocks_in_the_stated_fraction_and_seeded():
    masks = holdout_blocks(3, 30, 40, 0.25, 8, seed=5)
    assert masks.shape == (3, 30, 40) and masks.dtype == torch.bool
    grid = torch.zeros(3, 4, 5, dtype=torch.bool)  # ceil(30/8) x ceil(40/8) blocks, the last row cut to 6 pixels
    for by in range(4):
        for bx in range(5):
            block = masks[:, 8 * by:8 * by + 8, 8 * bx:8 * bx + 8]
            assert bool((block == block[:, :1, :1]).all()), "a block is either held out or not, as a whole"
            grid[:, by, bx] = block[:, 0, 0]
    assert grid.sum(dim=(1, 2)).tolist() == [5, 5, 5]  # round(0.25 * 20 blocks) per view
    assert not torch.equal(grid[0], grid[1])  # each view draws its own blocks
    assert torch.equal(masks, holdout_blocks(3, 30, 40, 0.25, 8, seed=5))
    assert not torch.equal(masks, holdout_blocks(3, 30, 40, 0.25, 8, seed=6))
    assert holdout_blocks(1, 8, 8, 0.01, 4, seed=0).sum() == 16  # at least one block per view
    with pytest.raises(ValueError, match=r"holds out every pixel of a 4 x 4 training image"):
        holdout_blocks(1, 4, 4, 0.01, 8, seed=0)  # one block in all: nothing left to fit (trained on nothing)


@pytest.mark.parametrize("kwargs, match", [({"fraction": 0.0}, "fraction"), ({"fraction": 1.0}, "fraction"),
                                           ({"block": 0}, "block")])
def test_holdout_blocks_reject_bad_settings(kwargs, match):
    args = {"views": 2, "height": 8, "width": 8, "fraction": 0.5, "block": 4, "seed": 0, **kwargs}
    with pytest.raises(ValueError, match=match):
        holdout_blocks(**args)


def test_trainconfig_holds_out_views_or_blocks_not_both():
    with pytest.raises(ValueError, match="not both"):
        preset("tiny", validation_every=3, validation_blocks=0.1)
    with pytest.raises(ValueError, match="validation_blocks"):
        preset("tiny", validation_blocks=1.5)


def test_held_out_pixels_never_influence_training_only_the_validation_score(box_room, tmp_path):
    """Two datasets that differ only in the held-out pixels (white in one) train to identical models, while the
    validation PSNR, computed on exactly those pixels, drops for the altered one."""

    import numpy as np
    from PIL import Image

    from spotlessgs.training.checkpoint import load_checkpoint
    from spotlessgs.training.data import load_training_views
    from spotlessgs.training.trainer import train

    cfg = _tiny(iterations=30, image_width=None, densify_from=10, densify_until=25, checkpoint_every=30,
                validation_blocks=0.3, validation_block=4)
    views = load_training_views(box_room)
    masks = holdout_blocks(len(views.names), views.cameras.height, views.cameras.width, 0.3, 4, seed=0).numpy()
    altered = tmp_path / "altered"
    shutil.copytree(box_room, altered)
    for k, name in enumerate(views.names):
        path = altered / "images" / name
        img = np.array(Image.open(path))
        img[masks[k]] = 255
        Image.fromarray(img).save(path)

    results = [train(data, tmp_path / f"run{i}", "darkgs", cfg, seed=0, progress=False)
               for i, data in enumerate((box_room, altered))]
    a, b = (load_checkpoint(tmp_path / f"run{i}") for i in range(2))
    for key, tensor in a["gaussians"].items():
        torch.testing.assert_close(b["gaussians"][key], tensor, rtol=0, atol=0, msg=key)
    assert results[0].validation_psnr > results[1].validation_psnr + 3.0


def test_the_validation_score_is_the_mean_of_the_scores_over_the_last_third(box_room, tmp_path):
    from spotlessgs.training.trainer import read_metrics, train

    cfg = _tiny(iterations=30, image_width=None, densify_from=10, densify_until=25, checkpoint_every=30,
                validation_blocks=0.3, validation_block=4, validation_average=3)
    result = train(box_room, tmp_path / "run", "darkgs", cfg, seed=0, progress=False)
    scored = [r for r in read_metrics(tmp_path / "run" / "metrics.jsonl") if "validation_psnr" in r]
    assert [r["step"] for r in scored] == [20, 25, 30]
    assert result.validation_psnr == pytest.approx(sum(r["validation_psnr"] for r in scored) / 3)
    assert result.validation_psnr_dark == pytest.approx(sum(r["validation_psnr_dark"] for r in scored) / 3)
    assert len({round(r["validation_psnr"], 6) for r in scored}) == 3  # the model changed between the scores
    summary = json.loads((tmp_path / "run" / "train_summary.json").read_text())
    assert summary["validation_psnr_dark"] == pytest.approx(result.validation_psnr_dark)
