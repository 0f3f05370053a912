"""The library API of a run (spotlessgs.run): RunSpec as a value, train(spec, run_dir) -> Run, and Run's folder."""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import pytest
import torch

from conftest import synthetic_box_dataset
from evaluation.runner import EvalConfig
from spotlessgs.io.errors import InputError
from spotlessgs.run import Run, RunSpec, train
from spotlessgs.training.config import STRATEGIES, preset
from spotlessgs.training.selection import SelectionConfig

pytestmark = pytest.mark.usefixtures("one_torch_thread")

SMALL = (("iterations", 10), ("image_width", 32), ("num_threads", 1), ("densify_from", 1000), ("log_every", 10),
         ("checkpoint_every", 10), ("init_points", 200), ("max_gaussians", 300), ("brdf_hidden", 8))


@pytest.fixture(scope="module")
def box(tmp_path_factory):
    return synthetic_box_dataset(tmp_path_factory, "run-api", seed=4)


@pytest.fixture(scope="module")
def run(box, tmp_path_factory) -> Run:
    return train(RunSpec(data=box, model="darkgs", preset="tiny", overrides=SMALL), tmp_path_factory.mktemp("r") / "r",
                 progress=False)


def test_a_spec_is_a_value_and_builds_the_preset_strategy_and_overrides(box):
    spec = RunSpec(data=str(box), model="spotless", preset="tiny", strategy="budget",
                   overrides=[("iterations", 300), ("num_threads", 2)])
    again = RunSpec(data=box, model="spotless", preset="tiny", strategy="budget",
                    overrides=(("iterations", 300), ("num_threads", 2)))
    assert spec == again and hash(spec) == hash(again) and spec.data == box
    config = spec.train_config()
    assert config == preset("tiny", iterations=300, num_threads=2).replace(**STRATEGIES["budget"])
    assert config.densify_until == round(preset("tiny").densify_until * 300 / preset("tiny").iterations)


@pytest.mark.parametrize("fields, match", [
    ({"model": "nerf"}, "unknown model 'nerf'"),
    ({"preset": "huge"}, "unknown preset 'huge'"),
    ({"strategy": "greedy"}, "unknown strategy 'greedy'"),
    ({"overrides": (("iteratons", 5),)}, r"overrides name no TrainConfig field: \['iteratons'\]"),
    ({"selection": SelectionConfig()}, "only apply to model 'auto'"),
    ({"light_prior": (0.0, 0.1)}, "light_prior needs 3 values"),
])
def test_a_bad_spec_is_refused_when_made(box, fields, match):
    with pytest.raises(ValueError, match=match):
        RunSpec(data=box, **fields)


def test_train_through_the_spec_is_the_trainers_run(box, run, tmp_path):
    """The same spec through the trainer's own call gives the same model, bit for bit."""
    from spotlessgs.training.checkpoint import load_checkpoint
    from spotlessgs.training.trainer import train as trainer_train

    spec = RunSpec(data=box, model="darkgs", preset="tiny", overrides=SMALL)
    trainer_train(box, tmp_path / "direct", "darkgs", spec.train_config(), seed=0, progress=False)
    mine, direct = load_checkpoint(run.dir), load_checkpoint(tmp_path / "direct")
    for name, tensor in mine["gaussians"].items():
        assert torch.equal(tensor, direct["gaussians"][name]), name


def test_a_run_owns_its_folder(run, box):
    assert run.finished and run.summary["steps"] == 10 and run.model == "darkgs"
    assert run.config == RunSpec(data=box, model="darkgs", preset="tiny", overrides=SMALL).train_config()
    assert run.decision is None  # a given model: no selection
    assert Run.load(run.dir) == run
    assert run.info["seed"] == 0 and json.loads((run.dir / "run.json").read_text())["model"] == "darkgs"


def test_a_run_relights_renders_and_evaluates(run, tmp_path):
    relit = run.relight("test", tmp_path / "relit", progress=False, device="cpu")
    assert relit["count"] == len(list((tmp_path / "relit").glob("*.png"))) > 0
    assert not (run.dir / "relit.json").exists()  # another folder's render never writes the run's own summary
    own = run.relight(progress=False, device="cpu")  # RUN/relit, what evaluate scores
    assert json.loads((run.dir / "relit.json").read_text()) == {"schema_version": 1, **json.loads(json.dumps(own))}
    run.relight("test", tmp_path / "relit-2", progress=False, device="cpu")
    assert json.loads((run.dir / "relit.json").read_text())["count"] == own["count"]  # still the run's own
    results = run.evaluate(EvalConfig(lpips=False, temporal=False, progress=False, num_threads=1),
                           out_dir=tmp_path / "eval")
    saved = json.loads((tmp_path / "eval" / "results.json").read_text())
    assert saved["psnr"] == results["psnr"] and results["num_images"] == len(results["test_views"]) == 2
    assert saved["relit_manifest"]["checkpoint_step"] == run.summary["steps"]
    spot = run.render("test", tmp_path / "spot", progress=False, device="cpu")
    assert spot["mode"] == "spot"


def test_a_folder_that_is_no_run_is_one_clear_error(tmp_path):
    with pytest.raises(FileNotFoundError, match="not a training run"):
        Run.load(tmp_path)
    (tmp_path / "run.json").write_text("{")
    with pytest.raises(InputError, match="run.json: .*not valid JSON"):
        Run.load(tmp_path)


def test_auto_through_the_spec_records_the_decision(box, tmp_path):
    spec = RunSpec(data=box, model="auto", preset="tiny", overrides=(*SMALL[1:], ("iterations", 30)),
                   selection=SelectionConfig(min_proxy_iterations=5))
    run = train(spec, tmp_path / "auto", progress=False)
    assert run.decision is not None and run.model == run.decision["chosen"]
    assert dataclasses.replace(spec, seed=1) != spec


def test_run_files_carry_a_schema_version_and_a_newer_one_is_refused(run, tmp_path):
    import shutil

    from spotlessgs.training.checkpoint import RUN_SCHEMA_VERSION

    for name in ("run.json", "config.json", "train_summary.json", "light.json"):
        assert json.loads((run.dir / name).read_text())["schema_version"] == RUN_SCHEMA_VERSION, name
    copy = Path(shutil.copytree(run.dir, tmp_path / "run"))
    info = json.loads((copy / "run.json").read_text())
    del info["schema_version"]  # an older version's run: read as before
    (copy / "run.json").write_text(json.dumps(info))
    assert Run.load(copy).model == "darkgs"
    (copy / "run.json").write_text(json.dumps({**info, "schema_version": RUN_SCHEMA_VERSION + 1}))
    with pytest.raises(InputError, match=r"run.json: written by a newer SpotlessGS \(run schema version 2"):
        Run.load(copy)
    summary = json.loads((copy / "train_summary.json").read_text())
    (copy / "run.json").write_text(json.dumps(info))
    (copy / "train_summary.json").write_text(json.dumps({**summary, "schema_version": 7}))
    with pytest.raises(InputError, match="train_summary.json: written by a newer SpotlessGS"):
        Run.load(copy).summary
