"""Errors that are a user's doing (bad file, bad value, busy folder), as opposed to bugs.

The command-line layer prints these as one line naming the file and the problem and exits non-zero; anything else is
an internal error and keeps its traceback. Library code raises them; it never prints or exits.
"""

from __future__ import annotations

import errno
import os
import re


class InputError(ValueError):
    """A bad input file, folder or value; the message names the file and the problem (exit code 2)."""


class OutputOverlapError(InputError):
    """A command was asked to write into its own input (or to read from its own output)."""


class FolderLockedError(RuntimeError):
    """Another process is writing the same folder; the message names its process id and host (exit code 1)."""


class WriteError(OSError):
    """A file could not be written (disk full, quota, read-only file system, permission); names the file and cause.

    ``errno`` is the OS's code; the message is the whole story (``FILE: cannot write: CAUSE``).
    """

    def __str__(self) -> str:
        return str(self.strerror)


#: errno values that mean "the machine refused the write", each with the cause said in words.
_WRITE_CAUSES = {
    errno.ENOSPC: "no space left on the device",
    errno.EDQUOT: "disk quota exceeded",
    errno.EROFS: "read-only file system",
    errno.EACCES: "permission denied",
    errno.EPERM: "operation not permitted",
    errno.EFBIG: "file too large for the file system or the process's file-size limit",
}


def write_error(path: str | os.PathLike, exc: BaseException) -> WriteError | None:
    """A one-line :class:`WriteError` for ``path`` when ``exc`` is a refused write, else None.

    Libraries often hide ENOSPC behind their own message (torch: "unexpected pos 621248 vs 621136", PIL: "cannot write
    mode RGB"); when the folder has (almost) no free space left such an error (an OSError, or a message that reads
    like a failed write) is said to be the full disk. Programming errors (TypeError, KeyError, ...) never are.
    """
    code = getattr(exc, "errno", None)
    if code is None:  # libraries written in Rust or C++ (safetensors, OpenEXR) put the OS error in their message
        found = re.search(r"os error (\d+)|\[Errno (\d+)\]", str(exc))
        code = int(found.group(1) or found.group(2)) if found else None
    if code in _WRITE_CAUSES:
        return WriteError(code, f"{os.fspath(path)}: cannot write: {_WRITE_CAUSES[code]}")
    if _may_hide_a_failed_write(exc) and _nearly_full(path):
        return WriteError(errno.ENOSPC, f"{os.fspath(path)}: cannot write: no space left on the device ({exc})")
    return None


#: Exceptions that are programming errors: never relabelled as a full disk, whatever their message says.
_BUG_TYPES = (TypeError, AttributeError, NameError, LookupError, AssertionError, ArithmeticError, RecursionError,
              NotImplementedError)
#: How libraries word a write that the OS refused (torch: "unexpected pos", "file write failed"; Rust: "os error
#: 28", "IoError", "StorageFull"; PIL: "cannot write mode").
_WRITE_FAILURE_WORDS = re.compile(r"write|unexpected pos|os error|ioerror|i/o error|errno|no space|storagefull",
                                  re.IGNORECASE)


def _may_hide_a_failed_write(exc: BaseException) -> bool:
    """Whether ``exc`` can be a refused write in disguise: an OSError, or a library's error worded like one."""
    if isinstance(exc, OSError):
        return True
    if isinstance(exc, (*_BUG_TYPES, InputError, FolderLockedError)):  # a bug, or the user's error: said as it is
        return False
    return bool(_WRITE_FAILURE_WORDS.search(str(exc)))


def _nearly_full(path: str | os.PathLike, margin_bytes: int = 1 << 20) -> bool:
    """Whether the file system that holds ``path`` has less than ``margin_bytes`` free (False when unknown)."""
    folder = os.path.dirname(os.path.abspath(os.fspath(path))) or "."
    while folder and not os.path.isdir(folder):
        folder = os.path.dirname(folder)
    try:
        stats = os.statvfs(folder)
    except OSError:
        return False
    return stats.f_bavail * stats.f_frsize < margin_bytes
