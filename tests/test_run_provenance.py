"""Provenance of derived folders and relocatable runs, on a tiny trained run of a synthetic dataset (no Blender).

- every relight/render writes a manifest; `spotless eval RUN` refuses stale (training resumed after relighting),
  unlisted, changed or unrecorded relit images with one line naming the folder, the problem and what to do;
- a second relight with other options or views replaces the first one's folder as a whole (never a mix);
- run.json records the dataset relative to the run too, so a run moved with its dataset still works, and
  ``--data`` points a moved run at its dataset.
"""

from __future__ import annotations

import json
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

from conftest import synthetic_box_dataset
from evaluation.runner import EvalConfig, evaluate_folders, evaluate_run
from spotlessgs.io.errors import FolderLockedError, InputError
from spotlessgs.io.images import write_png
from spotlessgs.io.provenance import sha256_file
from spotlessgs.manifest import MANIFEST_NAME, read_manifest
from spotlessgs.training.config import preset

pytestmark = pytest.mark.usefixtures("one_torch_thread")

QUICK = EvalConfig(lpips=False, progress=False, num_threads=1)
ITERATIONS = 20
TEST_VIEWS = ["frame_00000.png", "frame_00011.png"]  # 14 frames, every 11th is a test view
ALL_VIEWS = [f"frame_{k:05d}.png" for k in range(14)]


def _config():
    return preset("tiny", iterations=ITERATIONS, image_width=40, num_threads=1, densify_from=1000, log_every=10,
                  checkpoint_every=10, init_points=300, max_gaussians=400, brdf_hidden=8)


@pytest.fixture(scope="module")
def trained(tmp_path_factory):
    """``ROOT/data`` (14 frames, 40x30) and ``ROOT/run``: darkgs stopped at step 10 of 20 (resumable)."""
    from spotlessgs.training.trainer import train

    data = synthetic_box_dataset(tmp_path_factory, "prov-data", seed=2)
    root = data.parent
    data = data.rename(root / "data")
    train(data, root / "run", "darkgs", _config(), seed=0, progress=False, stop_after=10)
    return root


@pytest.fixture
def moved(trained, tmp_path):
    """A copy of ROOT (run and dataset moved together) whose recorded absolute dataset path no longer exists,
    as after ``mv ROOT elsewhere``."""
    root = tmp_path / "moved"
    shutil.copytree(trained, root)
    info = json.loads((root / "run" / "run.json").read_text())
    info["data_dir"] = str(tmp_path / "gone" / "data")
    (root / "run" / "run.json").write_text(json.dumps(info))
    return root


def _copy_run(trained: Path, tmp_path: Path) -> Path:
    """A copy of the run alone (its dataset stays where run.json's absolute path says), for a test to change."""
    return shutil.copytree(trained / "run", tmp_path / "run")


def _relight(run, **kw):
    from spotlessgs.rendering import render_run

    return render_run(run, "relit", progress=False, device="cpu", **kw)


def _images(folder: Path) -> list[str]:
    return sorted(p.name for p in folder.iterdir() if not p.name.startswith("."))


def _siblings(folder: Path) -> list[str]:
    return sorted(p.name for p in folder.parent.iterdir() if p.name.startswith(f".{folder.name}"))


# ---- (1) stale images: training resumed after relighting --------------------------------------------------------


def test_eval_refuses_images_of_an_earlier_checkpoint(trained, tmp_path):
    from spotlessgs.training.trainer import train

    run = _copy_run(trained, tmp_path)
    summary = _relight(run)
    assert summary["checkpoint_step"] == 10
    first = evaluate_run(run, QUICK)
    manifest = read_manifest(run / "relit")
    assert manifest["checkpoint"]["step"] == 10 and first["relit_manifest"]["checkpoint_step"] == 10
    assert first["relit_manifest"]["sha256"] == sha256_file(run / "relit" / MANIFEST_NAME)

    train(trained / "data", run, "darkgs", _config(), seed=0, progress=False, resume=True)  # on to step 20
    with pytest.raises(InputError, match=r"relit: stale relit images: made from the checkpoint at step 10, .*now "
                                         r"step 20.*run `spotless relight .*run` again"):
        evaluate_run(run, QUICK)

    checkpoint = run / "checkpoints" / "last.safetensors"
    whole = checkpoint.read_bytes()
    checkpoint.write_bytes(whole[: len(whole) // 2])  # a damaged checkpoint is not "training went on"
    with pytest.raises(InputError, match=r"last\.safetensors: the run's checkpoint cannot be read \(damaged or cut "
                                         r"short\), and it is not the one the relit images .* \(step 10\)"):
        evaluate_run(run, QUICK)
    checkpoint.write_bytes(whole)

    _relight(run)
    again = evaluate_run(run, QUICK)
    assert again["relit_manifest"]["checkpoint_step"] == 20
    eval_manifest = read_manifest(run / "eval")
    assert eval_manifest["kind"] == "eval" and eval_manifest["checkpoint"]["step"] == 20
    assert eval_manifest["scored"]["manifest_sha256"] == again["relit_manifest"]["sha256"]
    assert {f["name"] for f in eval_manifest["frames"]} == {"results.json", "results.md", "figures/grid.png"}
    saved = json.loads((run / "eval" / "results.json").read_text())
    assert saved["relit_manifest"] == again["relit_manifest"]


# ---- (2) two relights never mix -----------------------------------------------------------------------------------


def test_second_relight_replaces_the_first_and_eval_scores_only_it(trained, tmp_path, monkeypatch):
    import spotlessgs.io.atomic as atomic

    run = _copy_run(trained, tmp_path)
    relit = run / "relit"
    _relight(run, l0=[0.5, 0.5, 0.5])
    assert _images(relit) == ALL_VIEWS
    _relight(run, which="test", l0=[2.0, 2.0, 2.0], exr=True)
    assert _images(relit) == sorted(TEST_VIEWS + [n.replace(".png", ".exr") for n in TEST_VIEWS])
    manifest = read_manifest(relit)
    assert manifest["options"]["views"] == "test" and manifest["options"]["l0"] == [2.0, 2.0, 2.0]
    assert manifest["options"]["exr"] is True
    assert [f["name"] for f in manifest["frames"]] == _images(relit)
    assert _siblings(relit) == []  # no temporary folder left behind
    # eval never scores the first relight's frames: the second one lacks most views
    with pytest.raises(FileNotFoundError, match=r"missing relit images for 12 view.*--views all"):
        evaluate_run(run, QUICK)

    monkeypatch.setattr(atomic, "_exchange", lambda a, b: False)  # no atomic exchange: rename, rename
    _relight(run, l0=[1.0, 1.0, 1.0])
    manifest = read_manifest(relit)
    assert _images(relit) == ALL_VIEWS and manifest["options"]["l0"] == [1.0, 1.0, 1.0]
    assert _siblings(relit) == []
    assert all(sha256_file(relit / f["name"]) == f["sha256"] for f in manifest["frames"])
    results = evaluate_run(run, QUICK)
    assert results["relit_manifest"]["sha256"] == sha256_file(relit / MANIFEST_NAME)
    assert results["num_images"] == 2 and [r["name"] for r in results["per_image"]] == TEST_VIEWS


def test_an_interrupted_relight_leaves_the_previous_folder_intact(trained, tmp_path, monkeypatch):
    import spotlessgs.rendering as rendering

    run = _copy_run(trained, tmp_path)
    _relight(run, l0=[1.0, 1.0, 1.0])
    before = (run / "relit" / MANIFEST_NAME).read_bytes()
    calls = {"n": 0}
    real = rendering.write_png

    def fail_on_fourth(path, img):
        calls["n"] += 1
        if calls["n"] == 4:
            raise KeyboardInterrupt
        real(path, img)

    monkeypatch.setattr(rendering, "write_png", fail_on_fourth)
    with pytest.raises(KeyboardInterrupt):
        _relight(run, l0=[3.0, 3.0, 3.0])
    assert (run / "relit" / MANIFEST_NAME).read_bytes() == before and _siblings(run / "relit") == []
    evaluate_run(run, QUICK)  # still the complete first relight


def test_render_refuses_a_busy_run_and_an_output_it_may_not_replace(trained, tmp_path):
    from spotlessgs.rendering import render_run

    run = _copy_run(trained, tmp_path)
    _relight(run)
    holder = subprocess.Popen(  # another process trains the run (a lock is re-entrant within one process)
        [sys.executable, "-c", "import sys; from spotlessgs.io.folder_lock import folder_lock\n"
         f"with folder_lock({str(run)!r}, 'spotless train'):\n    print('held', flush=True); sys.stdin.read()"],
        stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True)
    try:
        assert holder.stdout.readline().strip() == "held"
        with pytest.raises(FolderLockedError, match="spotless train"):
            _relight(run)
        with pytest.raises(FolderLockedError, match="spotless train"):
            evaluate_run(run, QUICK)
    finally:
        holder.communicate("", timeout=30)
    notes = tmp_path / "notes"
    notes.mkdir()
    (notes / "todo.txt").write_text("keep me")
    with pytest.raises(InputError, match=r"notes: holds files that are not images.*todo.txt"):
        _relight(run, out_dir=notes)
    with pytest.raises(InputError, match="is or holds the run folder"):
        render_run(run, "spot", out_dir=run, progress=False, device="cpu")
    with pytest.raises(InputError, match="inside the input --data"):
        _relight(run, out_dir=trained / "data" / "relit")
    assert (notes / "todo.txt").read_text() == "keep me"
    summary = render_run(run, "spot", "test", progress=False, device="cpu")
    assert read_manifest(run / "render")["kind"] == "render" and summary["manifest"].endswith(MANIFEST_NAME)
    # eval refuses a spotlight render placed where relit images belong
    shutil.rmtree(run / "relit", ignore_errors=True)
    shutil.copytree(run / "render", run / "relit")
    with pytest.raises(InputError, match="output of `spotless render`, not relit images"):
        evaluate_run(run, QUICK)


# ---- (3) changed, unlisted or unrecorded frames --------------------------------------------------------------------


def test_eval_names_a_changed_an_unlisted_frame_and_a_missing_manifest(trained, tmp_path):
    run = _copy_run(trained, tmp_path)
    relit = run / "relit"
    _relight(run)
    gt = trained / "data" / "gt"
    evaluate_folders(relit, gt, QUICK)  # folder mode checks the manifest too, and passes

    original = (relit / "frame_00003.png").read_bytes()
    write_png(relit / "frame_00003.png", np.full((30, 40, 3), 0.5, dtype=np.float32))
    message = r"relit: 1 file\(s\) changed since they were written.*frame_00003.png; run `spotless relight"
    with pytest.raises(InputError, match=message):
        evaluate_run(run, QUICK)
    with pytest.raises(InputError, match=r"changed since they were written.*frame_00003.png; write --pred"):
        evaluate_folders(relit, gt, QUICK)
    (relit / "frame_00003.png").write_bytes(original)

    shutil.copy(relit / "frame_00001.png", relit / "frame_00099.png")
    with pytest.raises(InputError, match=r"relit: 1 file\(s\) not listed in its manifest .*relight`.*frame_00099"):
        evaluate_run(run, QUICK)
    (relit / "frame_00099.png").unlink()
    evaluate_run(run, QUICK)

    good = json.loads((relit / MANIFEST_NAME).read_text())
    for edit, problem in ((lambda m: m.update(frames=[1]), r"frames\[0\] is not an object with a name and a sha256"),
                          (lambda m: m["frames"][0].pop("name"), r"frames\[0\] is not an object with a name"),
                          (lambda m: m["frames"][0].update(name="../../run.json"), r"frames\[0\] names "
                                                                                   r"'../../run.json', not a file"),
                          (lambda m: m.update(checkpoint="abc"), "checkpoint is not a JSON object")):
        damaged = json.loads(json.dumps(good))
        edit(damaged)
        (relit / MANIFEST_NAME).write_text(json.dumps(damaged))
        with pytest.raises(InputError, match=rf"relit/\.manifest\.json: damaged manifest \({problem}.*write the"):
            evaluate_run(run, QUICK)
    (relit / MANIFEST_NAME).unlink()
    with pytest.raises(InputError, match=r"relit: no manifest \(\.manifest\.json\).*run `spotless relight"):
        evaluate_run(run, QUICK)


def test_folder_mode_scores_a_relight_with_exr_files_its_manifest_vouches_for(trained, tmp_path):
    """`relight --exr` writes an EXR beside each PNG: folder mode scores the PNGs of such a folder (its manifest
    lists every file), and still refuses a stray file in a folder without one."""
    out = tmp_path / "relit-exr"
    _relight(trained / "run", out_dir=out, exr=True)
    assert any(p.suffix == ".exr" for p in out.iterdir())
    results = evaluate_folders(out, trained / "data" / "gt", QUICK)
    assert results["num_images"] == len(ALL_VIEWS) and results["pred_manifest"]["kind"] == "relit"
    plain = tmp_path / "plain"
    shutil.copytree(out, plain)
    (plain / MANIFEST_NAME).unlink()
    with pytest.raises(ValueError, match=r"plain: non-image files found: .*\.exr"):
        evaluate_folders(plain, trained / "data" / "gt", QUICK)


def test_folder_mode_records_a_checkpoint_that_moved_on(trained, tmp_path, caplog):
    from spotlessgs.training.trainer import train

    run = _copy_run(trained, tmp_path)
    _relight(run, which="all", out_dir=tmp_path / "step10")
    train(trained / "data", run, "darkgs", _config(), seed=0, progress=False, resume=True)
    results = evaluate_folders(tmp_path / "step10", trained / "data" / "gt", QUICK, out_dir=tmp_path / "scores")
    assert results["pred_manifest"]["checkpoint_step"] == 10 and results["pred_manifest"]["checkpoint_current"] is False
    assert "changed since" in caplog.text
    assert read_manifest(tmp_path / "scores")["kind"] == "eval-folders"


# ---- (4) relocatable runs -------------------------------------------------------------------------------------------


def test_run_and_dataset_moved_together_work_without_data(moved, tmp_path):
    from spotlessgs.export import export_ply

    run = moved / "run"
    info = json.loads((run / "run.json").read_text())
    assert info["data_dir_relative"] == "../data" and not Path(info["data_dir"]).exists()
    summary = _relight(run)
    assert read_manifest(run / "relit")["dataset"]["path"] == str((moved / "data").resolve())
    assert summary["count"] == 14
    assert evaluate_run(run, QUICK)["data_dir"] == str((moved / "data").resolve())
    assert export_ply(run, tmp_path / "model.ply").is_file()


def test_a_moved_run_needs_data_and_the_commands_accept_it(trained, tmp_path):
    from spotlessgs.cli import main

    run = tmp_path / "elsewhere" / "deep" / "run"
    shutil.copytree(trained / "run", run)
    data = shutil.copytree(trained / "data", tmp_path / "datasets" / "box")
    info = json.loads((run / "run.json").read_text())
    info["data_dir"] = str(tmp_path / "gone" / "data")  # the dataset was moved away as well
    (run / "run.json").write_text(json.dumps(info))

    cli = CliRunner()
    res = cli.invoke(main, ["relight", str(run), "-q", "--device", "cpu"])
    assert res.exit_code == 2, res.output
    assert "the run's dataset was not found at data_dir_relative '../data'" in res.output
    assert str(tmp_path / "gone" / "data") in res.output and "--data DIR" in res.output
    assert len(res.output.strip().splitlines()) == 1  # one line, no traceback

    res = cli.invoke(main, ["relight", str(run), "-q", "--device", "cpu", "--data", str(data)])
    assert res.exit_code == 0, res.output
    res = cli.invoke(main, ["render", str(run), "-q", "--device", "cpu", "--views", "test", "--data", str(data)])
    assert res.exit_code == 0, res.output
    res = cli.invoke(main, ["export", str(run), "--out", str(tmp_path / "m.ply"), "--data", str(data)])
    assert res.exit_code == 0 and (tmp_path / "m.ply").is_file(), res.output
    res = cli.invoke(main, ["eval", str(run), "--no-lpips", "--quiet", "--threads", "1"])
    assert res.exit_code != 0 and "--data" in res.output
    res = cli.invoke(main, ["eval", str(run), "--no-lpips", "--quiet", "--threads", "1", "--data", str(data)])
    assert res.exit_code == 0, res.output
    assert json.loads((run / "eval" / "results.json").read_text())["data_dir"] == str(data.resolve())
    res = cli.invoke(main, ["eval", "--pred", str(run / "relit"), "--gt", str(data / "gt"), "--data", str(data)])
    assert res.exit_code == 2 and "--data only applies to RUN mode" in res.output


def test_old_run_json_without_the_relative_path_still_works(moved, tmp_path):
    from spotlessgs.training.checkpoint import resolve_data_dir

    run = moved / "run"
    data = (moved / "data").resolve()
    info = json.loads((run / "run.json").read_text())
    old = {k: v for k, v in info.items() if k != "data_dir_relative"}
    (run / "run.json").write_text(json.dumps({**old, "data_dir": str(data)}))
    _relight(run, which="all")
    assert evaluate_run(run, QUICK)["data_dir"] == str(data)
    # older hand-written run.json files: a relative data_dir is taken relative to the run folder
    assert resolve_data_dir(run, {"data_dir": "../data"}) == data
    with pytest.raises(InputError, match=r"run: the run's dataset was not found at data_dir '/nowhere'; .*--data DIR"):
        resolve_data_dir(run, {"data_dir": "/nowhere"})
    assert resolve_data_dir(run, {"data_dir": "/nowhere"}, override=data) == data


def test_resume_accepts_the_dataset_at_its_new_place(moved):
    from spotlessgs.training.trainer import train

    run = moved / "run"
    result = train(moved / "data", run, "darkgs", _config(), seed=0, progress=False, resume=True)
    assert result.steps == ITERATIONS
    info = json.loads((run / "run.json").read_text())
    assert info["data_dir"] == str((moved / "data").resolve()) and info["data_dir_relative"] == "../data"
    with pytest.raises(ValueError, match="other settings"):
        train(moved / "data", run, "darkgs", _config().replace(lr_albedo=0.01), seed=0, progress=False, resume=True)


def test_a_run_records_what_its_floating_point_results_depend_on(trained):
    """CPU model, torch's CPU kernel level, the C++ kernel's build flags and the thread count: the facts that make two
    runs of the same code, data and seed bit-identical or not (docs/results.md, "Determinism")."""
    import platform

    import torch

    from spotlessgs.rasterizer.cpp_kernel import CXX_FLAGS

    numerics = json.loads((trained / "run" / "config.json").read_text())["provenance"]["numerics"]
    assert numerics["torch_cpu_capability"] == torch.backends.cpu.get_cpu_capability()
    assert numerics["threads"] == json.loads((trained / "run" / "config.json").read_text())["train"]["num_threads"]
    assert numerics["kernel_flags"][:len(CXX_FLAGS)] == list(CXX_FLAGS)  # then -march=native where the compiler took it
    cpuinfo = Path("/proc/cpuinfo").read_text() if Path("/proc/cpuinfo").is_file() else ""
    assert numerics["cpu"] and (numerics["cpu"] in cpuinfo or numerics["cpu"] == platform.processor())
