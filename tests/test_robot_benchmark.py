"""`spotless benchmark robot`: one row per robot-camera component, resumable, with each component's cost and gain."""

from __future__ import annotations

import json
import shutil

import pytest
from click.testing import CliRunner

from evaluation.synthetic import render_room_sequence, write_dataset_folder
from spotlessgs.cli import main
from spotlessgs.experiments.robot_benchmark import RESULTS_JSON, RESULTS_MD, markdown_table

pytestmark = pytest.mark.usefixtures("one_torch_thread")


@pytest.fixture(scope="module")
def rooms(tmp_path_factory):
    root = tmp_path_factory.mktemp("robot-bench")
    write_dataset_folder(render_room_sequence(num_frames=12, width=48, height=36, seed=2), root / "ideal")
    write_dataset_folder(render_room_sequence(num_frames=12, width=48, height=36, seed=2, lens="opencv",
                                              distortion=(-0.18, 0.03, 0.0, 0.0)), root / "robot", with_depth=False)
    return root


def test_each_row_trains_once_and_the_table_gives_cost_and_gain(rooms, tmp_path):
    out = tmp_path / "bench"
    args = ["benchmark", "robot", "--ideal", str(rooms / "ideal"), "--robot", str(rooms / "robot"), "--out", str(out),
            "--rows", "robot,lens-ignored", "--preset", "tiny", "--iterations", "20"]
    result = CliRunner().invoke(main, args)
    assert result.exit_code == 0, result.output
    saved = json.loads((out / RESULTS_JSON).read_text())
    assert [r["row"] for r in saved["rows"]] == ["robot", "lens-ignored"]
    for r in saved["rows"]:  # mean |a - b| >= |mean |a| - mean |b||; these rooms have no uniform ground truth
        assert r["flicker_excess"] >= abs(r["flicker"] - r["flicker_truth"]) - 1e-12
        assert r["flicker_excess"] > 0 and "flicker_excess_uniform" not in r and "psnr_aligned_uniform" not in r
    assert (out / RESULTS_MD).read_text() in result.output
    # the lens-ignored copy reads the same images as a pinhole; the robot dataset itself is untouched
    copy = json.loads((out / "data-lens-ignored" / "transforms.json").read_text())
    original = json.loads((rooms / "robot" / "transforms.json").read_text())
    assert (copy["k1"], copy["k2"], original["k1"], original["k2"]) == (0.0, 0.0, -0.18, 0.03)
    assert copy["frames"] == original["frames"]
    checkpoint = out / "robot" / "run" / "checkpoints" / "last.safetensors"
    stamp = checkpoint.stat().st_mtime_ns
    again = CliRunner().invoke(main, args)  # a rerun reuses the finished rows
    assert again.exit_code == 0, again.output
    assert checkpoint.stat().st_mtime_ns == stamp and json.loads((out / RESULTS_JSON).read_text())["rows"] == \
        saved["rows"]
    bad = CliRunner().invoke(main, [*args[:8], "--rows", "robot,fisheye"])
    assert bad.exit_code == 2 and "unknown rows ['fisheye']" in bad.output
    # a row trained under other settings is not reused: one line names each, nothing is retrained or rewritten
    other = CliRunner().invoke(main, [*args, "--seed", "1", "--set", "depth_spread=off"])
    assert other.exit_code == 2 and "Traceback" not in other.output
    assert "the row was trained with other settings (depth_spread: run 'auto', now 'off'; seed: run 0, now 1); " \
           "use a new --out" in other.output
    assert checkpoint.stat().st_mtime_ns == stamp and json.loads((out / RESULTS_JSON).read_text()) == saved
    # the settings it trained with, however given, are the same settings: reused (the preset's own iteration count)
    same = CliRunner().invoke(main, [*args[:10], "--preset", "tiny", "--iterations", "20", "--set", "depth_spread=auto",
                                     "--set", "num_threads=1"])
    assert same.exit_code == 0, same.output
    assert checkpoint.stat().st_mtime_ns == stamp and json.loads((out / RESULTS_JSON).read_text())["rows"] == \
        saved["rows"]
    # the lens-ignored copy of another robot dataset (other poses) is refused, not reused
    other_robot = tmp_path / "other-robot"
    shutil.copytree(rooms / "robot", other_robot)
    moved = json.loads((other_robot / "transforms.json").read_text())
    moved["frames"][0]["transform_matrix"][0][3] += 0.1
    (other_robot / "transforms.json").write_text(json.dumps(moved))
    refused = CliRunner().invoke(main, [*args[:4], "--robot", str(other_robot), *args[6:8], "--rows", "lens-ignored",
                                        *args[10:]])
    assert refused.exit_code == 2 and "the lens-ignored copy was made from another dataset than" in refused.output
    # ... and so is a finished row trained on the robot dataset when --robot now holds other files
    results = (out / RESULTS_JSON).read_bytes()
    refused = CliRunner().invoke(main, [*args[:4], "--robot", str(other_robot), *args[6:]])
    assert refused.exit_code == 2 and "Traceback" not in refused.output
    assert f"the row was trained with other settings (dataset: trained on other files than {other_robot} holds)" \
        in refused.output
    assert checkpoint.stat().st_mtime_ns == stamp and (out / RESULTS_JSON).read_bytes() == results
    # --set reaches every row's training
    switched = CliRunner().invoke(main, [*args[:6], "--out", str(tmp_path / "off"), "--rows", "robot", "--preset", "tiny",
                                         "--iterations", "20", "--set", "depth_spread=off"])
    assert switched.exit_code == 0, switched.output
    config = json.loads((tmp_path / "off" / "robot" / "run" / "config.json").read_text())
    row = json.loads((tmp_path / "off" / RESULTS_JSON).read_text())["rows"][0]
    assert config["train"]["depth_spread"] == "off" and row["row"] == "robot"


def test_the_table_states_each_components_cost_and_gain_against_the_full_robot_row():
    def row(name, ms, psnr):
        return {"row": name, "switched_off": name, "ms_per_step": ms, "psnr_aligned": psnr, "ssim_aligned": 0.5,
                "flicker": 0.1, "flicker_truth": 0.09}

    table = markdown_table([row("ideal", 30.0, 19.5), {**row("robot", 35.0, 19.0), "flicker_excess": 0.052,
                                                       "flicker_excess_uniform": 0.0261, "psnr_aligned_uniform": 20.456},
                            row("no-photometric", 33.5, 18.7)])
    lines = table.splitlines()
    assert "| 35.0 | 19.00 / 20.46 | 0.500 |" in lines[3]  # against both ground truths
    assert "| 30.0 | 19.50 / – | 0.500 |" in lines[2]  # a dataset without the uniform one, or an earlier row
    assert "| 0.100 (0.090) | 0.052 / 0.026 |" in lines[3]  # the relit flicker beyond each truth's
    assert "| 0.100 (0.090) | – / – |" in lines[2]  # a row saved before those were measured
    assert lines[2].endswith("| – | -0.50 (robot − ideal) |")
    assert lines[4].endswith("| +1.5 | +0.30 |")  # the photometric camera: 1.5 ms per step for 0.3 dB


def test_a_robot_dataset_with_the_uniform_truth_is_scored_against_both(rooms, tmp_path):
    from evaluation.runner import score_test_views
    from spotlessgs.io.images import read_image, write_png

    robot = tmp_path / "robot-uniform"
    shutil.copytree(rooms / "robot", robot)
    (robot / "gt_uniform").mkdir()
    for frame in sorted((robot / "gt").glob("*.png")):  # another truth: each lamps-on one mirrored
        write_png(robot / "gt_uniform" / frame.name, read_image(frame)[:, ::-1])
    record = json.loads((robot / "transforms.json").read_text())
    record["spotless"]["renderer"]["ground_truths"] = {"lamps": "gt", "uniform": "gt_uniform"}
    (robot / "transforms.json").write_text(json.dumps(record))
    out = tmp_path / "bench"
    result = CliRunner().invoke(main, ["benchmark", "robot", "--ideal", str(rooms / "ideal"), "--robot", str(robot),
                                       "--out", str(out), "--rows", "robot", "--preset", "tiny", "--iterations", "20"])
    assert result.exit_code == 0, result.output
    row = json.loads((out / RESULTS_JSON).read_text())["rows"][0]
    lamps = score_test_views(robot, out / "robot" / "relit", 1)
    uniform = score_test_views(robot, out / "robot" / "relit", 1, ground_truth="uniform")
    assert row["psnr_aligned"] == lamps["psnr_aligned"] != uniform["psnr_aligned"]
    assert (row["psnr_aligned_uniform"], row["ssim_aligned_uniform"]) == (uniform["psnr_aligned"],
                                                                          uniform["ssim_aligned"])
    assert f"| {row['psnr_aligned']:.2f} / {row['psnr_aligned_uniform']:.2f} |" in result.output
    assert "flicker_excess_uniform" in row
