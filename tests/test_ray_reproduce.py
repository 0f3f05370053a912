"""The tiny reproduction on a two-node Ray cluster started on this machine (1 CPU per node), with the worker node
killed during a training stage and started again: the job finishes, the killed stage continues from its checkpoint,
and every number of results.json that is not a timing equals the local executor's with the same threads per stage.

Slow (about 10 minutes on the 2-core machine): ``python3 -m pytest -q -m slow tests/test_ray_reproduce.py``.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest

pytest.importorskip("ray")

from local_ray_cluster import LocalRayCluster  # noqa: E402
from test_fault_injection import _numbers  # noqa: E402

pytestmark = [pytest.mark.slow, pytest.mark.blender]


def _reproduce(out: Path, env: dict, *options: str) -> subprocess.CompletedProcess:
    command = [sys.executable, "-m", "spotlessgs.cli", "reproduce", "--preset", "tiny", "--out", str(out), *options]
    return subprocess.run(command, env=env, capture_output=True, text=True, timeout=3600)


def _training_run_of(pids: list[int]) -> Path | None:
    """The run folder whose lock one of ``pids`` holds (the trainer locks RUN/.lock while it trains)."""
    for pid in pids:
        try:
            targets = [os.readlink(f"/proc/{pid}/fd/{fd}") for fd in os.listdir(f"/proc/{pid}/fd")]
        except OSError:
            continue
        for target in targets:
            if target.endswith("/.lock") and "/runs/" in target and "/selection/" not in target:
                return Path(target).parent
    return None


def test_tiny_reproduction_on_a_ray_cluster_survives_a_lost_worker_node_and_matches_the_local_run(tmp_path):
    cluster = LocalRayCluster(cpus=1).start(workers=1)
    killed: dict = {}
    try:
        worker = cluster.workers[0]

        def kill_the_worker_node_during_training() -> None:
            deadline = time.monotonic() + 1800
            while time.monotonic() < deadline and "run" not in killed:
                run = _training_run_of(cluster.node_processes(worker))
                if run is not None and (run / "checkpoints" / "last.safetensors").is_file():
                    killed["run"] = run
                    cluster.kill_worker(worker)
                    time.sleep(2.0)
                    cluster.add_worker()
                    return
                time.sleep(0.05)

        killer = threading.Thread(target=kill_the_worker_node_during_training, daemon=True)
        killer.start()
        on_ray = _reproduce(tmp_path / "ray", cluster.env, "--executor", "ray", "--ray-address", cluster.address)
        killer.join(timeout=60)
    finally:
        cluster.stop()
    assert on_ray.returncode == 0, on_ray.stdout + on_ray.stderr
    assert "run" in killed, "no training stage ran on the worker node with a checkpoint"
    run = killed["run"]
    stage = f"train/{run.parent.name}/{run.name}"
    marker = json.loads((tmp_path / "ray" / ".stages" / f"{stage}.json").read_text())
    assert marker["result"]["train"]["resumed_from_step"] >= 1, marker["result"]["train"]  # not from scratch

    local = _reproduce(tmp_path / "local", dict(os.environ), "--jobs", "2")  # 1 thread per stage, as on Ray
    assert local.returncode == 0, local.stdout + local.stderr
    ours = dict(_numbers(json.loads((tmp_path / "ray" / "results.json").read_text())))
    reference = dict(_numbers(json.loads((tmp_path / "local" / "results.json").read_text())))
    assert ours.keys() == reference.keys()
    differing = {k: (ours[k], reference[k]) for k in ours if ours[k] != pytest.approx(reference[k], rel=1e-6)}
    assert not differing, differing
