"""`spotless train --set KEY=VALUE`: any trainer setting from the command line (spotlessgs.training.config)."""

from __future__ import annotations

import json

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
