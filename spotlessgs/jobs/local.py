"""Run a :class:`~spotlessgs.jobs.graph.StageGraph` on this machine: independent stages in parallel, each in its own
fresh 'spawn' process (``max_tasks_per_child=1``, see :mod:`spotlessgs.jobs.worker`).

Each worker gets ``threads`` CPU threads (by default ``max(1, cores // jobs)``; OMP/MKL environment and the stage's
``threads`` argument).
"""

from __future__ import annotations

import logging
import multiprocessing
import os
import time
from concurrent.futures import FIRST_COMPLETED, Future, ProcessPoolExecutor, wait
from pathlib import Path
from typing import Callable

from spotlessgs.io.signals import deferred_interrupts
from spotlessgs.jobs.graph import StageGraph
from spotlessgs.jobs.plan import RunReport, plan_run
from spotlessgs.jobs.worker import prepare_worker, run_stage

log = logging.getLogger(__name__)


def threads_per_job(jobs: int, cores: int | None = None) -> int:
    """CPU threads for each of ``jobs`` parallel stages: max(1, cores // jobs)."""
    if jobs < 1:
        raise ValueError(f"jobs must be at least 1, got {jobs}")
    cores = cores if cores is not None else (os.cpu_count() or 1)
    return max(1, cores // jobs)


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


def execute_local(graph: StageGraph, root: str | Path, jobs: int = 1, cores: int | None = None,
                  threads: int | None = None,
                  on_done: Callable[[str, dict | None], None] | None = None,
        raise_on_failure: bool = True) -> RunReport:
    """Run every unfinished stage of ``graph`` (markers under ``root``) and every stage that depends on one, at most
    ``jobs`` at a time, each with ``threads`` CPU threads (default :func:`threads_per_job`); ``on_done(name,
    summary)`` as each stage ends (``summary`` None when it failed).

    Raises:
        StageFailedError: naming each failed stage with its error, and the stages it blocked.
    """
    root = Path(root)
    threads = threads if threads is not None else threads_per_job(jobs, cores)
    if jobs < 1 or threads < 1:
        raise ValueError(f"jobs and threads must be at least 1, got {jobs} and {threads}")
    pending, report = plan_run(graph, root)
    if not pending:
        return report
    done = set(report.skipped)
    running: dict[Future, str] = {}
    context = multiprocessing.get_context("spawn")
    with ProcessPoolExecutor(max_workers=jobs, mp_context=context, initializer=prepare_worker, initargs=(threads,),
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
                            if future.result()["restarted"]:
                                report.retried.append(name)
                            log.info("done %s (%.1f s)", name, future.result()["seconds"])
                        else:
                            report.failed[name] = f"{type(error).__name__}: {error}"
                            log.error("stage %s failed: %s", name, report.failed[name])
                        if on_done is not None:
                            on_done(name, future.result() if error is None else None)
        except BaseException:  # Ctrl-C, SIGTERM (spotlessgs.io.signals.Terminated) or a bug: stop every stage now
            _stop_workers(pool)  # first: shutdown() forgets the pool's processes
            pool.shutdown(wait=True, cancel_futures=True)
            raise
    report.blocked.extend(n for n in pending if n not in report.blocked)
    if raise_on_failure:
        report.raise_if_failed(root)
    return report
