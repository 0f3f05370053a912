"""A benchmark's finished run is reused only under the settings it was trained with
(spotlessgs.experiments.run_settings)."""

from __future__ import annotations

import dataclasses
import json

import pytest

from spotlessgs.experiments.run_settings import check_finished_row, refuse_other_settings, settings_differences
from spotlessgs.run import RunSpec


def _finished_row(row_dir, spec: RunSpec, model: str = "spotless", drop: tuple[str, ...] = (),
                  train_settings: dict | None = None):
    """A row folder as a benchmark leaves it: row.json and the run's config.json recording ``spec``'s settings
    (without the TrainConfig fields ``drop``, as a run saved before they existed; ``train_settings`` as the run
    resolved them)."""
    train = {k: v for k, v in dataclasses.asdict(spec.train_config()).items() if k not in drop}
    train.update(train_settings or {})
    (row_dir / "run").mkdir(parents=True)
    (row_dir / "run" / "config.json").write_text(json.dumps({"train": train,
                                                             "run": {"model": model, "seed": spec.seed}}))
    (row_dir / "row.json").write_text("{}")


def test_a_row_is_refused_naming_each_setting_that_differs_and_reused_under_the_same(tmp_path):
    spec = RunSpec(data=tmp_path, model="spotless", preset="tiny", seed=0, overrides=(("num_threads", 1),))
    _finished_row(tmp_path / "row", spec)
    check_finished_row(tmp_path / "row", spec)  # the same settings: reused
    # the same settings spelled otherwise: a default given explicitly, overrides in another order
    same = RunSpec(data=tmp_path, model="spotless", preset="tiny", seed=0,
                   overrides=(("depth_spread", "auto"), ("num_threads", 1)))
    assert settings_differences(tmp_path / "row" / "run", same) == []
    other = RunSpec(data=tmp_path, model="darkgs", preset="tiny", seed=1,
                    overrides=(("num_threads", 1), ("depth_spread", "off")))
    with pytest.raises(ValueError, match=r"row/run: the row was trained with other settings \(depth_spread: run "
                                         r"'auto', now 'off'; model: run 'spotless', now 'darkgs'; seed: run 0, now "
                                         r"1\); use a new --out"):
        check_finished_row(tmp_path / "row", other)
    check_finished_row(tmp_path / "unfinished", other)  # no row.json: the trainer compares a resume itself


def test_a_run_saved_before_a_setting_compares_with_what_it_trained_with(tmp_path):
    """A field absent from an older run's config.json takes the value the run trained with (PREDATING_VALUES), not
    today's default: a run from before the depth-spread switch trained the term for every model ("on")."""
    spec = RunSpec(data=tmp_path, model="spotless", preset="tiny", overrides=(("depth_spread", "on"),))
    _finished_row(tmp_path / "row", spec, drop=("depth_spread",))
    refuse_other_settings(tmp_path / "row" / "run", spec)
    today = RunSpec(data=tmp_path, model="spotless", preset="tiny")
    assert settings_differences(tmp_path / "row" / "run", today) == ["depth_spread: run 'on', now 'auto'"]


def test_an_auto_run_is_compared_without_the_model_its_selection_chose(tmp_path):
    """An ``auto`` run saves the settings its chosen model trained with: the proxies' light model (here no dataset,
    so an untrusted start: the MLP profile that the spec's rid_model "auto" resolves to for them)."""
    spec = RunSpec(data=tmp_path, model="auto", preset="tiny")
    _finished_row(tmp_path / "row", spec, model="auto-sh3-mlp", train_settings={"rid_model": "mlp"})
    assert spec.train_config().rid_model == "auto"
    assert settings_differences(tmp_path / "row" / "run", spec) == []
    assert settings_differences(tmp_path / "row" / "run", RunSpec(data=tmp_path, model="auto", preset="tiny",
                                                                   overrides=(("rid_model", "monotone"),))) == [
        "rid_model: run 'mlp', now 'monotone'"]
    assert settings_differences(tmp_path / "row" / "run", RunSpec(data=tmp_path, model="auto", preset="tiny",
                                                                   seed=2)) == ["seed: run 0, now 2"]
