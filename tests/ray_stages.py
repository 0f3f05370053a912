"""Stage functions for the executor tests on a Ray cluster (module level: Ray workers import them by name)."""

from __future__ import annotations

import json
import os
import time
from pathlib import Path
from typing import Any

from spotlessgs.io.atomic import write_json


def _node() -> str:
    try:
        import ray

        return ray.get_runtime_context().get_node_id()
    except Exception:  # not in a Ray worker (the local executor)
        return "local"


def record(path: str, seconds: float, threads: int) -> dict[str, Any]:
    """Sleep ``seconds``; write where, when and with which thread environment this ran."""
    start = time.time()
    time.sleep(seconds)
    facts = {"node": _node(), "pid": os.getpid(), "start": start, "end": time.time(), "threads": threads,
             "omp": os.environ.get("OMP_NUM_THREADS")}
    write_json(Path(path), facts)
    return facts


def count_steps(folder: str, steps: int, seconds_per_step: float, threads: int) -> dict[str, Any]:
    """A resumable job: ``steps`` steps of ``seconds_per_step``, each logged (``log.jsonl``: step, pid, node) and
    checkpointed (``checkpoint.json``) when done; a rerun continues after the last checkpointed step."""
    del threads
    out = Path(folder)
    out.mkdir(parents=True, exist_ok=True)
    checkpoint = out / "checkpoint.json"
    start = json.loads(checkpoint.read_text())["done"] if checkpoint.is_file() else 0
    for step in range(start, steps):
        with open(out / "log.jsonl", "a") as log:
            log.write(json.dumps({"step": step, "pid": os.getpid(), "node": _node(), "time": time.time()}) + "\n")
        time.sleep(seconds_per_step)
        write_json(checkpoint, {"done": step + 1})
    return {"steps": steps, "resumed_from": start}


def fail(message: str, threads: int) -> None:
    """Raise ValueError(message)."""
    raise ValueError(message)
