"""Output folders that never touch their inputs or someone else's files: a command refuses ``OUT`` equal to or inside
an input (and the reverse), and a folder that holds files but no record of the command's own earlier run, before it
writes anything."""

from __future__ import annotations

import os
from pathlib import Path
from typing import Mapping, Sequence

from spotlessgs.io.errors import InputError, OutputOverlapError


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


def refuse_foreign_folder(folder: str | os.PathLike, records: Sequence[str], option: str, what: str,
                          count_hidden: bool | Sequence[str] = False) -> None:
    """Raise unless ``folder`` is absent, empty, or holds one of ``records`` (a file name the command writes into
    every folder it makes): a folder with other files is someone else's, and the command would replace or mix with
    them.

    Args:
        folder: the output folder.
        records: the command's own record files (e.g. ``["reproduce.json"]``); any one of them marks an earlier run.
        option: how the user names the folder (``--out``, ``OUT_DIR``).
        what: what an earlier run's folder is, for the message (e.g. ``"a reproduction of known settings"``).
        count_hidden: which hidden entries (names starting with ``.``) count as files: all of them (True, for a
            command that replaces the whole folder), none (False), or the names listed (the command's own hidden
            state, e.g. ``[".stages"]``).

    Raises:
        InputError: ``folder`` is a file, or holds files but no record; the message names up to four of them.
    """
    path = Path(folder)
    if path.exists() and not path.is_dir():
        raise InputError(f"{folder}: {option} is a file, not a folder")
    if not path.is_dir() or any((path / name).is_file() for name in records):
        return
    names = sorted(p.name for p in path.iterdir() if not p.name.startswith(".") or count_hidden is True
                   or (count_hidden is not False and p.name in count_hidden))
    if names:
        shown = ", ".join(names[:4]) + (f" and {len(names) - 4} more" if len(names) > 4 else "")
        raise InputError(f"{folder}: holds files but no {' or '.join(records)} ({shown}): not {what}; choose an "
                         f"empty or new {option}")


def refuse_working_directory(output: str | os.PathLike, option: str) -> None:
    """Raise where ``output``, a folder that a command replaces whole (written beside it, then swapped in), is the
    current working directory or holds it: the swap would move the shell's folder away from under it.

    Raises:
        OutputOverlapError: naming the folder and the option.
    """
    cwd = _real(os.getcwd())
    if cwd.is_relative_to(_real(output)):
        raise OutputOverlapError(f"{output}: {option} is or holds the current directory ({cwd}); the command replaces "
                                 f"its whole output folder: choose a new folder for {option}")
