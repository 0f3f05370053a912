"""Output folders that never touch their inputs: a command refuses ``OUT`` equal to or inside an input (and the
reverse), before it writes anything."""

from __future__ import annotations

import os
from pathlib import Path
from typing import Mapping

from spotlessgs.io.errors import OutputOverlapError


def _real(path: str | os.PathLike) -> Path:
    """Absolute path with symbolic links resolved (also for parts that do not exist yet)."""
    return Path(os.path.realpath(os.path.abspath(os.fspath(path))))


def refuse_overlap(output: str | os.PathLike, inputs: Mapping[str, str | os.PathLike | None],
                   output_name: str = "output") -> None:
    """Raise unless ``output`` and every input are disjoint (neither equal to nor inside the other).

    Args:
        output: the folder (or file) the command writes.
        inputs: what it reads, by the name the user knows it under (e.g. ``{"--data": data_dir}``); None entries
            are skipped. An input *file* may sit inside the output folder only if it is the output itself, which is
            refused too.
        output_name: how the user names the output (``--out``, ``OUT``).

    Raises:
        OutputOverlapError: naming both paths and which contains which.
    """
    out = _real(output)
    for name, value in inputs.items():
        if value is None:
            continue
        src = _real(value)
        if out == src:
            raise OutputOverlapError(f"{output}: {output_name} is the same path as the input {name} ({value}); "
                                     "a command never writes into its own input: choose another output")
        if out.is_relative_to(src):
            raise OutputOverlapError(f"{output}: {output_name} is inside the input {name} ({value}); "
                                     "a command never writes into its own input: choose an output outside it")
        if src.is_relative_to(out):
            raise OutputOverlapError(f"{output}: {output_name} contains the input {name} ({value}); "
                                     "choose an output that does not hold the input")
