"""Nothing lost, nothing executed: safe checkpoints, outputs that never overwrite inputs, file modes, folder locks,
degenerate inputs, full disks and read-only folders, clean stops on SIGINT/SIGTERM, one-line CLI errors.

Every test drives the real code paths (the CLI through a subprocess or click's runner) on a tiny synthetic dataset
rendered by ray casting (no Blender).
"""

from __future__ import annotations

import hashlib
import os
import pickle
import shutil
import signal
import socket
import stat
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
import torch

from spotlessgs.io.errors import FolderLockedError, InputError, OutputOverlapError
from tests.conftest import synthetic_box_dataset

ROOT = Path(__file__).resolve().parents[1]
pytestmark = pytest.mark.usefixtures("one_torch_thread")


def _tiny_config(**overrides):
    from spotlessgs.training.config import preset

    base = dict(iterations=12, image_width=40, num_threads=1, densify_from=4, densify_until=10, densify_every=4,
                log_every=2, checkpoint_every=6, validation_blocks=0)
    base.update(overrides)
    return preset("tiny", **base)


@pytest.fixture(scope="module")
def box(tmp_path_factory) -> Path:
    return synthetic_box_dataset(tmp_path_factory, "reliability-box", seed=5)


@pytest.fixture(scope="module")
def trained(box, tmp_path_factory) -> Path:
    from spotlessgs.training.trainer import train

    run = tmp_path_factory.mktemp("reliability-run") / "run"
    train(box, run, "spotless", _tiny_config(), seed=0, progress=False)
    return run


def _cli(*args: str, cwd: Path | None = None, **kwargs) -> subprocess.CompletedProcess:
    """Run ``spotless ARGS`` in a fresh interpreter (signals, exit codes and stderr as a user sees them)."""
    env = {**os.environ, "PYTHONPATH": str(ROOT), "OMP_NUM_THREADS": "1"}
    return subprocess.run([sys.executable, "-m", "spotlessgs.cli", *args], capture_output=True, text=True,
                          cwd=cwd or ROOT, env=env, timeout=300, **kwargs)


def _last_line(text: str) -> str:
    return [line for line in text.strip().splitlines() if line.strip()][-1]


def _tree_digest(folder: Path) -> dict[str, str]:
    return {str(p.relative_to(folder)): hashlib.sha256(p.read_bytes()).hexdigest()
            for p in sorted(folder.rglob("*")) if p.is_file()}


# ---- 1. loading a checkpoint never runs code ------------------------------------------------------------------------


class _Exploit:
    """Unpickling this runs a shell command that creates ``marker`` (what a crafted ``last.pt`` did)."""

    def __init__(self, marker: Path) -> None:
        self.marker = marker

    def __reduce__(self):
        return (os.system, (f"touch {self.marker}",))


def _plant_malicious_checkpoint(run: Path, marker: Path) -> None:
    for old in (run / "checkpoints").glob("last.*"):
        old.unlink()
    with open(run / "checkpoints" / "last.pt", "wb") as fh:
        pickle.dump({"version": 1, "step": _Exploit(marker)}, fh)


def test_the_exploit_really_runs_code_when_unpickled(tmp_path):
    """The planted file is a real exploit: a plain unpickle (what weights_only=False did) runs its command."""
    marker = tmp_path / "pwned"
    pickle.loads(pickle.dumps(_Exploit(marker)))  # noqa: S301 - the point of the test
    assert marker.exists()


@pytest.mark.parametrize("entry", ["train --resume", "relight", "render", "export", "train --init-from",
                                   "baseline2d cyclegan"])
def test_a_malicious_checkpoint_is_refused_by_every_loader(entry, trained, box, tmp_path):
    run = tmp_path / "shared-run"
    shutil.copytree(trained, run)
    marker = tmp_path / "pwned"
    if entry == "baseline2d cyclegan":
        evil = tmp_path / "checkpoint.pt"
        with open(evil, "wb") as fh:
            pickle.dump({"format": "spotlessgs-cyclegan-v1", "step": _Exploit(marker)}, fh)
        result = _cli("baseline2d", "enhance", "cyclegan", str(box / "images"), str(tmp_path / "out"),
                      "--checkpoint", str(evil))
        named = str(evil)
    elif entry == "train --init-from":  # model selection's warm start reads another run's checkpoint
        from spotlessgs.training.trainer import train

        _plant_malicious_checkpoint(run, marker)
        with pytest.raises(InputError, match="cannot read this older-format checkpoint safely"):
            train(box, tmp_path / "warm", "spotless", _tiny_config(), progress=False, init_from=run)
        assert not marker.exists()
        return
    else:
        train_args = ["train", "--data", str(box), "--out", str(run), "--preset", "tiny", "--iterations", "4",
                      "--width", "40", "-q"]
        if entry == "train --resume":  # a run the CLI started, so that only the checkpoint differs
            shutil.rmtree(run)
            assert _cli(*train_args).returncode == 0
        _plant_malicious_checkpoint(run, marker)
        named = str(run / "checkpoints" / "last.pt")
        args = {
            "train --resume": [*train_args, "--resume"],
            "relight": ["relight", str(run), "--views", "test", "-q"],
            "render": ["render", str(run), "--views", "test", "-q"],
            "export": ["export", str(run), "--out", str(tmp_path / "model.ply")],
        }[entry]
        result = _cli(*args)
    assert not marker.exists(), "loading the checkpoint ran the planted command"
    assert result.returncode == 2, result.stderr
    line = _last_line(result.stderr)
    assert named in line and "checkpoint safely" in line and "could run code" in line, result.stderr
    assert "Traceback" not in result.stderr


def test_checkpoints_are_safetensors_and_round_trip_exactly(tmp_path):
    from spotlessgs.io.tensor_file import load_tree, save_tree

    tree = {
        "step": 7, "ratio": 0.1 + 0.2, "nan": float("nan"), "flag": True, "none": None, "name": "x",
        "gaussians": {"means": torch.randn(5, 3), "mask": torch.tensor([True, False])},
        "optimizer": {"state": {0: {"step": torch.tensor(3.0), "exp_avg": torch.rand(5, 3)}},
                      "param_groups": [{"lr": 1e-3, "betas": (0.9, 0.999), "params": [0]}]},
        "generator": torch.Generator().manual_seed(3).get_state(),
        "history": [1.5, float("inf")], "array": np.arange(6, dtype=np.int64).reshape(2, 3),
    }
    path = save_tree(tmp_path / "ckpt.safetensors", tree, "test-format")
    assert path.read_bytes()[8:9] == b"{"  # a safetensors header (JSON after an 8-byte length), not a pickle
    back = load_tree(path, "test-format")
    assert back["optimizer"]["state"][0]["step"].item() == 3.0 and 0 in back["optimizer"]["state"]
    assert back["optimizer"]["param_groups"][0]["betas"] == (0.9, 0.999)
    assert back["ratio"] == 0.1 + 0.2 and np.isnan(back["nan"]) and back["history"][1] == float("inf")
    assert torch.equal(back["gaussians"]["means"], tree["gaussians"]["means"])
    assert torch.equal(back["gaussians"]["mask"], tree["gaussians"]["mask"])
    assert torch.equal(back["generator"], tree["generator"])
    np.testing.assert_array_equal(back["array"], tree["array"])
    with pytest.raises(InputError, match="expected 'other'"):
        load_tree(path, "other")
    (tmp_path / "junk.safetensors").write_bytes(b"\x10\x00\x00\x00\x00\x00\x00\x00not json at all!")
    with pytest.raises(InputError, match="junk.safetensors: not a readable safetensors file"):
        load_tree(tmp_path / "junk.safetensors", "test-format")


def test_a_plain_older_checkpoint_still_loads_and_the_next_save_replaces_it(trained, tmp_path):
    """Runs of the previous version (``last.pt``: tensors and plain data) load with weights_only=True."""
    from spotlessgs.training.checkpoint import checkpoint_path, load_checkpoint, save_checkpoint

    run = tmp_path / "old-run"
    shutil.copytree(trained, run)
    state = load_checkpoint(run)
    checkpoint_path(run).unlink()
    torch.save(state, run / "checkpoints" / "last.pt")
    restored = load_checkpoint(run)
    assert torch.equal(restored["gaussians"]["means"], state["gaussians"]["means"])
    assert restored["optimizers"].keys() == state["optimizers"].keys()
    export = _cli("export", str(run), "--out", str(tmp_path / "model.ply"))
    assert export.returncode == 0, export.stderr
    save_checkpoint(run, {k: v for k, v in restored.items() if k != "version"})
    assert checkpoint_path(run).is_file() and not (run / "checkpoints" / "last.pt").exists()


# ---- 2. no command writes into its own input ----------------------------------------------------------------------


def test_enhance_refuses_to_overwrite_its_inputs(box, tmp_path):
    data = tmp_path / "data"
    shutil.copytree(box, data)
    before = _tree_digest(data)
    for out in (data / "images", data / "images" / "enhanced", data):
        result = _cli("baseline2d", "enhance", "clahe", str(data / "images"), str(out))
        assert result.returncode == 2, result.stderr
        assert "never writes into its own input" in result.stderr or "does not hold the input" in result.stderr
        assert "Traceback" not in result.stderr
    assert _tree_digest(data) == before
    ok = _cli("baseline2d", "enhance", "clahe", str(data / "images"), str(tmp_path / "clahe"))
    assert ok.returncode == 0, ok.stderr


def test_train_refuses_a_run_folder_inside_its_dataset(box, tmp_path):
    from spotlessgs.training.trainer import train

    data = tmp_path / "data"
    shutil.copytree(box, data)
    with pytest.raises(OutputOverlapError, match="inside the input --data"):
        train(data, data / "run", "3dgs", _tiny_config(), progress=False)
    with pytest.raises(OutputOverlapError, match="contains the input --data"):
        train(data, tmp_path, "3dgs", _tiny_config(), progress=False)
    assert not (data / "run").exists()


# ---- 6. file modes follow the umask ----------------------------------------------------------------------------


@pytest.mark.parametrize("umask, mode", [(0o022, 0o644), (0o002, 0o664), (0o077, 0o600)])
def test_written_files_get_the_mode_of_the_umask(tmp_path, umask, mode):
    from spotlessgs.io.atomic import write_json
    from spotlessgs.io.images import write_png
    from spotlessgs.training.checkpoint import save_checkpoint

    old = os.umask(umask)
    try:
        write_json(tmp_path / "a.json", {"x": 1})
        write_png(tmp_path / "a.png", np.zeros((4, 4, 3), np.float32))
        ckpt = save_checkpoint(tmp_path, {"step": 1, "gaussians": {"means": torch.zeros(2, 3)}})
    finally:
        os.umask(old)
    for path in (tmp_path / "a.json", tmp_path / "a.png", ckpt):
        assert stat.S_IMODE(path.stat().st_mode) == mode, path


# ---- 7. one writer per run folder ---------------------------------------------------------------------------------


def test_a_second_writer_is_refused_with_the_holders_pid_and_host(box, tmp_path):
    run = tmp_path / "run"
    holder = subprocess.Popen(
        [sys.executable, "-c", "import sys, time; from spotlessgs.io.folder_lock import folder_lock\n"
         f"with folder_lock({str(run)!r}, 'spotless train'):\n    print('held', flush=True); time.sleep(60)"],
        stdout=subprocess.PIPE, text=True, env={**os.environ, "PYTHONPATH": str(ROOT)})
    try:
        assert holder.stdout.readline().strip() == "held"
        result = _cli("train", "--data", str(box), "--out", str(run), "--preset", "tiny", "--iterations", "4",
                      "--width", "40", "-q")
        assert result.returncode == 1, result.stderr
        line = _last_line(result.stderr)
        assert f"process {holder.pid} on host {socket.gethostname()}" in line and str(run) in line, line
        assert not (run / "run.json").exists()
    finally:
        holder.kill()
        holder.wait()
    from spotlessgs.io.folder_lock import folder_lock

    with folder_lock(run, "test"):  # the kernel released the killed holder's lock
        with folder_lock(run, "nested in the same process"):
            pass


def test_the_lock_is_exclusive_between_processes(tmp_path):
    from spotlessgs.io.folder_lock import folder_lock

    code = ("from spotlessgs.io.folder_lock import folder_lock\n"
            f"with folder_lock({str(tmp_path)!r}, 'other'): pass")
    with folder_lock(tmp_path, "me"):
        other = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                               env={**os.environ, "PYTHONPATH": str(ROOT)})
        assert other.returncode != 0 and "FolderLockedError" in other.stderr and f"process {os.getpid()}" in \
            other.stderr
    assert FolderLockedError.__mro__[1] is RuntimeError


# ---- 8. degenerate input -----------------------------------------------------------------------------------------


def _dataset_with(box: Path, tmp_path: Path, make) -> Path:
    from spotlessgs.io.images import read_image, write_png

    data = tmp_path / "data"
    shutil.copytree(box, data)
    frames = sorted((data / "images").glob("*.png"))
    for k, path in enumerate(frames):
        image = make(k, read_image(path))
        if image is not None:
            write_png(path, image)
    return data


def test_all_black_frames_are_an_error_not_55_db(box, tmp_path):
    data = _dataset_with(box, tmp_path, lambda k, img: np.zeros_like(img))
    result = _cli("train", "--data", str(data), "--out", str(tmp_path / "run"), "--preset", "tiny",
                  "--iterations", "4", "--width", "40", "-q")
    assert result.returncode == 2, result.stderr
    assert "every training frame is black" in _last_line(result.stderr) and str(data) in result.stderr


def test_all_white_frames_are_an_error(box, tmp_path):
    from spotlessgs.training.data import load_training_views

    data = _dataset_with(box, tmp_path, lambda k, img: np.ones_like(img))
    with pytest.raises(InputError, match="every training frame is saturated"):
        load_training_views(data, 40)


def test_identical_frames_are_an_error(box, tmp_path):
    from spotlessgs.io.images import read_image
    from spotlessgs.training.data import load_training_views

    first = read_image(sorted((box / "images").glob("*.png"))[0])
    data = _dataset_with(box, tmp_path, lambda k, img: first)
    with pytest.raises(InputError, match="are the same image"):
        load_training_views(data, 40)


def test_some_black_frames_are_named_and_left_out(box, tmp_path, caplog):
    from spotlessgs.training.data import load_training_views

    data = _dataset_with(box, tmp_path, lambda k, img: np.zeros_like(img) if k in (1, 2) else None)
    reference = load_training_views(box, 40)
    with caplog.at_level("WARNING"):
        views = load_training_views(data, 40)
    names = [views.names[k] for k in (1, 2)]
    warning = [r.getMessage() for r in caplog.records if "black" in r.getMessage()]
    assert warning and all(n in warning[0] for n in names), caplog.text
    assert views.train == [k for k in reference.train if k not in (1, 2)]


# ---- 9. full disk, read-only folder: one line naming the file and the cause --------------------------------------


@pytest.fixture
def small_tmpfs(tmp_path):
    mount = tmp_path / "small"
    mount.mkdir()
    try:
        subprocess.run(["mount", "-t", "tmpfs", "-o", "size=400k", "tmpfs", str(mount)], check=True,
                       capture_output=True)
    except (OSError, subprocess.CalledProcessError) as exc:
        pytest.skip(f"cannot mount a small tmpfs here ({exc})")
    yield mount
    subprocess.run(["umount", "-l", str(mount)], check=False)


def test_a_full_disk_while_checkpointing_names_the_file_and_the_cause(box, small_tmpfs):
    run = small_tmpfs / "run"
    result = _cli("train", "--data", str(box), "--out", str(run), "--preset", "tiny", "--iterations", "12",
                  "--width", "40", "--max-gaussians", "4000", "-q")
    assert result.returncode == 1, result.stdout + result.stderr
    line = _last_line(result.stderr)
    assert "no space left on the device" in line and str(run) in line, result.stderr
    assert "Traceback" not in result.stderr and "unexpected pos" not in line
    assert not list(run.rglob(".*.partial-*")), "a temporary file survived"


def test_a_file_size_limit_names_the_file(box, tmp_path):
    """Without mount privileges: RLIMIT_FSIZE makes every larger write fail with EFBIG."""
    import resource

    def limit() -> None:
        signal.signal(signal.SIGXFSZ, signal.SIG_IGN)
        resource.setrlimit(resource.RLIMIT_FSIZE, (64_000, 64_000))

    run = tmp_path / "run"
    result = _cli("train", "--data", str(box), "--out", str(run), "--preset", "tiny", "--iterations", "12",
                  "--width", "40", "-q", preexec_fn=limit)
    assert result.returncode == 1, result.stderr
    line = _last_line(result.stderr)
    assert "cannot write" in line and str(run) in line and "file too large" in line, result.stderr
    assert not list(run.rglob(".*.partial-*"))


def test_a_read_only_file_system_names_the_file(box, small_tmpfs):
    subprocess.run(["mount", "-o", "remount,ro", str(small_tmpfs)], check=True)
    result = _cli("baseline2d", "enhance", "clahe", str(box / "images"), str(small_tmpfs / "out"))
    assert result.returncode == 1, result.stderr
    line = _last_line(result.stderr)
    assert "read-only file system" in line and str(small_tmpfs / "out") in line, result.stderr
    assert "Traceback" not in result.stderr


def test_a_folder_without_write_permission_names_the_file(tmp_path):
    """Root ignores file permissions, so the write runs in a child process that dropped to ``nobody``."""
    from spotlessgs.io.atomic import write_json
    from spotlessgs.io.errors import WriteError

    folder = tmp_path / "readonly"
    folder.mkdir()
    folder.chmod(0o555)
    os.chmod(tmp_path, 0o755)
    read, write = os.pipe()
    pid = os.fork()
    if pid == 0:  # child: drop privileges, try the write, report the message
        try:
            if os.geteuid() == 0:
                os.setgid(65534)
                os.setuid(65534)
            write_json(folder / "results.json", {"x": 1})
            message = "written"
        except WriteError as exc:
            message = f"WriteError: {exc}"
        except BaseException as exc:  # noqa: BLE001
            message = f"{type(exc).__name__}: {exc}"
        os.write(write, message.encode())
        os._exit(0)
    os.close(write)
    os.waitpid(pid, 0)
    message = os.read(read, 4096).decode()
    os.close(read)
    assert message == f"WriteError: {folder / 'results.json'}: cannot write: permission denied", message
    assert list(folder.iterdir()) == []


# ---- clean stops: SIGINT / SIGTERM during training ------------------------------------------------------------------


@pytest.mark.parametrize("signum, code", [(signal.SIGINT, 130), (signal.SIGTERM, 143)])
def test_training_stops_cleanly_on_a_signal_and_resumes_to_the_same_model(box, tmp_path, signum, code):
    from spotlessgs.training.checkpoint import load_checkpoint

    args = ["train", "--data", str(box), "--preset", "tiny", "--iterations", "400", "--width", "40", "--seed", "1",
            "--threads", "1", "-q"]
    env = {**os.environ, "PYTHONPATH": str(ROOT), "OMP_NUM_THREADS": "1"}
    run = tmp_path / "run"
    proc = subprocess.Popen([sys.executable, "-m", "spotlessgs.cli", *args, "--out", str(run)], env=env,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    deadline = time.time() + 120
    while time.time() < deadline and not (run / "metrics.jsonl").is_file() or \
            (run / "metrics.jsonl").stat().st_size == 0:
        assert proc.poll() is None, proc.communicate()
        time.sleep(0.05)
    proc.send_signal(signum)
    start = time.time()
    _out, err = proc.communicate(timeout=60)
    assert proc.returncode == code, err
    assert time.time() - start < 10
    assert "stopped by signal" in _last_line(err) and "Traceback" not in err
    step = load_checkpoint(run)["step"]
    assert 0 < step < 400 and step % 100 != 0 or step == 400, step  # saved where it stopped, not at a multiple
    assert not list(run.rglob(".*.partial-*"))
    resumed = _cli(*args, "--out", str(run), "--resume")
    assert resumed.returncode == 0, resumed.stderr
    whole = _cli(*args, "--out", str(tmp_path / "whole"))
    assert whole.returncode == 0, whole.stderr
    a, b = load_checkpoint(run), load_checkpoint(tmp_path / "whole")
    for name, tensor in b["gaussians"].items():
        torch.testing.assert_close(a["gaussians"][name], tensor, rtol=1e-5, atol=1e-6, msg=name)


# ---- smaller items ------------------------------------------------------------------------------------------------


@pytest.mark.parametrize("camera, match", [
    # k1 = -0.9 folds the image: the radius 0.8 of the corners maps back inside (d r_d / d r = 1 + 3 k1 r^2 < 0)
    ("1 OPENCV 64 48 50 50 32 24 -0.9 0 0 0", r"cameras\.txt: COLMAP camera 1: the opencv distortion .* cannot be inverted"),
    ("1 FOV 64 48 50 50 32 24 0.5", r"cameras\.txt: COLMAP camera 1: model FOV is not supported"),
])
def test_a_colmap_camera_we_cannot_use_names_cameras_txt(tmp_path, camera, match):
    from spotlessgs.io.dataset import read_dataset

    sparse = tmp_path / "sparse" / "0"
    sparse.mkdir(parents=True)
    (tmp_path / "images").mkdir()
    (sparse / "cameras.txt").write_text(camera + "\n")
    (sparse / "images.txt").write_text("1 1 0 0 0 0 0 0 1 a.png\n\n")
    (sparse / "points3D.txt").write_text("")
    with pytest.raises(ValueError, match=match):
        read_dataset(tmp_path)


def test_a_too_small_image_for_lpips_mentions_no_lpips():
    from evaluation.lpips import lpips

    with pytest.raises(ValueError, match="--no-lpips"):
        lpips(torch.rand(1, 3, 16, 16), torch.rand(1, 3, 16, 16))


def test_cli_errors_are_one_line_and_debug_shows_the_traceback(tmp_path):
    missing = tmp_path / "nothing"
    missing.mkdir()
    plain = _cli("relight", str(missing))
    assert plain.returncode == 2 and "Traceback" not in plain.stderr
    assert _last_line(plain.stderr) == f"spotlessgs.cli: error: {missing}: not a training run (no run.json)" or \
        _last_line(plain.stderr).endswith(f"error: {missing}: not a training run (no run.json)")
    debug = _cli("--debug", "relight", str(missing))
    assert debug.returncode == 2 and "Traceback" in debug.stderr
