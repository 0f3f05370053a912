"""How long a finished job's stage graph would take on N nodes, from the stage times its done-markers recorded.

Each marker holds the stage's wall time (``seconds``), its threads and its dependencies (``deps``). The projection
replays the graph on ``nodes`` identical nodes of ``slots`` stage slots each (``cores_per_node // threads``): a stage
starts as soon as its dependencies have finished and a slot is free, ready stages taking free slots longest remaining
chain first (the classic list-scheduling rule; a real scheduler does no better on average, Ray's first-come order can
do worse), and lasts its measured time times an optional scale factor per stage family (to carry measured rates to a
larger preset). Moving data between nodes and starting processes cost nothing here. The critical path (the longest
chain of dependent stages) is what no number of nodes can beat.
"""

from __future__ import annotations

import fnmatch
import heapq
from dataclasses import dataclass
from pathlib import Path
from typing import Iterable, Mapping, Sequence

from spotlessgs.io.atomic import PARTIAL_MARK
from spotlessgs.io.errors import InputError
from spotlessgs.io.json_files import read_json
from spotlessgs.jobs.graph import MARKER_DIR, topological_order


@dataclass(frozen=True)
class MeasuredStage:
    """A finished stage as its marker recorded it."""

    name: str
    seconds: float
    threads: int
    deps: tuple[str, ...]


@dataclass(frozen=True)
class Projection:
    """The replay of a graph on ``nodes`` nodes."""

    nodes: int
    slots_per_node: int
    wall_seconds: float  # when the last stage ends
    busy_fraction: float  # stage-seconds / (slots x wall time)
    critical_path_seconds: float
    critical_path: tuple[str, ...]


def read_measured_stages(root: str | Path) -> list[MeasuredStage]:
    """Every done-marker under ``root/.stages`` (InputError when there is none, or a marker has no ``deps``: it was
    written before 2026-11-25, when markers began to record them; rerun the job into a new folder)."""
    folder = Path(root) / MARKER_DIR
    stages = []
    for path in sorted(folder.rglob("*.json")):
        if PARTIAL_MARK in path.name:  # a killed write's temporary file, not a marker
            continue
        marker = read_json(path, "a stage's done-marker", required=("stage", "seconds"))
        if "deps" not in marker:
            raise InputError(f"{path}: this done-marker does not record its stage's dependencies (written before "
                             "2026-11-25); a projection needs a job run since")
        stage, seconds, threads, deps = marker["stage"], marker["seconds"], marker.get("threads", 1), marker["deps"]
        if (not isinstance(stage, str) or isinstance(seconds, bool) or not isinstance(seconds, (int, float))
                or not isinstance(threads, int) or threads < 1 or not isinstance(deps, list)
                or not all(isinstance(d, str) for d in deps) or not seconds >= 0):
            raise InputError(f"{path}: damaged done-marker: expected a stage name, seconds >= 0, a thread count >= 1 "
                             "and a list of dependency names")
        stages.append(MeasuredStage(stage, float(seconds), threads, tuple(deps)))
    if not stages:
        raise InputError(f"{folder}: no finished stage to project from")
    return stages


def scale_factor(name: str, scales: Mapping[str, float]) -> float:
    """The factor of the first ``scales`` pattern (fnmatch, e.g. ``render/*``) that matches ``name``, else 1."""
    for pattern, factor in scales.items():
        if fnmatch.fnmatchcase(name, pattern):
            return float(factor)
    return 1.0


def _ordered(stages: Sequence[MeasuredStage]) -> list[MeasuredStage]:
    """The stages in dependency order (the order the executors submit them), ties kept as given."""
    by_name = {s.name: s for s in stages}
    missing = sorted({d for s in stages for d in s.deps if d not in by_name})
    if missing:
        raise InputError(f"the finished stages depend on stages that have no marker: {missing}")
    return [by_name[name] for name in topological_order({s.name: s.deps for s in stages})]


def critical_path(stages: Sequence[MeasuredStage], scales: Mapping[str, float] = {}) -> tuple[float, list[str]]:
    """(length in seconds, stage names) of the longest chain of dependent stages."""
    finish: dict[str, float] = {}
    before: dict[str, str | None] = {}
    for stage in _ordered(stages):
        start, previous = 0.0, None
        for dep in stage.deps:
            if finish[dep] > start:
                start, previous = finish[dep], dep
        finish[stage.name] = start + stage.seconds * scale_factor(stage.name, scales)
        before[stage.name] = previous
    end = max(finish, key=finish.get)
    path = [end]
    while before[path[-1]] is not None:
        path.append(before[path[-1]])
    return finish[end], path[::-1]


def project(stages: Sequence[MeasuredStage], nodes: int, cores_per_node: int, threads: int | None = None,
            scales: Mapping[str, float] = {}) -> Projection:
    """Replay ``stages`` on ``nodes`` nodes of ``cores_per_node`` cores, each stage running ``threads`` threads (by
    default the most any marker recorded) and lasting its measured time times its scale factor."""
    if nodes < 1 or cores_per_node < 1:
        raise ValueError(f"nodes and cores per node must be at least 1, got {nodes} and {cores_per_node}")
    threads = threads or max(s.threads for s in stages)
    slots_per_node = max(1, cores_per_node // threads)
    order = _ordered(stages)
    duration = {s.name: s.seconds * scale_factor(s.name, scales) for s in order}
    dependents: dict[str, list[str]] = {s.name: [] for s in order}
    for s in order:
        for dep in s.deps:
            dependents[dep].append(s.name)
    remaining: dict[str, float] = {}  # the stage and the longest chain after it
    for s in reversed(order):
        remaining[s.name] = duration[s.name] + max((remaining[d] for d in dependents[s.name]), default=0.0)
    rank = {s.name: i for i, s in enumerate(sorted(order, key=lambda s: (-remaining[s.name], s.name)))}
    by_rank = {i: name for name, i in rank.items()}
    waiting = {s.name: set(s.deps) for s in order}
    ready = [rank[n] for n, deps in waiting.items() if not deps]
    heapq.heapify(ready)
    free, now, running = nodes * slots_per_node, 0.0, []  # running: heap of (end time, rank)
    while ready or running:
        while ready and free > 0:
            name = by_rank[heapq.heappop(ready)]
            heapq.heappush(running, (now + duration[name], rank[name]))
            free -= 1
        now, finished = heapq.heappop(running)
        free += 1
        for name in dependents[by_rank[finished]]:
            waiting[name].discard(by_rank[finished])
            if not waiting[name]:
                heapq.heappush(ready, rank[name])
    length, path = critical_path(stages, scales)
    total = sum(duration.values())
    return Projection(nodes, slots_per_node, now, total / (nodes * slots_per_node * now) if now > 0 else 0.0,
                      length, tuple(path))


def projection_table(stages: Sequence[MeasuredStage], node_counts: Iterable[int], cores_per_node: int,
                     threads: int | None = None, scales: Mapping[str, float] = {}) -> str:
    """A Markdown table of the projected wall time on each node count, and the critical path."""
    rows = [project(stages, n, cores_per_node, threads, scales) for n in node_counts]
    lines = ["| nodes | stage slots | projected wall time | busy | critical path |", "|---:|---:|---:|---:|---:|"]
    for p in rows:
        lines.append(f"| {p.nodes} | {p.nodes * p.slots_per_node} | {_minutes(p.wall_seconds)} | "
                     f"{100 * p.busy_fraction:.0f} % | {_minutes(p.critical_path_seconds)} |")
    durations = {s.name: s.seconds * scale_factor(s.name, scales) for s in stages}
    path = rows[0].critical_path if rows else ()
    lines += ["", "Critical path: " + " -> ".join(f"{name} ({_minutes(durations[name])})" for name in path)]
    return "\n".join(lines)


def _minutes(seconds: float) -> str:
    return f"{seconds / 60:.1f} min" if seconds < 3600 else f"{seconds / 3600:.1f} h"
