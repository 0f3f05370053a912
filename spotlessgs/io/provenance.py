"""How an output was made: command line, versions, seed, time. Recorded in every output folder."""

from __future__ import annotations

import datetime as _dt
import hashlib
import importlib.metadata
import os
import platform
import shlex
import sys
from typing import Any


def package_version(name: str) -> str | None:
    """Installed version of a distribution, or None when it is not installed."""
    try:
        return importlib.metadata.version(name)
    except importlib.metadata.PackageNotFoundError:
        return None


def sha256_file(path: str | os.PathLike, chunk: int = 1 << 20) -> str:
    """Hex sha256 of a file's content (read in chunks: checkpoints can be large)."""
    digest = hashlib.sha256()
    with open(path, "rb") as fh:
        while block := fh.read(chunk):
            digest.update(block)
    return digest.hexdigest()


def provenance(seed: int | None = None, extra_packages: tuple[str, ...] = (), **fields: Any) -> dict[str, Any]:
    """A JSON-serialisable record of the running command and environment.

    Args:
        seed: the command's seed, when it has one.
        extra_packages: distributions whose versions should be recorded besides spotlessgs, numpy and torch.
        **fields: anything else to record (e.g. ``blender_version``).
    """
    packages = {name: package_version(name) for name in ("spotlessgs", "numpy", "torch", *extra_packages)}
    record: dict[str, Any] = {
        "command": " ".join(shlex.quote(a) for a in sys.argv),
        "python": platform.python_version(),
        "platform": platform.platform(),
        "packages": {k: v for k, v in packages.items() if v is not None},
        "created_utc": _dt.datetime.now(_dt.timezone.utc).isoformat(timespec="seconds"),
    }
    if seed is not None:
        record["seed"] = int(seed)
    record.update(fields)
    return record
