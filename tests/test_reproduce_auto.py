"""The reproduction's automatic mode on a synthetic dataset (no Blender): the ``auto`` training stage selects the model,
trains it with the Gaussian budget, counts the selection in its training time, and the report's collection reads
what each run needed from the run folders (run_decisions) into the tables."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from conftest import synthetic_box_dataset
from spotlessgs.io.atomic import write_json
from spotlessgs.experiments.reproduce.config import preset
from spotlessgs.experiments.reproduce.pipeline import check_or_record_config
from spotlessgs.experiments.reproduce.report import collect
from spotlessgs.jobs.graph import write_marker
from spotlessgs.experiments.reproduce.tables import runtime_table, table1
from spotlessgs.experiments.reproduce.tasks import method_spec, train_method
from spotlessgs.training.selection import SELECTION_FILE, run_decisions

pytestmark = pytest.mark.usefixtures("one_torch_thread")

ITERATIONS = 40
PROXY = 10


@pytest.fixture(scope="module")
def auto_run(tmp_path_factory):
    data = synthetic_box_dataset(tmp_path_factory, "reproduce-auto-data", seed=3)
    run = tmp_path_factory.mktemp("reproduce-auto") / "auto"
    result = train_method(str(data), str(run), "auto", "tiny", ITERATIONS, None, (0.5,), sfm=False,
                          sfm_matcher="sequential", lpips=False, seed=0, threads=1,
                          selection_min_proxy_iterations=PROXY)
    return data, run, result


def test_auto_config_is_the_gaussian_budget_of_the_command_line():
    from spotlessgs.training.config import STRATEGIES

    auto = method_spec(Path("data"), "auto", "tiny", 40, 32, threads=1, seed=0).train_config()
    fixed = method_spec(Path("data"), "spotless", "tiny", 40, 32, threads=1, seed=0).train_config()
    assert auto.gaussian_budget and auto.validation_every >= 2 and not fixed.gaussian_budget
    assert auto.replace(**{k: getattr(fixed, k) for k in STRATEGIES["budget"]}) == fixed  # nothing else differs
    assert (auto.iterations, auto.image_width, auto.num_threads) == (40, 32, 1)


def test_auto_stage_records_the_selection(auto_run):
    _, run, result = auto_run
    decision = json.loads((run / SELECTION_FILE).read_text())
    selection = result["selection"]
    assert selection["chosen"] == decision["chosen"] == run_decisions(run)["model chosen"]
    assert selection["chosen"] in [c["name"] for c in selection["candidates"]]
    assert selection["tolerance_db"] == decision["tolerance_db"] == 0.25  # the selection default
    # the smaller proxy length reached the selection (round(0.05 * 40) = 2 steps is below the minimum)
    assert decision["settings"]["proxy_iterations"] == PROXY and decision["settings"]["base_iterations"] == PROXY
    assert decision["settings"]["full_iterations"] == ITERATIONS
    # the chosen model was trained in full, with the budget
    config = json.loads((run / "config.json").read_text())
    assert config["train"]["gaussian_budget"] and config["model_config"]["name"] == selection["chosen"]
    budget = json.loads((run / "gaussian_budget.json").read_text())
    assert budget["final_gaussians"] == run_decisions(run)["Gaussians"] == result["train"]["num_gaussians"] > 0


def test_auto_training_time_counts_the_selection(auto_run):
    _, _, result = auto_run
    train, curve = result["train"], result["curve"]
    assert train["selection_seconds"] == result["selection"]["seconds"] > 0
    loops = train["ms_per_step"] * ITERATIONS / 1000.0  # ms / step is the final model's training loop alone
    assert train["seconds"] == pytest.approx(train["selection_seconds"] + loops, rel=1e-9)
    assert [p["step"] for p in curve] == [ITERATIONS // 2, ITERATIONS]
    assert train["selection_seconds"] < curve[0]["train_seconds"] < curve[1]["train_seconds"] == train["seconds"]
    assert curve[1]["psnr_aligned"] == result["metrics"]["psnr_aligned"]


def test_method_stage_leaves_the_inputs_to_their_own_stage(auto_run):
    """A method's evaluation scores its relit sequence only: the dataset's eval-inputs stage scores the inputs."""
    _, run, result = auto_run
    assert "input" not in result["metrics"] and result["metrics"]["psnr_aligned"] > 0
    saved = json.loads((run / "eval" / "results.json").read_text())
    assert "input" not in saved and saved["config"]["inputs"] is False


def test_collect_reads_what_each_run_needed(auto_run, tmp_path):
    """The report's collection adds run_decisions of every run folder; the tables show them."""
    _, auto_dir, result = auto_run
    config = preset("tiny", variants=("uneven",), methods=("spotless", "auto"), baselines=(), sensor_noise=None,
                    robot_camera=False)
    check_or_record_config(config, tmp_path)
    runs = tmp_path / "runs" / "bedroom-uneven"
    (runs / "spotless").mkdir(parents=True)
    write_json(runs / "spotless" / "run.json", {"model": "spotless"})
    write_json(runs / "spotless" / "train_summary.json", {"num_gaussians": 4321})
    (runs / "auto").symlink_to(auto_dir)
    for method in ("spotless", "auto"):
        write_marker(tmp_path, f"train/bedroom-uneven/{method}",
                     {"result": json.loads(json.dumps(result)), "seconds": 1.0, "peak_rss_mb": 1.0})
    inputs = {"psnr": 8.5, "ssim": 0.25, "psnr_aligned": 9.5, "ssim_aligned": 0.3}
    write_marker(tmp_path, "eval-inputs/bedroom-uneven", {"result": {"metrics": inputs}, "seconds": 1.0})
    write_marker(tmp_path, "ceiling/bedroom-uneven", {"result": {"skipped": "no albedo pass"}, "seconds": 1.0})
    collected = collect(tmp_path, config)
    assert collected["datasets"]["bedroom-uneven"]["input"] == inputs
    methods = collected["datasets"]["bedroom-uneven"]["methods"]
    chosen, count = result["selection"]["chosen"], result["train"]["num_gaussians"]
    assert methods["spotless"]["decisions"] == {"model chosen": "spotless", "Gaussians": 4321}
    assert methods["auto"]["decisions"] == {"model chosen": chosen, "Gaussians": count}
    t1 = table1(collected)
    assert [r[-2:] for r in t1.rows if r[0] == "bedroom-uneven"][1:] == [["spotless (sh3+mlp)", 4321],
                                                                         [chosen, count]]
    rt = runtime_table(collected)
    auto_row = next(r for r in rt.rows if r[1] == "SpotlessGS auto (selection + budget)")
    assert auto_row[2:6] == [chosen, count, result["train"]["seconds"], result["train"]["selection_seconds"]]
