"""The reproduction's ``eval-inputs`` stage (spotlessgs.experiments.reproduce.tasks.evaluate_inputs) on a synthetic dataset (no
Blender): it scores a dataset's uneven inputs once with exactly the numbers that ``evaluate_run``'s ``input`` block
gave every method before (same functions, same settings, SfM included), and names what is wrong with bad datasets."""

from __future__ import annotations

import json
import shutil

import pytest

from evaluation.runner import evaluate_run
from evaluation.synthetic import render_room_sequence, write_dataset_folder
from spotlessgs.io.atomic import to_jsonable, write_json
from spotlessgs.io.images import write_png
from spotlessgs.experiments.reproduce.tasks import _eval_config, compact_metrics, evaluate_inputs

pytestmark = pytest.mark.usefixtures("one_torch_thread")

SETTINGS = {"sfm": True, "sfm_matcher": "sequential", "lpips": True, "seed": 0}


@pytest.fixture(scope="module")
def dataset(tmp_path_factory):
    """A 12-frame 200x150 posed dataset (test views 0, 4, 8) and a run folder whose relit images are the ground
    truth."""
    root = tmp_path_factory.mktemp("inputs-stage")
    seq = render_room_sequence(num_frames=12, width=200, height=150, seed=1)
    names = write_dataset_folder(seq, root / "data", test_every=4)
    run = root / "run"
    write_json(run / "run.json", {"data_dir": str(root / "data")})
    for k, name in enumerate(names):
        write_png(run / "relit" / name, seq.even[k])
    return root / "data", run


@pytest.fixture(scope="module")
def both(dataset, tmp_path_factory):
    """(evaluate_run's results with the inputs, as every method stage computed them before; the stage's summary and
    output folder)."""
    data, run = dataset
    out = tmp_path_factory.mktemp("inputs-out")
    full = evaluate_run(run, _eval_config(threads=1, **SETTINGS), out_dir=out / "eval")
    summary = evaluate_inputs(str(data), str(out / "inputs"), threads=1, **SETTINGS)
    return full, summary, out / "inputs"


def test_stage_numbers_equal_evaluate_runs_input_block(both):
    full, summary, _ = both
    before = to_jsonable(compact_metrics(full)["input"])  # what a method's marker held as metrics["input"]
    assert summary == {"metrics": before}
    metrics = summary["metrics"]
    assert {"psnr", "ssim", "lpips", "psnr_aligned", "ssim_aligned", "lpips_aligned", "tmp_psnr", "tmp_ssim",
            "tmp_psnr_warped", "sfm", "num_images", "exposure_gain"} <= set(metrics)
    assert metrics["num_images"] == 3 and metrics["sfm"]["total_images"] == 12
    # SfM ran on the inputs (the spotlight-lit synthetic inputs register nothing at this size, as in evaluate_run)
    assert {"registered_images", "reprojection_error_px", "observations_per_image"} <= set(metrics["sfm"])
    assert metrics["psnr_aligned"] < full["psnr_aligned"] - 10  # the inputs are the uneven images, not the relit ones


def test_stage_writes_full_results_and_sfm_folder(both):
    full, _, out = both
    saved = json.loads((out / "results.json").read_text())
    assert saved["mode"] == "inputs" and saved["test_views"] == ["frame_00000.png", "frame_00004.png",
                                                                 "frame_00008.png"]
    assert saved["per_image"] == to_jsonable(full["input"]["per_image"])
    assert saved["config"]["sfm_config"] == full["config"]["sfm_config"] and saved["config"]["lpips"]
    assert saved["provenance"]["packages"]["numpy"]
    assert (out / "sfm").is_dir()


def test_stage_without_sfm_or_lpips(dataset, tmp_path):
    data, _ = dataset
    metrics = evaluate_inputs(str(data), str(tmp_path), **{**SETTINGS, "sfm": False, "lpips": False},
                              threads=1)["metrics"]
    assert "sfm" not in metrics and "lpips" not in metrics and metrics["tmp_ssim"] > 0
    assert not (tmp_path / "sfm").exists()


def _copy(data, dest):
    shutil.copytree(data, dest)
    return dest


def test_stage_errors_name_the_problem(dataset, tmp_path):
    data, _ = dataset
    no_gt = _copy(data, tmp_path / "no_gt")
    meta = json.loads((no_gt / "transforms.json").read_text())
    for frame in meta["frames"]:
        frame.pop("gt_file_path")
    write_json(no_gt / "transforms.json", meta)
    with pytest.raises(ValueError, match="no_gt: no test view has a ground-truth image"):
        evaluate_inputs(str(no_gt), str(tmp_path / "o1"), threads=1, **SETTINGS)

    missing = _copy(data, tmp_path / "missing")
    (missing / "gt" / "frame_00004.png").unlink()
    with pytest.raises(FileNotFoundError, match=r"gt/frame_00004.png: image listed in transforms.json does not exist"):
        evaluate_inputs(str(missing), str(tmp_path / "o2"), threads=1, **SETTINGS)

    spread = _copy(data, tmp_path / "spread")
    meta = json.loads((spread / "transforms.json").read_text())
    (spread / "more").mkdir()
    shutil.move(str(spread / "images" / "frame_00009.png"), str(spread / "more" / "frame_00009.png"))
    meta["frames"][9]["file_path"] = "more/frame_00009.png"
    write_json(spread / "transforms.json", meta)
    with pytest.raises(ValueError, match=r"spread: input images are spread over 2 folders .* SfM needs them in one"):
        evaluate_inputs(str(spread), str(tmp_path / "o3"), threads=1, **SETTINGS)
