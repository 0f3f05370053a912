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
