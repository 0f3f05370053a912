"""Run a :class:`StageGraph`: independent stages in parallel, each in its own fresh 'spawn' process.

A fresh process per stage (``max_tasks_per_child=1``) keeps Blender's ``bpy`` (one scene per process) isolated, makes
the process's peak resident memory the stage's own peak, and lets a crash take down one stage only. Each worker gets
``threads = max(1, cores // jobs)`` CPU threads (OMP/MKL environment and the stage's ``threads`` argument).
"""

from __future__ import annotations

import logging
import multiprocessing
import os
import resource
import signal
import time
from concurrent.futures import FIRST_COMPLETED, Future, ProcessPoolExecutor, wait
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from simulator.child_process import die_with_parent
from simulator.child_process import drop_blender_script_paths as _drop_blender_script_paths
from spotlessgs.io.signals import deferred_interrupts, raise_on_sigterm
from spotlessgs.experiments.reproduce.stages import (
    Stage, StageGraph, is_done, marker_path, prepare_retry, resolve, write_marker,
)

log = logging.getLogger(__name__)

_THREAD_ENV = ("OMP_NUM_THREADS", "MKL_NUM_THREADS", "OPENBLAS_NUM_THREADS")


class StageFailedError(RuntimeError):
    """One or more stages raised; their dependents were not run (finished stages keep their markers)."""


@dataclass
class RunReport:
    """What one execution did."""

    ran: list[str] = field(default_factory=list)  # stages run now, in completion order
    skipped: list[str] = field(default_factory=list)  # stages already done before this run
    failed: dict[str, str] = field(default_factory=dict)  # stage -> error message
    blocked: list[str] = field(default_factory=list)  # stages not run because a dependency failed
    retried: list[str] = field(default_factory=list)  # interrupted stages whose partial output was deleted


def threads_per_job(jobs: int, cores: int | None = None) -> int:
    """CPU threads for each of ``jobs`` parallel stages: max(1, cores // jobs)."""
    if jobs < 1:
        raise ValueError(f"jobs must be at least 1, got {jobs}")
    cores = cores if cores is not None else (os.cpu_count() or 1)
    return max(1, cores // jobs)


def _init_worker(threads: int) -> None:
    """Set the thread environment before the stage imports numpy/torch; tie the worker's life to the parent's;
    SIGTERM raises in the stage (so that its atomic writes remove their temporary files) instead of ending it."""
    for key in _THREAD_ENV:
        os.environ[key] = str(threads)
    _drop_blender_script_paths()
    die_with_parent(signal.SIGTERM)
    raise_on_sigterm()


# How often the scheduling loop looks for a stop request while stages run (seconds).
_POLL_SECONDS = 0.25


def _stop_workers(pool: ProcessPoolExecutor, grace_seconds: float = 5.0) -> None:
    """SIGTERM every worker of ``pool`` (their stages stop; unfinished stages have no marker and are redone on the
    next run), then SIGKILL those still alive after ``grace_seconds``. ``ProcessPoolExecutor`` has no public way to
    stop running tasks before Python 3.14, hence its ``_processes``; call it before ``pool.shutdown()``, which drops
    that table (with ``wait=False`` the pool's manager thread then fails on it)."""
    workers = list((getattr(pool, "_processes", None) or {}).values())
    for worker in workers:
        if worker.is_alive():
            worker.terminate()
    deadline = time.monotonic() + grace_seconds
    for worker in workers:
        worker.join(max(0.0, deadline - time.monotonic()))
        if worker.is_alive():
            worker.kill()


def run_stage(root: str, stage: Stage, threads: int) -> dict[str, Any]:
    """Worker entry: call the stage's function, then write its marker with wall time and peak memory.

    Returns:
        the marker's content: the function's summary under ``result``, ``seconds`` and ``peak_rss_mb`` (the worker
        process's peak resident set size, ru_maxrss).
    """
    function = resolve(stage.function)
    start = time.perf_counter()
    result = function(**stage.kwargs, threads=threads)
    summary = {
        "stage": stage.name,
        "result": result if result is not None else {},
        "seconds": time.perf_counter() - start,
        "peak_rss_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0,
        "threads": threads,
    }
    write_marker(Path(root), stage.name, summary)
    return summary


def execute(graph: StageGraph, root: str | Path, jobs: int = 1, cores: int | None = None) -> RunReport:
    """Run every unfinished stage of ``graph`` (markers under ``root``) and every stage that depends on one, at most
    ``jobs`` at a time.

    Raises:
        StageFailedError: naming each failed stage with its error, and the stages it blocked.
    """
    root = Path(root)
    threads = threads_per_job(jobs, cores)
    report = RunReport()
    stale: set[str] = set()
    for name in graph.order:
        if not is_done(root, name):
            stale.add(name)
            stale |= graph.dependents(name)  # results built on work that is redone are redone too
    pending = [name for name in graph.order if name in stale]
    report.skipped = [name for name in graph.order if name not in stale]
    for name in pending:
        marker_path(root, name).unlink(missing_ok=True)
    if not pending:
        return report
    done = set(report.skipped)
    running: dict[Future, str] = {}
    context = multiprocessing.get_context("spawn")
    with ProcessPoolExecutor(max_workers=jobs, mp_context=context, initializer=_init_worker, initargs=(threads,),
                             max_tasks_per_child=1) as pool:
        try:
            # Ctrl-C and SIGTERM only set stop.signum here and are raised at one safe point per round: raised inside
            # the pool's own code (submit spawning a worker, wait holding the futures' locks) they could leave a lock
            # held and the shutdown below waiting forever
            with deferred_interrupts() as stop:
                while pending or running:
                    for name in list(pending):
                        if len(running) >= jobs:
                            break
                        stage = graph[name]
                        if any(d in report.failed or d in report.blocked for d in stage.deps):
                            pending.remove(name)
                            report.blocked.append(name)
                            continue
                        if all(d in done for d in stage.deps):
                            pending.remove(name)
                            if prepare_retry(root, stage):
                                report.retried.append(name)
                                log.info("stage %s was interrupted: deleted %s, starting it again", name,
                                         stage.output)
                            log.info("start %s", name)
                            running[pool.submit(run_stage, str(root), stage, threads)] = name
                    if not running:
                        break
                    finished, _ = wait(list(running), timeout=_POLL_SECONDS, return_when=FIRST_COMPLETED)
                    stop.raise_if_requested()
                    for future in finished:
                        name = running.pop(future)
                        error = future.exception()
                        if error is None:
                            done.add(name)
                            report.ran.append(name)
                            log.info("done %s (%.1f s)", name, future.result()["seconds"])
                        else:
                            report.failed[name] = f"{type(error).__name__}: {error}"
                            log.error("stage %s failed: %s", name, report.failed[name])
        except BaseException:  # Ctrl-C, SIGTERM (spotlessgs.io.signals.Terminated) or a bug: stop every stage now
            _stop_workers(pool)  # first: shutdown() forgets the pool's processes
            pool.shutdown(wait=True, cancel_futures=True)
            raise
    report.blocked.extend(n for n in pending if n not in report.blocked)
    if report.failed:
        lines = [f"{name}: {msg}" for name, msg in report.failed.items()]
        blocked = f"; not run because of them: {report.blocked}" if report.blocked else ""
        raise StageFailedError(f"{len(report.failed)} stage(s) failed under {root}: " + " | ".join(lines) + blocked)
    return report
