"""Graphs of resumable stages and the executors that run them: on this machine (a pool of 'spawn' processes) or on
a Ray cluster. ``spotless reproduce`` and ``spotless-sim render-many`` build a graph and call :func:`execute`.

Modules: ``graph`` (stages, their resources and done-markers), ``plan`` (what a run has to do, what it did),
``worker`` (one stage inside a worker process), ``local`` and ``ray_cluster`` (the executors), ``projection``
(wall time of a graph on N nodes from measured stage times).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Callable

from spotlessgs.jobs.graph import Stage, StageGraph, StageResources
from spotlessgs.jobs.local import execute_local, threads_per_job
from spotlessgs.jobs.plan import RunReport, StageFailedError

EXECUTORS = ("local", "ray")

__all__ = ["EXECUTORS", "ExecutorSpec", "RunReport", "Stage", "StageFailedError", "StageGraph", "StageResources",
           "execute", "threads_per_job"]


@dataclass(frozen=True)
class ExecutorSpec:
    """Where and how the stages run.

    Attributes:
        kind: ``local`` (worker processes on this machine) or ``ray`` (tasks on a Ray cluster).
        jobs: ``local``: stages run at once (Ray runs as many as the cluster's resources allow).
        threads: CPU threads per stage (None: ``max(1, cores // jobs)`` locally, 1 on Ray, where a stage asks for as
            many CPUs as it runs threads). Results depend on it: compare runs with the same value.
        ray_address: ``auto``, ``HOST:PORT`` or None (a private Ray instance on this machine).
        max_retries: Ray: runs of a stage whose worker or node died, after the first.
    """

    kind: str = "local"
    jobs: int = 1
    threads: int | None = None
    ray_address: str | None = "auto"
    max_retries: int = 3

    def __post_init__(self) -> None:
        if self.kind not in EXECUTORS:
            raise ValueError(f"unknown executor {self.kind!r}; choose one of {list(EXECUTORS)}")
        if self.jobs < 1:
            raise ValueError(f"jobs must be at least 1, got {self.jobs}")
        if self.threads is not None and self.threads < 1:
            raise ValueError(f"threads must be at least 1, got {self.threads}")

    def check(self) -> None:
        """Before anything is written: ImportError when the Ray executor has no Ray, ConnectionError when nothing
        answers at ``ray_address`` (HOST:PORT)."""
        if self.kind == "ray":
            from spotlessgs.jobs.ray_cluster import check_reachable, import_ray

            import_ray()
            check_reachable(self.ray_address)

    def stage_threads(self, cores: int | None = None) -> int:
        """The CPU threads each stage gets."""
        if self.threads is not None:
            return self.threads
        return threads_per_job(self.jobs, cores) if self.kind == "local" else 1


def execute(graph: StageGraph, root: str | Path, spec: ExecutorSpec = ExecutorSpec(),
            on_done: Callable[[str, dict | None], None] | None = None,
        raise_on_failure: bool = True) -> RunReport:
    """Run every unfinished stage of ``graph`` (done-markers under ``root``) with the executor ``spec`` names.

    ``on_done(name, summary)`` is called in this process as each stage ends (``summary`` None when it failed), e.g.
    to advance a progress bar.

    Raises:
        StageFailedError: naming each failed stage with its error, and the stages it blocked (with
        ``raise_on_failure`` False the report lists them instead).
    """
    if spec.kind == "ray":
        from spotlessgs.jobs.ray_cluster import RayOptions, execute_ray

        options = RayOptions(address=spec.ray_address, threads=spec.stage_threads(), max_retries=spec.max_retries)
        return execute_ray(graph, root, options, on_done=on_done, raise_on_failure=raise_on_failure)
    return execute_local(graph, root, jobs=spec.jobs, threads=spec.stage_threads(), on_done=on_done,
                         raise_on_failure=raise_on_failure)
