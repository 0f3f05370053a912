"""`spotless benchmark robot`: one row per robot-camera component, resumable, with each component's cost and gain."""

from __future__ import annotations

import json

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


def test_the_table_states_each_components_cost_and_gain_against_the_full_robot_row():
    def row(name, ms, psnr):
        return {"row": name, "switched_off": name, "ms_per_step": ms, "psnr_aligned": psnr, "ssim_aligned": 0.5,
                "flicker": 0.1, "flicker_truth": 0.09}

    table = markdown_table([row("ideal", 30.0, 19.5), row("robot", 35.0, 19.0), row("no-photometric", 33.5, 18.7)])
    lines = table.splitlines()
    assert lines[2].endswith("| – | -0.50 (robot − ideal) |")
    assert lines[4].endswith("| +1.5 | +0.30 |")  # the photometric camera: 1.5 ms per step for 0.3 dB
