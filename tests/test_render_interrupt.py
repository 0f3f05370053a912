"""Stopping a render: Ctrl-C and SIGTERM stop `spotless-sim render` within seconds (exit 130 / 143), SIGKILL leaves
nothing that the next run does not remove, and the resumed dataset equals an uninterrupted render byte for byte.

Blender runs in a child process of the render (Cycles swallows Ctrl-C): these tests start the command as a subprocess,
signal it once its first frame exists, then resume in-process. Renders are tiny (64x48 px) with enough samples that a
frame takes about a second.
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

pytestmark = pytest.mark.blender

ROOT = Path(__file__).resolve().parents[1]
SCENE = ROOT / "scenes" / "bedroom" / "house.json"
FRAMES = 6
SETTINGS = dict(frames=FRAMES, width=64, height=48, samples=40, seed=3)


def _config():
    from simulator.render_pipeline import RenderConfig

    return RenderConfig.from_preset("uneven", **SETTINGS)


def _render(out: Path) -> dict:
    from simulator.render_pipeline import ExecutionOptions, render_dataset

    return render_dataset(SCENE, out, _config(), execution=ExecutionOptions(progress=False))


@pytest.fixture(scope="module")
def reference(tmp_path_factory) -> Path:
    """The same dataset rendered without interruption."""
    out = tmp_path_factory.mktemp("reference") / "bedroom"
    summary = _render(out)
    assert summary["rendered"] == FRAMES and summary["complete"]
    return out


def _start(out: Path) -> subprocess.Popen:
    """`python3 -m simulator.cli render ...` in its own session, with Ctrl-C's default disposition (a shell that
    starts a background job ignores SIGINT in it, and Python would then never raise KeyboardInterrupt)."""
    args = [sys.executable, "-m", "simulator.cli", "render", "--scene", str(SCENE), "--out", str(out), "-q"]
    for key, value in SETTINGS.items():
        args += [f"--{key}", str(value)]
    return subprocess.Popen(args, cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            start_new_session=True,
                            preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))


def _wait_for(path: Path, proc: subprocess.Popen, timeout: float = 180.0) -> None:
    deadline = time.monotonic() + timeout
    while not path.exists():
        if proc.poll() is not None:
            out, err = proc.communicate()
            pytest.fail(f"the render ended (exit {proc.returncode}) before {path} existed:\n{out}\n{err}")
        if time.monotonic() > deadline:
            proc.kill()
            pytest.fail(f"{path} did not appear within {timeout} s")
        time.sleep(0.02)


def _children(pid: int) -> list[int]:
    """Process ids of the children of ``pid`` (Linux /proc)."""
    found = []
    for task in Path(f"/proc/{pid}/task").iterdir():
        text = (task / "children").read_text().split()
        found += [int(t) for t in text]
    return found


def _alive(pid: int) -> bool:
    """True while ``pid`` runs (a zombie waiting for its reaper counts as dead)."""
    try:
        stat = Path(f"/proc/{pid}/stat").read_text()
    except (FileNotFoundError, ProcessLookupError):
        return False
    return stat.rsplit(")", 1)[1].split()[0] not in ("Z", "X")


def _leftovers(out: Path) -> list[str]:
    """Temporary files of atomic writes and renderer scratch folders under ``out``."""
    return sorted(str(p.relative_to(out)) for p in out.rglob("*")
                  if ".partial-" in p.name or p.name.startswith(".render-scratch"))


def _frames_on_disk(out: Path) -> list[str]:
    return sorted(p.name for p in (out / "images").glob("frame_*.png"))


def _assert_same_dataset(out: Path, reference: Path) -> None:
    """Every file byte-identical to the uninterrupted render's, transforms.json apart from its provenance block
    (timestamps, host); no file more, no file less."""
    files = sorted(str(p.relative_to(reference)) for p in reference.rglob("*") if p.is_file())
    assert sorted(str(p.relative_to(out)) for p in out.rglob("*") if p.is_file()) == files
    for name in files:
        if name == "transforms.json":
            mine, theirs = (json.loads((d / name).read_text()) for d in (out, reference))
            for meta in (mine, theirs):
                meta["spotless"].pop("provenance")
            assert mine == theirs
        else:
            assert (out / name).read_bytes() == (reference / name).read_bytes(), name


@pytest.mark.parametrize("signum", [signal.SIGINT, signal.SIGTERM], ids=["SIGINT", "SIGTERM"])
def test_a_signal_stops_the_render_within_seconds_and_a_rerun_completes_it(tmp_path, reference, signum):
    out = tmp_path / "bedroom"
    proc = _start(out)
    _wait_for(out / "images" / "frame_00000.png", proc)
    proc.send_signal(signum)
    sent = time.monotonic()
    try:
        stdout, stderr = proc.communicate(timeout=10)
    except subprocess.TimeoutExpired:
        proc.kill()
        pytest.fail(f"the render was still running 10 s after {signal.Signals(signum).name}")
    assert proc.returncode == 128 + signum, (stdout, stderr)
    assert time.monotonic() - sent < 10
    assert "stopped by signal" in stderr and "Traceback" not in stderr, stderr
    done = _frames_on_disk(out)
    assert 1 <= len(done) < FRAMES, done
    assert _leftovers(out) == []
    assert not (out / "transforms.json").exists()
    for name in done:  # the finished frames are valid
        for sub, ext in (("images", "png"), ("gt", "png"), ("exr", "exr")):
            stem = Path(name).stem
            assert (out / sub / f"{stem}.{ext}").read_bytes() == (reference / sub / f"{stem}.{ext}").read_bytes()
    summary = _render(out)
    assert summary["skipped"] == len(done) and summary["rendered"] == FRAMES - len(done) and summary["complete"]
    _assert_same_dataset(out, reference)


def test_after_sigkill_the_render_process_dies_too_and_a_rerun_leaves_nothing_behind(tmp_path, reference):
    """SIGKILL runs no clean-up: the Blender process dies with its parent (the kernel kills it), and the next run
    removes the temporary files and the scratch folder before it resumes."""
    out = tmp_path / "bedroom"
    proc = _start(out)
    _wait_for(out / "images" / "frame_00000.png", proc)
    children = _children(proc.pid)
    # what a kill in the middle of a write leaves (atomic writes' temporary files)
    (out / "images" / ".frame_00003.png.partial-k1ll3d.png").write_bytes(b"half a png")
    (out / "exr" / ".frame_00004.exr.partial-k1ll3d.exr").write_bytes(b"half an exr")
    (out / ".transforms.json.partial-k1ll3d.json").write_text("{")
    proc.kill()
    proc.communicate()
    deadline = time.monotonic() + 10
    while any(_alive(pid) for pid in children) and time.monotonic() < deadline:
        time.sleep(0.05)
    assert not [pid for pid in children if _alive(pid)], "the render process outlived its parent"
    assert _leftovers(out), "the kill should have left temporary files"
    summary = _render(out)
    assert summary["complete"] and summary["rendered"] + summary["skipped"] == FRAMES
    assert _leftovers(out) == []
    _assert_same_dataset(out, reference)


def test_a_render_process_killed_from_outside_is_an_error_naming_it(tmp_path):
    """Only the Blender process dies (the out-of-memory killer, say): the command fails with one line, keeps the
    finished frames, and leaves no temporary file."""
    out = tmp_path / "bedroom"
    proc = _start(out)
    _wait_for(out / "images" / "frame_00000.png", proc)
    render_processes = [pid for pid in _children(proc.pid) if _renders(pid)]
    assert len(render_processes) == 1
    os.kill(render_processes[0], signal.SIGKILL)
    stdout, stderr = proc.communicate(timeout=30)
    assert proc.returncode == 1, (stdout, stderr)
    assert "the Blender render process stopped unexpectedly (killed by SIGKILL" in stderr, stderr
    assert "rerun the same command to resume" in stderr
    assert 1 <= len(_frames_on_disk(out)) < FRAMES
    assert _leftovers(out) == []


def _renders(pid: int) -> bool:
    """Whether process ``pid`` is a multiprocessing child other than the resource tracker (the render process)."""
    cmdline = Path(f"/proc/{pid}/cmdline").read_bytes().replace(b"\0", b" ").decode(errors="replace")
    return "multiprocessing" in cmdline and "resource_tracker" not in cmdline


def test_an_error_in_the_render_process_comes_back_with_its_type_and_message(tmp_path):
    """`images` is a file, not a folder: writing the first frame's image fails in the render process, and the same
    exception (type, message, file name) is raised by render_dataset; the scratch folder is gone."""
    from simulator.front3d import LoadOptions
    from simulator.render_pipeline import ExecutionOptions, RenderConfig, _prepare_plan, plan_poses, render_dataset
    from simulator.scene_model import content_sha256

    out = tmp_path / "bedroom"
    out.mkdir()
    config = RenderConfig(frames=2, width=64, height=48, samples=4)
    scene, _room, objects, poses = plan_poses(SCENE, config, LoadOptions())
    _prepare_plan(out, SCENE, config, poses, content_sha256(objects, scene.lights))  # a render began here
    (out / "images").write_text("not a folder")
    with pytest.raises(FileExistsError) as err:
        render_dataset(SCENE, out, config, execution=ExecutionOptions(progress=False))
    assert err.value.filename == str(out / "images") and str(err.value).startswith("[Errno 17]")
    assert "Traceback" in str(err.value.__cause__)  # the render process's traceback, for --debug
    assert _leftovers(out) == []


def test_render_inside_a_spawned_pool_worker(tmp_path):
    """`spotless reproduce` renders in a (non-daemonic) spawn pool worker, which may start the render process."""
    import multiprocessing
    from concurrent.futures import ProcessPoolExecutor

    from spotlessgs.experiments.reproduce.tasks import render_room

    with ProcessPoolExecutor(1, mp_context=multiprocessing.get_context("spawn"), max_tasks_per_child=1) as pool:
        summary = pool.submit(render_room, str(SCENE), str(tmp_path / "d"), "uneven", 2, 64, 48, 4, 3, 1).result()
    assert summary["rendered"] == 2 and summary["complete"]
    assert (tmp_path / "d" / "transforms.json").is_file() and _leftovers(tmp_path / "d") == []


def test_start_of_run_clean_up_keeps_other_shards_files(tmp_path):
    """An unsharded run owns its folder and removes every leftover; a shard removes only its own frames' temporary
    files and its own scratch folder (other shards may be writing theirs)."""
    from simulator.render_pipeline import remove_leftovers, scratch_dir

    def plant() -> None:
        for k in range(4):
            for sub, ext in (("images", "png"), ("gt", "png"), ("exr", "exr")):
                (tmp_path / sub).mkdir(exist_ok=True)
                (tmp_path / sub / f".frame_{k:05d}.{ext}.partial-ab12cd.{ext}").write_bytes(b"x")
        (tmp_path / ".plan.json.partial-ab12cd.json").write_text("{")
        for shard in ((0, 2), (1, 2), (0, 1)):
            (scratch_dir(tmp_path, shard)).mkdir(exist_ok=True)
            (scratch_dir(tmp_path, shard) / "uneven.exr").write_bytes(b"x")
        (tmp_path / "images" / "frame_00001.png").write_bytes(b"a finished frame")

    plant()
    remove_leftovers(tmp_path, (1, 2), frames=[1, 3])
    left = _leftovers(tmp_path)
    assert not [p for p in left if "frame_00001" in p or "frame_00003" in p or "1of2" in p]
    assert len([p for p in left if "frame_00000" in p or "frame_00002" in p]) == 6
    assert ".plan.json.partial-ab12cd.json" in left and ".render-scratch-0of2" in left
    remove_leftovers(tmp_path, (0, 1), frames=range(4))
    assert _leftovers(tmp_path) == []
    assert (tmp_path / "images" / "frame_00001.png").read_bytes() == b"a finished frame"


def test_log_records_of_the_render_process_reach_the_parent_as_plain_records():
    """The child's log handler sends each record, message formatted and traceback as text, over its pipe: nothing
    in the record needs the child's objects to be rebuilt. The pipe is read with a timeout, so this cannot block."""
    import logging
    import multiprocessing

    from simulator.render_pipeline import _PipeLogHandler

    parent, child = multiprocessing.Pipe(duplex=True)
    logger = logging.getLogger("spotless-test.render-child")
    logger.propagate = False
    handler = _PipeLogHandler(child)
    logger.addHandler(handler)
    try:
        logger.warning("frame %d is black", 7)
        try:
            raise ValueError("bad face index 12")
        except ValueError:
            logger.exception("scene %s failed", "room.json")
    finally:
        logger.removeHandler(handler)
    received = []
    while parent.poll(5.0):
        received.append(parent.recv())
        if len(received) == 2:
            break
    assert [kind for kind, _ in received] == ["log", "log"]
    first, second = (record for _, record in received)
    assert (first.getMessage(), first.levelno, first.name) == ("frame 7 is black", logging.WARNING, logger.name)
    assert second.getMessage().startswith("scene room.json failed\nTraceback")
    assert "ValueError: bad face index 12" in second.getMessage()
    assert second.exc_info is None and second.args is None
    parent.close()
    child.close()
