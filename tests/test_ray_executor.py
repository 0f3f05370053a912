"""The Ray executor on a real two-node Ray cluster started on this machine (1 CPU per node): dependencies, failures,
a worker node killed mid-stage, a driver killed and restarted, and render-many's datasets against the local
executor's. About a minute and a half on the 2-core machine.
"""

from __future__ import annotations

import json
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest

ray = pytest.importorskip("ray")

from local_ray_cluster import DRIVER_ENV, LocalRayCluster  # noqa: E402
from spotlessgs.jobs import ExecutorSpec, Stage, StageGraph, StageResources  # noqa: E402
from spotlessgs.jobs.graph import is_done, read_marker  # noqa: E402
from spotlessgs.jobs.plan import StageFailedError  # noqa: E402
from spotlessgs.jobs.ray_cluster import RAY_MISSING, RayOptions, execute_ray, task_options  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
STAGES = "ray_stages"


@pytest.fixture(scope="module")
def cluster():
    with pytest.MonkeyPatch.context() as patch:  # this process is a driver of the cluster too
        for key, value in DRIVER_ENV.items():
            patch.setenv(key, value)
        nodes = LocalRayCluster(cpus=1).start(workers=1)
        try:
            yield nodes
        finally:
            nodes.stop()


def _options(cluster) -> RayOptions:
    return RayOptions(address=cluster.address, threads=1)


def test_stages_run_on_both_nodes_after_their_dependencies_and_are_skipped_when_done(cluster, tmp_path):
    facts = {name: tmp_path / f"{name}.json" for name in ("a", "b", "c")}
    graph = StageGraph([
        Stage("a", f"{STAGES}:record", {"path": str(facts["a"]), "seconds": 3.0}),
        Stage("b", f"{STAGES}:record", {"path": str(facts["b"]), "seconds": 3.0}),
        Stage("c", f"{STAGES}:record", {"path": str(facts["c"]), "seconds": 0.0}, deps=("a", "b")),
    ])
    report = execute_ray(graph, tmp_path / "out", _options(cluster))
    assert sorted(report.ran) == ["a", "b", "c"] and report.skipped == [] and not report.failed
    a, b, c = (json.loads(facts[n].read_text()) for n in "abc")
    assert a["node"] != b["node"]  # one CPU per node: the two independent stages ran side by side on both nodes
    assert c["start"] >= max(a["end"], b["end"])  # the dependent started after both dependencies had finished
    assert {a["omp"], b["omp"], c["omp"]} == {"1"} and a["pid"] != b["pid"] != c["pid"]
    marker = read_marker(tmp_path / "out", "c")
    assert marker["threads"] == 1 and marker["result"]["node"] == c["node"] and marker["restarted"] is False
    again = execute_ray(graph, tmp_path / "out", _options(cluster))
    assert again.ran == [] and sorted(again.skipped) == ["a", "b", "c"]


def test_a_failing_stage_is_reported_with_its_error_and_the_rest_still_finishes(cluster, tmp_path):
    graph = StageGraph([
        Stage("bad", f"{STAGES}:fail", {"message": "the input is broken"}),
        Stage("after-bad", f"{STAGES}:record", {"path": str(tmp_path / "x.json"), "seconds": 0.0}, deps=("bad",)),
        Stage("good", f"{STAGES}:record", {"path": str(tmp_path / "good.json"), "seconds": 0.0}),
    ])
    with pytest.raises(StageFailedError, match=r"bad: ValueError: the input is broken.*not run because of them: "
                                               r"\['after-bad'\]"):
        execute_ray(graph, tmp_path / "out", _options(cluster))
    assert is_done(tmp_path / "out", "good") and not is_done(tmp_path / "out", "bad")
    assert not (tmp_path / "x.json").exists()  # a stage whose dependency failed never runs
    report = execute_ray(graph, tmp_path / "out", _options(cluster), raise_on_failure=False)
    assert report.failed == {"bad": "ValueError: the input is broken"} and report.blocked == ["after-bad"]
    assert report.skipped == ["good"]  # finished work is kept


def _log(folder: Path) -> list[dict]:
    path = folder / "log.jsonl"
    return [json.loads(line) for line in path.read_text().splitlines()] if path.is_file() else []


def test_a_worker_node_killed_mid_stage_has_the_stage_resumed_from_its_checkpoint(cluster, tmp_path):
    """Both nodes run a resumable stage; the worker node is SIGKILLed during its stage and started again: Ray runs
    that stage again, which continues from its checkpoint (no step before it runs twice), and the job finishes."""
    folders = {name: tmp_path / name for name in ("x", "y")}
    graph = StageGraph([
        *(Stage(name, f"{STAGES}:count_steps", {"folder": str(folder), "steps": 10, "seconds_per_step": 0.5},
                clean_on_retry=False) for name, folder in folders.items()),
        Stage("z", f"{STAGES}:record", {"path": str(tmp_path / "z.json"), "seconds": 0.0}, deps=("x", "y")),
    ])
    worker = cluster.workers[0]
    killed: dict = {}

    def kill_the_worker_node_mid_stage() -> None:
        deadline = time.monotonic() + 120
        while time.monotonic() < deadline:
            logs = {name: _log(folder) for name, folder in folders.items()}
            if all(len(entries) >= 3 for entries in logs.values()):
                break
            time.sleep(0.2)
        nodes = {name: entries[0]["node"] for name, entries in logs.items()}
        head_node = ray_head_node(cluster)
        killed["stage"] = next(name for name, node in nodes.items() if node != head_node)
        killed["steps_before"] = len(_log(folders[killed["stage"]]))
        cluster.kill_worker(worker)
        time.sleep(2.0)
        cluster.add_worker()

    killer = threading.Thread(target=kill_the_worker_node_mid_stage)
    killer.start()
    report = execute_ray(graph, tmp_path / "out", _options(cluster))
    killer.join()
    cluster.wait_for_nodes(2)
    assert sorted(report.ran) == ["x", "y", "z"] and not report.failed
    name = killed["stage"]
    entries = _log(folders[name])
    attempts = list(dict.fromkeys(e["pid"] for e in entries))
    assert len(attempts) == 2, entries  # killed once, run again once
    second = [e["step"] for e in entries if e["pid"] == attempts[1]]
    resumed_from = read_marker(tmp_path / "out", name)["result"]["resumed_from"]
    assert resumed_from >= 2 and second == list(range(resumed_from, 10))  # continued from the checkpoint
    first = [e["step"] for e in entries if e["pid"] == attempts[0]]
    assert first == list(range(len(first))) and len(first) <= resumed_from + 1  # at most the step in flight redone
    other = "y" if name == "x" else "x"
    assert len({e["pid"] for e in _log(folders[other])}) == 1  # the stage on the surviving node ran once


def ray_head_node(cluster) -> str:
    """The node id of the cluster's head node (asked by a short-lived driver)."""
    code = ("import ray; ray.init(address=%r, logging_level='ERROR'); "
            "print(next(n['NodeID'] for n in ray.nodes() if n['Alive'] and "
            "n['Resources'].get('node:__internal_head__')))" % cluster.address)
    done = subprocess.run([sys.executable, "-c", code], env=cluster.env, capture_output=True, text=True, timeout=120,
                          check=True)
    return done.stdout.strip().splitlines()[-1]


_DRIVER = """
import sys
from spotlessgs.jobs import Stage, StageGraph
from spotlessgs.jobs.ray_cluster import RayOptions, execute_ray
out, folder, address = sys.argv[1:4]
graph = StageGraph([
    Stage("first", "ray_stages:record", {"path": folder + "/first.json", "seconds": 0.0}),
    Stage("long", "ray_stages:count_steps", {"folder": folder + "/long", "steps": 8, "seconds_per_step": 0.5},
          deps=("first",), clean_on_retry=False),
])
report = execute_ray(graph, out, RayOptions(address=address, threads=1))
print("RAN", sorted(report.ran), "SKIPPED", sorted(report.skipped))
"""


def test_a_driver_killed_and_restarted_resumes_the_job(cluster, tmp_path):
    command = [sys.executable, "-c", _DRIVER, str(tmp_path / "out"), str(tmp_path), cluster.address]
    driver = subprocess.Popen(command, env=cluster.env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    deadline = time.monotonic() + 120
    while len(_log(tmp_path / "long")) < 3 and time.monotonic() < deadline:
        time.sleep(0.2)
    driver.kill()
    driver.wait(timeout=30)
    time.sleep(3.0)  # Ray ends the dead driver's tasks
    steps_then = len(_log(tmp_path / "long"))
    time.sleep(1.5)
    assert len(_log(tmp_path / "long")) == steps_then  # its stage stopped with it
    done = subprocess.run(command, env=cluster.env, capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stdout + done.stderr
    assert "RAN ['long'] SKIPPED ['first']" in done.stdout
    marker = read_marker(tmp_path / "out", "long")
    assert marker["result"]["resumed_from"] >= 2
    assert [e["step"] for e in _log(tmp_path / "long")][-8 + marker["result"]["resumed_from"]:] == list(
        range(marker["result"]["resumed_from"], 8))


def test_task_resources_threads_memory_and_a_gpu_only_where_the_cluster_has_one():
    train = Stage("train/x", "m:f", resources=StageResources(memory_mb=1500, gpu=True))
    render = Stage("render/x", "m:f", resources=StageResources(memory_mb=2048))
    on_gpus = task_options(train, threads=4, max_retries=3, cluster_gpus=2.0)
    assert (on_gpus["num_cpus"], on_gpus["num_gpus"], on_gpus["memory"]) == (4, 1, 1500 * 1024 * 1024)
    assert on_gpus["runtime_env"]["env_vars"]["OMP_NUM_THREADS"] == "4"
    assert on_gpus["max_retries"] == 3 and on_gpus["retry_exceptions"] is False and on_gpus["name"] == "train/x"
    assert task_options(train, threads=1, max_retries=0, cluster_gpus=0.0)["num_gpus"] == 0  # CPU-only cluster
    assert task_options(render, threads=1, max_retries=3, cluster_gpus=2.0)["num_gpus"] == 0
    assert "memory" not in task_options(Stage("s", "m:f"), threads=1, max_retries=3, cluster_gpus=0.0)


def test_a_stage_must_fit_one_node_with_its_cpus_gpu_and_memory_together():
    """A GPU stage on a cluster whose GPU node has fewer CPUs than --threads (and a CPU node has enough) waited
    forever: the CPU and memory checks looked at the largest node of each, not at one node holding all three."""
    from spotlessgs.jobs.ray_cluster import check_feasible

    gib = 2.0**30
    graph = StageGraph([Stage("train/x", "m:f", resources=StageResources(memory_mb=1024, gpu=True)),
                        Stage("render/x", "m:f", resources=StageResources(memory_mb=3072))])
    cpu_node, gpu_node = {"CPU": 2.0, "memory": 8 * gib}, {"CPU": 1.0, "GPU": 1.0, "memory": 2 * gib}
    check_feasible(graph, ["render/x"], 2, [cpu_node, gpu_node])  # renders fit the CPU node
    check_feasible(graph, ["train/x"], 1, [cpu_node, gpu_node])
    with pytest.raises(ValueError, match=r"stage train/x asks for a GPU, 2 CPU\(s\) and 1024 MiB on one node, but no "
                                         r"node of the Ray cluster has them together \(its GPU nodes have at most 1 "
                                         r"CPU\(s\)\); use --threads 1"):
        check_feasible(graph, ["render/x", "train/x"], 2, [cpu_node, gpu_node])
    check_feasible(graph, ["train/x"], 2, [cpu_node])  # no GPU in the cluster: the stage runs on CPUs
    with pytest.raises(ValueError, match=r"stage render/x asks for 2 CPU\(s\) and 3072 MiB on one node"):
        check_feasible(graph, ["render/x"], 2, [{"CPU": 2.0, "memory": 1 * gib}, {"CPU": 1.0, "memory": 4 * gib}])
    with pytest.raises(ValueError, match=r"every stage asks for 4 CPU\(s\) \(--threads\) but the largest node"):
        check_feasible(graph, ["render/x"], 4, [cpu_node, gpu_node])


def test_ray_address_auto_without_a_cluster_is_said_before_anything_is_written(tmp_path, monkeypatch):
    """`reproduce --executor ray` (--ray-address auto) on a machine without a cluster wrote reproduce.json and its
    lock, then failed with Ray's advice about an --address flag that spotless does not have."""
    import ray._private.utils

    from spotlessgs.experiments.reproduce.config import preset
    from spotlessgs.experiments.reproduce.pipeline import reproduce

    monkeypatch.delenv("RAY_ADDRESS", raising=False)
    monkeypatch.setattr(ray._private.utils, "read_ray_address", lambda temp_dir=None: None)
    with pytest.raises(ConnectionError, match=r"--ray-address auto: no Ray cluster to join .*--ray-address local"):
        reproduce(preset("tiny"), tmp_path / "out", executor=ExecutorSpec("ray"))
    assert not (tmp_path / "out").exists()
    monkeypatch.setenv("RAY_ADDRESS", "127.0.0.1:1")  # nothing listens on port 1
    with pytest.raises(ConnectionError, match=r"127\.0\.0\.1:1: no Ray cluster answers there"):
        ExecutorSpec("ray").check()


def test_relative_folders_reach_ray_workers_as_absolute_paths(tmp_path, monkeypatch):
    """A Ray worker resolves a relative --out or --scenes-dir in its node's working directory: outputs and markers
    landed there and a rerun never found them. The Ray executor gets absolute paths; the local one keeps them as
    given (results name the folder the way the user did)."""
    import spotlessgs.experiments.reproduce.pipeline as pipeline
    from spotlessgs.experiments.reproduce.config import preset

    seen = {}
    monkeypatch.setattr(ExecutorSpec, "check", lambda self: None)
    monkeypatch.setattr(pipeline, "execute", lambda graph, root, executor: seen.update(graph=graph, root=root))
    monkeypatch.chdir(tmp_path)
    pipeline.reproduce(preset("tiny"), "out", executor=ExecutorSpec("ray"))
    assert seen["root"] == tmp_path / "out"
    kwargs = [v for stage in seen["graph"].stages.values() for k, v in stage.kwargs.items() if k.endswith("dir")]
    assert kwargs and all(Path(v).is_absolute() for v in kwargs if isinstance(v, str))
    pipeline.reproduce(preset("tiny"), "out", executor=ExecutorSpec("local"))
    assert seen["root"] == Path("out")


def test_clear_errors_without_ray_or_with_too_many_threads(cluster, tmp_path, monkeypatch):
    graph = StageGraph([Stage("a", f"{STAGES}:record", {"path": str(tmp_path / "a.json"), "seconds": 0.0})])
    with pytest.raises(ValueError, match=r"asks for 2 CPU\(s\) \(--threads\) but the largest node of the Ray "
                                         r"cluster has 1; use --threads 1"):
        execute_ray(graph, tmp_path / "out", RayOptions(address=cluster.address, threads=2))
    huge = StageGraph([Stage("a", f"{STAGES}:record", {"path": str(tmp_path / "a.json"), "seconds": 0.0},
                             resources=StageResources(memory_mb=10**9))])
    with pytest.raises(ValueError, match=r"stage a declares 1000000000 MiB of memory but the largest node"):
        execute_ray(huge, tmp_path / "out", _options(cluster))
    assert not (tmp_path / "a.json").exists()
    monkeypatch.setitem(sys.modules, "ray", None)
    with pytest.raises(ImportError, match=r"pip install 'spotlessgs\[cluster\]'") as error:
        execute_ray(graph, tmp_path / "out", _options(cluster))
    assert str(error.value) == RAY_MISSING
    assert ExecutorSpec("ray").stage_threads() == 1 and ExecutorSpec("local", jobs=2).stage_threads(cores=4) == 2


# ---- render-many on the cluster ----------------------------------------------------------------------------------

_SETTINGS = {"frames": 4, "width": 32, "height": 24, "samples": 2, "seed": 0, "path": "paper"}


def _dataset_files(root: Path) -> dict[str, bytes]:
    """Every file of every dataset under ``root`` (locks, markers and the job summary aside), transforms.json
    without its provenance block (which names the command and the time)."""
    files = {}
    for path in sorted(root.rglob("*")):
        relative = path.relative_to(root)
        if not path.is_file() or relative.parts[0] == ".stages" or path.name.startswith(".lock") or \
                path.name == "render_many.json":
            continue
        data = path.read_bytes()
        if path.name == "transforms.json":
            meta = json.loads(data)
            meta["spotless"].pop("provenance")
            data = json.dumps(meta, sort_keys=True).encode()
        files[str(relative)] = data
    return files


@pytest.mark.blender
def test_render_many_on_the_cluster_renders_every_frame_once_resumes_and_matches_the_local_executor(cluster,
                                                                                                    tmp_path):
    from simulator.render_many import find_scenes, render_many
    from simulator.render_pipeline import frame_paths

    scenes = find_scenes([str(ROOT / "scenes" / room / "house.json") for room in ("bedroom", "office", "corridor")])
    on_ray = ExecutorSpec("ray", ray_address=cluster.address)
    summary = render_many(scenes, ["uneven", "saturated"], tmp_path / "ray", _SETTINGS, frames_per_task=2,
                          executor=on_ray, progress=False)
    assert summary["complete"] and not summary["failed"] and len(summary["datasets"]) == 6
    assert summary["tasks_run"] == 6 * 3  # two ranges of two frames and one finishing task per dataset
    rendered = [read_marker(tmp_path / "ray", f"render/{d['dataset']}/frames-{a}-{a + 2}")["result"]["rendered"]
                for d in summary["datasets"] for a in (0, 2)]
    assert rendered == [2] * 12  # every frame rendered once
    # resumable: nothing to do again; a lost frame is rendered again by its range alone
    assert render_many(scenes, ["uneven", "saturated"], tmp_path / "ray", _SETTINGS, frames_per_task=2,
                       executor=on_ray, progress=False)["tasks_run"] == 0
    for path in frame_paths(tmp_path / "ray" / "office-saturated", 3).values():
        path.unlink()
    (tmp_path / "ray" / ".stages" / "render" / "office-saturated" / "frames-2-4.json").unlink()
    again = render_many(scenes, ["uneven", "saturated"], tmp_path / "ray", _SETTINGS, frames_per_task=2,
                        executor=on_ray, progress=False)
    assert again["tasks_run"] == 2 and [d["rendered_now"] for d in again["datasets"]] == [0, 0, 0, 1, 0, 0]
    # the local executor with the same threads per task writes byte-identical datasets
    local = render_many(scenes, ["uneven", "saturated"], tmp_path / "local", _SETTINGS, frames_per_task=2,
                        executor=ExecutorSpec("local", jobs=2, threads=1), progress=False)
    assert local["complete"]
    ours, theirs = _dataset_files(tmp_path / "ray"), _dataset_files(tmp_path / "local")
    assert ours.keys() == theirs.keys() and len(ours) > 6 * 4 * 3
    assert [name for name in ours if ours[name] != theirs[name]] == []
