"""Folder locks between processes: exclusive writers, shared readers and render shards, reproduce and add-noise
refusing a second writer, read-only folders; the render process's errors keep their type."""

from __future__ import annotations

import errno
import os
import subprocess
import sys
from contextlib import contextmanager
from pathlib import Path

import pytest

from spotlessgs.io.errors import FolderLockedError, WriteError
from spotlessgs.io.folder_lock import folder_lock

ROOT = Path(__file__).resolve().parents[1]


@contextmanager
def held_by_another_process(folder: Path, command: str = "other", **kwargs):
    """Another Python process holds ``folder_lock(folder, command, **kwargs)`` for the block's duration."""
    code = ("import time; from spotlessgs.io.folder_lock import folder_lock\n"
            f"with folder_lock({str(folder)!r}, {command!r}, **{kwargs!r}):\n"
            "    print('held', flush=True); time.sleep(60)")
    holder = subprocess.Popen([sys.executable, "-c", code], stdout=subprocess.PIPE, text=True,
                              env={**os.environ, "PYTHONPATH": str(ROOT)})
    try:
        assert holder.stdout.readline().strip() == "held"
        yield holder
    finally:
        holder.kill()
        holder.wait()


def test_readers_share_a_folder_a_writer_excludes_them(tmp_path):
    with held_by_another_process(tmp_path, shared=True):
        with folder_lock(tmp_path, "second reader", shared=True):
            pass
        with pytest.raises(FolderLockedError, match="a reader"):
            with folder_lock(tmp_path, "writer"):
                pass
    with held_by_another_process(tmp_path, "spotless train") as writer:
        with pytest.raises(FolderLockedError, match=f"spotless train` \\(process {writer.pid}"):
            with folder_lock(tmp_path, "reader", shared=True):
                pass


def test_a_reader_of_an_unwritable_folder_without_a_lock_file_takes_no_lock(tmp_path, monkeypatch):
    """A colleague's read-only run that no writer ever locked: a reader proceeds; a writer gets one clear line."""
    import spotlessgs.io.folder_lock as module

    real_open = os.open

    def refusing_open(path, flags, *args):
        if Path(path).name == module.LOCK_NAME and flags & os.O_CREAT:
            raise PermissionError(errno.EACCES, "Permission denied", str(path))
        return real_open(path, flags, *args)

    monkeypatch.setattr(module.os, "open", refusing_open)
    with folder_lock(tmp_path, "reader", shared=True) as lock_file:
        assert not lock_file.exists()
    with pytest.raises(WriteError, match=r"\.lock: cannot write: permission denied"):
        with folder_lock(tmp_path, "writer"):
            pass


def test_commands_that_write_outside_a_run_read_it_shared_and_lock_their_own_output(tmp_path):
    """relight / render / eval into a folder outside the run: several at once on one run (each its own output),
    beside no writer of the run, never two into one output; into the run itself: the run's writer lock."""
    from spotlessgs.io.folder_lock import source_and_output_locks

    run, outs = tmp_path / "run", tmp_path / "outs"
    run.mkdir()
    outs.mkdir()
    with held_by_another_process(run, "spotless relight", shared=True):  # another relight reads the run
        with held_by_another_process(outs, "spotless relight", name=".a.lock"):  # ... and writes outs/a
            with source_and_output_locks(run, outs / "b", "spotless relight"):  # another output: side by side
                pass
            with pytest.raises(FolderLockedError, match="spotless relight"):  # the same output
                with source_and_output_locks(run, outs / "a", "spotless relight"):
                    pass
        with pytest.raises(FolderLockedError):  # an output inside the run needs the run alone
            with source_and_output_locks(run, run / "relit", "spotless relight"):
                pass
    with held_by_another_process(run, "spotless train"):
        with pytest.raises(FolderLockedError, match="spotless train"):
            with source_and_output_locks(run, outs / "b", "spotless relight"):
                pass


def test_render_shards_run_side_by_side_but_not_twice_nor_beside_a_whole_render(tmp_path):
    from simulator.render_pipeline import FramePart, _render_lock

    with held_by_another_process(tmp_path, "shard 0", shared=True):
        with held_by_another_process(tmp_path, "shard 0", name=".lock-shard-0-of-2"):
            with _render_lock(tmp_path, FramePart((1, 2))):  # another shard: fine
                pass
            with pytest.raises(FolderLockedError, match="shard 0"):  # the same shard again
                with _render_lock(tmp_path, FramePart((0, 2))):
                    pass
            with pytest.raises(FolderLockedError):  # the whole render beside the shards
                with _render_lock(tmp_path, FramePart((0, 1))):
                    pass


def test_render_many_frame_ranges_run_side_by_side_but_not_twice(tmp_path):
    from simulator.render_pipeline import FramePart, _render_lock

    with held_by_another_process(tmp_path, "frames 0-10", shared=True):
        with held_by_another_process(tmp_path, "frames 0-10", name=".lock-frames-0-10"):
            with _render_lock(tmp_path, FramePart(frame_range=(10, 20))):  # another range: fine
                pass
            with pytest.raises(FolderLockedError, match="frames 0-10"):  # the same range again
                with _render_lock(tmp_path, FramePart(frame_range=(0, 10))):
                    pass
            with pytest.raises(FolderLockedError):  # the dataset's finishing render beside a running range
                with _render_lock(tmp_path, FramePart()):
                    pass


def test_a_second_reproduction_into_the_same_folder_is_refused_before_it_touches_anything(tmp_path):
    from spotlessgs.experiments.reproduce.config import preset
    from spotlessgs.experiments.reproduce.pipeline import reproduce

    out = tmp_path / "repro"
    with held_by_another_process(out, "spotless reproduce"):
        with pytest.raises(FolderLockedError, match="spotless reproduce"):
            reproduce(preset("tiny"), out)
    assert sorted(p.name for p in out.iterdir()) == [".lock"]


def test_a_reproduction_never_writes_into_its_scenes_folder(tmp_path):
    from spotlessgs.io.errors import OutputOverlapError
    from spotlessgs.experiments.reproduce.config import preset
    from spotlessgs.experiments.reproduce.pipeline import reproduce

    config = preset("tiny")
    with pytest.raises(OutputOverlapError, match="--scenes-dir"):
        reproduce(config, Path(config.scenes_dir) / "out")
    assert not (Path(config.scenes_dir) / "out").exists()


def test_add_noise_refuses_a_second_writer(tmp_path):
    from simulator.sensor_noise import SensorNoise, add_sensor_noise_to_dataset

    from test_sensor_noise import _dataset

    data = tmp_path / "data"
    _dataset(data, frames=2)
    out = tmp_path / "noisy"
    with held_by_another_process(out, "spotless-sim add-noise"):
        with pytest.raises(FolderLockedError, match="add-noise"):
            add_sensor_noise_to_dataset(data, out, SensorNoise())
    assert sorted(p.name for p in out.iterdir()) == [".lock"]


def test_errors_of_the_render_process_come_back_with_their_own_type():
    """Disk full in the render process is the same WriteError in the parent: its one-line message and errno."""
    from simulator.render_pipeline import _portable, _rebuilt
    from spotlessgs.io.errors import OutputOverlapError, write_error

    full = write_error(Path("/data/out/images/frame_00003.png"), OSError(errno.ENOSPC, "No space left on device"))
    for exc in (full, OutputOverlapError("out: inside the input --scene"), FolderLockedError("out: in use")):
        os_fields, type_name, message, _text = _portable(exc)
        again = _rebuilt(os_fields, type_name, message)
        assert type(again) is type(exc) and str(again) == str(exc)
    assert _rebuilt(*_portable(full)[:3]).errno == errno.ENOSPC


def exit_at_once(*_args) -> None:
    """Stands in for the render process's entry: dies before reading what the parent sends."""
    os._exit(3)


def test_a_render_process_that_dies_before_reading_its_work_is_reported_with_its_exit_status(tmp_path,
                                                                                               monkeypatch):
    """The parent's send of the scene (larger than a pipe's buffer) meets a closed pipe: that is reported as the
    process's end ("exit status 3"), not as a bare broken pipe (which click would turn into a silent exit 1)."""
    import numpy as np

    import simulator.render_pipeline as pipeline

    monkeypatch.setattr(pipeline, "_child_main", exit_at_once)
    scene = np.zeros(4_000_000, dtype=np.float32)  # 16 MB: the send cannot finish into the pipe's buffer
    with pytest.raises(pipeline.RenderProcessError, match="exit status 3"):
        pipeline._render_in_child(tmp_path, pipeline.RenderConfig(frames=2, width=64, height=48, samples=4),
                                  pipeline.ExecutionOptions(progress=False), scene, np.eye(4)[None], [0], "test")


def test_two_folder_mode_evaluations_never_write_one_output_folder(tmp_path):
    """`spotless eval --pred --gt --out OUT` took no lock: two at once mixed their results and manifests."""
    import numpy as np

    from evaluation.runner import EvalConfig, evaluate_folders
    from spotlessgs.io.images import write_png

    for folder in ("pred", "gt"):
        for k in range(2):
            write_png(tmp_path / folder / f"f{k}.png", np.full((24, 24, 3), 0.3 + 0.2 * k, np.float32))
    config = EvalConfig(lpips=False, temporal=False, progress=False, num_threads=1)
    with held_by_another_process(tmp_path, "spotless eval", name=".scores.lock"):
        with pytest.raises(FolderLockedError, match="spotless eval"):
            evaluate_folders(tmp_path / "pred", tmp_path / "gt", config, out_dir=tmp_path / "scores")
    assert not (tmp_path / "scores").exists()
    evaluate_folders(tmp_path / "pred", tmp_path / "gt", config, out_dir=tmp_path / "scores")
    assert (tmp_path / "scores" / "results.json").is_file()
