"""A small DAG of named stages, each with an output folder, its resource needs and an atomic done-marker.

A stage is a module-level function (so that a 'spawn' worker or a Ray worker can import it) called with keyword
arguments; it returns a JSON-able summary. The marker ``ROOT/.stages/<name>.json`` (written atomically after the
function returned) holds that summary plus the stage's wall time and peak resident memory. A stage with a marker is
done and is skipped; a stage without one that left an output folder behind was interrupted: with ``clean_on_retry``
its folder is deleted and it starts from scratch, otherwise the function is trusted to resume (the simulator's renders
skip finished frames, training continues from its checkpoint).
"""

from __future__ import annotations

import importlib
import logging
import re
import shutil
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Iterable, Mapping, Sequence

from spotlessgs.io.atomic import write_json
from spotlessgs.io.errors import InputError
from spotlessgs.io.json_files import read_json

log = logging.getLogger(__name__)

MARKER_DIR = ".stages"
_NAME = re.compile(r"^[A-Za-z0-9_.+\-/]+$")


@dataclass(frozen=True)
class StageResources:
    """What one stage needs of a machine, declared to a cluster scheduler (the Ray executor; the local executor
    gives every stage the same number of threads and ignores the rest).

    ``memory_mb`` is the stage's expected peak resident memory (None: not declared); ``gpu`` True marks a stage that
    can use a GPU (training): on a cluster that has GPUs it asks for one, so that it lands on a GPU node.
    """

    memory_mb: int | None = None
    gpu: bool = False

    def __post_init__(self) -> None:
        if self.memory_mb is not None and self.memory_mb <= 0:
            raise ValueError(f"StageResources.memory_mb must be positive, got {self.memory_mb}")


@dataclass(frozen=True)
class Stage:
    """One unit of work of the pipeline."""

    name: str  # unique id, e.g. "train/bedroom-uneven/spotless" (letters, digits, _ . + - /)
    function: str  # "package.module:function", called with ``kwargs`` in a worker process
    kwargs: dict[str, Any] = field(default_factory=dict)  # picklable keyword arguments
    deps: tuple[str, ...] = ()  # names of the stages that must be done first
    output: Path | None = None  # the folder this stage writes (deleted before a retry when clean_on_retry)
    clean_on_retry: bool = True  # False: the function resumes partial output itself
    resources: StageResources = field(default_factory=StageResources)

    def __post_init__(self) -> None:
        if not _NAME.match(self.name) or ".." in self.name or self.name.startswith("/"):
            raise ValueError(f"stage name {self.name!r} may only hold letters, digits and _ . + - / (no '..')")
        if ":" not in self.function:
            raise ValueError(f"stage {self.name}: function {self.function!r} must be 'package.module:function'")


def resolve(function: str) -> Callable[..., Any]:
    """Import ``package.module:function`` (ValueError naming it when it does not exist)."""
    module_name, _, attr = function.partition(":")
    try:
        return getattr(importlib.import_module(module_name), attr)
    except (ImportError, AttributeError) as exc:
        raise ValueError(f"stage function {function!r} cannot be imported: {exc}") from exc


def marker_path(root: Path, name: str) -> Path:
    """Where the done-marker of stage ``name`` lives."""
    return Path(root) / MARKER_DIR / f"{name}.json"


#: What a done-marker must hold to be read (:func:`spotlessgs.jobs.worker.run_stage` also writes ``stage``,
#: ``seconds`` and more).
MARKER_KEYS = ("result",)


def is_done(root: Path, name: str) -> bool:
    """True when stage ``name`` has finished: its marker exists and is whole (a marker damaged by hand, which no
    report could read, counts as not done: the stage runs again, with a warning naming the file)."""
    path = marker_path(root, name)
    if not path.is_file():
        return False
    try:
        read_marker(root, name)
    except InputError as exc:
        log.warning("%s; the stage runs again", exc)
        return False
    return True


def read_marker(root: Path, name: str) -> dict[str, Any]:
    """The summary recorded by a finished stage (FileNotFoundError naming the stage when it has not finished;
    InputError naming the marker when it is damaged)."""
    path = marker_path(root, name)
    if not path.is_file():
        raise FileNotFoundError(f"{path}: stage {name!r} has not finished")
    marker = read_json(path, "a stage's done-marker", MARKER_KEYS)
    seconds = marker.get("seconds", 0.0)
    if not isinstance(marker["result"], dict) or isinstance(seconds, bool) or not isinstance(seconds, (int, float)):
        raise InputError(f"{path}: damaged done-marker: 'result' must be a JSON object and 'seconds' a number")
    return marker


def write_marker(root: Path, name: str, summary: dict[str, Any]) -> None:
    """Mark stage ``name`` done (atomically) with its summary."""
    write_json(marker_path(root, name), summary)


def prepare_retry(root: Path, stage: Stage) -> bool:
    """Before running an unfinished stage: delete its partial output when ``clean_on_retry``.

    Returns:
        True when partial output was deleted.
    """
    if stage.clean_on_retry and stage.output is not None and Path(stage.output).exists():
        shutil.rmtree(stage.output)
        return True
    return False


def topological_order(deps: Mapping[str, Sequence[str]]) -> list[str]:
    """The names of ``deps`` (name -> the names it depends on, every one a key) such that each comes after its
    dependencies, ties in the mapping's order (ValueError naming a cycle)."""
    state: dict[str, int] = {}  # 1 = on the stack, 2 = placed
    order: list[str] = []

    def visit(name: str, path: list[str]) -> None:
        if state.get(name) == 2:
            return
        if state.get(name) == 1:
            cycle = path[path.index(name):] + [name]
            raise ValueError(f"stage dependencies form a cycle: {' -> '.join(cycle)}")
        state[name] = 1
        for dep in deps[name]:
            visit(dep, path + [name])
        state[name] = 2
        order.append(name)

    for name in deps:
        visit(name, [])
    return order


class StageGraph:
    """Stages in insertion order with their dependencies checked (unknown names, duplicates, cycles)."""

    def __init__(self, stages: Iterable[Stage]):
        self.stages: dict[str, Stage] = {}
        for stage in stages:
            if stage.name in self.stages:
                raise ValueError(f"stage {stage.name!r} is defined twice")
            self.stages[stage.name] = stage
        for stage in self.stages.values():
            missing = [d for d in stage.deps if d not in self.stages]
            if missing:
                raise ValueError(f"stage {stage.name!r} depends on unknown stage(s) {missing}")
        self.order = topological_order({name: stage.deps for name, stage in self.stages.items()})

    def __len__(self) -> int:
        return len(self.stages)

    def __getitem__(self, name: str) -> Stage:
        return self.stages[name]

    def dependents(self, name: str) -> set[str]:
        """Every stage that needs ``name``, directly or indirectly."""
        out: set[str] = set()
        frontier = [name]
        while frontier:
            current = frontier.pop()
            for stage in self.stages.values():
                if current in stage.deps and stage.name not in out:
                    out.add(stage.name)
                    frontier.append(stage.name)
        return out
