"""Every documented user error of both command-line programs, through their real entry points (`spotless`,
`spotless-sim`): one line on stderr that names the file or option and the problem, the documented exit code (2 for
usage and input errors, 1 for the environment's), no traceback; `--debug` shows the traceback.

Each case builds its bad input in a fresh folder from a shared tiny dataset and run (14 frames, 40x30; darkgs, 10
steps, relit), so a case cannot leak into another.
"""

from __future__ import annotations

import json
import shutil
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

import click
import pytest
from click.testing import CliRunner

from conftest import synthetic_box_dataset

pytestmark = pytest.mark.usefixtures("one_torch_thread")

ROOT = Path(__file__).resolve().parents[1]
SHIPPED_SCENE = ROOT / "scenes" / "bedroom" / "house.json"
TRAIN = ("--preset", "tiny", "--iterations", "4", "--width", "32", "--threads", "1", "-q")


@pytest.fixture(scope="module")
def shared(tmp_path_factory) -> dict[str, Path]:
    """``data`` (a finished dataset) and ``run`` (trained on it, relit)."""
    from spotlessgs.rendering import render_run
    from spotlessgs.training.config import preset
    from spotlessgs.training.trainer import train

    data = synthetic_box_dataset(tmp_path_factory, "cli-errors", seed=5)
    run = data.parent / "run"
    config = preset("tiny", iterations=10, image_width=32, num_threads=1, densify_from=1000, log_every=10,
                    checkpoint_every=10, init_points=200, max_gaussians=300, brdf_hidden=8)
    train(data, run, "darkgs", config, seed=0, progress=False)
    render_run(run, "relit", "all", progress=False, device="cpu")
    return {"data": data, "run": run}


@dataclass(frozen=True)
class Case:
    """A bad invocation: ``make(tmp, shared)`` prepares its inputs and returns (program, argv)."""

    name: str
    make: Callable[[Path, dict[str, Path]], tuple[str, list[str]]]
    code: int
    fragments: tuple[str, ...]  # each must appear in the error line ({tmp} is replaced by the case's folder)


def _copy(src: Path, dst: Path) -> Path:
    return Path(shutil.copytree(src, dst, symlinks=True))


def _data_copy(tmp: Path, s: dict[str, Path]) -> Path:
    """``tmp/box``: a copy of the dataset."""
    return _copy(s["data"], tmp / "box")


def _run_copy(tmp: Path, s: dict[str, Path]) -> Path:
    """``tmp/run`` beside ``tmp/box``, copies of the run and its dataset (the run finds the copy through its relative
    path, ``../box``)."""
    _data_copy(tmp, s)
    return _copy(s["run"], tmp / "run")


def _damaged_transforms(tmp, s):
    data = _data_copy(tmp, s)
    (data / "transforms.json").write_text('{"frames": [')
    return "spotless", ["train", "--data", str(data), "--out", str(tmp / "out"), *TRAIN]


def _missing_image(tmp, s):
    data = _data_copy(tmp, s)
    sorted((data / "images").glob("*.png"))[3].unlink()
    return "spotless", ["train", "--data", str(data), "--out", str(tmp / "out"), *TRAIN]


def _not_a_dataset(tmp, s):
    (tmp / "photos").mkdir()
    return "spotless", ["train", "--data", str(tmp / "photos"), "--out", str(tmp / "out"), *TRAIN]


def _colmap_camera(tmp, s, camera: str):
    sparse = tmp / "colmap" / "sparse" / "0"
    sparse.mkdir(parents=True)
    (tmp / "colmap" / "images").mkdir()
    (sparse / "cameras.txt").write_text(camera + "\n")
    (sparse / "images.txt").write_text("1 1 0 0 0 0 0 0 1 frame.png\n\n")
    (sparse / "points3D.txt").write_text("")
    shutil.copy(sorted((s["data"] / "images").glob("*.png"))[0], tmp / "colmap" / "images" / "frame.png")
    return "spotless", ["train", "--data", str(tmp / "colmap"), "--out", str(tmp / "out"), *TRAIN]


def _folding_lens(tmp, s):
    return _colmap_camera(tmp, s, "1 OPENCV 64 48 50 50 32 24 -0.9 0 0 0")  # folds the image: no inverse


def _unsupported_camera_model(tmp, s):
    return _colmap_camera(tmp, s, "1 FOV 64 48 50 50 32 24 0.5")


def _undecodable_frame(tmp, s):
    frames = tmp / "frames"
    frames.mkdir()
    shutil.copy(sorted((s["data"] / "images").glob("*.png"))[0], frames / "a.png")
    (frames / "b.png").write_bytes(b"not a png")
    return "spotless", ["prepare", "--images", str(frames), "--out", str(tmp / "prepared"), "-q"]


def _out_inside_data(tmp, s):
    data = _data_copy(tmp, s)
    return "spotless", ["train", "--data", str(data), "--out", str(data / "run"), *TRAIN]


def _existing_run_without_resume(tmp, s):
    run = _run_copy(tmp, s)
    return "spotless", ["train", "--data", str(tmp / "box"), "--out", str(run), "--model", "darkgs", *TRAIN]


def _resume_other_settings(tmp, s):
    run = _run_copy(tmp, s)
    return "spotless", ["train", "--data", str(tmp / "box"), "--out", str(run), "--model", "spotless", "--resume",
                        *TRAIN]


def _damaged_config(tmp, s):
    run = _run_copy(tmp, s)
    (run / "config.json").write_text("not json")
    return "spotless", ["train", "--data", str(tmp / "box"), "--out", str(run), "--model", "darkgs", "--resume",
                        *TRAIN]


def _selection_option_without_auto(tmp, s):
    return "spotless", ["train", "--data", str(s["data"]), "--out", str(tmp / "out"), "--tolerance-db", "0.1",
                        *TRAIN]


def _unknown_preset(tmp, s):
    return "spotless", ["train", "--data", str(s["data"]), "--out", str(tmp / "out"), "--preset", "huge"]


def _zero_iterations(tmp, s):
    return "spotless", ["train", "--data", str(s["data"]), "--out", str(tmp / "out"), "--iterations", "0"]


def _relight_not_a_run(tmp, s):
    (tmp / "folder").mkdir()
    return "spotless", ["relight", str(tmp / "folder"), "-q"]


def _relight_damaged_run_json(tmp, s):
    run = _run_copy(tmp, s)
    (run / "run.json").write_text("{")
    return "spotless", ["relight", str(run), "-q", "--device", "cpu"]


def _relight_moved_dataset(tmp, s):
    run = _copy(s["run"], tmp / "elsewhere" / "run")
    info = json.loads((run / "run.json").read_text())
    info["data_dir"] = str(tmp / "gone")
    (run / "run.json").write_text(json.dumps(info))
    return "spotless", ["relight", str(run), "-q", "--device", "cpu"]


def _relight_bad_data_option(tmp, s):
    run = _run_copy(tmp, s)
    return "spotless", ["relight", str(run), "-q", "--device", "cpu", "--data", str(tmp / "nowhere")]


def _relight_truncated_checkpoint(tmp, s):
    run = _run_copy(tmp, s)
    ckpt = run / "checkpoints" / "last.safetensors"
    ckpt.write_bytes(ckpt.read_bytes()[:100])
    return "spotless", ["relight", str(run), "-q", "--device", "cpu"]


def _relight_into_dataset(tmp, s):
    run = _run_copy(tmp, s)
    return "spotless", ["relight", str(run), "-q", "--device", "cpu", "--out", str(tmp / "box" / "images")]


def _relight_into_photos(tmp, s):
    run = _run_copy(tmp, s)
    (tmp / "photos").mkdir()
    (tmp / "photos" / "holiday.jpg").write_bytes(b"\xff\xd8 not really")
    return "spotless", ["relight", str(run), "-q", "--device", "cpu", "--out", str(tmp / "photos")]


def _export_over_checkpoint(tmp, s):
    run = _run_copy(tmp, s)
    return "spotless", ["export", str(run), "--out", str(run / "checkpoints" / "last.safetensors")]


def _eval_before_relight(tmp, s):
    run = _run_copy(tmp, s)
    shutil.rmtree(run / "relit")
    return "spotless", ["eval", str(run), "--no-lpips", "--no-sfm"]


def _eval_out_into_pred(tmp, s):
    pred = _copy(s["run"] / "relit", tmp / "pred")
    return "spotless", ["eval", "--pred", str(pred), "--gt", str(s["data"] / "gt"), "--out", str(pred / "scores"),
                        "--no-lpips", "--no-sfm"]


def _eval_json_over_transforms(tmp, s):
    run = _run_copy(tmp, s)
    return "spotless", ["eval", str(run), "--no-lpips", "--no-sfm", "--json", str(tmp / "box" / "transforms.json")]


def _enhance_in_place(tmp, s):
    data = _data_copy(tmp, s)
    return "spotless", ["baseline2d", "enhance", "clahe", str(data / "images"), str(data / "images")]


def _enhance_missing_input(tmp, s):
    return "spotless", ["baseline2d", "enhance", "clahe", str(tmp / "nothing"), str(tmp / "out")]


def _reproduce_unknown_preset(tmp, s):
    return "spotless", ["reproduce", "--preset", "gigantic", "--out", str(tmp / "out")]


def _reproduce_out_in_scenes(tmp, s):
    scenes = _copy(ROOT / "scenes", tmp / "scenes")
    return "spotless", ["reproduce", "--preset", "tiny", "--scenes-dir", str(scenes), "--out", str(scenes / "out")]


def _sim_render_missing_scene(tmp, s):
    return "sim", ["render", "--scene", str(tmp / "house.json"), "--out", str(tmp / "out"), "-q"]


def _sim_render_damaged_scene(tmp, s):
    (tmp / "house.json").write_text("{\"furniture\": [")
    return "sim", ["render", "--scene", str(tmp / "house.json"), "--out", str(tmp / "out"), "-q"]


def _sim_render_out_is_scene_folder(tmp, s):
    scene = _copy(SHIPPED_SCENE.parent, tmp / "bedroom") / "house.json"
    return "sim", ["render", "--scene", str(scene), "--out", str(scene.parent), "--frames", "2", "-q"]


def _sim_render_bad_shard(tmp, s):
    return "sim", ["render", "--scene", str(SHIPPED_SCENE), "--out", str(tmp / "out"), "--shard", "3/2", "-q"]


def _sim_inspect_damaged_scene(tmp, s):
    (tmp / "house.json").write_text("[]")
    return "sim", ["inspect", "--scene", str(tmp / "house.json")]


def _sim_add_noise_not_a_dataset(tmp, s):
    (tmp / "folder").mkdir()
    return "sim", ["add-noise", "--data", str(tmp / "folder"), "--out", str(tmp / "noisy")]


def _sim_add_noise_into_source(tmp, s):
    data = _data_copy(tmp, s)
    return "sim", ["add-noise", "--data", str(data), "--out", str(data / "noisy")]


def _sim_benchmark_bad_samples(tmp, s):
    return "sim", ["benchmark", "--scene", str(SHIPPED_SCENE), "--out", str(tmp / "bench"), "--samples", "4,many"]


def _benchmark_unknown_preset(tmp, s):
    return "spotless", ["benchmark", "models", "--data", str(s["data"]), "--out", str(tmp / "bench"),
                        "--preset", "huge"]


def _sfm_rings_bad_label(tmp, s):
    return "spotless", ["sfm-rings", str(tmp)]


CASES = [
    Case("train: damaged transforms.json", _damaged_transforms, 2, ("{tmp}/box/transforms.json", "not valid JSON")),
    Case("train: a frame's image is missing", _missing_image, 2, ("frame_00003.png",)),
    Case("train: a folder that is no dataset", _not_a_dataset, 2, ("{tmp}/photos",)),
    Case("train: a lens that cannot be inverted", _folding_lens, 2, ("cameras.txt", "cannot be inverted")),
    Case("train: an unsupported COLMAP camera model", _unsupported_camera_model, 2, ("cameras.txt", "FOV")),
    Case("prepare: a frame that cannot be decoded", _undecodable_frame, 2, ("{tmp}/frames/b.png", "cannot be decoded")),
    Case("train: run folder inside the dataset", _out_inside_data, 2, ("inside the input --data",)),
    Case("train: existing run without --resume", _existing_run_without_resume, 2, ("--resume",)),
    Case("train: --resume with another model", _resume_other_settings, 2, ("{tmp}/run",)),
    Case("train: damaged config.json on --resume", _damaged_config, 2, ("{tmp}/run/config.json",)),
    Case("train: --tolerance-db without --model auto", _selection_option_without_auto, 2, ("--model auto",)),
    Case("train: unknown preset", _unknown_preset, 2, ("'huge'",)),
    Case("train: zero iterations", _zero_iterations, 2, ("--iterations",)),
    Case("relight: a folder that is no run", _relight_not_a_run, 2, ("{tmp}/folder", "run.json")),
    Case("relight: damaged run.json", _relight_damaged_run_json, 2, ("{tmp}/run/run.json",)),
    Case("relight: the dataset moved", _relight_moved_dataset, 2, ("--data",)),
    Case("relight: --data that does not exist", _relight_bad_data_option, 2, ("{tmp}/nowhere",)),
    Case("relight: truncated checkpoint", _relight_truncated_checkpoint, 2, ("{tmp}/run/checkpoints/last.safetensors",)),
    Case("relight: --out inside the dataset", _relight_into_dataset, 2, ("{tmp}/box/images", "inside the input --data")),
    Case("relight: --out holds other files", _relight_into_photos, 2, ("{tmp}/photos", "choose an empty or new --out")),
    Case("export: --out is the checkpoint", _export_over_checkpoint, 2, ("last.safetensors",)),
    Case("eval: run not relit yet", _eval_before_relight, 2, ("spotless relight",)),
    Case("eval: --out inside --pred", _eval_out_into_pred, 2, ("{tmp}/pred/scores", "--pred")),
    Case("eval: --json over the dataset's transforms.json", _eval_json_over_transforms, 2, ("transforms.json",)),
    Case("baseline2d enhance: output is the input", _enhance_in_place, 2, ("{tmp}/box/images",)),
    Case("baseline2d enhance: input missing", _enhance_missing_input, 2, ("{tmp}/nothing",)),
    Case("reproduce: unknown preset", _reproduce_unknown_preset, 2, ("'gigantic'",)),
    Case("reproduce: --out inside --scenes-dir", _reproduce_out_in_scenes, 2, ("--scenes-dir",)),
    Case("spotless-sim render: scene file missing", _sim_render_missing_scene, 2, ("{tmp}/house.json",)),
    Case("spotless-sim render: damaged scene file", _sim_render_damaged_scene, 2, ("{tmp}/house.json",)),
    Case("spotless-sim render: --out is the scene's folder", _sim_render_out_is_scene_folder, 2,
         ("contains the input --scene",)),
    Case("spotless-sim render: bad shard", _sim_render_bad_shard, 2, ("3/2",)),
    Case("spotless-sim inspect: not a house file", _sim_inspect_damaged_scene, 2, ("{tmp}/house.json",)),
    Case("spotless-sim add-noise: not a dataset", _sim_add_noise_not_a_dataset, 2, ("{tmp}/folder",)),
    Case("spotless-sim add-noise: --out inside --data", _sim_add_noise_into_source, 2, ("inside the input --data",)),
    Case("spotless-sim benchmark: bad sample counts", _sim_benchmark_bad_samples, 2, ("--samples", "'4,many'")),
    Case("benchmark models: unknown preset", _benchmark_unknown_preset, 2, ("'huge'",)),
    Case("sfm-rings: a run without a label", _sfm_rings_bad_label, 2, ("expected LABEL=SPARSE_DIR",)),
]


def _invoke(program: str, argv: list[str]):
    if program == "sim":
        from simulator.cli import main
    else:
        from spotlessgs.cli import main
    return CliRunner().invoke(main, argv)


def _error_line(result) -> str:
    lines = [line for line in result.stderr.strip().splitlines() if line.strip()]
    assert lines, f"no message on stderr (exit {result.exit_code}); stdout: {result.stdout}"
    return lines[-1]


@pytest.mark.parametrize("case", CASES, ids=[c.name for c in CASES])
def test_a_users_error_is_one_line_with_the_documented_exit_code(case, shared, tmp_path):
    program, argv = case.make(tmp_path, shared)
    before = sorted(str(p) for p in tmp_path.rglob("*"))
    result = _invoke(program, argv)
    assert "Traceback" not in result.output, result.output
    assert result.exit_code == case.code, (result.exit_code, result.output)
    line = _error_line(result)
    for fragment in case.fragments:
        assert fragment.replace("{tmp}", str(tmp_path)) in line, line
    after = sorted(str(p) for p in tmp_path.rglob("*"))
    assert set(before) <= set(after), "an input was removed"


def test_debug_shows_the_traceback_of_a_users_error(shared, tmp_path):
    program, argv = _relight_not_a_run(tmp_path, shared)
    result = _invoke(program, ["--debug", *argv])
    assert result.exit_code == 2 and "Traceback" in result.output, result.output


def test_the_command_line_programs_start_without_torch_or_blender():
    """`spotless --help` and `spotless-sim --help` load neither torch nor bpy (the library is imported by the command
    that needs it), so a mistyped option is answered at once."""
    import subprocess
    import sys

    code = "import sys, spotlessgs.cli, simulator.cli; print(sorted(m for m in ('torch', 'bpy') if m in sys.modules))"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True, cwd=ROOT)
    assert out.stdout.strip() == "[]", out.stdout + out.stderr


def test_numeric_options_refuse_nan_and_infinity(tmp_path):
    """click's FloatRange lets NaN through any bound (and inf through an open one): the CLIs' options refuse both."""
    from click.testing import CliRunner

    from spotlessgs.cli import main
    from spotlessgs.clitools import FiniteFloatRange

    assert FiniteFloatRange(0).convert("2.5", None, None) == 2.5
    for text in ("nan", "inf", "-inf"):
        with pytest.raises(click.BadParameter, match="not a finite number"):
            FiniteFloatRange(0 if text != "-inf" else None).convert(text, None, None)
    result = CliRunner().invoke(main, ["export", str(tmp_path), "--out", str(tmp_path / "x.ply"), "--l0", "nan", "1",
                                       "1"])
    assert result.exit_code == 2 and "'nan' is not a finite number" in result.output
