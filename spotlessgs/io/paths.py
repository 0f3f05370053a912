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


def refuse_run_file(output: str | os.PathLike, run_dir: str | os.PathLike, output_name: str,
                    may_replace: str | os.PathLike | None = None, own_suffix: str | None = None) -> None:
    """Raise where the output *file* ``output`` would replace a file of the run folder ``run_dir`` (its log, its
    summaries, a relit image): inside the run it may only be a new file directly in the run folder, a file directly
    in it with the suffix ``own_suffix`` (the command's own earlier output, e.g. ``.ply`` for an export), or lie
    inside the folder ``may_replace`` (a command's own output folder, e.g. ``RUN/eval``).

    Raises:
        OutputOverlapError: naming the file and what to choose instead.
    """
    out, run = _real(output), _real(run_dir)
    if not out.is_relative_to(run) or (may_replace is not None and out.is_relative_to(_real(may_replace))):
        return
    if out.parent == run and (not os.path.lexists(out) or (own_suffix is not None
                                                           and out.suffix.lower() == own_suffix)):
        return
    raise OutputOverlapError(f"{output}: {output_name} would replace a file of the run {run_dir} or write into one of "
                             "its folders; choose a path outside the run or a new file name in it")
