"""Outputs never destroy what the user did not ask to replace, on a tiny trained run of a synthetic dataset:

- `spotless relight/render --out DIR` replaces an existing non-empty DIR only when it is an earlier render (its
  manifest says so, or it is the run's own RUN/relit or RUN/render); a folder of photos, another dataset's images,
  a repository or the run's checkpoints are refused with one line (exit 2) and left as they were;
- a render interrupted between the two renames of the folder swap gets its previous folder back on the next run;
- `spotless eval` never writes its folder or its --json into its inputs (both modes);
- `spotless export --out` never replaces the dataset's files, the checkpoint, run.json or config.json;
- `spotless eval RUN` finds the dataset like every other command (run.json's relative path, --data).
"""

from __future__ import annotations

import json
import os
import shutil
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

from conftest import synthetic_box_dataset
from evaluation.runner import EvalConfig, evaluate_folders, evaluate_run
from spotlessgs.io.errors import InputError, OutputOverlapError
from spotlessgs.io.images import write_png
from spotlessgs.manifest import MANIFEST_NAME, read_manifest

pytestmark = pytest.mark.usefixtures("one_torch_thread")

QUICK = EvalConfig(lpips=False, temporal=False, progress=False, num_threads=1)
TEST_VIEWS = ["frame_00000.png", "frame_00011.png"]  # 14 frames, every 11th is a test view


@pytest.fixture(scope="module")
def trained(tmp_path_factory):
    """``ROOT/data`` (14 frames, 40x30) and ``ROOT/run`` (darkgs, 10 steps) with ``RUN/relit`` of every view."""
    from spotlessgs.rendering import render_run
    from spotlessgs.training.config import preset
    from spotlessgs.training.trainer import train

    data = synthetic_box_dataset(tmp_path_factory, "safety-data", seed=3)
    root = data.parent
    data = data.rename(root / "data")
    config = preset("tiny", iterations=10, image_width=40, num_threads=1, densify_from=1000, log_every=10,
                    checkpoint_every=10, init_points=200, max_gaussians=300, brdf_hidden=8)
    train(data, root / "run", "darkgs", config, seed=0, progress=False)
    render_run(root / "run", "relit", "all", progress=False, device="cpu")
    return root


def _cli(*args: str):
    from spotlessgs.cli import main

    return CliRunner().invoke(main, list(args))


def _one_line_error(res, *fragments: str) -> None:
    assert res.exit_code == 2, res.output
    assert len(res.output.strip().splitlines()) == 1 and "Traceback" not in res.output, res.output
    for fragment in fragments:
        assert fragment in res.output, res.output


def _snapshot(folder: Path) -> dict[str, bytes]:
    return {p.relative_to(folder).as_posix(): p.read_bytes() for p in sorted(folder.rglob("*")) if p.is_file()}


def _photos(folder: Path, n: int = 2) -> dict[str, bytes]:
    for k in range(n):
        write_png(folder / f"IMG_{k:04d}.png", np.full((12, 16, 3), 0.2 + 0.3 * k, dtype=np.float32))
    return _snapshot(folder)


def _relight(run: Path, *extra: str):
    return _cli("relight", str(run), "-q", "--device", "cpu", "--views", "test", *extra)


# ---- (1) relight/render replace only an earlier render ------------------------------------------------------------


def test_relight_refuses_a_folder_of_photos_and_another_datasets_images(trained, tmp_path):
    run = trained / "run"
    photos = tmp_path / "holiday"
    before = _photos(photos)
    _one_line_error(_relight(run, "--out", str(photos)), str(photos), "not images of an earlier render",
                    MANIFEST_NAME, "choose an empty or new --out")
    assert _snapshot(photos) == before

    other = shutil.copytree(trained / "data" / "images", tmp_path / "other_dataset" / "images")
    before = _snapshot(other)
    res = _cli("render", str(run), "-q", "--device", "cpu", "--views", "test", "--out", str(other))
    _one_line_error(res, str(other), "choose an empty or new --out")
    assert _snapshot(other) == before

    repo = tmp_path / "repo"  # hidden entries only: still not an empty folder
    (repo / ".git").mkdir(parents=True)
    (repo / ".git" / "HEAD").write_text("ref: refs/heads/main\n")
    _one_line_error(_relight(run, "--out", str(repo)), str(repo), ".git")
    assert (repo / ".git" / "HEAD").read_text() == "ref: refs/heads/main\n"
    assert not any(p.name.startswith(".holiday") or p.name.startswith(".repo") for p in tmp_path.iterdir())


def test_relight_refuses_the_checkpoints_folder_and_the_dataset(trained, tmp_path):
    from spotlessgs.rendering import _check_output

    run, data = trained / "run", trained / "data"
    with pytest.raises(OutputOverlapError, match=r"--out is the same path as the input RUN/checkpoints"):
        _check_output(run / "checkpoints", run, data)
    with pytest.raises(OutputOverlapError, match=r"--out is inside the input RUN/checkpoints"):
        _check_output(run / "checkpoints" / "relit", run, data)
    with pytest.raises(OutputOverlapError, match=r"--out is inside the input --data"):
        _check_output(data / "images", run, data)
    empty = tmp_path / "empty"
    empty.mkdir()
    _check_output(empty, run, data)  # an empty folder, a new one: fine
    _check_output(tmp_path / "new", run, data)


def test_relight_replaces_an_earlier_render_and_a_legacy_run_folder(trained, tmp_path):
    run = shutil.copytree(trained / "run", tmp_path / "run")
    out = tmp_path / "renders"
    assert _relight(run, "--out", str(out)).exit_code == 0
    assert read_manifest(out)["kind"] == "relit"
    res = _cli("render", str(run), "-q", "--device", "cpu", "--views", "test", "--out", str(out))
    assert res.exit_code == 0, res.output  # an earlier render (its manifest says so) is replaced
    assert read_manifest(out)["kind"] == "render"
    assert sorted(p.name for p in out.iterdir() if not p.name.startswith(".")) == TEST_VIEWS

    (run / "relit" / MANIFEST_NAME).unlink()  # RUN/relit as an older version left it: images, no manifest
    res = _relight(run)
    assert res.exit_code == 0, res.output
    assert read_manifest(run / "relit")["kind"] == "relit"


# ---- (2) an interrupted folder swap ---------------------------------------------------------------------------------


def test_a_crash_between_the_swap_renames_restores_the_previous_folder(tmp_path):
    from spotlessgs.io.atomic import partial_sibling
    from spotlessgs.rendering import _remove_partial_siblings

    out = tmp_path / "relit"
    old = partial_sibling(out, "old-")  # swap_in_folder renamed OUT away, then the process died
    before = _photos(old)
    new = partial_sibling(out)  # the new render's folder, not yet renamed to OUT
    _photos(new, 1)
    (tmp_path / "relit_keep").mkdir()  # a neighbour with a similar name is none of its business
    _remove_partial_siblings(out)
    assert out.is_dir() and _snapshot(out) == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["relit", "relit_keep"]
    _remove_partial_siblings(out)  # OUT present: temporary siblings only are removed, OUT stays
    assert _snapshot(out) == before


def test_a_failed_second_rename_puts_the_previous_folder_back(tmp_path, monkeypatch):
    import spotlessgs.io.atomic as atomic

    out, tmp = tmp_path / "relit", tmp_path / ".relit.partial-new"
    before = _photos(out)
    _photos(tmp, 1)
    monkeypatch.setattr(atomic, "_exchange", lambda a, b: False)
    real_rename, calls = os.rename, []

    def rename(src, dst):
        calls.append((src, dst))
        if len(calls) == 2:
            raise OSError(28, "No space left on device")
        real_rename(src, dst)

    monkeypatch.setattr(atomic.os, "rename", rename)
    with pytest.raises(OSError):
        atomic.swap_in_folder(tmp, out)
    monkeypatch.undo()
    assert _snapshot(out) == before


# ---- (3) eval never writes into its inputs --------------------------------------------------------------------------


def test_eval_folders_refuses_out_and_json_in_its_inputs(tmp_path):
    pred, gt = tmp_path / "pred", tmp_path / "gt"
    before_pred, before_gt = _photos(pred), _photos(gt)
    with pytest.raises(OutputOverlapError, match=r"pred: --out is the same path as the input --pred"):
        evaluate_folders(pred, gt, QUICK, out_dir=pred)
    with pytest.raises(OutputOverlapError, match=r"--out is inside the input --gt"):
        evaluate_folders(pred, gt, QUICK, out_dir=gt / "scores")
    with pytest.raises(OutputOverlapError, match=r"--json is inside the input --gt"):
        evaluate_folders(pred, gt, QUICK, json_path=gt / "results.json")
    res = _cli("eval", "--pred", str(pred), "--gt", str(gt), "--out", str(pred), "--quiet", "--no-lpips")
    _one_line_error(res, "--out is the same path as the input --pred")
    assert _snapshot(pred) == before_pred and _snapshot(gt) == before_gt
    evaluate_folders(pred, gt, QUICK, out_dir=tmp_path / "scores", json_path=tmp_path / "r.json")
    assert (tmp_path / "r.json").is_file()


def test_eval_run_refuses_json_in_its_inputs(trained):
    run, data = trained / "run", trained / "data"
    guarded = [data / "transforms.json", run / "run.json", run / "config.json",
               run / "checkpoints" / "last.safetensors", run / "relit" / "results.json"]
    before = {p: p.read_bytes() if p.exists() else None for p in guarded}
    for path in guarded:
        with pytest.raises(OutputOverlapError, match=r"--json is (inside|the same path as) the input"):
            evaluate_run(run, QUICK, json_path=path)
    res = _cli("eval", str(run), "--json", str(data / "transforms.json"), "--quiet", "--no-lpips")
    _one_line_error(res, "transforms.json: --json is inside the input --data")
    for path in (run / "metrics.jsonl", run / "train_summary.json"):
        res = _cli("eval", str(run), "--json", str(path), "--quiet", "--no-lpips")
        _one_line_error(res, f"{path.name}: --json would replace a file of the run")
    assert {p: p.read_bytes() if p.exists() else None for p in guarded} == before
    assert not (run / "eval").exists()  # refused before anything was written


def test_eval_out_takes_only_an_empty_folder_or_an_earlier_evaluation(trained, tmp_path):
    """An --out holding a render, the run's checkpoints or a user's notes (with an sfm/ work folder of the same name)
    is refused with one line and left as it was; an earlier evaluation's folder is written again."""
    run = trained / "run"
    pred, gt = tmp_path / "pred", tmp_path / "gt"
    _photos(pred), _photos(gt)
    mine = tmp_path / "mine"
    (mine / "sfm" / "pred").mkdir(parents=True)
    (mine / "sfm" / "pred" / "notes.txt").write_text("precious")
    (mine / "todo.txt").write_text("mine")
    before = _snapshot(mine)
    res = _cli("eval", "--pred", str(pred), "--gt", str(gt), "--out", str(mine), "--quiet", "--no-lpips", "--sfm")
    _one_line_error(res, "mine: holds files that are not an earlier evaluation's (todo.txt)")
    assert _snapshot(mine) == before
    checkpoints = _snapshot(run / "checkpoints")
    res = _cli("eval", str(run), "--out", str(run / "checkpoints"), "--quiet", "--no-lpips")
    _one_line_error(res, "checkpoints: holds files that are not an earlier evaluation's (last.safetensors)")
    assert _snapshot(run / "checkpoints") == checkpoints
    render = tmp_path / "render"
    assert _relight(run, "--out", str(render)).exit_code == 0
    rendered = _snapshot(render)
    with pytest.raises(InputError, match=r"render: holds files that are not an earlier evaluation's \(frame_"):
        evaluate_folders(pred, gt, QUICK, out_dir=render)
    res = _cli("eval", str(run), "--out", str(render), "--quiet", "--no-lpips")
    assert res.exit_code == 2 and "not an earlier evaluation's" in res.output, res.output
    assert _snapshot(render) == rendered
    evaluate_folders(pred, gt, QUICK, out_dir=tmp_path / "scores")
    evaluate_folders(pred, gt, QUICK, out_dir=tmp_path / "scores")  # an earlier evaluation: replaced
    assert (tmp_path / "scores" / MANIFEST_NAME).is_file()


def test_a_folder_replaced_whole_may_not_be_the_current_directory(trained, tmp_path, monkeypatch):
    """relight/enhance --out . (or a folder holding the shell's directory) were refused only after rendering every
    view, by the swap's rename ("Device or resource busy"); now up front, naming the option."""
    here = tmp_path / "emptyd" / "sub"
    here.mkdir(parents=True)
    monkeypatch.chdir(here)
    _one_line_error(_relight(trained / "run", "--out", "."), ".: --out is or holds the current directory")
    _one_line_error(_cli("baseline2d", "enhance", "clahe", str(trained / "data" / "images"), str(here.parent)),
                    "emptyd: OUT_DIR is or holds the current directory")
    assert not any(tmp_path.joinpath("emptyd").rglob("*.png")) and here.is_dir()


def test_folder_mode_scores_the_test_views_of_a_dataset_gt_folder_with_match_pred(trained, tmp_path, caplog):
    """`relight --views test` then `eval --pred OUT --gt DATA/gt` failed (the gt folder holds every view); averaging
    RUN/relit (every view) against DATA/gt silently mixed in the training views. --match pred scores the test views
    alone, as RUN mode does; a prediction folder of training views is scored with a warning."""
    import logging

    run, gt = trained / "run", trained / "data" / "gt"
    assert _relight(run, "--out", str(tmp_path / "test_only")).exit_code == 0
    res = _cli("eval", "--pred", str(tmp_path / "test_only"), "--gt", str(gt), "--quiet", "--no-lpips")
    assert res.exit_code == 2 and "missing from predictions" in res.output, res.output
    folders = evaluate_folders(tmp_path / "test_only", gt, QUICK, match="pred")
    for name in TEST_VIEWS:  # the same two views, each folder holding exactly them
        (tmp_path / "gt_test").mkdir(exist_ok=True)
        shutil.copy(gt / name, tmp_path / "gt_test" / name)
    exact = evaluate_folders(tmp_path / "test_only", tmp_path / "gt_test", QUICK)
    assert folders["num_images"] == exact["num_images"] == len(TEST_VIEWS) and folders["match"] == "pred"
    assert (folders["psnr"], folders["ssim_aligned"]) == (exact["psnr"], exact["ssim_aligned"])
    with caplog.at_level(logging.WARNING, logger="evaluation.runner"):
        every = evaluate_folders(run / "relit", gt, QUICK)
    assert every["num_images"] == 14
    assert any("relit with --views all: the scores include training views" in r.getMessage() for r in caplog.records)
    res = _cli("eval", str(run), "--match", "pred", "--quiet", "--no-lpips")
    assert res.exit_code == 2 and "--match only applies to folder mode" in res.output, res.output


# ---- (4) export never replaces the run's or the dataset's files ----------------------------------------------------


def test_export_refuses_the_checkpoint_run_files_and_the_dataset(trained, tmp_path):
    from spotlessgs.export import export_ply

    run, data = trained / "run", trained / "data"
    guarded = {"RUN/checkpoints": run / "checkpoints" / "last.safetensors", "RUN/run.json": run / "run.json",
               "RUN/config.json": run / "config.json", "--data": data / "points3d.ply"}
    before = {p: p.read_bytes() if p.exists() else None for p in guarded.values()}
    for name, path in guarded.items():
        res = _cli("export", str(run), "--out", str(path))
        _one_line_error(res, str(path), f"the input {name}")
    assert {p: p.read_bytes() if p.exists() else None for p in guarded.values()} == before
    with pytest.raises(OutputOverlapError, match="contains the input"):
        export_ply(run, run)
    with pytest.raises(InputError, match="--out is a folder"):
        export_ply(run, tmp_path)
    assert export_ply(run, tmp_path / "model.ply").is_file()
    # the run's other files and folders: its log, its summary, a relit image (an earlier export may be replaced)
    others = [run / "metrics.jsonl", run / "train_summary.json", next((run / "relit").glob("*.png")),
              run / "relit" / "new.ply"]
    before = {p: p.read_bytes() if p.exists() else None for p in others}
    for path in others:
        res = _cli("export", str(run), "--out", str(path))
        _one_line_error(res, str(path), "--out would replace a file of the run")
    assert {p: p.read_bytes() if p.exists() else None for p in others} == before
    assert export_ply(run, run / "model.ply").is_file() and export_ply(run, run / "model.ply").is_file()
    (run / "model.ply").unlink()


# ---- (5) eval finds a run's dataset like every other command --------------------------------------------------------


def test_eval_run_uses_the_relative_dataset_path_and_data(trained, tmp_path):
    run = shutil.copytree(trained / "run", tmp_path / "run")
    info = json.loads((run / "run.json").read_text())
    relative = os.path.relpath(trained / "data", run)
    (run / "run.json").write_text(json.dumps({**{k: v for k, v in info.items() if k != "data_dir"},
                                              "data_dir_relative": relative}))
    results = evaluate_run(run, QUICK)  # only data_dir_relative: found
    assert results["data_dir"] == str((trained / "data").resolve()) and results["num_images"] == 2

    (run / "run.json").write_text(json.dumps({k: v for k, v in info.items()
                                              if k not in ("data_dir", "data_dir_relative")}))
    with pytest.raises(InputError, match=r"run.json has no data_dir.*--data DIR"):
        evaluate_run(run, QUICK)
    assert evaluate_run(run, QUICK, data_dir=trained / "data")["num_images"] == 2

    (run / "run.json").write_text("[1")
    with pytest.raises(ValueError, match=r"run.json: .*not valid JSON"):
        evaluate_run(run, QUICK)
    (run / "run.json").write_text(json.dumps(info))
    shutil.rmtree(run / "relit")
    with pytest.raises(FileNotFoundError, match=r"relit: the run has no relit images; run `spotless relight"):
        evaluate_run(run, QUICK)


def test_a_folder_with_files_but_none_of_the_commands_records_is_refused_and_left_alone(tmp_path):
    """refuse_foreign_folder: absent, empty and recorded folders pass; a file or a folder of other files is refused
    with its name, the option and up to four entries; hidden entries count as the caller says."""
    from spotlessgs.io.paths import refuse_foreign_folder

    out = tmp_path / "out"
    refuse_foreign_folder(out, ["rec.json"], "--out", "an earlier run")  # absent
    out.mkdir()
    refuse_foreign_folder(out, ["rec.json"], "--out", "an earlier run")  # empty
    (out / ".DS_Store").write_bytes(b"x")
    refuse_foreign_folder(out, ["rec.json"], "--out", "an earlier run")  # hidden files ignored by default
    with pytest.raises(InputError, match=r"out: holds files but no rec\.json \(\.DS_Store\): not an earlier run; "
                                         r"choose an empty or new --out"):
        refuse_foreign_folder(out, ["rec.json"], "--out", "an earlier run", count_hidden=True)
    (out / ".state").mkdir()
    with pytest.raises(InputError, match=r"\(\.state\)"):
        refuse_foreign_folder(out, ["rec.json"], "--out", "an earlier run", count_hidden=[".state"])
    for name in "abcdef":
        (out / f"{name}.png").write_bytes(b"x")
    with pytest.raises(InputError, match=r"no a\.json or rec\.json \(a\.png, b\.png, c\.png, d\.png and 2 more\)"):
        refuse_foreign_folder(out, ["a.json", "rec.json"], "OUT", "an earlier run")
    (out / "rec.json").write_text("{}")
    refuse_foreign_folder(out, ["a.json", "rec.json"], "OUT", "an earlier run")  # an earlier run of the command
    assert sorted(p.name for p in out.iterdir()) == [".DS_Store", ".state", *[f"{n}.png" for n in "abcdef"],
                                                      "rec.json"]
    with pytest.raises(InputError, match=r"rec\.json: OUT is a file, not a folder"):
        refuse_foreign_folder(out / "rec.json", ["x"], "OUT", "an earlier run")
