"""`spotless train --set KEY=VALUE`: any trainer setting from the command line (spotlessgs.training.config)."""

from __future__ import annotations

import json
import re

import numpy as np
import pytest
from click.testing import CliRunner

from conftest import synthetic_box_dataset
from spotlessgs.training.config import parse_setting


def test_parse_setting_types_values_like_the_fields():
    assert parse_setting("loss_space=srgb") == ("loss_space", "srgb")
    assert parse_setting("falloff_tau=0.01") == ("falloff_tau", 0.01)
    assert parse_setting("learn_falloff=false") == ("learn_falloff", False)
    assert parse_setting("learn_falloff=1") == ("learn_falloff", True)
    assert parse_setting("max_gaussians=5000") == ("max_gaussians", 5000)
    assert parse_setting("init_points=300") == ("init_points", 300)  # a field whose default may be None
    assert parse_setting("init_points=none") == ("init_points", None)
    for bad, message in (("nope=1", "not KEY=VALUE"), ("loss_space", "not KEY=VALUE"),
                         ("falloff_tau=x", "falloff_tau: 'x' is not a finite number"),
                         ("learn_falloff=maybe", "learn_falloff: 'maybe' is not true or false"),
                         ("max_gaussians=2.5", "max_gaussians: '2.5' is not a whole number"),
                         ("init_points=many", "init_points: 'many' is not a whole number or none")):
        with pytest.raises(ValueError, match=message):
            parse_setting(bad)


def test_train_set_reaches_the_run_and_bad_values_stop_before_writing(tmp_path_factory, tmp_path):
    from spotlessgs.cli import main

    box = synthetic_box_dataset(tmp_path_factory, "settings", seed=3)
    out = tmp_path / "run"
    common = ["train", "--data", str(box), "--model", "darkgs", "--preset", "tiny", "--iterations", "8", "--width",
              "32", "--threads", "1", "-q"]
    result = CliRunner().invoke(main, [*common, "--out", str(out), "--set", "loss_space=srgb", "--set",
                                       "falloff_tau=0.02", "--set", "learn_falloff=false"])
    assert result.exit_code == 0, result.output
    saved = json.loads((out / "config.json").read_text())
    assert (saved["train"]["loss_space"], saved["model_config"]["falloff_tau"]) == ("srgb", 0.02)
    assert saved["model_config"]["learn_falloff"] is False
    light = json.loads((out / "light.json").read_text())["estimate"]
    assert light["falloff_tau_m2"] == pytest.approx(0.02)  # frozen: still its initial value
    bad = CliRunner().invoke(main, [*common, "--out", str(tmp_path / "bad"), "--set", "loss_space=log"])
    assert bad.exit_code != 0 and "loss_space must be 'linear' or 'srgb'" in bad.output
    assert not (tmp_path / "bad").exists()


@pytest.mark.parametrize("setting, message", [
    ("pose_align_lr=-1", "the learning rate pose_align_lr must be >= 0"),  # failed after training, losing the run
    ("ssim_lambda=5", r"ssim_lambda must be in \[0, 1\]"),
    ("prune_opacity=2", r"prune_opacity must be in \[0, 1\)"),
    ("reset_opacity_value=-1", r"reset_opacity_value must be in \[0, 1\)"),
    ("densify_grad_threshold=-1", "densify_grad_threshold must be >= 0"),
    ("percent_dense=-1", "percent_dense must be >= 0"),
    ("normal_gravity_weight=-1", "the loss weight normal_gravity_weight must be >= 0"),
    ("num_threads=2000", "num_threads must be at most 1024"),
    ("device=CPU", "device must be auto, cpu, cuda or cuda:N"),
    ("raster_backend=foo", "raster_backend must be one of auto, cpp, torch, gsplat"),
])
def test_settings_out_of_range_stop_before_anything_is_written(tmp_path, setting, message):
    """Each was accepted: it failed at the end of training, at the first render, or trained something meaningless."""
    from spotlessgs.cli import main

    result = CliRunner().invoke(main, ["train", "--data", str(tmp_path), "--out", str(tmp_path / "run"), "--preset",
                                       "tiny", "--set", setting])
    assert result.exit_code == 2 and "Traceback" not in result.output, result.output
    assert len(re.findall(message, result.output)) == 1, result.output
    assert not (tmp_path / "run").exists()


def test_the_python_api_refuses_wrongly_typed_settings_and_a_preset_override():
    """RunSpec overrides of the wrong type trained to the end and left a run nobody could read back."""
    from spotlessgs.run import RunSpec
    from spotlessgs.training.config import TrainConfig

    for field, value, message in (("image_width", 64.5, "image_width: expected a whole number or null, got 64.5"),
                                  ("iterations", True, "iterations: expected a whole number, got True"),
                                  ("falloff_tau", "0.01", "falloff_tau: expected a number, got '0.01'")):
        with pytest.raises(ValueError, match=message):
            RunSpec(data="d", preset="tiny", overrides=((field, value),)).train_config()
    assert RunSpec(data="d", overrides=(("falloff_tau", 0.01), ("falloff_tau", 0.5))).overrides == (
        ("falloff_tau", 0.5),)  # in code the last wins (a benchmark row's switches); the command line refuses twins
    with pytest.raises(ValueError, match="set the preset with RunSpec.preset"):
        RunSpec(data="d", overrides=(("preset", "paper"),))
    assert TrainConfig(device="cuda:1").device == "cuda:1"  # a GPU by its index is a device (resolved at training)


@pytest.mark.parametrize("args, message", [
    (["--set", "falloff_tau=0.01", "--set", "falloff_tau=0.5"], "falloff_tau set more than once"),
    (["--set", "preset=paper"], "preset is chosen with --preset, not --set"),
    (["--light-prior-weight", "2"], "--light-prior-weight weighs --light-prior"),
    (["--model", "3dgs", "--light-prior", "0", "0", "0"], "--light-prior has no effect with --model 3dgs"),
])
def test_options_that_would_be_ignored_are_refused(tmp_path, args, message):
    from spotlessgs.cli import main

    result = CliRunner().invoke(main, ["train", "--data", str(tmp_path), "--out", str(tmp_path / "run"), *args])
    assert result.exit_code == 2 and message in result.output, result.output
    assert not (tmp_path / "run").exists()


def test_lamp_path_reads_the_logged_positions_and_skips_what_it_cannot_read(tmp_path):
    from spotlessgs.training.light_report import lamp_path, plot_lamp_path

    metrics = tmp_path / "metrics.jsonl"
    metrics.write_text("\n".join([json.dumps({"step": 25, "light_translation_m": [0.01, 0.0, 0.0]}), "{broken",
                                  json.dumps({"step": 50, "loss": 0.1}),  # a model without a lamp logs no position
                                  json.dumps({"step": 75, "light_translation_m": [0.02, -0.01, 0.005]})]))
    steps, positions = lamp_path(metrics)
    np.testing.assert_array_equal(steps, [25, 75])
    np.testing.assert_allclose(positions, [[0.01, 0.0, 0.0], [0.02, -0.01, 0.005]])
    assert lamp_path(tmp_path / "missing.jsonl")[1].shape == (0, 3)
    plot_lamp_path(steps, positions, None, tmp_path / "light_path.png")
    assert (tmp_path / "light_path.png").stat().st_size > 0
