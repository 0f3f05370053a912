"""One writer per folder: an advisory ``fcntl`` lock on ``FOLDER/.lock`` that names its holder.

A second process that wants to write the same run (``spotless train --out R`` twice, ``relight`` during training)
gets :class:`~spotlessgs.io.errors.FolderLockedError` naming the holder's command, process id and host instead of
mixing its files with the first one's. The kernel drops the lock when the holder exits, however it exits (also on
SIGKILL), so a stale ``.lock`` file never blocks anyone.

A reader that must not see a folder change under it (``spotless eval`` of a run into another folder, one shard of a
render among several) takes the lock *shared*: readers do not block each other, a writer blocks them all. A reader of
a folder it cannot write (a colleague's read-only run) and that no writer ever locked takes no lock.
"""

from __future__ import annotations

import contextlib
import errno
import fcntl
import json
import os
import socket
from pathlib import Path
from typing import Iterator

from spotlessgs.io.errors import FolderLockedError, write_error

LOCK_NAME = ".lock"
# Locks this process holds ((resolved folder, lock file name) -> depth): a nested lock of the same folder (model selection's final run
# inside ``spotless train --model auto``) re-enters instead of blocking on its own holder.
_HELD: dict[tuple[Path, str], int] = {}


def _holder(lock_file: Path) -> str:
    """Who holds ``lock_file``: the writer's record, else "another process (a reader ...)" (readers write none)."""
    try:
        info = json.loads(lock_file.read_text() or "{}")
    except (OSError, ValueError):
        info = {}
    if not isinstance(info, dict) or "pid" not in info:
        return "another process (a reader: relight, render, eval or a render shard)"
    return f"`{info.get('command', '?')}` (process {info.get('pid', '?')} on host {info.get('host', '?')})"


@contextlib.contextmanager
def folder_lock(folder: str | os.PathLike, command: str, *, shared: bool = False,
                name: str = LOCK_NAME) -> Iterator[Path]:
    """Hold the lock of ``folder`` (created if needed) for the duration of the block.

    Args:
        folder: the folder to lock (a run, a dataset being written).
        command: what the holder is doing, shown to a second writer (e.g. ``spotless train``).
        shared: a reader's lock: other shared holders are let in, an exclusive holder is not.
        name: the lock file's name in ``folder`` (one per independent writer, e.g. per render shard).

    Raises:
        FolderLockedError: another process holds the lock in a conflicting mode (names the writer).
    """
    folder = Path(folder)
    lock_file = folder / name
    key = (Path(os.path.realpath(folder)), name)
    if key in _HELD:
        _HELD[key] += 1
        try:
            yield lock_file
        finally:
            _HELD[key] -= 1
        return
    fd = _open_lock_file(folder, lock_file, shared)
    if fd is None:  # a read-only folder no writer ever locked: nothing can change it under this reader
        yield lock_file
        return
    try:
        try:
            fcntl.flock(fd, (fcntl.LOCK_SH if shared else fcntl.LOCK_EX) | fcntl.LOCK_NB)
        except BlockingIOError:
            raise FolderLockedError(f"{folder}: in use by {_holder(lock_file)}; wait for it to finish or stop it "
                                    f"(the lock is {lock_file})") from None
        if not shared:
            record = json.dumps({"pid": os.getpid(), "host": socket.gethostname(), "command": command})
            os.ftruncate(fd, 0)
            os.pwrite(fd, record.encode(), 0)
        _HELD[key] = 1
        try:
            yield lock_file
        finally:
            del _HELD[key]
            if not shared:
                os.ftruncate(fd, 0)  # a later reader of a released lock finds no holder
            fcntl.flock(fd, fcntl.LOCK_UN)
    finally:
        os.close(fd)


@contextlib.contextmanager
def source_and_output_locks(source: str | os.PathLike, out: str | os.PathLike, command: str) -> Iterator[None]:
    """The locks of a command that reads the folder ``source`` (a run) and writes the folder ``out``: ``source``
    exclusively when ``out`` lies inside it, else ``source`` shared (a colleague's read-only run can be read, and
    several such commands read one run at once) and ``out`` through its own lock file ``.<name>.lock`` beside it
    (two commands never write one ``out``).

    Raises:
        FolderLockedError: a conflicting holder of either lock (named).
    """
    real_source, real_out = Path(os.path.realpath(source)), Path(os.path.realpath(out))
    if real_out.is_relative_to(real_source):
        with folder_lock(source, command):
            yield
        return
    with folder_lock(source, command, shared=True), folder_lock(real_out.parent, command, name=f".{real_out.name}.lock"):
        yield


def _open_lock_file(folder: Path, lock_file: Path, shared: bool) -> int | None:
    """The lock file's descriptor (the folder and file created when missing); None for a reader of a folder it cannot
    write that has no lock file."""
    if shared:
        with contextlib.suppress(FileNotFoundError):
            return os.open(lock_file, os.O_RDONLY)
    try:
        folder.mkdir(parents=True, exist_ok=True)
        return os.open(lock_file, os.O_RDWR | os.O_CREAT, 0o666)
    except OSError as exc:
        if shared and exc.errno in (errno.EACCES, errno.EPERM, errno.EROFS):
            return None
        raise (write_error(lock_file, exc) or exc) from exc
