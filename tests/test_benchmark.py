"""`spotless benchmark models`: one row per model from a train -> relight -> score run."""

from __future__ import annotations

import json

import pytest
import torch

from conftest import synthetic_box_dataset
from spotlessgs.experiments.benchmark import markdown_table, run_benchmark
from spotlessgs.io.images import read_image
from spotlessgs.metrics import psnr


@pytest.fixture(scope="module")
def box(tmp_path_factory):
    return synthetic_box_dataset(tmp_path_factory, "benchmark", seed=6)


def test_a_benchmark_row_scores_the_relit_test_views_against_the_ground_truth(box, tmp_path):
    rows = run_benchmark(box, tmp_path / "bench", ("darkgs",), "tiny", 10, 1)
    (row,) = rows
    assert row["variant"] == "darkgs" and row["iterations"] == 10 and row["gaussians"] > 0
    relit = sorted((tmp_path / "bench" / "darkgs" / "relit_test").glob("*.png"))
    assert relit and row["relit_fps"] > 0 and row["render_fps"] > 0
    assert (row["render_device"], row["render_views"]) == ("cpu", 14)  # every view is timed
    assert "peak_gpu_train_mb" not in row  # device memory is reported on CUDA only
    expected = [float(psnr(torch.from_numpy(read_image(p)).permute(2, 0, 1),
                           torch.from_numpy(read_image(box / "gt" / p.name)).permute(2, 0, 1))[0]) for p in relit]
    assert row["psnr"] == pytest.approx(sum(expected) / len(expected), abs=1e-4)
    saved = json.loads((tmp_path / "bench" / "train_benchmark.json").read_text())
    assert saved["rows"] == rows and "| darkgs |" in markdown_table(rows, 10, 1)
    again = run_benchmark(box, tmp_path / "bench", ("darkgs",), "tiny", 10, 1)  # finished rows are reused
    assert again == rows


def test_benchmark_settings_reach_every_variant(box, tmp_path):
    """`--set KEY=VALUE` trains each variant with the trainer setting (its run records it) and is named above the
    table; an unknown field or a mistyped value is one clear error."""
    from click.testing import CliRunner

    from spotlessgs.cli import main

    settings = (("loss_space", "srgb"), ("learn_falloff", False))
    rows = run_benchmark(box, tmp_path / "bench", ("darkgs",), "tiny", 10, 1, settings=settings)
    recorded = json.loads((tmp_path / "bench" / "darkgs" / "config.json").read_text())["train"]
    assert (recorded["loss_space"], recorded["learn_falloff"]) == ("srgb", False)
    assert markdown_table(rows, 10, 1, settings).startswith(
        "10 iterations per variant, 1 thread(s); settings: loss_space=srgb, learn_falloff=False")
    assert json.loads((tmp_path / "bench" / "train_benchmark.json").read_text())["settings"] == {
        "loss_space": "srgb", "learn_falloff": False}
    for bad, message in (("falloff=1", "not KEY=VALUE with KEY a TrainConfig field"),
                         ("falloff_tau=small", "falloff_tau: 'small' is not a finite number")):
        result = CliRunner().invoke(main, ["benchmark", "models", "--data", str(box), "--out", str(tmp_path / "x"),
                                           "--set", bad])
        assert result.exit_code == 2 and message in result.output and not (tmp_path / "x").exists()


@pytest.mark.parametrize("variant", ["3dgs", "spotless"])
def test_the_timed_relit_frame_is_the_image_relight_writes(box, tmp_path, variant):
    """`render_fps` times the image `spotless relight --l0 1,1,1` writes (before its PNG encoding): the frame kept on
    the device equals the written file to 8-bit rounding, for the relit model and for 3DGS's ordinary render."""
    from spotlessgs.io.colorspace import linear_to_srgb
    from spotlessgs.rendering import render_run, select_views
    from spotlessgs.run import RunSpec, given_overrides, train
    from spotlessgs.experiments.benchmark import relit_frame_renderer
    from spotlessgs.training.trainer import load_run

    run = tmp_path / variant
    train(RunSpec(data=box, model=variant, preset="tiny", seed=0, overrides=given_overrides(iterations=10)), run,
          progress=False)
    render_run(run, "relit", "test", tmp_path / "relit", l0=[1.0, 1.0, 1.0], progress=False)
    scene, views, config, _ = load_run(run)
    indices = select_views(views, "test")
    with torch.no_grad():
        frame = relit_frame_renderer(scene, views.cameras, config, indices[0])
        for k in indices[:3]:
            written = read_image(tmp_path / "relit" / views.names[k])
            timed = linear_to_srgb(frame(k).float().numpy())
            assert timed.shape == written.shape
            assert abs(timed.clip(0, 1) - written).max() <= 0.5 / 255 + 1e-6


def test_a_finished_row_of_other_settings_is_refused_and_copies_never_go_into_their_source(box, tmp_path):
    """`benchmark models` reused a finished row made with other iterations and recorded the new settings over it;
    `benchmark poses`/`robot` with --out inside their dataset copied it into itself until the path was too long."""
    from spotlessgs.experiments.pose_benchmark import run_pose_benchmark
    from spotlessgs.experiments.robot_benchmark import run_robot_benchmark
    from spotlessgs.io.errors import InputError, OutputOverlapError

    run_benchmark(box, tmp_path / "bench", ("darkgs",), "tiny", 4, 1)
    with pytest.raises(ValueError, match=r"darkgs: the darkgs row's run was trained with other settings .*iterations"):
        run_benchmark(box, tmp_path / "bench", ("darkgs",), "tiny", 3, 1)
    assert json.loads((tmp_path / "bench" / "train_benchmark.json").read_text())["iterations"] == 4
    (tmp_path / "bench" / "darkgs" / "benchmark_row.json").write_text('{"variant": "darkgs"}')
    with pytest.raises(InputError, match=r"benchmark_row\.json: .*'iterations'"):
        run_benchmark(box, tmp_path / "bench", ("darkgs",), "tiny", 4, 1)

    before = sorted(p.name for p in box.iterdir())
    with pytest.raises(OutputOverlapError, match="--out"):
        run_pose_benchmark(box, box / "bench", 0.05, 1.0, preset="tiny")
    with pytest.raises(OutputOverlapError, match="--out"):
        run_robot_benchmark(box, box, box / "bench", rows=("lens-ignored",), preset="tiny")
    assert sorted(p.name for p in box.iterdir()) == before


@pytest.mark.parametrize("variants, problem", [("3dgs,foo", "unknown ['foo']"), ("darkgs,darkgs", "repeated ['darkgs']"),
                                               (",", "no names")])
def test_bad_variant_lists_are_refused_before_anything_trains(tmp_path, variants, problem):
    """`--variants 3dgs,foo` trained 3dgs first and failed on foo minutes later."""
    from click.testing import CliRunner

    from spotlessgs.cli import main

    result = CliRunner().invoke(main, ["benchmark", "models", "--data", str(tmp_path), "--out", str(tmp_path / "b"),
                                       "--variants", variants])
    assert result.exit_code == 2 and problem in result.output, result.output
    assert not (tmp_path / "b").exists()


@pytest.mark.parametrize("args, problem", [
    (["models", "--set", "iterations=20"], "--set iterations (use --iterations)"),  # the table printed 1500
    (["models", "--set", "num_threads=2"], "--set num_threads (use --threads)"),
    (["robot", "--ideal", "IN", "--robot", "IN", "--rows", ","], "no row named"),  # replaced a finished table
    (["robot", "--ideal", "IN", "--robot", "IN", "--rows", "ideal,ideal"], "rows ['ideal'] given twice"),
    (["poses", "--rows", "clean,clean"], "rows ['clean'] given twice"),
])
def test_benchmark_options_that_would_mislabel_or_empty_a_table_are_refused(tmp_path, args, problem):
    from click.testing import CliRunner

    from spotlessgs.cli import main

    args = [str(tmp_path) if a == "IN" else a for a in args]
    data = [] if args[0] == "robot" else ["--data", str(tmp_path)]
    result = CliRunner().invoke(main, ["benchmark", args[0], *data, "--out", str(tmp_path / "b"), *args[1:]])
    assert result.exit_code == 2 and problem in result.output, result.output
    assert not (tmp_path / "b").exists()


def test_a_resumed_rows_training_time_is_not_reported_as_the_variants_cost():
    """A row interrupted and finished later reported its last session's seconds as the variant's training time."""
    row = {"variant": "spotless", "iterations": 200, "ms_per_step": 25.0, "gaussians": 800, "relit_fps": 30.0,
           "peak_rss_mb": 400.0}
    table = markdown_table([{**row, "train_seconds": 5.0, "resumed": False},
                            {**row, "variant": "darkgs", "train_seconds": None, "resumed": True}], 200, 1)
    assert "| spotless | 25.0 | 5.0 | 800 |" in table and "| darkgs (resumed) | 25.0 | – | 800 |" in table
    assert "a (resumed) row was interrupted and finished in a later session" in table
    assert "(resumed)" not in markdown_table([{**row, "train_seconds": 5.0, "resumed": False}], 200, 1)

    from spotlessgs.experiments.selection_benchmark import _spread

    assert _spread([1.0, 3.0]) == {"mean": 2.0, "min": 1.0, "max": 3.0}
    assert _spread([1.0, None]) == {"mean": None, "min": None, "max": None}
