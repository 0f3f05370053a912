"""What runs inside an executor's worker process: its set-up, and one stage from start to done-marker.

Every executor runs a stage in a fresh process of its own (a 'spawn' pool worker, or a Ray worker that runs one task
and exits), so that Blender's ``bpy`` (one scene per process) stays isolated, the process's peak resident memory is the
stage's own, and a crash takes down one stage only.
"""

from __future__ import annotations

import logging
import os
import resource
import signal
import time
from pathlib import Path
from typing import Any

from spotlessgs.io.processes import die_with_parent, drop_blender_script_paths
from spotlessgs.io.signals import raise_on_sigterm
from spotlessgs.jobs.graph import Stage, prepare_retry, resolve, write_marker

log = logging.getLogger(__name__)

#: Environment variables that set the thread count of OpenMP, MKL and OpenBLAS (read when numpy/torch load).
THREAD_ENV = ("OMP_NUM_THREADS", "MKL_NUM_THREADS", "OPENBLAS_NUM_THREADS")


def thread_environment(threads: int) -> dict[str, str]:
    """The environment variables that give a worker ``threads`` CPU threads."""
    if threads < 1:
        raise ValueError(f"threads must be at least 1, got {threads}")
    return {key: str(threads) for key in THREAD_ENV}


def prepare_worker(threads: int, stop_on_sigterm: bool = True) -> None:
    """Set the thread environment before the stage imports numpy/torch and tie the worker's life to its parent's.

    ``stop_on_sigterm`` (the local pool's workers): the parent's death and SIGTERM raise in the stage, which stops
    like on Ctrl-C (its atomic writes remove their temporary files). A Ray worker passes False: a SIGTERM there means
    that its node is going away, which Ray must see as a lost worker (and run the stage again elsewhere), not as a
    stage that stopped itself (which Ray would report as cancelled); it dies with its raylet.
    """
    os.environ.update(thread_environment(threads))
    drop_blender_script_paths()
    if stop_on_sigterm:
        die_with_parent(signal.SIGTERM)
        raise_on_sigterm()
    else:
        die_with_parent(signal.SIGKILL)


def run_stage(root: str, stage: Stage, threads: int) -> dict[str, Any]:
    """Run one stage: delete the partial output an interrupted earlier attempt left (when ``stage.clean_on_retry``),
    call the stage's function, then write its done-marker with wall time and peak memory.

    Returns:
        the marker's content: the function's summary under ``result``, ``seconds``, ``peak_rss_mb`` (the worker
        process's peak resident set size, ru_maxrss), ``threads``, ``restarted`` (True when partial output of an
        interrupted attempt was deleted first), ``host`` and ``deps`` (the stage's dependencies).
    """
    restarted = prepare_retry(Path(root), stage)
    if restarted:
        log.info("stage %s was interrupted: deleted %s, starting it again", stage.name, stage.output)
    function = resolve(stage.function)
    start = time.perf_counter()
    result = function(**stage.kwargs, threads=threads)
    summary = {
        "stage": stage.name,
        "result": result if result is not None else {},
        "seconds": time.perf_counter() - start,
        "peak_rss_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0,
        "threads": threads,
        "restarted": restarted,
        "host": os.uname().nodename,
        "deps": list(stage.deps),  # what a projection onto N nodes replays (spotlessgs.jobs.projection)
    }
    write_marker(Path(root), stage.name, summary)
    return summary
