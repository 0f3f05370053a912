"""One writer per folder: an advisory ``fcntl`` lock on ``FOLDER/.lock`` that names its holder.

A second process that wants to write the same run (``spotless train --out R`` twice, ``relight`` during training)
gets :class:`~spotlessgs.io.errors.FolderLockedError` naming the holder's command, process id and host instead of
mixing its files with the first one's. The kernel drops the lock when the holder exits, however it exits (also on
SIGKILL), so a stale ``.lock`` file never blocks anyone. Readers take no lock.
"""

from __future__ import annotations

import contextlib
import fcntl
import json
import os
import socket
from pathlib import Path
from typing import Iterator

from spotlessgs.io.errors import FolderLockedError, write_error

LOCK_NAME = ".lock"
# Folders this process holds (resolved path -> depth): a nested lock of the same folder (model selection's final run
# inside ``spotless train --model auto``) re-enters instead of blocking on its own holder.
_HELD: dict[Path, int] = {}


def _holder(lock_file: Path) -> str:
    try:
        info = json.loads(lock_file.read_text() or "{}")
    except (OSError, ValueError):
        return "another process"
    return f"`{info.get('command', '?')}` (process {info.get('pid', '?')} on host {info.get('host', '?')})"


@contextlib.contextmanager
def folder_lock(folder: str | os.PathLike, command: str) -> Iterator[Path]:
    """Hold the write lock of ``folder`` (created if needed) for the duration of the block.

    Args:
        folder: the folder to lock (a run, a dataset being written).
        command: what the holder is doing, shown to a second writer (e.g. ``spotless train``).

    Raises:
        FolderLockedError: another process holds the lock (names it).
    """
    folder = Path(folder)
    lock_file = folder / LOCK_NAME
    key = Path(os.path.realpath(folder))
    if key in _HELD:
        _HELD[key] += 1
        try:
            yield lock_file
        finally:
            _HELD[key] -= 1
        return
    try:
        folder.mkdir(parents=True, exist_ok=True)
        fd = os.open(lock_file, os.O_RDWR | os.O_CREAT, 0o666)
    except OSError as exc:
        raise (write_error(lock_file, exc) or exc) from exc
    try:
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            raise FolderLockedError(f"{folder}: in use by {_holder(lock_file)}; wait for it to finish or stop it "
                                    f"(the lock is {lock_file})") from None
        record = json.dumps({"pid": os.getpid(), "host": socket.gethostname(), "command": command})
        os.ftruncate(fd, 0)
        os.pwrite(fd, record.encode(), 0)
        _HELD[key] = 1
        try:
            yield lock_file
        finally:
            del _HELD[key]
            os.ftruncate(fd, 0)  # a later reader of a released lock finds no holder
            fcntl.flock(fd, fcntl.LOCK_UN)
    finally:
        os.close(fd)
