"""End to end: `spotless eval RUN` and `spotless eval --pred --gt` on a synthetic dataset, outputs and error paths."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
import torch
from click.testing import CliRunner
from PIL import Image

from evaluation.cli import eval_command
from spotlessgs.metrics import psnr, ssim
from evaluation.runner import EvalConfig, evaluate_folders, evaluate_run
from evaluation.sfm import SfmConfig
from evaluation.synthetic import render_room_sequence, write_dataset_folder
from spotlessgs.io.atomic import write_json
from spotlessgs.io.colorspace import linear_to_srgb, srgb_to_linear
from spotlessgs.io.images import read_image, write_png

TOP_KEYS = {"psnr", "ssim", "lpips", "psnr_aligned", "ssim_aligned", "lpips_aligned", "tmp_psnr", "tmp_ssim", "sfm"}
QUIET = EvalConfig(progress=False, num_threads=1)  # no progress bars, one torch thread
SFM_KEYS = {"reprojection_error_px", "observations_per_image", "registered_images", "total_images", "points3d"}

pytestmark = pytest.mark.usefixtures("one_torch_thread")



def _darker(img: np.ndarray, factor: float) -> np.ndarray:
    """The same image ``factor`` times as bright in linear light."""
    return linear_to_srgb(srgb_to_linear(img.astype(np.float64)) * factor)


@pytest.fixture(scope="module")
def run_dir(tmp_path_factory):
    root = tmp_path_factory.mktemp("evalrun")
    seq = render_room_sequence(num_frames=12, width=200, height=150, seed=1)
    names = write_dataset_folder(seq, root / "data", test_every=4)
    run = root / "run"
    write_json(run / "run.json", {"data_dir": "../data"})  # relative to the run folder
    for k, n in enumerate(names):
        write_png(run / "relit" / n, _darker(seq.even[k], 0.5))  # a perfect relighting at half the exposure
    return run


@pytest.fixture(scope="module")
def run_results(run_dir):
    cfg = EvalConfig(sfm=True, sfm_config=SfmConfig(seed=0), progress=False, num_threads=1)
    return evaluate_run(run_dir, cfg)


def test_run_results_keys_and_values(run_results, run_dir):
    r = run_results
    assert TOP_KEYS <= set(r) and SFM_KEYS <= set(r["sfm"])
    assert r["test_views"] == ["frame_00000.png", "frame_00004.png", "frame_00008.png"]
    assert r["num_images"] == 3 and len(r["per_image"]) == 3
    # half exposure: raw scores are poor, the aligned ones nearly perfect (8-bit rounding only)
    assert r["exposure_gain"] == pytest.approx(2.0, rel=0.01)
    assert r["psnr"] < 20 and r["psnr_aligned"] > 38 and r["ssim_aligned"] > 0.99 and r["lpips_aligned"] < 0.01
    # the relit sequence beats the spotlight inputs on every image metric
    inp = r["input"]
    assert inp["psnr_aligned"] < r["psnr_aligned"] - 10 and inp["lpips"] > r["lpips"]
    # the per-image numbers are the library functions' numbers on the files
    pred = torch.from_numpy(read_image(run_dir / "relit" / "frame_00004.png")).permute(2, 0, 1)
    gt = torch.from_numpy(read_image(run_dir.parent / "data" / "gt" / "frame_00004.png")).permute(2, 0, 1)
    row = r["per_image"][1]
    assert row["name"] == "frame_00004.png"
    assert row["psnr"] == pytest.approx(float(psnr(pred, gt)[0]), abs=1e-5)
    assert row["ssim"] == pytest.approx(float(ssim(pred, gt)[0]), abs=1e-6)
    # warped temporal consistency is available (depth EXRs) and beats the plain figure on a static scene
    assert r["tmp_psnr_warped"] > r["tmp_psnr"] + 5
    assert r["input"]["tmp_psnr"] is not None
    # a perfect relighting's brightness changes as the truth's: no flicker beyond it (8-bit rounding only), whatever
    # its own
    assert r["tmp_flicker_excess"] < 0.002 and r["tmp_flicker"] > 0.01


def test_run_sfm_relit_registers_everything(run_results):
    s = run_results["sfm"]
    assert s["registered_images"] == s["total_images"] == 12
    assert s["reprojection_error_px"] < 1.0
    assert s["trajectory"]["ate_rmse"] < 0.05
    assert SFM_KEYS <= set(run_results["input"]["sfm"])


def test_run_outputs_written(run_results, run_dir):
    out = run_dir / "eval"
    data = json.loads((out / "results.json").read_text())
    assert TOP_KEYS <= set(data) and data["provenance"]["packages"]["numpy"]
    md = (out / "results.md").read_text()
    assert "| relit |" in md and "| input (uneven) |" in md and "Structure from motion" in md
    for fig in ("grid.png", "sfm_trajectories.png"):
        with Image.open(out / "figures" / fig) as im:
            assert im.size[0] > 300 and im.size[1] > 200


def test_folders_mode_via_cli(run_dir, tmp_path):
    pred, gt = run_dir / "relit", run_dir.parent / "data" / "gt"
    json_path = tmp_path / "res.json"
    result = CliRunner().invoke(eval_command, ["--pred", str(pred), "--gt", str(gt), "--json", str(json_path),
                                               "--out", str(tmp_path / "out"), "--quiet", "--threads", "1"])
    assert result.exit_code == 0, result.output
    assert "| prediction |" in result.output
    data = json.loads(json_path.read_text())
    assert {"psnr", "ssim", "lpips", "psnr_aligned", "tmp_psnr", "tmp_ssim"} <= set(data) and "sfm" not in data
    assert data["num_images"] == 12
    assert (tmp_path / "out" / "figures" / "grid.png").is_file()
    assert json.loads((tmp_path / "out" / "results.json").read_text())["psnr"] == data["psnr"]


def test_folders_identical_images(tmp_path):
    for sub in ("a", "b"):
        for k in range(2):
            write_png(tmp_path / sub / f"{k}.png", np.full((40, 40, 3), 0.25 + 0.5 * k))
    r = evaluate_folders(tmp_path / "a", tmp_path / "b", QUIET, json_path=tmp_path / "r.json")
    assert math.isinf(r["psnr"]) and r["ssim"] == pytest.approx(1.0) and r["lpips"] == 0.0
    assert r["exposure_gain"] == pytest.approx(1.0)
    assert json.loads((tmp_path / "r.json").read_text())["psnr"] is None  # JSON has no infinity


def test_folders_with_sfm_and_estimated_intrinsics(run_dir, tmp_path):
    cfg = EvalConfig(lpips=False, aligned=False, temporal=False, sfm=True, progress=False, num_threads=1)
    r = evaluate_folders(run_dir / "relit", run_dir.parent / "data" / "gt", cfg, out_dir=tmp_path)
    assert "lpips" not in r and "psnr_aligned" not in r
    # COLMAP has to find the focal length itself here (a harder problem): part of the sequence registers
    assert 3 <= r["sfm"]["registered_images"] <= r["sfm"]["total_images"] == 12
    assert r["sfm"]["reprojection_error_px"] < 1.5 and "trajectory" not in r["sfm"]
    assert (tmp_path / "figures" / "sfm_trajectories.png").is_file()


def test_size_mismatch_is_named(tmp_path):
    write_png(tmp_path / "p" / "x.png", np.zeros((20, 30, 3)))
    write_png(tmp_path / "g" / "x.png", np.zeros((20, 31, 3)))
    with pytest.raises(ValueError, match=r"x.png: size mismatch: prediction .* is 30x20, reference .* is 31x20"):
        evaluate_folders(tmp_path / "p", tmp_path / "g", QUIET)


def test_degenerate_folders_are_one_error_naming_the_files(tmp_path):
    """All-black predictions (no exposure gain), images smaller than SSIM's window, frames of two sizes in one
    sequence: an InputError naming the folder or the files, not an error without a path."""
    from spotlessgs.io.errors import InputError

    for k in range(2):
        write_png(tmp_path / "black" / f"{k}.png", np.zeros((20, 20, 3)))
        write_png(tmp_path / "gt" / f"{k}.png", np.full((20, 20, 3), 0.5))
        write_png(tmp_path / "tiny" / f"{k}.png", np.zeros((8, 8, 3)))
        write_png(tmp_path / "tiny_gt" / f"{k}.png", np.zeros((8, 8, 3)))
    config = EvalConfig(lpips=False, progress=False, num_threads=1)
    with pytest.raises(InputError, match=r"black: every pixel of the 2 predicted image\(s\) is black"):
        evaluate_folders(tmp_path / "black", tmp_path / "gt", config)
    with pytest.raises(InputError, match=r"tiny/0.png against .*tiny_gt/0.png: images of 8x8 pixels are smaller"):
        evaluate_folders(tmp_path / "tiny", tmp_path / "tiny_gt", config)
    write_png(tmp_path / "mixed" / "0.png", np.full((20, 20, 3), 0.4))
    write_png(tmp_path / "mixed" / "1.png", np.full((20, 24, 3), 0.4))
    write_png(tmp_path / "mixed_gt" / "0.png", np.full((20, 20, 3), 0.5))
    write_png(tmp_path / "mixed_gt" / "1.png", np.full((20, 24, 3), 0.5))
    with pytest.raises(InputError, match=r"mixed/0.png and 1.png: temporal .*frames 0 and 1 differ in shape"):
        evaluate_folders(tmp_path / "mixed", tmp_path / "mixed_gt", config)


def test_run_errors(run_dir, tmp_path):
    with pytest.raises(FileNotFoundError, match=r"not a training run \(no run.json\)"):
        evaluate_run(tmp_path, QUIET)
    bad = tmp_path / "bad"
    write_json(bad / "run.json", {"seed": 1})
    with pytest.raises(ValueError, match=r"the run's dataset was not recorded \(run.json has no data_dir\)"):
        evaluate_run(bad, QUIET)
    write_json(bad / "run.json", {"data_dir": str(run_dir.parent / "data")})
    with pytest.raises(FileNotFoundError, match="the run has no relit images"):
        evaluate_run(bad, QUIET)
    write_png(bad / "relit" / "frame_00000.png", np.zeros((150, 200, 3)))
    with pytest.raises(FileNotFoundError, match=r"missing relit images for 11 view\(s\)"):
        evaluate_run(bad, QUIET)


def test_run_without_ground_truth(run_dir, tmp_path):
    meta = json.loads((run_dir.parent / "data" / "transforms.json").read_text())
    for fr in meta["frames"]:
        fr.pop("gt_file_path")
    write_json(tmp_path / "data" / "transforms.json", meta)  # the shared reader takes relative paths only
    (tmp_path / "data" / "images").symlink_to(run_dir.parent / "data" / "images")
    write_json(tmp_path / "run" / "run.json", {"data_dir": str(tmp_path / "data")})
    (tmp_path / "run" / "relit").symlink_to(run_dir / "relit")
    with pytest.raises(ValueError, match="no test view has a ground-truth image"):
        evaluate_run(tmp_path / "run", QUIET)


def test_cli_usage_errors(run_dir):
    r = CliRunner().invoke(eval_command, [str(run_dir), "--pred", str(run_dir)])
    assert r.exit_code == 2 and "give either RUN or --pred/--gt, not both" in r.output
    r = CliRunner().invoke(eval_command, ["--pred", str(run_dir)])
    assert r.exit_code == 2 and "give a RUN folder, or both --pred DIR and --gt DIR" in r.output
    from spotlessgs.cli import main  # input errors become one line and exit 2 in the `spotless` group

    r = CliRunner().invoke(main, ["eval", "--pred", str(run_dir / "relit"), "--gt", str(run_dir.parent / "data"),
                                  "--quiet"])
    assert r.exit_code == 2 and "error: " in r.output and "non-image files found: transforms.json" in r.output
    assert "Traceback" not in r.output


def test_config_errors():
    with pytest.raises(ValueError, match="grid_frames must be at least 1, got 0"):
        EvalConfig(grid_frames=0)
    with pytest.raises(ValueError, match="num_threads must be at least 1, got 0"):
        EvalConfig(num_threads=0)


def test_temporal_block_needs_one_pose_per_image(run_dir):
    from evaluation.dataset import read_dataset
    from evaluation.runner import temporal_block

    data = read_dataset(run_dir.parent / "data")
    paths = [f.input_path for f in data.frames[:3]]
    with pytest.raises(ValueError, match="temporal input: 3 images but 12 posed frames"):
        temporal_block(paths, QUIET, "input", data)
    assert temporal_block(paths[:1], QUIET, "input") == {}


def test_run_without_inputs_scores_the_relit_sequence_only(run_dir, run_results, tmp_path):
    """``inputs=False`` drops the ``input`` block (metrics, temporal, SfM of the inputs) and nothing else: the relit
    numbers are those of the default evaluation, which keeps scoring the inputs."""
    cfg = EvalConfig(sfm=True, sfm_config=SfmConfig(seed=0), progress=False, num_threads=1, inputs=False)
    r = evaluate_run(run_dir, cfg, out_dir=tmp_path / "eval")
    assert "input" not in r and r["config"]["inputs"] is False
    assert EvalConfig().inputs and run_results["config"]["inputs"] is True and "input" in run_results
    assert sorted(p.name for p in (tmp_path / "eval" / "sfm").iterdir()) == ["relit"]
    assert sorted(p.name for p in (run_dir / "eval" / "sfm").iterdir()) == ["input", "input_gt", "relit"]
    assert run_results["input"]["sfm_gt"]["total_images"] == run_results["input"]["sfm"]["total_images"]

    def relit_only(results: dict) -> dict:
        return {k: v for k, v in results.items() if k not in ("input", "config", "provenance")}

    assert relit_only(r) == relit_only(run_results)  # SfM with one thread and a seed is bit-reproducible
    saved = json.loads((tmp_path / "eval" / "results.json").read_text())
    assert "input" not in saved and saved["psnr"] == pytest.approx(run_results["psnr"])
    md = (tmp_path / "eval" / "results.md").read_text()
    assert "| relit |" in md and "| input (uneven) |" not in md
    with Image.open(tmp_path / "eval" / "figures" / "sfm_trajectories.png") as one, \
            Image.open(run_dir / "eval" / "figures" / "sfm_trajectories.png") as two:
        assert one.size[0] < two.size[0]  # one trajectory panel (relit) instead of two
