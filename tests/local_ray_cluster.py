"""A real Ray cluster on this machine for the tests: a head node and worker nodes on 127.0.0.1, each node its own
``ray start --block`` process group with a fixed number of CPUs, so that one node can be killed (SIGKILL to its
group: its raylet and its workers die at once, as when a machine is lost) and started again.

The nodes see the repository and this folder on their PYTHONPATH, so that stage functions defined in test helper
modules can be imported by the Ray workers.
"""

from __future__ import annotations

import os
import shutil
import signal
import socket
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
TESTS = Path(__file__).resolve().parent


#: What a driver process of the test cluster needs in its environment.
DRIVER_ENV = {"RAY_AUTH_MODE": "disabled", "RAY_USAGE_STATS_ENABLED": "0"}


def _free_port() -> int:
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        return sock.getsockname()[1]


def ray_command() -> list[str]:
    """The ``ray`` command of this Python (its console script beside the interpreter, else ``python -m``)."""
    script = Path(sys.executable).with_name("ray")
    return [str(script)] if script.is_file() else [sys.executable, "-m", "ray.scripts.scripts"]


class LocalRayCluster:
    """Head + worker nodes with ``cpus`` CPUs each, started with :meth:`start` and removed with :meth:`stop`."""

    def __init__(self, cpus: int = 1):
        self.cpus = cpus
        self.port = _free_port()
        # short: Ray's unix sockets live under it and a socket path may not exceed 107 characters
        self.temp_dir = Path(tempfile.mkdtemp(prefix="rt", dir="/tmp"))
        self.head: subprocess.Popen | None = None
        self.workers: list[subprocess.Popen] = []
        # RAY_AUTH_MODE: a private `ray.init()` (the Ray executor with no address) writes ~/.ray/auth_token, after which
        # nodes started by `ray start` turn token authentication on while drivers do not; a test cluster on
        # 127.0.0.1 runs without it, and the tests' drivers say so too (DRIVER_ENV)
        self.env = dict(os.environ, **DRIVER_ENV,
                        PYTHONPATH=os.pathsep.join([str(ROOT), str(TESTS)] + (
                            [os.environ["PYTHONPATH"]] if os.environ.get("PYTHONPATH") else [])))

    @property
    def address(self) -> str:
        return f"127.0.0.1:{self.port}"

    def _start_node(self, *args: str) -> subprocess.Popen:
        log = open(self.temp_dir / f"node-{len(self.workers) + (self.head is not None)}.log", "ab")
        return subprocess.Popen([*ray_command(), "start", "--block", "--node-ip-address=127.0.0.1",
                                 f"--num-cpus={self.cpus}", "--num-gpus=0", "--object-store-memory=100000000",
                                 "--disable-usage-stats", *args],
                                env=self.env, stdout=log, stderr=subprocess.STDOUT, start_new_session=True)

    def start(self, workers: int = 1) -> "LocalRayCluster":
        """Start the head node and ``workers`` worker nodes, and wait until every node is alive."""
        try:
            self.head = self._start_node("--head", f"--port={self.port}", "--include-dashboard=false",
                                         f"--temp-dir={self.temp_dir}", f"--ray-client-server-port={_free_port()}")
            self.wait_for_nodes(1)  # a worker that starts before the head's GCS answers fails to join
            for _ in range(workers):
                self.add_worker()
            self.wait_for_nodes(1 + workers)
        except BaseException:
            self.stop()
            raise
        return self

    def add_worker(self) -> subprocess.Popen:
        """Start one more worker node (it joins in a few seconds: see :meth:`wait_for_nodes`)."""
        worker = self._start_node(f"--address={self.address}")
        self.workers.append(worker)
        return worker

    def kill_worker(self, worker: subprocess.Popen) -> None:
        """SIGKILL a worker node's whole process group: its raylet and the Ray workers running its tasks."""
        os.killpg(worker.pid, signal.SIGKILL)
        worker.wait(timeout=30)
        self.workers.remove(worker)

    def node_processes(self, node: subprocess.Popen) -> list[int]:
        """The processes of a node: its own process group (raylet, agents) and the Ray workers its raylet started
        (each in a session of its own) with their children."""
        parents: dict[int, int] = {}
        group: list[int] = []
        for entry in os.listdir("/proc"):
            if not entry.isdigit():
                continue
            try:
                stat = Path(f"/proc/{entry}/stat").read_text()
            except OSError:
                continue
            fields = stat[stat.rindex(")") + 2:].split()  # after "pid (comm) ": state ppid pgrp ...
            parents[int(entry)] = int(fields[1])
            if int(fields[2]) == node.pid:
                group.append(int(entry))
        found, frontier = set(group), list(group)
        while frontier:
            parent = frontier.pop()
            for pid, ppid in parents.items():
                if ppid == parent and pid not in found:
                    found.add(pid)
                    frontier.append(pid)
        return sorted(found)

    def alive_nodes(self) -> int:
        """Alive nodes, asked of the cluster by a short-lived driver process."""
        code = ("import ray; ray.init(address=%r, logging_level='ERROR'); "
                "print(sum(1 for n in ray.nodes() if n['Alive']))" % self.address)
        done = subprocess.run([sys.executable, "-c", code], env=self.env, capture_output=True, text=True,
                              timeout=120)
        return int(done.stdout.strip().splitlines()[-1]) if done.returncode == 0 and done.stdout.strip() else 0

    def wait_for_nodes(self, count: int, timeout: float = 120.0) -> None:
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            if self.alive_nodes() == count:
                return
            time.sleep(1.0)
        raise TimeoutError(f"the Ray cluster at {self.address} did not reach {count} alive node(s) in {timeout} s")

    def stop(self) -> None:
        for process in [*self.workers, *([self.head] if self.head else [])]:
            try:
                os.killpg(process.pid, signal.SIGKILL)
            except ProcessLookupError:
                pass
            process.wait(timeout=30)
        self.workers, self.head = [], None
        shutil.rmtree(self.temp_dir, ignore_errors=True)
