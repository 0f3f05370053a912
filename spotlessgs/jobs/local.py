"""Run a :class:`~spotlessgs.jobs.graph.StageGraph` on this machine: independent stages in parallel, each in a fresh
'spawn' process of its own (see :mod:`spotlessgs.jobs.worker`), so that a worker that dies (killed for memory, a
crash in native code) fails its own stage only: the others run on and its dependents are reported as blocked.

Each worker gets ``threads`` CPU threads (by default ``max(1, cores // jobs)``; OMP/MKL environment and the stage's
``threads`` argument). A stage's result or error comes back through a pipe; an error's traceback is logged at debug
level (``spotless -v``) beside its one-line message.
"""

from __future__ import annotations

import logging
import multiprocessing
import os
import signal
import time
import traceback
from dataclasses import dataclass
from multiprocessing.connection import Connection, wait
from pathlib import Path
from typing import Any, Callable

from spotlessgs.io.signals import deferred_interrupts
from spotlessgs.jobs.graph import Stage, StageGraph
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
# How long a worker that sent its result may take to exit before it is stopped (seconds).
_EXIT_SECONDS = 60.0


def _worker_main(sender: Connection, root: str, stage: Stage, threads: int) -> None:
    """A stage's process: set up, run the stage, send ``("done", summary)`` or ``("failed", message, traceback)``."""
    prepare_worker(threads)
    try:
        message: tuple = ("done", run_stage(root, stage, threads))
    except BaseException as exc:  # noqa: BLE001 - every failure goes back to the parent, which decides
        message = ("failed", f"{type(exc).__name__}: {exc}", traceback.format_exc())
    try:
        sender.send(message)
    finally:
        sender.close()


@dataclass
class _Worker:
    """A running stage's process and the end of its pipe that the parent reads."""

    process: Any  # multiprocessing.context.SpawnProcess
    receiver: Connection


def _death(exitcode: int | None) -> str:
    """Why a worker that sent nothing ended, from its exit code (a negative one is the signal that killed it)."""
    if exitcode is not None and exitcode < 0:
        try:
            name = signal.Signals(-exitcode).name
        except ValueError:
            name = f"signal {-exitcode}"
        hint = " (killed: perhaps the machine ran out of memory)" if -exitcode == signal.SIGKILL else ""
        return f"WorkerDied: the stage's process was ended by {name}{hint}"
    return f"WorkerDied: the stage's process exited with code {exitcode} before reporting a result"


def _outcome(worker: _Worker) -> tuple[dict | None, str | None, str | None]:
    """(summary, error, traceback) of a worker whose pipe or process is ready; the process is reaped."""
    message = None
    if worker.receiver.poll():
        try:
            message = worker.receiver.recv()
        except (EOFError, OSError):  # it closed its end without sending: it died
            message = None
    worker.process.join(_EXIT_SECONDS if message is not None else None)
    if worker.process.is_alive():  # sent its result but hangs on exit (a stray non-daemon thread)
        worker.process.kill()
        worker.process.join()
    worker.receiver.close()
    if message is None:
        return None, _death(worker.process.exitcode), None
    if message[0] == "done":
        return message[1], None, None
    return None, message[1], message[2]


def _stop_workers(workers: list[_Worker], grace_seconds: float = 5.0) -> None:
    """SIGTERM every running worker (their stages stop; unfinished stages have no marker and are redone on the next
    run), then SIGKILL those still alive after ``grace_seconds``."""
    for worker in workers:
        if worker.process.is_alive():
            worker.process.terminate()
    deadline = time.monotonic() + grace_seconds
    for worker in workers:
        worker.process.join(max(0.0, deadline - time.monotonic()))
        if worker.process.is_alive():
            worker.process.kill()
            worker.process.join()
        worker.receiver.close()


def execute_local(graph: StageGraph, root: str | Path, jobs: int = 1, cores: int | None = None,
                  threads: int | None = None,
                  on_done: Callable[[str, dict | None], None] | None = None,
                  raise_on_failure: bool = True) -> RunReport:
    """Run every unfinished stage of ``graph`` (markers under ``root``) and every stage that depends on one, at most
    ``jobs`` at a time, each with ``threads`` CPU threads (default :func:`threads_per_job`); ``on_done(name,
    summary)`` as each stage ends (``summary`` None when it failed).

    Raises:
        StageFailedError: naming each failed stage with its error (a worker that died: the signal), and the stages
            it blocked.
    """
    root = Path(root)
    threads = threads if threads is not None else threads_per_job(jobs, cores)
    if jobs < 1 or threads < 1:
        raise ValueError(f"jobs and threads must be at least 1, got {jobs} and {threads}")
    pending, report = plan_run(graph, root)
    if not pending:
        return report
    done = set(report.skipped)
    running: dict[str, _Worker] = {}
    context = multiprocessing.get_context("spawn")
    try:
        # Ctrl-C and SIGTERM only set stop.signum here and are raised at one safe point per round, never half-way
        # through starting a worker
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
                        receiver, sender = context.Pipe(duplex=False)
                        process = context.Process(target=_worker_main, args=(sender, str(root), stage, threads),
                                                  name=f"stage {name}")
                        running[name] = _Worker(process, receiver)
                        process.start()
                        sender.close()  # the child holds the other copy: its death closes the pipe
                if not running:
                    break
                handles = {w.receiver: n for n, w in running.items()}
                handles.update({w.process.sentinel: n for n, w in running.items()})
                ready = {handles[h] for h in wait(list(handles), timeout=_POLL_SECONDS)}
                stop.raise_if_requested()
                for name in [n for n in running if n in ready]:
                    summary, error, trace = _outcome(running.pop(name))
                    if error is None:
                        done.add(name)
                        report.ran.append(name)
                        if summary["restarted"]:
                            report.retried.append(name)
                        log.info("done %s (%.1f s)", name, summary["seconds"])
                    else:
                        report.failed[name] = error
                        log.error("stage %s failed: %s", name, error)
                        if trace:
                            log.debug("stage %s traceback:\n%s", name, trace)
                    if on_done is not None:
                        on_done(name, summary)
    except BaseException:  # Ctrl-C, SIGTERM (spotlessgs.io.signals.Terminated) or a bug: stop every stage now
        _stop_workers(list(running.values()))
        raise
    report.blocked.extend(n for n in pending if n not in report.blocked)
    if raise_on_failure:
        report.raise_if_failed(root)
    return report
