"""Run a :class:`~spotlessgs.jobs.graph.StageGraph` on a Ray cluster (``pip install 'spotlessgs[cluster]'``).

Every unfinished stage becomes one Ray task, submitted at once in dependency order: a stage's dependencies are passed
to its task as object refs, so Ray starts it when they have finished and never if one of them failed. Each task
declares what it needs: ``threads`` CPUs, the stage's expected peak memory and, for a stage that can use a GPU
(training) on a cluster that has GPUs, one GPU. A task runs in a fresh worker process that exits after it
(``max_calls=1``; see :mod:`spotlessgs.jobs.worker`), with the thread environment set by its ``runtime_env``.

Faults: a worker or node that dies while a stage runs makes Ray run the task again elsewhere (``max_retries``); the
stage then resumes from what it wrote (renders skip finished frames, training continues from its checkpoint) or,
when it cannot resume (``clean_on_retry``), starts again from scratch. An exception raised by the stage itself is not
retried: the stage is reported failed with its error, its dependents blocked, and everything else still runs. The
driver waits on the tasks' results (``ray.wait``), not on files; Ctrl-C or SIGTERM cancels every task, and a rerun
skips the stages that have their done-markers.

The output folder must be on a filesystem that every node sees at the same path (NFS, Lustre, ...): the stages read
their inputs from it and write their outputs and done-markers to it.
"""

from __future__ import annotations

import logging
import math
import os
import socket
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable

from spotlessgs.io.signals import deferred_interrupts
from spotlessgs.jobs.graph import Stage, StageGraph
from spotlessgs.jobs.plan import RunReport, plan_run
from spotlessgs.jobs.worker import prepare_worker, run_stage, thread_environment

log = logging.getLogger(__name__)

#: The message when Ray is not installed.
RAY_MISSING = "the Ray executor needs Ray: pip install 'spotlessgs[cluster]' (or pip install 'ray[default]')"
# How long one wait for a finished task lasts before the driver looks for Ctrl-C / SIGTERM (seconds).
_WAIT_SECONDS = 0.5


@dataclass(frozen=True)
class RayOptions:
    """How to use the cluster.

    Attributes:
        address: the cluster to join: ``auto`` (the one this machine belongs to, or ``$RAY_ADDRESS``), ``HOST:PORT``
            of its head node, or None to start a private single-machine Ray instance for this execution.
        threads: CPU threads of every stage, and the CPUs its task asks for (results depend on the thread count:
            docs/results.md, "Determinism").
        max_retries: how often a stage whose worker or node died is run again.
    """

    address: str | None = "auto"
    threads: int = 1
    max_retries: int = 3

    def __post_init__(self) -> None:
        if self.threads < 1:
            raise ValueError(f"threads must be at least 1, got {self.threads}")
        if self.max_retries < 0:
            raise ValueError(f"max_retries must be >= 0, got {self.max_retries}")


def import_ray():
    """The ``ray`` module, or ImportError with the install command."""
    try:
        import ray
    except ImportError as exc:
        raise ImportError(RAY_MISSING) from exc
    return ray


def _ray_stage(root: str, stage: Stage, threads: int, *finished_dependencies: dict[str, Any]) -> dict[str, Any]:
    """The Ray task of one stage (its dependencies' summaries arrive as arguments only to order the tasks)."""
    del finished_dependencies
    prepare_worker(threads, stop_on_sigterm=False)
    return run_stage(root, stage, threads)


def task_options(stage: Stage, threads: int, max_retries: int, cluster_gpus: float) -> dict[str, Any]:
    """The Ray options of ``stage``'s task: its resources, retries, name and thread environment."""
    options: dict[str, Any] = {
        "num_cpus": threads,
        "num_gpus": 1 if stage.resources.gpu and cluster_gpus >= 1 else 0,
        "max_retries": max_retries,
        "retry_exceptions": False,
        "name": stage.name,
        "runtime_env": {"env_vars": thread_environment(threads)},
    }
    if stage.resources.memory_mb is not None:
        options["memory"] = int(stage.resources.memory_mb) * 1024 * 1024
    return options


#: Seconds to wait for a head node's port to accept a connection before saying that no cluster is there (Ray's own
#: connection attempts go on for minutes).
CONNECT_TIMEOUT_S = 5.0


def auto_address() -> str | None:
    """Where ``--ray-address auto`` connects: ``$RAY_ADDRESS``, else the cluster that ``ray start`` last began on this
    machine (Ray's own record of it), else None (no cluster to join). Ray's reader of that record is private: where
    it is missing the answer is ``auto`` itself (not probed)."""
    if os.environ.get("RAY_ADDRESS"):
        return os.environ["RAY_ADDRESS"]
    try:
        from ray._private.utils import read_ray_address
    except ImportError:
        return "auto"
    return read_ray_address() or None


def check_reachable(address: str | None, timeout: float = CONNECT_TIMEOUT_S) -> None:
    """ConnectionError naming ``address`` (``HOST:PORT``; ``auto``: see :func:`auto_address`) when nothing accepts
    a connection there within ``timeout`` seconds; None (a private instance this process starts) is not probed."""
    if address == "auto":
        found = auto_address()
        if found is None:
            raise ConnectionError("--ray-address auto: no Ray cluster to join (RAY_ADDRESS is not set and no `ray "
                                  "start` ran on this machine); start one with `ray start --head`, or give "
                                  "--ray-address HOST:PORT, or --ray-address local for a private instance")
        address = found
    if address in (None, "auto") or "://" in str(address):
        return
    host, _, port = str(address).rpartition(":")
    if not host or not port.isdigit():
        raise ValueError(f"--ray-address {address!r} is not HOST:PORT, auto or local")
    try:
        socket.create_connection((host, int(port)), timeout=timeout).close()
    except OSError as exc:
        raise ConnectionError(f"{address}: no Ray cluster answers there ({exc}); start its head node with `ray start "
                              f"--head --port {port}` or give the right --ray-address") from exc


def _connect(ray, address: str | None) -> bool:
    """Join the cluster at ``address`` (or start a private instance); True when this call started the connection."""
    if ray.is_initialized():
        return False
    check_reachable(address)
    # "local", not None: with None Ray joins $RAY_ADDRESS or the last cluster started on this machine
    ray.init(address=address if address is not None else "local", log_to_driver=True,
             logging_level=logging.WARNING, configure_logging=False)
    return True


def _alive_nodes(ray) -> list[dict[str, float]]:
    """The resources (``CPU``, ``GPU``, ``memory`` in bytes, ...) of every alive node of the cluster."""
    return [dict(node.get("Resources", {})) for node in ray.nodes() if node.get("Alive")]


def check_feasible(graph: StageGraph, pending: list[str], threads: int, nodes: list[dict[str, float]]) -> None:
    """ValueError when a stage's task (:func:`task_options`) fits no single node of ``nodes`` (each node's
    resources, as :func:`_alive_nodes` gives them): its CPUs, GPU and memory must all be on one node, else Ray waits
    for such a node forever.

    Raises:
        ValueError: naming the stage, what it asks for and what the cluster has, with the --threads that fits.
    """
    most_cpus = max((n.get("CPU", 0.0) for n in nodes), default=0.0)
    if most_cpus < threads:
        raise ValueError(f"every stage asks for {threads} CPU(s) (--threads) but the largest node of the Ray cluster "
                         f"has {most_cpus:g}; use --threads {max(1, math.floor(most_cpus))}")
    most_memory = max((n.get("memory", 0.0) for n in nodes), default=0.0)
    cluster_gpus = sum(n.get("GPU", 0.0) for n in nodes)
    for name in pending:
        wanted = task_options(graph[name], threads, 0, cluster_gpus)
        memory = wanted.get("memory", 0)
        if memory > most_memory:
            raise ValueError(f"stage {name} declares {memory // 2**20} MiB of memory but the largest node of the Ray "
                             f"cluster offers {most_memory / 2**20:.0f} MiB; add a node with more memory")
        fits = [n for n in nodes if n.get("CPU", 0.0) >= threads and n.get("GPU", 0.0) >= wanted["num_gpus"]
                and n.get("memory", 0.0) >= memory]
        if fits:
            continue
        asked = f"{threads} CPU(s) and {memory // 2**20} MiB"
        if not wanted["num_gpus"]:
            raise ValueError(f"stage {name} asks for {asked} on one node, but no node of the Ray cluster has them "
                             "together; use fewer --threads or add a node with more memory")
        cpus = max((n.get("CPU", 0.0) for n in nodes if n.get("GPU", 0.0) >= 1), default=0.0)
        raise ValueError(f"stage {name} asks for a GPU, {asked} on one node, but no node of the Ray cluster has them "
                         f"together (its GPU nodes have at most {cpus:g} CPU(s)); use --threads "
                         f"{max(1, math.floor(cpus))} or add a GPU node")


def _failure(ray, error: BaseException) -> str:
    """One line for a failed task: the stage's own exception, not Ray's wrapping of it."""
    cause = error
    if isinstance(error, ray.exceptions.RayTaskError):
        cause = error.cause if error.cause is not None else error
    text = " ".join(str(cause).split())
    return f"{type(cause).__name__}: {text}"


def execute_ray(graph: StageGraph, root: str | Path, options: RayOptions = RayOptions(),
                on_done: Callable[[str, dict | None], None] | None = None,
        raise_on_failure: bool = True) -> RunReport:
    """Run every unfinished stage of ``graph`` (markers under ``root``) and every stage that depends on one as Ray
    tasks on the cluster ``options.address``; ``on_done(name, summary)`` as each stage ends (``summary`` None when it
    failed).

    Raises:
        ImportError: Ray is not installed. ConnectionError: no cluster at ``options.address``.
        ValueError: a stage asks for more CPUs or memory than any node of the cluster has (it would never start).
        StageFailedError: naming each failed stage with its error, and the stages it blocked.
    """
    root = Path(root)
    pending, report = plan_run(graph, root)
    if not pending:
        return report
    ray = import_ray()
    started = _connect(ray, options.address)
    try:
        nodes = _alive_nodes(ray)
        gpus = sum(n.get("GPU", 0.0) for n in nodes)
        check_feasible(graph, pending, options.threads, nodes)
        remote = ray.remote(max_calls=1)(_ray_stage)
        refs: dict[str, Any] = {}
        for name in pending:  # dependency order: every dependency's ref exists before its dependents are submitted
            stage = graph[name]
            after = [refs[d] for d in stage.deps if d in refs]
            refs[name] = remote.options(**task_options(stage, options.threads, options.max_retries, gpus)).remote(
                str(root), stage, options.threads, *after)
            log.info("submitted %s", name)
        _collect(ray, graph, refs, report, on_done)
    finally:
        if started:
            ray.shutdown()
    if raise_on_failure:
        report.raise_if_failed(root)
    return report


def _collect(ray, graph: StageGraph, refs: dict[str, Any], report: RunReport,
             on_done: Callable[[str, dict | None], None] | None) -> None:
    """Wait for every task of ``refs`` and record each stage as ran, failed or blocked (a stage whose dependency
    failed or was blocked is blocked: Ray does not run it). Ctrl-C / SIGTERM cancels every unfinished task."""
    stage_of = {ref: name for name, ref in refs.items()}
    outstanding = list(refs.values())
    order = {name: i for i, name in enumerate(graph.order)}
    try:
        with deferred_interrupts() as stop:
            while outstanding:
                ready, outstanding = ray.wait(outstanding, num_returns=len(outstanding), timeout=_WAIT_SECONDS,
                                              fetch_local=False)
                stop.raise_if_requested()
                for ref in sorted(ready, key=lambda r: order[stage_of[r]]):  # dependencies before dependents
                    name = stage_of[ref]
                    if any(d in report.failed or d in report.blocked for d in graph[name].deps):
                        report.blocked.append(name)
                        continue
                    try:
                        summary = ray.get(ref)
                    except Exception as error:  # the stage raised, or Ray gave up on it (retries used up)
                        report.failed[name] = _failure(ray, error)
                        log.error("stage %s failed: %s", name, report.failed[name])
                        log.debug("stage %s: %s", name, error)  # Ray's text of it holds the worker's traceback
                        summary = None
                    else:
                        report.ran.append(name)
                        if summary.get("restarted"):
                            report.retried.append(name)
                        log.info("done %s (%.1f s on %s)", name, summary["seconds"], summary.get("host", "?"))
                    if on_done is not None:
                        on_done(name, summary)
    except BaseException:
        for ref in outstanding:
            ray.cancel(ref, force=True, recursive=True)
        raise
