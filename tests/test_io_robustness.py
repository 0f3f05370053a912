"""Robustness of the I/O layer: which file an error names, durable atomic writes, damaged files as one-line errors,
signal handlers put back, prompt stops outside the step loop, dark linear frames.

Each test drives the real code on tiny data (a 14-frame 40x30 synthetic dataset, runs of a few steps).
"""

from __future__ import annotations

import errno
import json
import os
import re
import shutil
import signal
import stat
import threading
from pathlib import Path

import numpy as np
import pytest
import torch

from spotlessgs.io.errors import InputError, OutputOverlapError, WriteError
from tests.conftest import synthetic_box_dataset

pytestmark = pytest.mark.usefixtures("one_torch_thread")


def _tiny_config(**overrides):
    from spotlessgs.training.config import preset

    base = dict(iterations=2, image_width=40, num_threads=1, densify_from=4, densify_until=10, densify_every=4,
                log_every=1, checkpoint_every=2, validation_blocks=0, max_gaussians=500)
    base.update(overrides)
    return preset("tiny", **base)


@pytest.fixture(scope="module")
def box(tmp_path_factory) -> Path:
    return synthetic_box_dataset(tmp_path_factory, "robustness-box", seed=7)


@pytest.fixture(scope="module")
def trained(box, tmp_path_factory) -> Path:
    from spotlessgs.training.trainer import train

    run = tmp_path_factory.mktemp("robustness-run") / "run"
    train(box, run, "3dgs", _tiny_config(), seed=0, progress=False)
    return run


def _one_line(exc: BaseException) -> str:
    text = str(exc)
    assert "\n" not in text, text
    return text


# ---- 1. atomic_path: a refused write names the destination, a failed read names its own file ----------------------


def test_a_read_error_in_the_block_names_the_source_not_the_destination(tmp_path):
    from spotlessgs.io.atomic import atomic_path

    src, dest = tmp_path / "source.png", tmp_path / "out" / "copy.png"
    src.write_bytes(b"x")
    with pytest.raises(PermissionError) as info:
        with atomic_path(dest):  # as shutil.copy2(src, tmp) with an unreadable src raises it
            raise PermissionError(errno.EACCES, os.strerror(errno.EACCES), str(src))
    assert not isinstance(info.value, WriteError)
    assert info.value.filename == str(src)
    assert not dest.exists() and not list(dest.parent.iterdir())


@pytest.mark.parametrize("named", ["tmp", "dest", None])
def test_a_refused_write_of_the_file_itself_names_the_destination(tmp_path, named):
    from spotlessgs.io.atomic import atomic_path

    dest = tmp_path / "results.json"
    with pytest.raises(WriteError) as info:
        with atomic_path(dest) as tmp:
            filename = {"tmp": str(tmp), "dest": str(dest), None: None}[named]
            raise PermissionError(errno.EACCES, os.strerror(errno.EACCES), filename)
    assert _one_line(info.value) == f"{dest}: cannot write: permission denied"


def test_a_nested_write_error_keeps_its_own_file(tmp_path):
    from spotlessgs.io.atomic import atomic_path

    inner = tmp_path / "inner.bin"
    with pytest.raises(WriteError, match="inner.bin: cannot write: no space"):
        with atomic_path(tmp_path / "outer.bin"):
            raise WriteError(errno.ENOSPC, f"{inner}: cannot write: no space left on the device")


@pytest.fixture
def nearly_full_disk(monkeypatch):
    """Every file system reports no free space (what ``_nearly_full`` looks at)."""
    real = os.statvfs

    class Full:
        def __init__(self, stats) -> None:
            self.f_frsize, self.f_bavail = stats.f_frsize, 0

    monkeypatch.setattr(os, "statvfs", lambda path: Full(real(path)))


def test_a_programming_error_on_a_nearly_full_disk_is_not_called_a_full_disk(tmp_path, nearly_full_disk):
    from spotlessgs.io.atomic import atomic_path
    from spotlessgs.io.errors import write_error

    dest = tmp_path / "a.bin"
    assert write_error(dest, TypeError("write() argument must be str, not bytes")) is None
    assert write_error(dest, KeyError("means")) is None
    with pytest.raises(TypeError, match="unsupported operand"):
        with atomic_path(dest):
            _ = 1 + "1"  # noqa: F841 - a bug in the block
    assert not dest.exists()


@pytest.mark.parametrize("exc", [RuntimeError("[enforce fail at inline_container.cc:778] . PytorchStreamWriter "
                                              "failed writing file data/0: file write failed"),
                                 RuntimeError("unexpected pos 621248 vs 621136"),
                                 OSError("cannot write mode RGB as PNG")])
def test_a_library_write_failure_on_a_nearly_full_disk_is_a_full_disk(tmp_path, nearly_full_disk, exc):
    from spotlessgs.io.atomic import atomic_path

    dest = tmp_path / "a.bin"
    with pytest.raises(WriteError) as info:
        with atomic_path(dest):
            raise exc
    assert _one_line(info.value).startswith(f"{dest}: cannot write: no space left on the device")


# ---- 2. the umask is read without changing it ---------------------------------------------------------------------


@pytest.fixture
def umask_027():
    real = os.umask  # tests replace os.umask
    old = real(0o027)
    yield
    real(old)


def test_the_umask_is_read_without_setting_it(tmp_path, monkeypatch, umask_027):
    from spotlessgs.io import atomic

    if atomic._umask_from_proc() is None:
        pytest.skip("no /proc/self/status Umask field here")

    def forbidden(mask):
        raise AssertionError("os.umask was called (it changes the umask of every thread)")

    monkeypatch.setattr(os, "umask", forbidden)
    assert atomic.new_file_mode() == 0o640
    atomic.write_json(tmp_path / "a.json", {"x": 1})
    assert stat.S_IMODE((tmp_path / "a.json").stat().st_mode) == 0o640


def test_without_proc_the_umask_is_set_and_restored_once_per_process(monkeypatch, umask_027):
    from spotlessgs.io import atomic

    monkeypatch.setattr(atomic, "_umask_from_proc", lambda: None)
    monkeypatch.setattr(atomic, "_UMASK_CACHE", [])
    calls = []
    real = os.umask

    def counting(mask):
        calls.append(mask)
        return real(mask)

    monkeypatch.setattr(os, "umask", counting)
    modes = set()
    threads = [threading.Thread(target=lambda: modes.add(atomic.new_file_mode())) for _ in range(8)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert modes == {0o640} and atomic.new_file_mode() == 0o640
    assert len(calls) == 2, calls  # one set, one restore
    assert real(0o027) == 0o027  # left as it was


# ---- 3. atomic_path syncs the file before the rename and the folder after it -------------------------------------


def test_atomic_path_syncs_the_data_then_renames_then_syncs_the_folder(tmp_path, monkeypatch):
    from spotlessgs.io.atomic import atomic_path

    events = []
    real_fsync, real_replace = os.fsync, os.replace

    def fsync(fd):
        events.append(("fsync", os.readlink(f"/proc/self/fd/{fd}")))
        return real_fsync(fd)

    def replace(src, dst):
        events.append(("replace", os.fspath(dst)))
        return real_replace(src, dst)

    monkeypatch.setattr(os, "fsync", fsync)
    monkeypatch.setattr(os, "replace", replace)
    dest = tmp_path / "image.png"
    with atomic_path(dest) as tmp:
        tmp.write_bytes(b"data")  # a library that writes and closes the file without syncing it
    kinds = [kind for kind, _ in events]
    assert kinds == ["fsync", "replace", "fsync"], events
    assert ".image.png.partial-" in events[0][1]
    assert events[2][1] == os.path.realpath(tmp_path)
    assert dest.read_bytes() == b"data"


def test_a_folder_that_cannot_be_synced_is_no_error(tmp_path, monkeypatch):
    from spotlessgs.io.atomic import write_json

    real_fsync = os.fsync

    def fsync(fd):
        if stat.S_ISDIR(os.fstat(fd).st_mode):
            raise OSError(errno.EINVAL, "Invalid argument")
        return real_fsync(fd)

    monkeypatch.setattr(os, "fsync", fsync)
    write_json(tmp_path / "a.json", {"x": 1})
    assert json.loads((tmp_path / "a.json").read_text()) == {"x": 1}


# ---- 4. a damaged tensor file's structure is one line naming the file ----------------------------------------------


@pytest.mark.parametrize("tree", [
    '{"__items__": 5}',
    '{"__items__": [[[1, 2], 3]]}',  # a list as a dict key
    '{"__items__": [[1]]}',
    '{"__tuple__": 3}',
    '{"a": {"__tensor__": [1]}}',
    '{"__items__": [[{"a": 1}, 2]]}',  # an object as a dict key
    "[" * 100_000 + "]" * 100_000,  # too deep for the JSON parser
    '{"a": ' + '{"__tuple__": [' * 900 + "1" + "]}" * 900 + "}",  # too deep for the decoder
    "{not json",
], ids=["items-not-a-list", "list-key", "short-pair", "tuple-not-a-list", "list-tensor-key", "object-key",
        "too-deep-for-json", "too-deep-for-the-decoder", "not-json"])
def test_a_damaged_tensor_file_structure_is_one_line_naming_the_file(tmp_path, tree):
    from safetensors.torch import save_file

    from spotlessgs.io.tensor_file import load_tree

    path = tmp_path / "last.safetensors"
    save_file({"t0": torch.zeros(2)}, str(path), metadata={"format": "kind", "tree": tree})
    with pytest.raises(InputError) as info:
        load_tree(path, "kind")
    assert _one_line(info.value).startswith(f"{path}: damaged file")


# ---- 5. the project's JSON files: damaged or incomplete ones are named ---------------------------------------------


@pytest.mark.parametrize("text, problem", [("", "not valid JSON"), ("{bad", "not valid JSON"),
                                           ("[1, 2]", "expected a JSON object, found an array"),
                                           ("\xff\xfe", None)])
def test_read_json_names_the_file_and_the_problem(tmp_path, text, problem):
    from spotlessgs.io.json_files import read_json

    path = tmp_path / "x.json"
    if problem is None:
        path.write_bytes(b"\xff\xfe{")
        problem = "not UTF-8"
    else:
        path.write_text(text)
    with pytest.raises(InputError) as info:
        read_json(path, "thing")
    assert _one_line(info.value).startswith(f"{path}: damaged thing: {problem}")
    with pytest.raises(InputError, match=f"{tmp_path / 'missing.json'}: no such file"):
        read_json(tmp_path / "missing.json", "thing")
    path.write_text('{"a": 1}')
    with pytest.raises(InputError, match=r"x.json: damaged thing: missing key 'b'"):
        read_json(path, "thing", ("a", "b"))
    assert read_json(path, "thing", ("a",)) == {"a": 1}


def test_a_damaged_run_json_is_named(tmp_path):
    from spotlessgs.training.checkpoint import read_run_info

    (tmp_path / "run.json").write_text("{")
    with pytest.raises(InputError) as info:
        read_run_info(tmp_path)
    assert _one_line(info.value).startswith(f"{tmp_path / 'run.json'}: damaged run description: not valid JSON")
    (tmp_path / "run.json").write_text("null")
    with pytest.raises(InputError, match="run.json: damaged run description: expected a JSON object"):
        read_run_info(tmp_path)


def test_load_run_names_a_damaged_config_json_and_a_missing_key(trained, tmp_path):
    from spotlessgs.training.trainer import load_run

    run = tmp_path / "run"
    shutil.copytree(trained, run)
    config = run / "config.json"
    good = config.read_text()
    config.write_text(good[: len(good) // 2])  # cut by a crash of another tool
    with pytest.raises(InputError, match=f"^{config}: damaged run settings: not valid JSON"):
        load_run(run, device="cpu")
    config.write_text(json.dumps({"run": {}}))
    with pytest.raises(InputError, match=f"^{config}: damaged run settings: missing key 'train'"):
        load_run(run, device="cpu")
    config.write_text(json.dumps({"train": {**json.loads(good)["train"], "no_such_setting": 1}}))
    with pytest.raises(InputError, match=f"^{config}: the training settings do not fit"):
        load_run(run, device="cpu")
    config.write_text(good)
    info = json.loads((run / "run.json").read_text())
    (run / "run.json").write_text(json.dumps({k: v for k, v in info.items() if k != "seed"}))
    with pytest.raises(InputError, match=f"^{run / 'run.json'}: damaged run description: missing key 'seed'"):
        load_run(run, device="cpu")


def test_resume_names_a_damaged_config_json(box, trained, tmp_path):
    from spotlessgs.training.trainer import train

    run = tmp_path / "run"
    shutil.copytree(trained, run)
    config = run / "config.json"
    config.write_text("")
    with pytest.raises(InputError, match=f"^{config}: damaged run settings: not valid JSON"):
        train(box, run, "3dgs", _tiny_config(), seed=0, resume=True, progress=False)
    config.write_text(json.dumps({"train": {}}))
    with pytest.raises(InputError, match=f"^{config}: damaged run settings: missing key 'run'"):
        train(box, run, "3dgs", _tiny_config(), seed=0, resume=True, progress=False)


def test_a_damaged_model_selection_json_is_named(tmp_path):
    from spotlessgs.training.selection import (
        SELECTION_FILE, SELECTION_VERSION, SelectionConfig, _settings, run_decisions, select_model,
    )

    data, run = tmp_path / "data", tmp_path / "run"
    data.mkdir()
    run.mkdir()
    path = run / SELECTION_FILE
    config, selection = _tiny_config(), SelectionConfig()
    path.write_text('{"version": ')
    with pytest.raises(InputError, match=f"^{path}: damaged model selection decision: not valid JSON"):
        select_model(data, run, config, 0, selection, resume=True)
    settings = json.loads(json.dumps(_settings(config, selection, 0, data.resolve())))
    path.write_text(json.dumps({"version": SELECTION_VERSION, "settings": settings}))
    with pytest.raises(InputError, match=f"^{path}: damaged model selection decision: missing key 'chosen'"):
        select_model(data, run, config, 0, selection, resume=True)
    (run / "run.json").write_text(json.dumps({"model": "auto"}))
    (run / "train_summary.json").write_text("{}")
    path.write_text(json.dumps({"chosen": "sh1-lambert"}))
    with pytest.raises(InputError, match="train_summary.json: damaged training summary: missing key"):
        run_decisions(run)


# ---- 6. a full disk while appending metrics.jsonl names the file ---------------------------------------------------


def test_a_full_disk_while_logging_metrics_names_metrics_jsonl(box, tmp_path, monkeypatch):
    from spotlessgs.training import trainer

    class FullDisk:
        def __init__(self, fh) -> None:
            self.fh = fh

        def write(self, text):
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))

        def flush(self):
            self.fh.flush()

        def close(self):
            self.fh.close()

    def fake_open(path, *args, **kwargs):
        fh = open(path, *args, **kwargs)
        return FullDisk(fh) if Path(path).name == "metrics.jsonl" else fh

    monkeypatch.setattr(trainer, "open", fake_open, raising=False)
    run = tmp_path / "run"
    with pytest.raises(WriteError) as info:
        trainer.train(box, run, "3dgs", _tiny_config(), seed=0, progress=False)
    assert _one_line(info.value) == f"{run / 'metrics.jsonl'}: cannot write: no space left on the device"


# ---- 7. signal handlers are put back ------------------------------------------------------------------------------


def test_the_cli_puts_back_the_sigterm_handler(tmp_path):
    from click.testing import CliRunner

    from spotlessgs.cli import main

    def mine(signum, frame):  # an embedding application's handler
        pass

    before = signal.signal(signal.SIGTERM, mine)
    try:
        result = CliRunner().invoke(main, ["--help"])
        assert result.exit_code == 0, result.output
        assert signal.getsignal(signal.SIGTERM) is mine
        result = CliRunner().invoke(main, ["export", str(tmp_path / "no-such-run"), "--out", str(tmp_path / "a.ply")])
        assert result.exit_code != 0
        assert signal.getsignal(signal.SIGTERM) is mine
    finally:
        signal.signal(signal.SIGTERM, before)


def test_deferred_interrupts_leaves_a_handler_installed_by_c_code(monkeypatch):
    from spotlessgs.io.signals import deferred_interrupts

    saved = {s: signal.getsignal(s) for s in (signal.SIGINT, signal.SIGTERM)}
    real = signal.signal

    def as_if_c_installed_them(signum, handler):
        if handler is None:
            raise TypeError("signal handler must be signal.SIG_IGN, signal.SIG_DFL, or a callable object")
        real(signum, handler)
        return None  # what signal.signal returns for a handler that was not installed from Python

    monkeypatch.setattr(signal, "signal", as_if_c_installed_them)
    try:
        with deferred_interrupts() as stop:
            pass
        assert not stop.requested
    finally:
        for s, handler in saved.items():
            real(s, handler)


# ---- 8. a stop outside the step loop is prompt ---------------------------------------------------------------------


def _interrupt_now() -> None:
    """Deliver SIGINT to this (the main) thread; its Python handler runs before the next line."""
    signal.pthread_kill(threading.main_thread().ident, signal.SIGINT)


def test_ctrl_c_while_the_images_load_stops_before_any_step(box, tmp_path, monkeypatch):
    from spotlessgs.training import trainer
    from spotlessgs.training.checkpoint import existing_checkpoint

    real = trainer.load_training_views

    def load_then_interrupt(*args, **kwargs):
        views = real(*args, **kwargs)
        _interrupt_now()
        return views

    monkeypatch.setattr(trainer, "load_training_views", load_then_interrupt)
    run = tmp_path / "run"
    with pytest.raises(KeyboardInterrupt):
        trainer.train(box, run, "3dgs", _tiny_config(iterations=50), seed=0, progress=False)
    assert existing_checkpoint(run) is None
    assert not (run / "metrics.jsonl").exists() and not (run / "config.json").exists()
    assert not list(run.rglob(".*.partial-*"))


def test_ctrl_c_after_the_last_step_skips_the_final_evaluation_and_resume_finishes(box, tmp_path, monkeypatch):
    from spotlessgs.training import trainer
    from spotlessgs.training.checkpoint import load_checkpoint

    evaluated = []
    real_evaluate = trainer.evaluate_reconstruction

    def evaluate(*args, **kwargs):
        evaluated.append(1)
        return real_evaluate(*args, **kwargs)

    class InterruptOnClose:  # the metrics file is closed after the step loop, before the final evaluation
        def __init__(self, fh) -> None:
            self.fh = fh

        def write(self, text):
            return self.fh.write(text)

        def flush(self):
            self.fh.flush()

        def close(self):
            self.fh.close()
            _interrupt_now()

    def fake_open(path, *args, **kwargs):
        fh = open(path, *args, **kwargs)
        return InterruptOnClose(fh) if Path(path).name == "metrics.jsonl" else fh

    monkeypatch.setattr(trainer, "evaluate_reconstruction", evaluate)
    monkeypatch.setattr(trainer, "open", fake_open, raising=False)
    run = tmp_path / "run"
    config = _tiny_config(iterations=3, checkpoint_every=100)
    with pytest.raises(KeyboardInterrupt):
        trainer.train(box, run, "3dgs", config, seed=0, progress=False)
    assert evaluated == []
    assert load_checkpoint(run)["step"] == 3  # the last step is saved: resume only evaluates
    assert not (run / "train_summary.json").exists()
    monkeypatch.undo()
    result = trainer.train(box, run, "3dgs", config, seed=0, resume=True, progress=False)
    assert result.steps == 3 and (run / "train_summary.json").is_file()
    # the resume trained no step: its summary has the interrupted session's time per step and last loss
    logged = json.loads((run / "metrics.jsonl").read_text().splitlines()[-1])
    summary = json.loads((run / "train_summary.json").read_text())
    assert logged["step"] == 3 and (summary["ms_per_step"], summary["final_loss"]) == (logged["ms_per_step"],
                                                                                       logged["loss"])


# ---- 9. `--model auto` refuses --out inside --data before creating anything --------------------------------------


def test_a_finished_run_shared_without_its_checkpoint_is_not_trained_over(box, trained, tmp_path):
    """A colleague's finished run, copied without checkpoints/: training into it again is refused and every file
    stays as it was (only --resume, which model selection uses on its proxies, trains it again from the start)."""
    from spotlessgs.training.trainer import train

    run = tmp_path / "run"
    shutil.copytree(trained, run)
    shutil.rmtree(run / "checkpoints")
    before = {p.name: p.read_bytes() for p in run.iterdir() if p.is_file()}
    assert "train_summary.json" in before and "metrics.jsonl" in before
    with pytest.raises(FileExistsError, match=r"run holds a finished training run without its checkpoint "
                                              r"\(checkpoints/last.safetensors\).*use a new --out"):
        train(box, run, "3dgs", _tiny_config(), seed=0, progress=False)
    assert {p.name: p.read_bytes() for p in run.iterdir() if p.is_file()} == before


def test_data_for_a_moved_dataset_must_hold_the_runs_own_files(box, trained, tmp_path_factory, tmp_path):
    """--data (relight, render, eval, export, load_run) points at where the run's dataset went: a copy of it is taken,
    another dataset (frames named alike) is refused in one line before anything is written."""
    from click.testing import CliRunner

    from spotlessgs.cli import main
    from spotlessgs.training.checkpoint import read_run_info, resolve_data_dir

    moved = tmp_path / "moved"
    shutil.copytree(box, moved)
    assert resolve_data_dir(trained, read_run_info(trained), moved) == moved.resolve()
    other = synthetic_box_dataset(tmp_path_factory, "robustness-other-box", seed=8)
    with pytest.raises(InputError, match=r"other-box.*: --data holds other files than the run .*run was trained on"):
        resolve_data_dir(trained, read_run_info(trained), other)
    for command in (["relight", str(trained), "--out", str(tmp_path / "relit")], ["eval", str(trained)],
                    ["export", str(trained), "--out", str(tmp_path / "x.ply")]):
        result = CliRunner().invoke(main, [*command, "--data", str(other)])
        assert result.exit_code == 2 and "--data holds other files than the run" in result.output, result.output
    assert not (tmp_path / "relit").exists() and not (tmp_path / "x.ply").exists()


def _edited_checkpoint(trained: Path, where: Path, edit) -> Path:
    """A copy of the run ``trained`` in ``where`` whose checkpoint ``edit(checkpoint dict)`` changed."""
    from spotlessgs.io.tensor_file import load_tree, save_tree
    from spotlessgs.training.checkpoint import CHECKPOINT_FORMAT, checkpoint_path

    run = shutil.copytree(trained, where)
    ckpt = load_tree(checkpoint_path(run), CHECKPOINT_FORMAT)
    edit(ckpt)
    save_tree(checkpoint_path(run), ckpt, CHECKPOINT_FORMAT)
    return run


def _set(table: str, name: str, value):
    def edit(ckpt):
        ckpt[table][name] = value(ckpt[table][name])
    return edit


@pytest.mark.parametrize("edit, problem", [
    (_set("gaussians", "means", lambda t: t.clone().fill_(float("nan"))),
     r"gaussians.means has \d+ value\(s\) that are not finite"),
    (_set("gaussians", "quats", lambda t: t[:-1]), r"the Gaussians' tensors hold \[\d+, \d+\] rows"),
    (_set("gaussians", "means", lambda t: t.double()), r"gaussians.means is a torch.float64 tensor"),
    (lambda ckpt: ckpt.update(gaussians={k: v[:0] for k, v in ckpt["gaussians"].items()}),
     r"tensors hold \[0\] rows, expected one count of at least 1"),
    (lambda ckpt: ckpt.pop("appearance"), r"'appearance' is not a table of tensors"),
    (lambda ckpt: ckpt["gaussians"].pop("quats"), r"damaged checkpoint: .*quats"),
    (lambda ckpt: ckpt.update(step="abc"), r"step 'abc' is not a whole number"),
])
def test_a_damaged_checkpoint_is_one_line_naming_it(box, trained, tmp_path, edit, problem):
    """A checkpoint edited by hand or damaged: relight stops with one line naming checkpoints/last.safetensors
    before writing anything (a NaN model relit to black images with exit 0)."""
    from click.testing import CliRunner

    from spotlessgs.cli import main

    run = _edited_checkpoint(trained, tmp_path / "run", edit)
    result = CliRunner().invoke(main, ["relight", str(run), "--out", str(tmp_path / "relit"), "-q"])
    assert result.exit_code == 2 and len(result.output.strip().splitlines()) == 1, result.output
    assert re.search(rf"checkpoints/last.safetensors: .*{problem}", result.output), result.output
    assert not (tmp_path / "relit").exists()


def test_resume_refuses_a_checkpoint_beyond_the_runs_iterations_or_without_optimizer_state(box, trained, tmp_path):
    from spotlessgs.training.trainer import train

    for name, edit, problem in (("late", lambda ckpt: ckpt.update(step=100), "it is at step 100, beyond the run's 2"),
                                ("bare", lambda ckpt: ckpt.pop("strategy"), "it lacks strategy")):
        run = _edited_checkpoint(trained, tmp_path / name, edit)
        with pytest.raises(InputError, match=rf"last.safetensors: cannot resume from this checkpoint: {problem}"):
            train(box, run, "3dgs", _tiny_config(), seed=0, progress=False, resume=True)


@pytest.mark.parametrize("file, edit, problem", [
    ("config.json", lambda c: c["train"].update(image_width="40"),
     r"config.json: damaged run settings: train.image_width: expected a whole number or null, got '40'"),
    ("config.json", lambda c: c["train"].update(linear_input="yes"),
     r"train.linear_input: expected true or false, got 'yes'"),
    ("config.json", lambda c: c["train"].update(depth_spread_every=0),
     r"config.json: damaged run settings: TrainConfig: depth_spread_every must be >= 1"),
    ("run.json", lambda r: r.update(seed="abc"), r"run.json: damaged run description: seed 'abc' is not a whole"),
    ("run.json", lambda r: r.update(model="foo"), r"run.json: damaged run description: model 'foo' is not one of"),
    ("run.json", lambda r: r.update(model=[1]), r"run.json: damaged run description: model \[1\] is not one of"),
    ("run.json", lambda r: r.update(model_config=[1]), r"run.json: damaged model_config: is not a JSON object"),
    ("run.json", lambda r: r.update(model_config={"bogus": 1}), r"run.json: the model_config does not fit"),
    ("run.json", lambda r: r.update(data_dir=5, data_dir_relative=None), r"run.json: damaged run description: "
                                                                         r"data_dir 5 is not a path"),
])
def test_hand_edited_run_files_are_one_line_naming_the_file_and_field(box, trained, tmp_path, file, edit, problem):
    from click.testing import CliRunner

    from spotlessgs.cli import main

    run = shutil.copytree(trained, tmp_path / "run")
    record = json.loads((run / file).read_text())
    edit(record)
    (run / file).write_text(json.dumps(record))
    result = CliRunner().invoke(main, ["relight", str(run), "--out", str(tmp_path / "relit"), "-q"])
    assert result.exit_code == 2 and len(result.output.strip().splitlines()) == 1, result.output
    assert re.search(problem, result.output), result.output
    assert not (tmp_path / "relit").exists()


def test_field_types_follow_the_annotations():
    from spotlessgs.models.shading import ModelConfig
    from spotlessgs.training.config import TrainConfig, field_type_errors

    assert field_type_errors(TrainConfig, {"iterations": 10, "image_width": None, "ssim_lambda": 1, "preset": "x",
                                           "linear_input": False, "not_a_field": object()}) == []
    assert field_type_errors(TrainConfig, {"iterations": 1.5, "ssim_lambda": True, "preset": 3}) == [
        "iterations: expected a whole number, got 1.5", "ssim_lambda: expected a number, got True",
        "preset: expected text, got 3"]
    assert field_type_errors(ModelConfig, {"light_model": "lamp"}) == [
        "light_model: expected one of 'none', 'spotlight', got 'lamp'"]


def test_train_auto_refuses_a_fixed_model_run_before_selecting(box, tmp_path, monkeypatch):
    """`--model auto --resume` on a run trained with --model spotless ran the whole selection, then failed the
    settings check and left a model_selection.json that the run never followed."""
    from spotlessgs.training import selection
    from spotlessgs.training.trainer import train

    run = tmp_path / "run"
    train(box, run, "darkgs", _tiny_config(iterations=2), seed=0, progress=False)
    monkeypatch.setattr(selection, "select_model", lambda *a, **k: pytest.fail("selected before refusing"))
    with pytest.raises(ValueError, match=r"run: holds a run trained without model selection \(no "
                                         r"model_selection\.json\); --model auto cannot resume it"):
        selection.train_auto(box, run, _tiny_config(iterations=2), resume=True, progress=False)
    assert not (run / selection.SELECTION_FILE).exists()


def test_a_warm_started_run_resumes_after_its_source_moved(box, tmp_path):
    """The warm start's source path (an auto run's own selection/base) was compared on --resume: a moved auto run
    could not be resumed. The checkpoint supersedes the source, which is no longer compared."""
    import shutil

    from spotlessgs.training.trainer import train

    cfg = _tiny_config(iterations=4, checkpoint_every=2, densify_from=1, densify_every=1, densify_until=4)
    train(box, tmp_path / "source", "darkgs", cfg, seed=0, progress=False)
    train(box, tmp_path / "run", "darkgs", cfg, seed=0, progress=False, init_from=tmp_path / "source", stop_after=2)
    shutil.move(tmp_path / "source", tmp_path / "moved")
    result = train(box, tmp_path / "run", "darkgs", cfg, seed=0, progress=False, init_from=tmp_path / "moved",
                   resume=True)
    assert result.steps == 4


def test_train_auto_refuses_a_run_folder_inside_its_dataset_before_creating_it(tmp_path):
    from spotlessgs.training.selection import train_auto

    data = tmp_path / "data"
    data.mkdir()
    with pytest.raises(OutputOverlapError, match="inside the input --data"):
        train_auto(data, data / "run", _tiny_config(), progress=False)
    assert list(data.iterdir()) == []


# ---- 10. dark frames of linear input are not taken for black ones --------------------------------------------------


def test_the_black_level_is_an_srgb_brightness_also_for_linear_files():
    from spotlessgs.io.frame_quality import frame_stats, problem

    dim = np.zeros((10, 10, 3), np.float32)
    dim[:, :5] = 1.0 / 255.0  # 13/255 once encoded as sRGB: a dark frame, not a black one
    clipped = np.zeros((10, 10), bool)
    assert problem(frame_stats(dim, clipped, linear=True)) is None
    assert problem(frame_stats(dim, clipped)) == "black"  # as sRGB-encoded values it is black
    assert problem(frame_stats(np.zeros_like(dim), clipped, linear=True)) == "black"


def test_dark_linear_frames_are_kept_for_training(box, tmp_path):
    from spotlessgs.io.images import read_image, write_png
    from spotlessgs.training.data import load_training_views

    data = tmp_path / "data"
    shutil.copytree(box, data)
    frames = sorted((data / "images").glob("*.png"))
    for k in (1, 2):  # a linear exposure of the box far too short: values of 0 and 1/255 in the file
        image = read_image(frames[k])
        write_png(frames[k], np.where(image > np.median(image), 1.0 / 255.0, 0.0).astype(np.float32))
    views = load_training_views(data, 40, linear_input=True)
    reference = load_training_views(box, 40, linear_input=True)
    assert {1, 2} & set(reference.train), reference.train
    assert views.train == reference.train


def test_resume_trims_a_damaged_metrics_log_to_the_checkpoints_steps(tmp_path):
    """Lines after the checkpoint's step go; so do lines that are not a step's record (hand-edited or damaged:
    a JSON list, a step that is not a number, a line cut by a crash) instead of stopping the resume."""
    from spotlessgs.training.checkpoint import truncate_metrics

    path = tmp_path / "metrics.jsonl"
    lines = [json.dumps({"step": s, "loss": 0.1 * s}) for s in range(1, 6)]
    path.write_text("\n".join([lines[0], "[1]", json.dumps({"step": "x"}), *lines[1:], '{"step": 6, "lo']) + "\n")
    truncate_metrics(path, 3)
    assert path.read_text().splitlines() == lines[:3]


def test_black_test_frames_and_a_single_usable_training_frame_are_warned_about(box, tmp_path, caplog):
    from spotlessgs.io.images import write_png
    from spotlessgs.training.data import load_training_views

    data = tmp_path / "data"
    shutil.copytree(box, data)
    reference = load_training_views(box, 40)
    names = sorted(p.name for p in (data / "images").glob("*.png"))
    for k in [reference.test[0], *reference.train[1:]]:  # one test frame and all training frames but one: black
        write_png(data / "images" / names[k], np.zeros((30, 40, 3), np.float32))
    with caplog.at_level("WARNING"):
        views = load_training_views(data, 40)
    assert views.train == reference.train[:1]
    assert f"1 test frame(s) are black (no signal); scores against them say nothing of the model: " \
           f"{names[reference.test[0]]}" in caplog.text
    assert f"only one usable training frame ({names[reference.train[0]]})" in caplog.text


def test_train_settings_by_flag_and_set_and_their_ranges(box, tmp_path, monkeypatch):
    """--set of a setting that has a flag (device, linear_input) takes effect when the flag is not given, and giving
    both is a usage error; --set values are typed by the field (none for the optional ones) and checked for range
    before any image loads; --light-prior refuses NaN."""
    from click.testing import CliRunner

    import spotlessgs.run as run_module
    from spotlessgs.cli import main

    seen = {}

    def record_the_spec(spec, *args, **kwargs):
        seen["spec"] = spec
        raise SystemExit(0)  # stop before any image loads

    monkeypatch.setattr(run_module, "train", record_the_spec)

    def train(*args):
        seen.clear()
        return CliRunner().invoke(main, ["train", "--data", str(box), "--out", str(tmp_path / "run"), "-q", *args])

    result = train("--set", "device=cpu", "--set", "linear_input=true", "--set", "validation_block=none")
    assert result.exit_code == 0, result.output
    overrides = dict(seen["spec"].overrides)
    assert overrides["device"] == "cpu" and overrides["linear_input"] is True and overrides["validation_block"] is None
    result = train("--device", "cpu", "--set", "device=cuda")
    assert result.exit_code == 2 and "--device and --set device=... both set device; give one of them" in result.output
    for setting, message in (("validation_block=x", "validation_block: 'x' is not a whole number or none"),
                             ("falloff_tau=nan", "falloff_tau: 'nan' is not a finite number")):
        result = train("--set", setting)
        assert result.exit_code == 2 and message in result.output, result.output
    result = train("--light-prior", "nan", "0", "0")
    assert result.exit_code == 2 and "'nan' is not a finite number" in result.output
    from spotlessgs.training.config import preset

    for overrides, message in ((dict(iterations=0), "iterations must be >= 1"),
                               (dict(checkpoint_every=0), "checkpoint_every must be >= 1"),
                               (dict(lr_means_final=0.0), "lr_means_init and lr_means_final must be > 0"),
                               (dict(lr_albedo=-0.1), "the learning rate lr_albedo must be >= 0"),
                               (dict(image_width=4), "image_width must be >= 8"),
                               (dict(ssim_lambda=float("inf")), "ssim_lambda must be finite")):
        with pytest.raises(ValueError, match=message):
            preset("tiny", **overrides)
    assert preset("tiny", lr_normals=0.0).lr_normals == 0.0  # held normals: a zero rate is a setting


def test_a_resume_may_change_the_thread_count_and_device_and_records_it(box, tmp_path):
    """The thread count and the device choose the machine, not the model: a run stopped on one node resumes on
    another. config.json keeps the settings the run began with and lists each resume's machine settings; a model
    setting is still refused."""
    from spotlessgs.training.trainer import train

    run = tmp_path / "run"
    cfg = _tiny_config(iterations=4, checkpoint_every=2, densify_from=1, densify_every=1, densify_until=4)
    train(box, run, "3dgs", cfg, seed=0, progress=False, stop_after=2)
    began = json.loads((run / "config.json").read_text())
    with pytest.raises(ValueError, match=r"other settings .*\(lr_opacity: run [\d.]+, now 0\.5\)"):
        train(box, run, "3dgs", cfg.replace(num_threads=2, lr_opacity=0.5), seed=0, progress=False, resume=True)
    assert json.loads((run / "config.json").read_text()) == began
    result = train(box, run, "3dgs", cfg.replace(num_threads=2, device="cpu"), seed=0, progress=False, resume=True)
    assert result.steps == 4
    saved = json.loads((run / "config.json").read_text())
    assert saved["train"] == began["train"] and (saved["train"]["num_threads"], saved["train"]["device"]) == (1, "auto")
    [record] = saved["resumed_with"]
    assert (record["step"], record["num_threads"], record["device"], record["device_used"]) == (2, 2, "cpu", "cpu")
    assert record["numerics"]["threads"] == 2
    # the finished run resumed once more trains no step and records nothing; it loads as any run
    train(box, run, "3dgs", cfg.replace(num_threads=2), seed=0, progress=False, resume=True)
    assert json.loads((run / "config.json").read_text())["resumed_with"] == [record]
    from spotlessgs.training.trainer import load_run

    scene, _views, config, _info = load_run(run, device="cpu")
    assert config.num_threads == 1 and len(scene.gaussians) > 0


def test_each_resume_is_compared_with_the_machine_settings_the_run_last_used(box, tmp_path):
    """1 thread, then 2, then 1 again: the third session was compared with the first and went unrecorded, so the
    record said that the last steps ran on 2 threads."""
    from spotlessgs.training.trainer import train

    run = tmp_path / "run"
    cfg = _tiny_config(iterations=6, checkpoint_every=2, densify_from=1, densify_every=1, densify_until=6)
    train(box, run, "3dgs", cfg, seed=0, progress=False, stop_after=2)
    train(box, run, "3dgs", cfg.replace(num_threads=2), seed=0, progress=False, resume=True, stop_after=4)
    train(box, run, "3dgs", cfg, seed=0, progress=False, resume=True)
    records = json.loads((run / "config.json").read_text())["resumed_with"]
    assert [(r["step"], r["num_threads"]) for r in records] == [(2, 2), (4, 1)]
    # the summary says the last session began at step 4: its seconds are not the run's training time
    assert json.loads((run / "train_summary.json").read_text())["session_started_at_step"] == 4


def test_a_generator_state_from_another_device_type_seeds_a_fixed_stream():
    """A CUDA generator's state (16 bytes) cannot set a CPU generator (5,056 bytes), nor the reverse: such a state
    seeds the generator from its digest, the same stream on every resume; a state of the right form restores it."""
    from spotlessgs.io.seeding import restore_generator, torch_generator

    source = torch_generator(0, "densify")
    torch.rand(3, generator=source)
    own = torch_generator(1, "densify")
    restore_generator(own, source.get_state())
    assert torch.equal(torch.rand(4, generator=own), torch.rand(4, generator=source))
    foreign = torch.arange(16, dtype=torch.uint8)  # the form of a CUDA generator's state
    a, b = torch_generator(2, "densify"), torch_generator(3, "densify")
    restore_generator(a, foreign)
    restore_generator(b, foreign)
    draws = torch.rand(4, generator=a)
    assert torch.equal(draws, torch.rand(4, generator=b))
    assert not torch.equal(draws, torch.rand(4, generator=torch_generator(2, "densify")))
