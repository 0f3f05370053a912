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
    assert relit and row["relit_fps"] > 0
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
                         ("falloff_tau=small", "falloff_tau: 'small' is not a float")):
        result = CliRunner().invoke(main, ["benchmark", "models", "--data", str(box), "--out", str(tmp_path / "x"),
                                           "--set", bad])
        assert result.exit_code == 2 and message in result.output and not (tmp_path / "x").exists()
