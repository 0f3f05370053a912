"""Atomic file writes: a reader never sees a half-written file, an interrupted write leaves the old one intact.

Temporary files are named ``.<name>.partial-<random><suffix>`` beside their target, so that a process killed with
SIGKILL (which runs no clean-up) leaves files that :func:`remove_partial_files` recognises and removes on the next
run. Finished files get the permissions the process's umask gives a new file (``mkstemp`` would leave 0600), their
data is synced to the disk before the rename (and the folder after it, where the file system allows), and a refused
write (full disk, quota, read-only, permission) raises one line naming the file and the cause.
"""

from __future__ import annotations

import contextlib
import json
import math
import os
import secrets
import shutil
import tempfile
import threading
from pathlib import Path
from typing import IO, Any, Iterator

from spotlessgs.io.errors import WriteError, write_error

#: Marks a temporary file of :func:`atomic_path` (see the module docstring).
PARTIAL_MARK = ".partial-"
_UMASK_LOCK = threading.Lock()
_UMASK_CACHE: list[int] = []  # the umask read by setting it (where /proc cannot tell), once per process


def _umask_from_proc() -> int | None:
    """The process's umask from ``/proc/self/status`` (Linux 4.7+), read without changing it; None where unknown."""
    try:
        with open("/proc/self/status", encoding="ascii", errors="replace") as fh:
            for line in fh:
                if line.startswith("Umask:"):
                    return int(line.split(":", 1)[1].strip(), 8)
    except (OSError, ValueError):
        pass
    return None


def current_umask() -> int:
    """The process's umask.

    On Linux it is read from ``/proc/self/status`` at every call (so it follows ``os.umask`` changes) and never
    modified. Elsewhere ``os.umask`` can only be read by setting it, which races with other threads creating files:
    that is done once per process, under a lock, and the value cached.
    """
    mask = _umask_from_proc()
    if mask is not None:
        return mask
    with _UMASK_LOCK:
        if not _UMASK_CACHE:
            mask = os.umask(0o022)
            os.umask(mask)
            _UMASK_CACHE.append(mask)
    return _UMASK_CACHE[0]


def new_file_mode() -> int:
    """The permission bits ``open(..., "w")`` would give a new file under the process's umask (0o666 & ~umask)."""
    return 0o666 & ~current_umask()


def remove_partial_files(folder: str | os.PathLike, recursive: bool = True) -> list[Path]:
    """Delete temporary files that an interrupted :func:`atomic_path` left in ``folder``; returns what was removed.

    Only call it where no other process is writing (a locked run folder, a render that owns its dataset folder).
    """
    folder = Path(folder)
    if not folder.is_dir():
        return []
    pattern = f".*{PARTIAL_MARK}*"
    found = folder.rglob(pattern) if recursive else folder.glob(pattern)
    removed = []
    for path in found:
        if path.is_file() and not path.is_symlink():
            with contextlib.suppress(FileNotFoundError):
                path.unlink()
                removed.append(path)
    return removed


@contextlib.contextmanager
def atomic_path(path: str | os.PathLike, suffix: str | None = None) -> Iterator[Path]:
    """Yield a temporary path next to ``path``; on success it is renamed onto ``path`` (atomic on POSIX).

    The temporary file keeps ``path``'s suffix (or ``suffix``) so that libraries which choose a format by extension
    (PIL, OpenEXR, Blender) write the right format. On an exception the temporary file is removed and ``path`` is left
    as it was.
    """
    path = Path(path)
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(prefix=f".{path.name}{PARTIAL_MARK}", suffix=suffix or path.suffix,
                                   dir=path.parent)
        os.close(fd)
    except OSError as exc:
        raise (write_error(path, exc) or exc) from exc
    tmp_path = Path(tmp)
    try:
        yield tmp_path
        os.chmod(tmp_path, new_file_mode())
        _fsync_file(tmp_path)  # the data is on disk before the name points at it (a crash never leaves it empty)
        os.replace(tmp_path, path)
    except BaseException as exc:
        with contextlib.suppress(FileNotFoundError):
            tmp_path.unlink()
        refused = write_error(path, exc) if _about_this_write(exc, tmp_path, path) else None
        if refused is not None:
            raise refused from exc
        raise
    _fsync_folder(path.parent)  # the rename itself survives a crash


def _fsync_file(path: Path) -> None:
    """Flush ``path``'s data to the disk."""
    fd = os.open(path, os.O_RDONLY)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


def _fsync_folder(folder: Path) -> None:
    """Flush ``folder``'s entries to the disk, best effort (some file systems and platforms cannot sync a folder)."""
    try:
        fd = os.open(folder, os.O_RDONLY)
    except OSError:
        return
    try:
        os.fsync(fd)
    except OSError:
        pass
    finally:
        os.close(fd)


def _about_this_write(exc: BaseException, tmp: Path, path: Path) -> bool:
    """Whether ``exc``, raised while writing ``tmp`` for ``path``, may be the write of that file being refused.

    An OSError that names another file (the block reading its source: ``shutil.copy2(src, tmp)`` with an unreadable
    ``src``) is not; nor is a :class:`WriteError` already naming its file, nor an interrupt.
    """
    if not isinstance(exc, Exception) or isinstance(exc, WriteError):
        return False
    if not isinstance(exc, OSError):
        return True
    ours = {os.path.abspath(tmp), os.path.abspath(path)}
    for name in (exc.filename, exc.filename2):
        if isinstance(name, (str, bytes, os.PathLike)) and os.path.abspath(os.fsdecode(name)) not in ours:
            return False
    return True


@contextlib.contextmanager
def atomic_open(path: str | os.PathLike, mode: str = "w", encoding: str | None = "utf-8") -> Iterator[IO[Any]]:
    """Open a temporary file for writing that replaces ``path`` atomically when the block exits cleanly."""
    if "b" in mode:
        encoding = None
    with atomic_path(path) as tmp, open(tmp, mode, encoding=encoding) as fh:
        yield fh  # closing flushes it; atomic_path syncs it to the disk before the rename


def to_jsonable(obj: Any) -> Any:
    """Recursively convert numpy scalars/arrays, tuples and paths to JSON types; NaN and ±inf become None."""
    import numpy as np

    if isinstance(obj, dict):
        return {str(k): to_jsonable(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [to_jsonable(v) for v in obj]
    if isinstance(obj, np.ndarray):
        return to_jsonable(obj.tolist())
    if isinstance(obj, (np.floating, float)):
        value = float(obj)
        return value if math.isfinite(value) else None
    if isinstance(obj, np.bool_):
        return bool(obj)
    if isinstance(obj, np.integer):
        return int(obj)
    if isinstance(obj, os.PathLike):
        return os.fspath(obj)
    return obj


def write_json(path: str | os.PathLike, obj: Any, indent: int = 2) -> None:
    """Write ``obj`` as JSON atomically (non-finite floats are rejected: JSON has no NaN)."""
    with atomic_open(path) as fh:
        json.dump(obj, fh, indent=indent, allow_nan=False)
        fh.write("\n")


def write_text(path: str | os.PathLike, text: str) -> None:
    """Write ``text`` atomically."""
    with atomic_open(path) as fh:
        fh.write(text)


def is_partial_name(name: str, target: str) -> bool:
    """Whether ``name`` is a temporary sibling of the folder ``target`` (see :func:`partial_sibling`)."""
    return name.startswith(f".{target}{PARTIAL_MARK}")


def partial_sibling(folder: str | os.PathLike, tag: str = "") -> Path:
    """A new, not yet existing, hidden temporary path beside ``folder`` (``.<name>.partial-<tag><random>``)."""
    folder = Path(folder)
    return folder.parent / f".{folder.name}{PARTIAL_MARK}{tag}{secrets.token_hex(6)}"


def _exchange(a: Path, b: Path) -> bool:
    """Swap two paths in one atomic step (Linux ``renameat2(RENAME_EXCHANGE)``); False where unsupported."""
    try:
        import ctypes

        renameat2 = ctypes.CDLL(None, use_errno=True).renameat2
    except (OSError, AttributeError):
        return False
    at_fdcwd, rename_exchange = -100, 2
    return renameat2(at_fdcwd, os.fsencode(a), at_fdcwd, os.fsencode(b), rename_exchange) == 0


def swap_in_folder(new: str | os.PathLike, target: str | os.PathLike) -> None:
    """Replace the folder ``target`` by the finished folder ``new`` (both in the same parent folder; ``target`` may be
    missing). A reader sees the old folder, then the new one (where the system cannot exchange two folders atomically:
    for an instant none in between), never a mix of both. Where the process dies between the two renames, the old
    folder is left as the sibling ``partial_sibling(target, "old-")``."""
    new, target = Path(new), Path(target)
    if target.is_dir() and not target.is_symlink():
        if _exchange(new, target):
            shutil.rmtree(new, ignore_errors=True)  # now the old folder
            return
        old = partial_sibling(target, "old-")
        os.rename(target, old)
        try:
            os.rename(new, target)
        except BaseException:
            os.rename(old, target)
            raise
        shutil.rmtree(old, ignore_errors=True)
    else:
        if target.is_symlink():
            target.unlink()
        os.rename(new, target)
