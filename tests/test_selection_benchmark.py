"""The selection / Gaussian-budget benchmark on synthetic datasets (no Blender): every room and run measured with
finite numbers, verdict arithmetic pinned on hand-made numbers, the figure written, reruns reuse finished runs."""

from __future__ import annotations

import json
import math
import shutil
from pathlib import Path

import pytest
from click.testing import CliRunner

from conftest import synthetic_box_dataset
from spotlessgs.experiments.selection_benchmark import (
    PLOT, RESULTS_JSON, RESULTS_MD, ROW_FILE, RUN_FOLDERS, BenchmarkSettings, aggregate_seeds, run_seeds,
    run_selection_benchmark, run_spec, selection_verdict, verdict_lines,
)
from spotlessgs.experiments.cli import selection as main
from spotlessgs.training.budget import budget_verdict
from spotlessgs.training.light_need import light_note

pytestmark = pytest.mark.usefixtures("one_torch_thread")

ARGS = ["--preset", "tiny", "--iterations", "40", "--width", "32", "--threads", "1", "--min-proxy-iterations", "8"]
SETTINGS = BenchmarkSettings("tiny", 40, 32, 1, 0, 8)


@pytest.fixture(scope="module")
def bench(tmp_path_factory):
    rooms = [synthetic_box_dataset(tmp_path_factory, "sb-a", seed=5).rename(
                 tmp_path_factory.mktemp("rooms-a") / "room_a"),
             synthetic_box_dataset(tmp_path_factory, "sb-b", seed=6).rename(
                 tmp_path_factory.mktemp("rooms-b") / "room_b")]
    out = tmp_path_factory.mktemp("selection-bench")
    args = [a for room in rooms for a in ("--data", str(room))] + ["--out", str(out), *ARGS]
    result = CliRunner().invoke(main, args)
    assert result.exit_code == 0, result.output + repr(result.exception)
    return rooms, out, result.output


# ---- verdict arithmetic ----------------------------------------------------------------------------------------


def test_selection_verdict_is_the_psnr_difference_against_the_tolerance():
    v = selection_verdict(30.0, 30.5, 0.25)
    assert v["delta_db"] == pytest.approx(-0.5) and not v["within"]
    assert selection_verdict(31.0, 30.0, 0.25) == {"delta_db": 1.0, "tolerance_db": 0.25, "within": True}
    assert selection_verdict(30.0, 30.25, 0.25)["within"]  # exactly at the tolerance
    assert selection_verdict(20.1, 20.3, 0.2)["within"]  # at the bound despite float rounding (-0.2000000000000028)
    assert not selection_verdict(20.0, 20.2501, 0.25)["within"]
    assert selection_verdict(30.0, 30.0, 0.0)["within"]


def test_light_note_states_the_light_measurements():
    need = {"dark_level": 0.0574, "low_frequency_share": 0.0831, "measured_on": "auto-sh3-lambert-light",
            "needed": True}
    assert light_note(need) == "; low-frequency light needed (dark level 0.057, share 8.3%)"
    assert light_note({**need, "needed": False}).startswith("; low-frequency light not needed")


def test_budget_verdict_needs_both_fewer_gaussians_and_little_psnr_loss():
    v = budget_verdict(1000, 650, 25.0, 24.9)
    assert v["reduction_pct"] == pytest.approx(35.0) and v["delta_db"] == pytest.approx(-0.1) and v["met"]
    assert budget_verdict(10, 7, 25.0, 25.0)["met"]  # exactly 30 % fewer
    assert budget_verdict(1000, 700, 20.3, 20.1)["met"]  # exactly 30 % and exactly 0.2 dB lower
    assert not budget_verdict(1000, 701, 25.0, 26.0)["met"]  # 29.9 % fewer
    assert not budget_verdict(1000, 500, 25.0, 24.79)["met"]  # 0.21 dB lower
    more = budget_verdict(1000, 1200, 25.0, 25.5)
    assert more["reduction_pct"] == pytest.approx(-20.0) and not more["met"]
    assert budget_verdict(1000, 900, 25.0, 25.0, min_reduction_pct=10.0, max_loss_db=0.0)["met"]


def test_verdict_lines_state_the_measured_numbers():
    lines = verdict_lines(selection_verdict(24.88, 25.0, 0.25), budget_verdict(1000, 650, 25.0, 24.9))
    assert lines == ["choice vs spotless: −0.12 dB (tolerance 0.25 dB) — within",
                     "budget: −35.0% Gaussians, −0.10 dB (bound 0.2 dB, at least 30% fewer) — met"]
    lines = verdict_lines(selection_verdict(25.5, 25.0, 0.25), budget_verdict(1000, 1100, 25.0, 24.0))
    assert lines == ["choice vs spotless: +0.50 dB (tolerance 0.25 dB) — within",
                     "budget: +10.0% Gaussians, −1.00 dB (bound 0.2 dB, at least 30% fewer) — missed"]
    assert verdict_lines(selection_verdict(24.0, 25.0, 0.25), budget_verdict(10, 7, 1.0, 1.0))[0].endswith("outside")


@pytest.mark.parametrize("call, match", [
    (lambda: selection_verdict(float("nan"), 25.0, 0.25), "chosen_psnr is not a finite number"),
    (lambda: selection_verdict(25.0, float("inf"), 0.25), "spotless_psnr is not a finite number"),
    (lambda: selection_verdict(25.0, 25.0, -0.1), "tolerance_db must be >= 0"),
    (lambda: budget_verdict(0, 5, 25.0, 25.0), "Gaussian counts must be >= 1"),
    (lambda: budget_verdict(5, 0, 25.0, 25.0), "Gaussian counts must be >= 1"),
    (lambda: budget_verdict(5, 4, None, 25.0), "default_psnr is not a finite number"),
    (lambda: BenchmarkSettings(threads=0), "threads must be >= 1"),
    (lambda: BenchmarkSettings(iterations=0), "iterations must be >= 1"),
    (lambda: BenchmarkSettings(min_proxy_iterations=0), "min_proxy_iterations must be >= 1"),
])
def test_bad_inputs_are_refused(call, match):
    with pytest.raises(ValueError, match=match):
        call()


def test_budget_run_uses_the_command_line_budget_fields():
    from spotlessgs.training.config import STRATEGIES

    default = run_spec(Path("data"), SETTINGS, "spotless", "default").train_config()
    budget = run_spec(Path("data"), SETTINGS, "spotless", "budget").train_config()
    auto = run_spec(Path("data"), SETTINGS, "auto", "default")
    assert auto.train_config() == default and auto.selection.min_proxy_iterations == SETTINGS.min_proxy_iterations
    assert (default.iterations, default.image_width, default.num_threads) == (40, 32, 1)
    assert not default.gaussian_budget
    assert budget == default.replace(**STRATEGIES["budget"])


# ---- the whole benchmark ---------------------------------------------------------------------------------------


def _finite_numbers(obj):
    if isinstance(obj, bool):
        return
    if isinstance(obj, (int, float)):
        assert math.isfinite(obj), obj
    elif isinstance(obj, dict):
        for v in obj.values():
            _finite_numbers(v)
    elif isinstance(obj, list):
        for v in obj:
            _finite_numbers(v)


def test_json_has_every_room_and_run_with_finite_numbers(bench):
    rooms, out, _output = bench
    results = json.loads((out / RESULTS_JSON).read_text())
    assert set(results["rooms"]) == {"room_a", "room_b"}
    assert results["settings"]["min_proxy_iterations"] == 8 and results["provenance"]["seed"] == 0
    for name, room in results["rooms"].items():
        assert set(room["runs"]) == {"spotless", "chosen", "budget"}
        assert room["selection"]["seconds"] > 0 and len(room["selection"]["candidates"]) == 4  # 2 BRDFs + 2 degrees
        assert room["runs"]["chosen"]["model"] == room["selection"]["chosen"]
        assert room["runs"]["spotless"]["model"] == "spotless" == room["runs"]["budget"]["model"]
        assert room["runs"]["budget"]["strategy"] == "budget"
        for run in room["runs"].values():
            assert run["steps"] == 40 and run["gaussians"] >= 1 and run["relit_views"] == 14
            for key in ("train_seconds", "ms_per_step", "relit_fps", "relit_fps_after_training", "psnr",
                        "psnr_aligned"):
                assert math.isfinite(run[key]) and run[key] > 0, (name, key, run[key])
            assert run["psnr_aligned"] >= run["psnr"] - 1e-6  # the best exposure gain cannot lower the PSNR
        _finite_numbers({k: v for k, v in room.items() if k != "data"})
        # the verdicts are recomputed from the stored numbers
        runs = room["runs"]
        assert room["verdicts"]["selection"] == selection_verdict(
            runs["chosen"]["psnr_aligned"], runs["spotless"]["psnr_aligned"], room["selection"]["tolerance_db"])
        assert room["verdicts"]["budget"] == budget_verdict(
            runs["spotless"]["gaussians"], runs["budget"]["gaussians"], runs["spotless"]["psnr_aligned"],
            runs["budget"]["psnr_aligned"])


def test_markdown_and_figure(bench):
    _rooms, out, output = bench
    md = (out / RESULTS_MD).read_text()
    results = json.loads((out / RESULTS_JSON).read_text())
    for name, room in results["rooms"].items():
        assert f"## {name}" in md
        need = room["selection"]["low_frequency_light"]
        assert need["measured_on"].startswith("auto-sh3-") and f"dark level {need['dark_level']:.3f}" in md
        for line in verdict_lines(room["verdicts"]["selection"], room["verdicts"]["budget"]):
            assert f"- {line}" in md
    assert md.count("| spotless | spotless | default |") == 2 and "choice vs spotless" in output
    assert (out / PLOT).read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_rerun_reuses_finished_runs_and_refuses_other_settings(bench, monkeypatch):
    import spotlessgs.training.trainer as trainer

    rooms, out, _output = bench
    before = json.loads((out / RESULTS_JSON).read_text())
    summaries = {p: p.stat().st_mtime_ns for p in out.glob("*/*/train_summary.json")}
    assert len(summaries) == 6
    calls = []
    monkeypatch.setattr(trainer, "train", lambda *a, **k: calls.append(a))
    after = run_selection_benchmark(rooms, out, SETTINGS)
    assert calls == []
    assert {p: p.stat().st_mtime_ns for p in out.glob("*/*/train_summary.json")} == summaries
    # everything is reused except the paired relit FPS, which is measured again on every invocation
    def without_paired_fps(rooms):
        return {name: {**room, "runs": {k: {f: v for f, v in r.items() if f != "relit_fps"}
                                        for k, r in room["runs"].items()}}
                for name, room in rooms.items()}

    assert without_paired_fps(after["rooms"]) == without_paired_fps(before["rooms"])
    assert all(r["relit_fps"] > 0 for room in after["rooms"].values() for r in room["runs"].values())
    with pytest.raises(ValueError, match=r"the run was trained with other settings \(num_threads: run 1, now 2\); use a new --out"):
        # other thread count: the selection's settings match (its decision is reused), the trained runs' do not
        run_selection_benchmark(rooms, out, BenchmarkSettings("tiny", 40, 32, 2, 0, 8))


def test_interrupted_scoring_is_redone_without_retraining(bench, monkeypatch, tmp_path):
    import spotlessgs.training.trainer as trainer

    rooms, out, _output = bench
    copy = tmp_path / "out"
    shutil.copytree(out, copy)
    row = copy / "room_a" / RUN_FOLDERS["budget"] / ROW_FILE
    old = json.loads(row.read_text())
    row.unlink()
    monkeypatch.setattr(trainer, "train", lambda *a, **k: pytest.fail("retrained a finished run"))
    again = run_selection_benchmark(rooms, copy, SETTINGS)
    new = again["rooms"]["room_a"]["runs"]["budget"]
    assert row.is_file()
    for key in ("gaussians", "steps", "train_seconds", "ms_per_step", "psnr", "psnr_aligned"):
        assert new[key] == pytest.approx(old[key], abs=1e-6), key


def test_datasets_are_refused_with_clear_errors(bench, tmp_path):
    rooms, _out, _output = bench
    with pytest.raises(ValueError, match="no dataset folders given"):
        run_selection_benchmark([], tmp_path / "o1", SETTINGS)
    twin = tmp_path / "x" / "room_a"
    shutil.copytree(rooms[0], twin)
    with pytest.raises(ValueError, match=r"share the room name\(s\) \['room_a'\]"):
        run_selection_benchmark([rooms[0], twin], tmp_path / "o2", SETTINGS)
    no_gt = tmp_path / "no_gt"
    shutil.copytree(rooms[0], no_gt)
    shutil.rmtree(no_gt / "gt")
    meta = json.loads((no_gt / "transforms.json").read_text())
    for frame in meta["frames"]:
        frame.pop("gt_file_path", None)
    (no_gt / "transforms.json").write_text(json.dumps(meta))
    with pytest.raises(ValueError, match="no_gt: --data: no test view has a ground-truth image"):
        run_selection_benchmark([rooms[0], no_gt], tmp_path / "o3", SETTINGS)
    assert not (tmp_path / "o3" / "room_a").exists()  # refused before the first room trained
    from spotlessgs.experiments.pose_benchmark import run_pose_benchmark
    from spotlessgs.experiments.robot_benchmark import run_robot_benchmark

    with pytest.raises(ValueError, match="no_gt: --data: no test view has a ground-truth image"):
        run_pose_benchmark(no_gt, tmp_path / "o4", 0.03, 0.3, preset="tiny")
    with pytest.raises(ValueError, match="no_gt: --robot: no test view has a ground-truth image"):
        run_robot_benchmark(rooms[0], no_gt, tmp_path / "o5", preset="tiny")
    assert not (tmp_path / "o4").exists() and not (tmp_path / "o5").exists()


# ---- several seeds ----------------------------------------------------------------------------------------------


def _seed_result(chosen, spotless_psnr, chosen_psnr, budget_psnr, budget_gaussians):
    """A one-room result of run_selection_benchmark with hand-made numbers."""
    def run(psnr, gaussians):
        return {"gaussians": gaussians, "train_seconds": 100.0, "relit_fps": 20.0, "psnr": psnr - 8,
                "psnr_aligned": psnr}
    runs = {"spotless": run(spotless_psnr, 20000), "chosen": run(chosen_psnr, 20000),
            "budget": run(budget_psnr, budget_gaussians)}
    room = {"selection": {"chosen": chosen, "tolerance_db": 0.25}, "runs": runs}
    room["verdicts"] = {"selection": selection_verdict(chosen_psnr, spotless_psnr, 0.25),
                        "budget": budget_verdict(20000, budget_gaussians, spotless_psnr, budget_psnr)}
    return {"rooms": {"bedroom": room}}


def test_seed_summary_judges_the_means_not_single_runs():
    # seed 0 misses the budget bound (-0.3 dB), seed 1 meets it (-0.1 dB): the mean loss -0.2 dB is at the bound
    per_seed = {1: _seed_result("sh0-mlp", 18.5, 18.4, 18.4, 12000), 0: _seed_result("sh1-lambert", 18.9, 18.5,
                                                                                     18.6, 14000)}
    room = aggregate_seeds(per_seed)["bedroom"]
    assert room["choices"] == {"0": "sh1-lambert", "1": "sh0-mlp"}
    assert room["runs"]["spotless"]["psnr_aligned"] == pytest.approx({"mean": 18.7, "min": 18.5, "max": 18.9})
    assert room["runs"]["budget"]["gaussians"] == pytest.approx({"mean": 13000, "min": 12000, "max": 14000})
    assert room["deltas"]["budget_db"] == pytest.approx([-0.3, -0.1])  # seed order
    assert room["deltas"]["budget_reduction_pct"] == pytest.approx([30.0, 40.0])
    assert room["deltas"]["selection_db"] == pytest.approx([-0.4, -0.1])
    budget = room["verdicts"]["budget"]
    assert budget["delta_db"] == pytest.approx(-0.2) and budget["reduction_pct"] == pytest.approx(35.0)
    assert budget["met"]
    selection = room["verdicts"]["selection"]  # mean choice 18.45 vs 18.7: -0.25, at the tolerance
    assert selection["delta_db"] == pytest.approx(-0.25) and selection["within"]
    per_seed[0] = _seed_result("sh1-lambert", 18.9, 18.4, 18.5, 14000)
    room = aggregate_seeds(per_seed)["bedroom"]
    assert not room["verdicts"]["budget"]["met"] and not room["verdicts"]["selection"]["within"]


def test_seed_summary_refuses_mismatched_seeds():
    with pytest.raises(ValueError, match="no seeds"):
        aggregate_seeds({})
    other = _seed_result("a", 1.0, 1.0, 1.0, 5)
    other["rooms"]["kitchen"] = other["rooms"].pop("bedroom")
    with pytest.raises(ValueError, match="different rooms"):
        aggregate_seeds({0: _seed_result("a", 1.0, 1.0, 1.0, 5), 1: other})
    with pytest.raises(ValueError, match="a seed is given twice"):
        run_seeds([], Path("unused"), SETTINGS, [3, 3])


def test_several_seeds_measure_each_seed_and_summarise(bench, tmp_path, monkeypatch):
    import spotlessgs.training.trainer as trainer

    rooms, out, _output = bench
    copy = tmp_path / "out"
    shutil.copytree(out, copy / "seed-0")  # seed 0 is measured already: reused, not retrained
    trained = []
    real_train = trainer.train
    monkeypatch.setattr(trainer, "train", lambda data, run_dir, *a, **k: (trained.append(run_dir),
                                                                          real_train(data, run_dir, *a, **k))[1])
    result = CliRunner().invoke(main, [a for room in rooms for a in ("--data", str(room))]
                                + ["--out", str(copy), *ARGS, "--seed", "0", "--seed", "7"])
    assert result.exit_code == 0, result.output + repr(result.exception)
    assert trained and all(copy / "seed-7" in Path(d).parents for d in trained)
    summary = json.loads((copy / RESULTS_JSON).read_text())
    assert summary["seeds"] == [0, 7] and set(summary["rooms"]) == {"room_a", "room_b"}
    for name, room in summary["rooms"].items():
        single = [json.loads((copy / f"seed-{s}" / RESULTS_JSON).read_text())["rooms"][name] for s in (0, 7)]
        assert json.loads((copy / "seed-7" / RESULTS_JSON).read_text())["provenance"]["seed"] == 7
        psnrs = [r["runs"]["budget"]["psnr_aligned"] for r in single]
        assert room["runs"]["budget"]["psnr_aligned"]["mean"] == pytest.approx(sum(psnrs) / 2)
        assert room["choices"] == {"0": single[0]["selection"]["chosen"], "7": single[1]["selection"]["chosen"]}
        _finite_numbers(room)
    md = (copy / RESULTS_MD).read_text()
    assert "seeds 0, 7" in md and md.count("On the means:") == 2 and "On the means:" in result.output
    assert (copy / PLOT).read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_paired_relit_fps_alternates_the_runs_and_keeps_each_ones_best_round(monkeypatch, tmp_path):
    from spotlessgs.experiments.selection_benchmark import paired_relit_fps
    from spotlessgs.run import Run

    timings = iter([10.0, 30.0, 14.0, 12.0, 11.0, 31.0])  # round 0: a, b, c; round 1: a, b, c
    calls = []

    def fake_relight(run, which, out_dir, **options):
        calls.append((run.dir.name, which))
        assert out_dir.parent != run.dir  # a scratch folder, never the run's own relit/
        return {"fps": next(timings)}

    monkeypatch.setattr(Run, "relight", fake_relight)
    runs = {"a": tmp_path / "ra", "b": tmp_path / "rb", "c": tmp_path / "rc"}
    assert paired_relit_fps(runs, rounds=2) == {"a": 12.0, "b": 30.0, "c": 31.0}
    assert calls == [("ra", "all"), ("rb", "all"), ("rc", "all")] * 2
    with pytest.raises(ValueError, match="rounds"):
        paired_relit_fps(runs, rounds=0)
