"""Unit tests of the reproduction pipeline: config, stage DAG, executor, tables and agreement logic."""

from __future__ import annotations

import json
import math
import os
import time
from pathlib import Path

import pytest

from spotlessgs.io.atomic import write_json
from spotlessgs.experiments.reproduce.config import ReproduceConfig, preset
from spotlessgs.jobs.local import execute_local as execute, threads_per_job
from spotlessgs.jobs.plan import StageFailedError
from spotlessgs.experiments.reproduce.pipeline import build_graph, check_or_record_config
from spotlessgs.jobs.graph import (
    Stage, StageGraph, is_done, marker_path, read_marker, resolve, write_marker,
)
from spotlessgs.experiments.reproduce.tables import (
    GT_SFM_LABEL, all_tables, agreement_notes, best_darkgs, ceiling_table, check_at_least, check_auto_vs_spotless,
    check_order, check_sfm,
    format_cell, model_chosen_cell, model_summary, runtime_table, table1, table2, table3, table4,
)
from spotlessgs.experiments.reproduce.tasks import curve_milestones

HERE = "test_reproduce_units"


# ---------------------------------------------------------------------------------------------------------------------
# Stage functions used by the executor tests (module level: the spawn workers import them from this module)


def append_line(path: str, text: str, threads: int) -> dict:
    """Append ``text`` to ``path`` (records the execution order)."""
    with open(path, "a", encoding="utf-8") as fh:
        fh.write(text + "\n")
    return {"text": text, "threads": threads}


def sleep_and_time(path: str, seconds: float, threads: int) -> dict:
    """Sleep, recording start and end times in ``path`` (a JSON file per stage)."""
    start = time.time()
    time.sleep(seconds)
    Path(path).write_text(json.dumps([start, time.time()]))
    return {}


def sleep_forever(path: str, threads: int) -> dict:
    Path(path).write_text(str(os.getpid()))
    time.sleep(120)
    return {}


def thread_env(threads: int) -> dict:
    """The worker's OMP thread setting and the ``threads`` argument it was given."""
    return {"omp": os.environ.get("OMP_NUM_THREADS"), "threads_arg": threads}


def fail(message: str, threads: int) -> dict:
    raise RuntimeError(message)


def kill_myself(threads: int) -> dict:
    """A worker that dies without raising (as one killed for memory does)."""
    import signal

    os.kill(os.getpid(), signal.SIGKILL)
    return {}


def _lookup(table: dict, key: str) -> str:
    return table[key]


def key_error(threads: int) -> dict:
    """A bug deep inside a stage: its traceback is the only way to find it."""
    return {"value": _lookup({}, "frame_width")}


def write_into(out_dir: str, name: str, crash: bool, threads: int) -> dict:
    """Write a file into ``out_dir``; with ``crash``, raise after writing (an interrupted stage)."""
    Path(out_dir).mkdir(parents=True, exist_ok=True)
    existing = sorted(p.name for p in Path(out_dir).iterdir())
    (Path(out_dir) / name).write_text("x")
    if crash:
        raise RuntimeError("interrupted")
    return {"found_before": existing}


# ---------------------------------------------------------------------------------------------------------------------
# Config


def test_presets_are_valid_and_distinct():
    tiny, quick, paper = preset("tiny"), preset("quick"), preset("paper")
    assert tiny.frames < quick.frames < paper.frames == 316
    assert not set(tiny.gan_rooms) & set(tiny.scenes)
    assert quick.gan_domains() == (("office",), ("living_room",))
    for config in (tiny, quick, paper):  # the automatic mode is trained in every preset
        assert config.methods[-1] == "auto" and len(config.methods) == 7
    assert tiny.selection_min_proxy_iterations == 20 and quick.selection_min_proxy_iterations is None


def test_config_errors():
    with pytest.raises(ValueError, match="unknown reproduce preset 'huge'"):
        preset("huge")
    with pytest.raises(ValueError, match=r"scenes: unknown \['kitchen'\]"):
        ReproduceConfig(scenes=("kitchen",))
    with pytest.raises(ValueError, match=r"Cycle-GAN training rooms \['bedroom'\] are also test rooms"):
        ReproduceConfig(scenes=("bedroom",), gan_rooms=("bedroom", "office"))
    with pytest.raises(ValueError, match="gan_rooms needs at least two rooms"):
        ReproduceConfig(gan_rooms=("office",))
    with pytest.raises(ValueError, match="frames must be at least 2"):
        ReproduceConfig(frames=1)
    with pytest.raises(ValueError, match="curve_fractions must lie in"):
        ReproduceConfig(curve_fractions=(1.0,))
    with pytest.raises(ValueError, match="lists an entry twice"):
        ReproduceConfig(methods=("3dgs", "3dgs"))
    with pytest.raises(ValueError, match="unknown ReproduceConfig field"):
        preset("tiny", bogus=1)
    with pytest.raises(ValueError, match="selection_min_proxy_iterations must be at least 1"):
        ReproduceConfig(selection_min_proxy_iterations=0)
    with pytest.raises(ValueError, match=r"methods: unknown \['autox'\]"):
        ReproduceConfig(methods=("autox",))
    with pytest.raises(FileNotFoundError, match="shipped room 'bedroom' not found"):
        ReproduceConfig(scenes_dir=Path("/nonexistent")).scene_file("bedroom")
    with pytest.raises(ValueError, match="sensor_noise must be \\(shot, read\\)"):
        ReproduceConfig(sensor_noise=(0.01, -1.0))
    with pytest.raises(ValueError, match="sensor_noise needs the 'uneven' variant"):
        ReproduceConfig(variants=("saturated",), baseline_variants=("saturated",))
    with pytest.raises(ValueError, match=r"noisy_methods: unknown \['ours'\]"):
        ReproduceConfig(noisy_methods=("ours",))
    with pytest.raises(ValueError, match="robot_camera needs the 'uneven' variant"):
        ReproduceConfig(sensor_noise=None, variants=("saturated",), baseline_variants=("saturated",))
    with pytest.raises(ValueError, match="robot_lens must be pinhole, opencv or fisheye"):
        ReproduceConfig(robot_lens="kannala")
    with pytest.raises(ValueError, match="robot_noise must be \\(shot, read\\)"):
        ReproduceConfig(robot_noise=(0.01,))
    with pytest.raises(ValueError, match=r"robot_methods: unknown \['ours'\]"):
        ReproduceConfig(robot_methods=("ours",))


def test_sensor_noise_copies_are_extra_datasets():
    quick = preset("quick", scenes=("bedroom", "office"), gan_rooms=("living_room", "corridor"))
    assert quick.noisy_datasets() == [("bedroom", "uneven-noisy"), ("office", "uneven-noisy")]
    assert quick.robot_datasets() == [("bedroom", "robot"), ("office", "robot")]
    assert quick.rgbd_datasets() == [("bedroom", "rgbd"), ("office", "rgbd")]
    assert quick.all_datasets() == (quick.datasets() + quick.noisy_datasets() + quick.robot_datasets()
                                    + quick.rgbd_datasets())
    assert quick.methods_for("uneven-noisy") == ("spotless",) and quick.methods_for("saturated") == quick.methods
    assert quick.methods_for("robot") == quick.methods and preset("tiny").methods_for("robot") == ("spotless",)
    assert quick.methods_for("rgbd") == ("darkgs", "spotless", "auto")
    assert preset("tiny").methods_for("rgbd") == ("spotless",)
    assert preset("quick", robot_depth_camera=False).rgbd_datasets() == []
    clean = preset("quick", sensor_noise=None, robot_camera=False, variants=("saturated",),
                   baseline_variants=("saturated",))
    assert clean.noisy_datasets() == [] and clean.all_datasets() == [("bedroom", "saturated")]
    with pytest.raises(ValueError, match="robot_depth_noise must be finite and >= 0"):
        ReproduceConfig(robot_depth_noise=-0.001)
    with pytest.raises(ValueError, match=r"rgbd_methods: unknown \['ours'\]"):
        ReproduceConfig(rgbd_methods=("ours",))


def test_cli_options_to_config():
    from spotlessgs.experiments.reproduce.cli import config_from_options

    c = config_from_options("quick", ("office",), 3, None, True)
    assert c.scenes == ("office",) and c.gan_rooms == ("living_room", "bedroom") and c.seed == 3 and not c.sfm
    assert config_from_options("tiny", (), 0, None, False) == preset("tiny")
    with pytest.raises(ValueError, match="gan_rooms needs at least two rooms"):
        config_from_options("quick", ("bedroom", "living_room", "office", "storage_room", "corridor"), 0, None, False)
    assert c.sensor_noise is None  # the noisy copies serve Table III only
    assert config_from_options("tiny", (), 0, None, False, no_sensor_noise=True) == preset("tiny", sensor_noise=None)


def test_cli_reports_refused_folder_and_bad_options(tmp_path):
    from click.testing import CliRunner

    from spotlessgs.cli import main

    check_or_record_config(preset("tiny", seed=5), tmp_path)
    result = CliRunner().invoke(main, ["reproduce", "--preset", "tiny", "--out", str(tmp_path)])
    assert result.exit_code == 2 and "made with other settings (seed: 5 then, 0 now)" in result.output
    result = CliRunner().invoke(main, ["reproduce", "--preset", "tiny", "--out", str(tmp_path), "--scenes", "bedroom",
                                       "--scenes", "office", "--scenes", "living_room", "--scenes", "storage_room",
                                       "--scenes", "corridor"])
    assert result.exit_code == 2 and "gan_rooms needs at least two rooms" in result.output
    result = CliRunner().invoke(main, ["reproduce", "--preset", "tiny", "--out", str(tmp_path), "--jobs", "0"])
    assert result.exit_code == 2 and "--jobs" in result.output


def test_curve_milestones():
    assert curve_milestones(150, (0.5,)) == [75, 150]
    assert curve_milestones(10, (0.01, 0.25, 0.5, 0.75)) == [1, 2, 5, 8, 10]  # round(2.5) = 2 (banker's), 7.5 -> 8
    assert curve_milestones(4, ()) == [4]


def test_config_fingerprint_refuses_other_settings(tmp_path):
    check_or_record_config(preset("tiny"), tmp_path)
    check_or_record_config(preset("tiny"), tmp_path)  # same settings: fine
    with pytest.raises(ValueError, match=r"made with other settings \(seed: 0 then, 3 now\)"):
        check_or_record_config(preset("tiny", seed=3), tmp_path)
    # the rooms read from another checkout: a location, not a setting (render stages check the rooms' content)
    moved = preset("tiny", scenes_dir=tmp_path / "elsewhere" / "scenes")
    check_or_record_config(moved, tmp_path)
    assert json.loads((tmp_path / "reproduce.json").read_text())["scenes_dir"] == str(moved.scenes_dir)
    with pytest.raises(ValueError, match=r"settings \(seed: 0 then, 3 now\)"):  # still refused beside another change
        check_or_record_config(preset("tiny", scenes_dir=moved.scenes_dir, seed=3), tmp_path)


def test_other_scenes_are_taken_only_when_their_rooms_are_the_rendered_ones(tmp_path):
    """A --scenes-dir whose bedroom differs from the one the folder's datasets were rendered from was recorded, and
    the finished renders skipped: results credited to rooms never rendered."""
    import shutil

    from spotlessgs.io.provenance import sha256_file

    config = preset("tiny")
    out = tmp_path / "out"
    check_or_record_config(config, out)
    room = config.scenes[0]
    dataset = out / "datasets" / f"{room}-uneven"
    dataset.mkdir(parents=True)
    (dataset / "plan.json").write_text(json.dumps({"fingerprint": {
        "scene_sha256": sha256_file(config.scene_file(room))}, "poses": []}))
    same = tmp_path / "same"
    shutil.copytree(config.scenes_dir, same)
    check_or_record_config(preset("tiny", scenes_dir=same), out)  # a copy of the same rooms: taken
    assert json.loads((out / "reproduce.json").read_text())["scenes_dir"] == str(same)
    changed = tmp_path / "changed"
    shutil.copytree(config.scenes_dir, changed)
    house = changed / room / "house.json"
    house.write_text(house.read_text() + "\n")  # another file: one more byte
    with pytest.raises(ValueError, match=rf"{room}/house\.json: differs from the room .*{room}-uneven was rendered "
                                         r"from"):
        check_or_record_config(preset("tiny", scenes_dir=changed), out)
    assert json.loads((out / "reproduce.json").read_text())["scenes_dir"] == str(same)


def test_a_reproduction_folder_without_its_settings_or_with_damaged_state_is_refused_in_one_line(tmp_path):
    """An --out of another tool's files, or a reproduction whose reproduce.json is gone (its finished stages were
    made under unknown settings), is refused with nothing written; a damaged reproduce.json names itself; a damaged
    done-marker counts as not done (its stage runs again) and a report reading it names it."""
    from spotlessgs.io.errors import InputError
    from spotlessgs.jobs.graph import is_done, marker_path, read_marker, write_marker

    foreign = tmp_path / "dataset"
    foreign.mkdir()
    (foreign / "transforms.json").write_text("{}")
    with pytest.raises(InputError, match=r"dataset: holds files but no reproduce\.json \(transforms\.json\)"):
        check_or_record_config(preset("tiny"), foreign)
    assert sorted(p.name for p in foreign.iterdir()) == ["transforms.json"]
    lost = tmp_path / "lost"
    write_marker(lost, "render/bedroom-uneven", {"stage": "render/bedroom-uneven", "result": {}, "seconds": 1.0})
    with pytest.raises(InputError, match=r"lost: holds files but no reproduce\.json \(\.stages\)"):
        check_or_record_config(preset("quick"), lost)
    damaged = tmp_path / "damaged"
    damaged.mkdir()
    for text in ('{"seed": 1', "[1, 2]"):
        (damaged / "reproduce.json").write_text(text)
        with pytest.raises(InputError, match=r"damaged/reproduce\.json: "):
            check_or_record_config(preset("tiny"), damaged)
    assert is_done(lost, "render/bedroom-uneven")
    for text in ('{"stage": "render/bedroom-uneven"', '{"stage": "render/bedroom-uneven", "seconds": 1}',
                 '{"stage": "x", "result": 5, "seconds": 1}', '{"result": {}, "seconds": "abc"}'):
        marker_path(lost, "render/bedroom-uneven").write_text(text)
        assert not is_done(lost, "render/bedroom-uneven")
        with pytest.raises(InputError, match=r"\.stages/render/bedroom-uneven\.json: "):
            read_marker(lost, "render/bedroom-uneven")


def test_pipeline_graph_shape(tmp_path):
    config = preset("tiny")
    graph = build_graph(config, tmp_path)
    names = set(graph.stages)
    # 2 renders + 7 trainings and 1 inputs' evaluation per dataset (2 datasets), 2 GAN renders, the GAN, 3 baselines
    # on the uneven set, the sensor-noise, the robot-camera and the RGB-D copies each with its SpotlessGS run and
    # inputs' evaluation, one relighting ceiling per dataset (5), report
    assert len(names) == 2 + 14 + 2 + 2 + 1 + 3 + 3 + 3 + 3 + 5 + 1
    noise = graph["noise/bedroom-uneven-noisy"]
    assert noise.function == "spotlessgs.experiments.reproduce.tasks:add_noise_copy" and not noise.clean_on_retry
    assert noise.deps == ("render/bedroom-uneven",)
    assert noise.kwargs == {"data_dir": str(tmp_path / "datasets" / "bedroom-uneven"),
                            "out_dir": str(tmp_path / "datasets" / "bedroom-uneven-noisy"), "shot": 0.002,
                            "read": 0.004, "seed": 0}
    assert sorted(n for n in names if "uneven-noisy" in n) == [
        "ceiling/bedroom-uneven-noisy", "eval-inputs/bedroom-uneven-noisy", "noise/bedroom-uneven-noisy",
        "train/bedroom-uneven-noisy/spotless"]
    ceiling = graph["ceiling/bedroom-robot"]  # the relighting ceiling after its dataset only
    assert ceiling.function == "spotlessgs.experiments.reproduce.tasks:evaluate_ceiling"
    assert ceiling.deps == ("robot/bedroom-robot",) and ceiling.output == tmp_path / "ceiling" / "bedroom-robot"
    assert graph["train/bedroom-uneven-noisy/spotless"].deps == ("noise/bedroom-uneven-noisy",)
    assert graph["eval-inputs/bedroom-uneven-noisy"].deps == ("noise/bedroom-uneven-noisy",)
    assert len(build_graph(preset("tiny", sensor_noise=None), tmp_path).stages) == len(names) - 4
    assert len(build_graph(preset("tiny", robot_camera=False), tmp_path).stages) == len(names) - 8
    assert len(build_graph(preset("tiny", robot_depth_camera=False), tmp_path).stages) == len(names) - 4
    rgbd = graph["robot/bedroom-rgbd"]  # the robot copy with an RGB-D camera: the same task, with its depth
    assert rgbd.function == "spotlessgs.experiments.reproduce.tasks:robot_camera_copy"
    assert rgbd.kwargs == {**graph["robot/bedroom-robot"].kwargs, "depth_noise": 0.0025,
                           "out_dir": str(tmp_path / "datasets" / "bedroom-rgbd")}
    assert graph["train/bedroom-rgbd/spotless"].deps == ("robot/bedroom-rgbd",)
    robot = graph["robot/bedroom-robot"]
    assert robot.function == "spotlessgs.experiments.reproduce.tasks:robot_camera_copy" and not robot.clean_on_retry
    assert robot.deps == ("render/bedroom-uneven",)
    assert robot.kwargs == {"data_dir": str(tmp_path / "datasets" / "bedroom-uneven"),
                            "out_dir": str(tmp_path / "datasets" / "bedroom-robot"), "shot": 0.002, "read": 0.004,
                            "sensitivity": 0.25, "lens": "opencv", "distortion": [-0.18, 0.03, 0.0, 0.0], "matcher": "exhaustive",
                            "seed": 0}
    assert graph["train/bedroom-robot/spotless"].deps == ("robot/bedroom-robot",)
    # the uneven inputs are scored once per dataset, with the methods' evaluation settings, after its render only
    inputs = graph["eval-inputs/bedroom-saturated"]
    assert inputs.function == "spotlessgs.experiments.reproduce.tasks:evaluate_inputs"
    assert inputs.deps == ("render/bedroom-saturated",) and inputs.clean_on_retry
    assert inputs.output == tmp_path / "inputs" / "bedroom-saturated"
    assert inputs.kwargs == {"data_dir": str(tmp_path / "datasets" / "bedroom-saturated"),
                             "out_dir": str(tmp_path / "inputs" / "bedroom-saturated"), "sfm": True,
                             "sfm_matcher": "exhaustive", "lpips": True, "seed": 0}
    for stage in (graph["train/bedroom-saturated/3dgs"], graph["baseline2d/bedroom-uneven/clahe"]):
        assert {k: stage.kwargs[k] for k in ("sfm", "sfm_matcher", "lpips", "seed")} == {
            k: inputs.kwargs[k] for k in ("sfm", "sfm_matcher", "lpips", "seed")}
    assert sorted(n for n in names if n.startswith("eval-inputs/")) == [
        "eval-inputs/bedroom-rgbd", "eval-inputs/bedroom-robot", "eval-inputs/bedroom-saturated",
        "eval-inputs/bedroom-uneven", "eval-inputs/bedroom-uneven-noisy"]
    no_sfm = build_graph(preset("tiny", sfm=False, lpips=False, seed=4), tmp_path)["eval-inputs/bedroom-uneven"]
    assert (no_sfm.kwargs["sfm"], no_sfm.kwargs["lpips"], no_sfm.kwargs["seed"]) == (False, False, 4)
    auto = graph["train/bedroom-uneven/auto"]
    assert auto.kwargs["variant"] == "auto" and auto.kwargs["selection_min_proxy_iterations"] == 20
    # a training stage resumes from its checkpoint (a retry on another Ray worker continues it) and can use a GPU
    assert auto.output == tmp_path / "runs" / "bedroom-uneven" / "auto" and not auto.clean_on_retry
    assert auto.resources.gpu and not graph["render/bedroom-uneven"].resources.gpu
    assert auto.resources.memory_mb == 1024 + 8000 * 8 // 1024  # the tiny trainer allows 8000 Gaussians
    assert all(s.resources.memory_mb for s in graph.stages.values())  # every stage declares its memory
    assert "selection_min_proxy_iterations" not in graph["train/bedroom-uneven/spotless"].kwargs
    assert graph["train/bedroom-saturated/spotless"].deps == ("render/bedroom-saturated",)
    assert set(graph["baseline2d/bedroom-uneven/cyclegan"].deps) == {"render/bedroom-uneven", "cyclegan/train"}
    assert graph["cyclegan/train"].kwargs["uneven_dirs"][0].endswith("gan-office/images")
    assert graph["cyclegan/train"].kwargs["even_dirs"][0].endswith("gan-living_room/gt")
    assert set(graph["report"].deps) == names - {"report"}
    order = graph.order
    assert order.index("render/bedroom-uneven") < order.index("train/bedroom-uneven/3dgs") < order.index("report")
    assert not graph["render/bedroom-uneven"].clean_on_retry and not graph["train/bedroom-uneven/3dgs"].clean_on_retry
    assert graph["baseline2d/bedroom-uneven/clahe"].clean_on_retry


# ---------------------------------------------------------------------------------------------------------------------
# Stage graph


def test_graph_errors():
    a = Stage("a", f"{HERE}:append_line")
    with pytest.raises(ValueError, match="stage 'a' is defined twice"):
        StageGraph([a, a])
    with pytest.raises(ValueError, match=r"stage 'b' depends on unknown stage\(s\) \['zz'\]"):
        StageGraph([Stage("b", f"{HERE}:append_line", deps=("zz",))])
    with pytest.raises(ValueError, match="dependencies form a cycle: x -> y -> x"):
        StageGraph([Stage("x", f"{HERE}:append_line", deps=("y",)), Stage("y", f"{HERE}:append_line", deps=("x",))])
    with pytest.raises(ValueError, match="may only hold letters"):
        Stage("../evil", f"{HERE}:append_line")
    with pytest.raises(ValueError, match="must be 'package.module:function'"):
        Stage("ok", "no_colon")
    with pytest.raises(ValueError, match="cannot be imported"):
        resolve("spotlessgs.experiments.reproduce.tasks:no_such_function")


def test_topological_order_and_dependents():
    g = StageGraph([Stage("c", f"{HERE}:f", deps=("b",)), Stage("b", f"{HERE}:f", deps=("a",)), Stage("a", f"{HERE}:f"),
                    Stage("d", f"{HERE}:f", deps=("a",))])
    assert g.order.index("a") < g.order.index("b") < g.order.index("c")
    assert g.dependents("a") == {"b", "c", "d"} and g.dependents("c") == set()


def test_threads_per_job():
    assert threads_per_job(1, 2) == 2 and threads_per_job(2, 2) == 1 and threads_per_job(3, 2) == 1
    assert threads_per_job(2, 16) == 8
    with pytest.raises(ValueError, match="jobs must be at least 1, got 0"):
        threads_per_job(0)


# ---------------------------------------------------------------------------------------------------------------------
# Executor (real spawn processes)


def test_dependency_order_skip_done_and_markers(tmp_path):
    log = tmp_path / "log.txt"
    stages = [Stage("second", f"{HERE}:append_line", {"path": str(log), "text": "second"}, deps=("first",)),
              Stage("first", f"{HERE}:append_line", {"path": str(log), "text": "first"})]
    report = execute(StageGraph(stages), tmp_path, jobs=2, cores=2)
    assert log.read_text().split() == ["first", "second"]
    assert sorted(report.ran) == ["first", "second"] and report.skipped == []
    marker = read_marker(tmp_path, "second")
    assert marker["result"] == {"text": "second", "threads": 1} and marker["seconds"] >= 0 and marker["peak_rss_mb"] > 0
    again = execute(StageGraph(stages), tmp_path, jobs=2, cores=2)
    assert again.ran == [] and sorted(again.skipped) == ["first", "second"]
    assert log.read_text().split() == ["first", "second"]  # nothing ran twice


def test_redoing_a_stage_redoes_its_dependents(tmp_path):
    log = tmp_path / "log.txt"
    stages = [Stage("a", f"{HERE}:append_line", {"path": str(log), "text": "a"}),
              Stage("b", f"{HERE}:append_line", {"path": str(log), "text": "b"}, deps=("a",)),
              Stage("c", f"{HERE}:append_line", {"path": str(log), "text": "c"})]
    execute(StageGraph(stages), tmp_path, jobs=1)
    marker_path(tmp_path, "a").unlink()
    report = execute(StageGraph(stages), tmp_path, jobs=1)
    assert report.ran == ["a", "b"] and report.skipped == ["c"]
    assert log.read_text().split() == ["a", "b", "c", "a", "b"]


def test_independent_stages_run_in_parallel(tmp_path):
    stages = [Stage(f"s{i}", f"{HERE}:sleep_and_time", {"path": str(tmp_path / f"s{i}.json"), "seconds": 1.5})
              for i in range(2)]
    execute(StageGraph(stages), tmp_path / "root", jobs=2, cores=2)
    (a0, a1), (b0, b1) = (json.loads((tmp_path / f"s{i}.json").read_text()) for i in range(2))
    assert a0 < b1 and b0 < a1  # the two sleeps overlap in time


def test_failure_blocks_dependents_and_keeps_others(tmp_path):
    log = tmp_path / "log.txt"
    stages = [Stage("bad", f"{HERE}:fail", {"message": "boom"}),
              Stage("after_bad", f"{HERE}:append_line", {"path": str(log), "text": "after"}, deps=("bad",)),
              Stage("good", f"{HERE}:append_line", {"path": str(log), "text": "good"})]
    with pytest.raises(StageFailedError, match=r"bad: RuntimeError: boom.*not run because of them: \['after_bad'\]"):
        execute(StageGraph(stages), tmp_path, jobs=1, cores=2)
    assert log.read_text().split() == ["good"]
    assert is_done(tmp_path, "good") and not is_done(tmp_path, "bad") and not is_done(tmp_path, "after_bad")
    with pytest.raises(FileNotFoundError, match="stage 'bad' has not finished"):
        read_marker(tmp_path, "bad")


def test_a_worker_that_dies_fails_its_own_stage_only(tmp_path):
    """A worker killed by a signal (out of memory, a crash in native code) broke the whole process pool: the stage
    running beside it failed too, the rest never ran and the pool's error escaped. Now it fails alone, named with
    the signal; its dependents are blocked, everything else runs."""
    log = tmp_path / "log.txt"
    stages = [Stage("slow", f"{HERE}:sleep_and_time", {"path": str(tmp_path / "slow.json"), "seconds": 1.5}),
              Stage("killed", f"{HERE}:kill_myself", {}),
              Stage("after_killed", f"{HERE}:append_line", {"path": str(log), "text": "x"}, deps=("killed",)),
              Stage("later", f"{HERE}:append_line", {"path": str(log), "text": "later"})]
    report = execute(StageGraph(stages), tmp_path / "root", jobs=2, cores=2, raise_on_failure=False)
    assert sorted(report.ran) == ["later", "slow"] and report.blocked == ["after_killed"]
    assert report.failed == {"killed": "WorkerDied: the stage's process was ended by SIGKILL (killed: perhaps the "
                                       "machine ran out of memory)"}
    assert log.read_text().split() == ["later"] and not is_done(tmp_path / "root", "killed")


def test_a_failed_stages_traceback_is_logged_at_debug_level(tmp_path, caplog):
    """The one-line error names the exception; the worker's traceback (file and line of the bug) is logged at debug
    level, which `spotless -v` shows (it was dropped)."""
    import logging

    with caplog.at_level(logging.DEBUG, logger="spotlessgs.jobs.local"):
        report = execute(StageGraph([Stage("bug", f"{HERE}:key_error", {})]), tmp_path, jobs=1,
                         raise_on_failure=False)
    assert report.failed == {"bug": "KeyError: 'frame_width'"}
    traces = [r.getMessage() for r in caplog.records if r.levelno == logging.DEBUG and "traceback" in r.getMessage()]
    assert len(traces) == 1 and "in _lookup" in traces[0] and "test_reproduce_units.py" in traces[0]


def test_interrupted_stage_restarts_from_scratch(tmp_path):
    out = tmp_path / "work"
    crash = Stage("w", f"{HERE}:write_into", {"out_dir": str(out), "name": "partial", "crash": True}, output=out)
    with pytest.raises(StageFailedError, match="interrupted"):
        execute(StageGraph([crash]), tmp_path, jobs=1)
    assert (out / "partial").exists() and not marker_path(tmp_path, "w").exists()
    retry = Stage("w", f"{HERE}:write_into", {"out_dir": str(out), "name": "final", "crash": False}, output=out)
    report = execute(StageGraph([retry]), tmp_path, jobs=1)
    assert report.retried == ["w"]
    assert read_marker(tmp_path, "w")["result"]["found_before"] == []  # the partial file was deleted first
    # A resumable stage (clean_on_retry=False) keeps its partial output.
    out2 = tmp_path / "resumable"
    first = Stage("r", f"{HERE}:write_into", {"out_dir": str(out2), "name": "a", "crash": True}, output=out2,
                  clean_on_retry=False)
    with pytest.raises(StageFailedError):
        execute(StageGraph([first]), tmp_path, jobs=1)
    second = Stage("r", f"{HERE}:write_into", {"out_dir": str(out2), "name": "b", "crash": False}, output=out2,
                   clean_on_retry=False)
    execute(StageGraph([second]), tmp_path, jobs=1)
    assert read_marker(tmp_path, "r")["result"]["found_before"] == ["a"]


# ---------------------------------------------------------------------------------------------------------------------
# Tables and agreement


def _metrics(psnr_a, ssim_a=0.5, lpips_a=0.4, sfm=None, **extra):
    out = {"psnr": psnr_a - 1, "ssim": ssim_a - 0.1, "lpips": lpips_a + 0.1, "psnr_aligned": psnr_a,
           "ssim_aligned": ssim_a, "lpips_aligned": lpips_a, "tmp_psnr": 15.0, "tmp_ssim": 0.6}
    if sfm is not None:
        out["sfm"] = sfm
    out.update(extra)
    return out


def _sfm(reproj, obs, reg, total=12):
    return {"reprojection_error_px": reproj, "observations_per_image": obs, "registered_images": reg,
            "total_images": total, "trajectory": None}


def _collected():
    methods = {
        "3dgs": _metrics(14.0, 0.55, 0.45, _sfm(0.8, 300.0, 12)),
        "darkgs": _metrics(15.0, 0.60, 0.42, _sfm(0.7, 400.0, 12)),
        "darkgs-calibrated": _metrics(15.5, 0.61, 0.41, _sfm(0.65, 410.0, 12)),
        "darkgs+sh": _metrics(16.0, 0.65, 0.40, _sfm(0.6, 420.0, 12)),
        "darkgs+brdf": _metrics(15.2, 0.62, 0.41, _sfm(0.7, 405.0, 12)),
        "spotless": _metrics(16.5, 0.66, 0.39, _sfm(0.5, 450.0, 12)),
        "auto": _metrics(16.4, 0.65, 0.40, _sfm(0.55, 440.0, 12)),
    }
    fps = {"3dgs": 200.0, "darkgs": 300.0, "darkgs-calibrated": 290.0, "darkgs+sh": 120.0, "darkgs+brdf": 90.0,
           "spotless": 80.0, "auto": 150.0}
    gaussians = {"3dgs": 110, "darkgs": 120, "darkgs-calibrated": 130, "darkgs+sh": 140, "darkgs+brdf": 150,
                 "spotless": 100, "auto": 60}
    entries = {m: {"metrics": v, "train": {"seconds": 10.0, "selection_seconds": 0.0, "ms_per_step": 5.0,
                                           "num_gaussians": gaussians[m], "peak_rss_mb": 500.0, "device": "cpu"},
                   "relight": {"fps": fps[m], "peak_rss_mb": 300.0},
                   "curve": [{"step": 5, "train_seconds": 5.0, "psnr_aligned": v["psnr_aligned"] - 1},
                             {"step": 10, "train_seconds": 10.0, "psnr_aligned": v["psnr_aligned"]}],
                   "decisions": {"model chosen": m, "Gaussians": gaussians[m]}}
               for m, v in methods.items()}
    entries["auto"]["decisions"]["model chosen"] = "auto-sh1-lambert"
    entries["auto"]["train"].update(seconds=14.0, selection_seconds=4.0)
    entries["auto"]["selection"] = {"chosen": "auto-sh1-lambert", "best": "auto-sh3-mlp", "tolerance_db": 0.25,
                                    "seconds": 4.0}
    base = {"clahe": _metrics(12.0, sfm=_sfm(1.0, 200.0, 10)), "msrcr": _metrics(12.5, sfm=_sfm(1.1, 190.0, 9)),
            "cyclegan": _metrics(13.0, sfm=_sfm(1.2, 150.0, 8))}
    return {"datasets": {"bedroom-uneven": {
        "room": "bedroom", "variant": "uneven", "input": _metrics(12.0, 0.50, 0.50, _sfm(1.0, 350.0, 11)),
        "methods": entries, "baselines2d": {m: {"metrics": v, "runtime": {"fps": 50.0}} for m, v in base.items()}}},
        "cyclegan": {"seconds": 30.0}}


def test_best_darkgs_picks_higher_aligned_psnr():
    methods = _collected()["datasets"]["bedroom-uneven"]["methods"]
    assert best_darkgs(methods)[0] == "darkgs-calibrated"
    methods["darkgs"]["metrics"]["psnr_aligned"] = 20.0
    assert best_darkgs(methods)[0] == "darkgs"
    assert best_darkgs({"darkgs": {"metrics": {"psnr_aligned": None}}})[0] == "darkgs"
    assert best_darkgs({}) == (None, None)


def test_table1_rows_and_paper_numbers():
    t = table1(_collected())
    ours = [r for r in t.rows if r[0] == "bedroom-uneven"]
    assert [r[1] for r in ours] == ["Input (spotlight-lit)", "3DGS", "DarkGS (best: calibrated light)",
                                    "SpotlessGS (ours)", "SpotlessGS auto (selection + budget)"]
    assert ours[2][t.columns.index("PSNR (aligned)")] == 15.5
    assert t.columns[-2:] == ["Model chosen", "Gaussians"]
    # what each run needed: nothing for the inputs, the winning DarkGS run's model, auto's decision
    assert [r[-2:] for r in ours] == [[None, None], ["3dgs (no light)", 110],
                                      ["darkgs-calibrated (const+lambert +calibrated)", 130],
                                      ["spotless (sh3+mlp)", 100], ["auto-sh1-lambert", 60]]
    paper_rows = {r[1]: r for r in t.rows if r[0] == "paper (synthetic)"}
    assert paper_rows["SpotlessGS (ours)"][2:5] == [12.67, 0.727, 0.381]
    assert paper_rows["3DGS"][2:5] == [6.04, 0.391, 0.424]
    md = t.markdown()
    assert ("| bedroom-uneven | SpotlessGS (ours) | 15.50 | 0.560 | 0.490 | 16.50 | 0.660 | 0.390 | "
            "spotless (sh3+mlp) | 100 |") in md
    assert ("| bedroom-uneven | SpotlessGS auto (selection + budget) | 15.40 | 0.550 | 0.500 | 16.40 | 0.650 | 0.400 | "
            "auto-sh1-lambert | 60 |") in md
    assert "| paper (synthetic) | SpotlessGS (ours) | 12.67 | 0.727 | 0.381 | n/a | n/a | n/a | n/a | n/a |" in md


def test_model_chosen_cells_describe_light_and_brdf():
    assert {m: model_summary(m) for m in ("3dgs", "darkgs", "darkgs-calibrated", "darkgs+sh", "darkgs+brdf",
                                          "spotless")} == {
        "3dgs": "no light", "darkgs": "const+lambert", "darkgs-calibrated": "const+lambert +calibrated",
        "darkgs+sh": "sh3+lambert", "darkgs+brdf": "const+mlp", "spotless": "sh3+mlp"}
    assert model_summary("auto-sh2-mlp") == "sh2+mlp" and model_summary("auto-sh0-lambert") == "sh0+lambert"
    assert model_summary("auto-sh4-mlp") is None and model_summary("my-model") is None
    assert model_chosen_cell("spotless") == "spotless (sh3+mlp)"
    assert model_chosen_cell("auto-sh2-mlp") == "auto-sh2-mlp"  # the candidate's name already says it
    assert model_chosen_cell("my-model") == "my-model" and model_chosen_cell(None) is None


def test_auto_rows_in_tables_two_to_four():
    c = _collected()
    t2 = table2(c)
    auto2 = next(r for r in t2.rows if r[1] == "auto: selected SH degree / BRDF + Gaussian budget")
    assert auto2[t2.columns.index("PSNR (aligned)")] == 16.4 and auto2[-2:] == ["auto-sh1-lambert", 60]
    t3 = table3(c)
    auto3 = next(r for r in t3.rows if r[1] == "SpotlessGS auto (selection + budget)")
    assert auto3[2:5] == [0.55, 440.0, 12]
    t4 = table4(c)
    assert [r[1] for r in t4.rows if r[0] == "bedroom-uneven"][-2:] == ["SpotlessGS (ours)",
                                                                       "SpotlessGS auto (selection + budget)"]


def test_runtime_table_has_model_chosen_gaussians_and_selection_time():
    t = runtime_table(_collected())
    assert t.columns[:6] == ["Dataset", "Method", "Model chosen", "Gaussians", "Training time (s)",
                             "of which selection (s)"]
    rows = {r[1]: r for r in t.rows if r[0] == "bedroom-uneven"}
    assert rows["SpotlessGS auto (selection + budget)"][2:7] == ["auto-sh1-lambert", 60, 14.0, 4.0, 5.0]
    assert rows["SpotlessGS (ours)"][2:7] == ["spotless (sh3+mlp)", 100, 10.0, None, 5.0]  # no selection: n/a
    assert rows["DarkGS + SH light"][2:4] == ["darkgs+sh (sh3+lambert)", 140]
    # each row its own run's model and Gaussians: the plain DarkGS row showed the calibrated (better) run's
    assert rows["DarkGS"][2:4] == ["darkgs (const+lambert)", 120] and rows["DarkGS"][7] == 300.0
    assert rows["CLAHE"][2:5] == [None, None, None] and rows["Cycle-GAN"][4] == 30.0
    assert all(len(r) == len(t.columns) for r in t.rows)
    md = t.markdown()
    assert ("| bedroom-uneven | SpotlessGS auto (selection + budget) | auto-sh1-lambert | 60 | 14.0 | 4.0 | 5.0 | "
            "150.0 |") in md


def test_auto_against_spotless_notes():
    ds = _collected()["datasets"]["bedroom-uneven"]
    psnr, count = check_auto_vs_spotless("bedroom-uneven", ds)
    # 16.40 vs 16.50 dB: -0.10 dB, inside 0.25 + 0.2 dB; 60 vs 100 Gaussians: 40 % fewer
    assert psnr.status == "agrees" and psnr.claim == ("Auto on bedroom-uneven: relit PSNR (aligned) within the "
                                                      "selection tolerance plus the budget bound of SpotlessGS")
    assert psnr.text.startswith("auto (auto-sh1-lambert) 16.40 dB vs SpotlessGS 16.50 dB: -0.10 dB, within the 0.45 "
                                "dB allowed (0.25 dB selection tolerance")
    assert count.status == "agrees"
    assert count.text == "auto (auto-sh1-lambert, Gaussian budget) 60 vs SpotlessGS 100 Gaussians: 40.0 % fewer."
    # the light rule's measurements, where the run recorded them, say why the degree was chosen
    ds["methods"]["auto"]["selection"]["low_frequency_light"] = {
        "dark_level": 0.0539, "low_frequency_share": 0.0834, "measured_on": "auto-sh3-lambert-light", "needed": False}
    assert check_auto_vs_spotless("bedroom-uneven", ds)[0].text.startswith(
        "auto (auto-sh1-lambert; low-frequency light not needed (dark level 0.054, share 8.3%)) 16.40 dB")
    ds["methods"]["auto"]["metrics"]["psnr_aligned"] = 16.0  # -0.50 dB: outside
    ds["methods"]["auto"]["decisions"]["Gaussians"] = 125  # 25 % more
    psnr, count = check_auto_vs_spotless("bedroom-uneven", ds)
    assert psnr.status == "disagrees" and "-0.50 dB, outside the 0.45 dB allowed" in psnr.text
    assert count.status == "disagrees" and count.text.endswith("125 vs SpotlessGS 100 Gaussians: 25.0 % more.")
    ds["methods"]["auto"]["metrics"]["psnr_aligned"] = 16.05  # exactly at the allowance counts as within
    assert check_auto_vs_spotless("bedroom-uneven", ds)[0].status == "agrees"
    ds["methods"]["auto"]["metrics"]["psnr_aligned"] = 16.78  # better than the fixed model
    better = check_auto_vs_spotless("bedroom-uneven", ds)[0]
    assert better.status == "agrees"
    assert "+0.28 dB, no loss, at least as good as SpotlessGS (0.25 dB selection tolerance" in better.text
    del ds["methods"]["auto"]["selection"]
    ds["methods"]["spotless"]["decisions"]["Gaussians"] = None
    psnr, count = check_auto_vs_spotless("bedroom-uneven", ds)
    assert psnr.status == "unknown" and psnr.text == "Cannot check, no value for selection tolerance."
    assert count.status == "unknown" and count.text == "Cannot check: auto 125, SpotlessGS None Gaussians."
    del ds["methods"]["spotless"]
    assert check_auto_vs_spotless("bedroom-uneven", ds) == []


def test_table3_handles_unregistered_sequences():
    c = _collected()
    c["datasets"]["bedroom-uneven"]["methods"]["3dgs"]["metrics"]["sfm"] = _sfm(None, None, 0)
    t = table3(c)
    row = next(r for r in t.rows if r[1] == "3DGS")
    assert row[2] is None and row[4] == 0
    assert "| bedroom-uneven | 3DGS | n/a | n/a | 0 | n/a | n/a |" in t.markdown()


def test_table3_has_the_ground_truth_reference_and_the_real_paper_rows():
    c = _collected()
    ds = c["datasets"]["bedroom-uneven"]
    assert not any(r[1] == GT_SFM_LABEL for r in table3(c).rows)  # no reference scored: no row
    ds["input"]["sfm_gt"] = dict(_sfm(0.9, 500.0, 12), models=2, trajectory={"ate_rmse": 0.01})
    t = table3(c)
    rows = [r for r in t.rows if r[0] == "bedroom-uneven"]
    assert rows[-1] == ["bedroom-uneven", GT_SFM_LABEL, 0.9, 500.0, 12, 2, 0.01]  # after the dataset's methods
    assert {r[0] for r in t.rows if r[1] == "SpotlessGS (ours)"} == {"bedroom-uneven", "paper (real, self-collected)"}
    note = check_sfm("c", _sfm(0.5, 100.0, 8), _sfm(0.4, 90.0, 8), "relit", ds["input"]["sfm_gt"])
    assert note.status == "disagrees"  # the reference is quoted, it does not change the verdict
    assert "evenly lit ground truth (reference): 12 registered, 0.900 px, 500.0 observations per image" in note.text


def test_all_tables_present_with_finite_numbers():
    tables = all_tables(_collected())
    assert [t.key for t in tables] == ["table1", "table2", "table3", "table4", "runtime"]
    for t in tables:
        ours = [r for r in t.rows if not str(r[0]).startswith("paper")]
        assert ours, t.key
        for r in ours:
            nums = [v for v in r[2:] if isinstance(v, (int, float))]
            assert nums and all(math.isfinite(v) for v in nums), (t.key, r)


def test_check_order_agrees_disagrees_unknown():
    ok = check_order("c", {"A": 3.0, "B": 2.0, "C": 1.0}, ["A", "B", "C"], True, "dB", {"A": 9, "B": 8, "C": 7}, 1)
    assert ok.status == "agrees"
    assert ok.text == ("Paper: A > B > C (9.0 > 8.0 > 7.0 dB). Ours: A 3.0, B 2.0, C 1.0 dB — same ordering as the "
                       "paper.")
    bad = check_order("c", {"A": 3.0, "B": 4.0, "C": 1.0}, ["A", "B", "C"], True)
    assert bad.status == "disagrees" and "disagrees with the paper's ordering: A ≤ B." in bad.text
    low = check_order("c", {"A": 0.5, "B": 0.4}, ["A", "B"], False)
    assert low.status == "disagrees" and "A ≥ B" in low.text
    unknown = check_order("c", {"A": 3.0, "B": float("nan")}, ["A", "B"], True)
    assert unknown.status == "unknown" and "no value for B" in unknown.text


def test_check_at_least():
    ours, ref = {"psnr": 20.0, "lpips": 0.3}, {"psnr": 18.0, "lpips": 0.35}
    assert check_at_least("c", ours, ref, {"psnr": True, "lpips": False}, "ours", "ref").status == "agrees"
    worse = check_at_least("c", ours, {"psnr": 21.0, "lpips": 0.2}, {"psnr": True, "lpips": False}, "ours", "ref")
    assert worse.status == "disagrees" and worse.text.endswith("worse on psnr, lpips.")
    none = check_at_least("c", {"r": None}, {"r": 1.0}, {"r": False}, "ours", "ref")
    assert none.status == "unknown"


def test_check_sfm():
    assert check_sfm("c", _sfm(0.5, 100.0, 10), _sfm(None, None, 0), "relit").status == "agrees"  # more registered
    assert check_sfm("c", _sfm(0.5, 100.0, 5), _sfm(0.9, 100.0, 8), "relit").status == "disagrees"
    assert check_sfm("c", _sfm(0.5, 100.0, 8), _sfm(0.9, 100.0, 8), "relit").status == "agrees"
    worse = check_sfm("c", _sfm(1.5, 100.0, 8), _sfm(0.9, 100.0, 8), "relit")
    assert worse.status == "disagrees" and worse.text.endswith("as many registered, higher error.")
    none = check_sfm("c", _sfm(None, None, 0), _sfm(None, None, 0), "relit")
    assert none.status == "unknown" and "no image registered in either sequence" in none.text
    # with the observations' rings the higher error is shown where it comes from (the verdict is unchanged)
    def rings(n_inner, err_inner, n_outer, err_outer):
        return [{"radius": [0.0, 0.5], "observations": n_inner, "mean_error_px": err_inner},
                {"radius": [0.5, 1.0], "observations": n_outer, "mean_error_px": err_outer}]

    relit = {**_sfm(0.3, 100.0, 8), "reprojection_error_by_radius": rings(50, 0.25, 50, 0.35)}
    original = {**_sfm(0.2, 60.0, 8), "reprojection_error_by_radius": rings(90, 0.18, 10, 0.4)}
    ringed = check_sfm("c", relit, original, "relit")
    assert ringed.status == "disagrees"
    assert ringed.text.endswith("original: 0–0.5 90% · 0.180, 0.5–1 10% · 0.400; "
                                "relit: 0–0.5 50% · 0.250, 0.5–1 50% · 0.350.")
    assert "as many registered, higher error. Reprojection error by image radius" in ringed.text
    assert check_sfm("c", relit, _sfm(0.2, 60.0, 8), "relit").text.endswith("higher error.")  # original lacks rings


def test_agreement_notes_on_hand_made_results():
    notes = {n.claim: n for n in agreement_notes(_collected())}
    assert notes["Table I ordering on bedroom-uneven (psnr_aligned)"].status == "agrees"
    # LPIPS: the paper ranks SpotlessGS < 3DGS < DarkGS; here DarkGS (0.41) beats 3DGS (0.45).
    assert notes["Table I ordering on bedroom-uneven (lpips_aligned)"].status == "disagrees"
    # Ablation: paper spotless > +SH > +BRDF > DarkGS; here +BRDF 15.2 < DarkGS (calibrated) 15.5.
    t2 = notes["Table II ordering on bedroom-uneven (psnr_aligned)"]
    assert t2.status == "disagrees" and "+BRDF ≤ DarkGS" in t2.text
    assert notes["Acceptance on bedroom-uneven: SpotlessGS beats Original on aligned metrics"].status == "agrees"
    sfm = notes["Acceptance on bedroom-uneven: SfM on SpotlessGS's relit sequence at least as good as on the original"]
    assert sfm.status == "agrees"
    assert notes["Table III ordering on bedroom-uneven (reprojection error)"].status == "agrees"
    # observations: paper spotless > darkgs > original > 3dgs; here original 350 < darkgs-cal 410 and > 3dgs 300
    assert notes["Table III ordering on bedroom-uneven (observations per image)"].status == "agrees"
    assert notes["Table IV on bedroom-uneven (psnr)"].status == "agrees"
    assert notes["Runtime ordering on bedroom-uneven (relit FPS)"].status == "agrees"
    assert notes["Auto on bedroom-uneven: no more Gaussians than SpotlessGS"].status == "agrees"


def _with_noisy_copy():
    """_collected() plus a sensor-noise copy on which only SpotlessGS was trained (its original barely registers)."""
    collected = _collected()
    spotless = collected["datasets"]["bedroom-uneven"]["methods"]["spotless"]
    collected["datasets"]["bedroom-uneven-noisy"] = {
        "room": "bedroom", "variant": "uneven-noisy", "sensor_noise": {"shot": 0.002, "read": 0.004, "written": 12},
        "input": _metrics(11.0, 0.40, 0.60, _sfm(0.45, 50.0, 3)),
        "methods": {"spotless": {**spotless, "metrics": _metrics(16.3, 0.65, 0.40, _sfm(0.5, 420.0, 12))}},
        "baselines2d": {}}
    return collected


def test_sensor_noise_copy_in_tables_and_notes():
    collected = _with_noisy_copy()
    t1, t2, t3 = table1(collected), table2(collected), table3(collected)
    assert [r[1] for r in t1.rows if r[0] == "bedroom-uneven-noisy"] == ["Input (spotlight-lit)", "SpotlessGS (ours)"]
    assert not [r for r in t2.rows if r[0] == "bedroom-uneven-noisy"]  # one run is no ablation
    noisy_sfm = [r for r in t3.rows if r[0] == "bedroom-uneven-noisy"]
    assert [(r[1], r[4]) for r in noisy_sfm] == [("Original (spotlight-lit)", 3), ("SpotlessGS (ours)", 12)]
    assert any(n.startswith("bedroom-uneven-noisy: the uneven renders with camera sensor noise (shot variance 0.002")
               for n in t3.notes)
    notes = {n.claim: n for n in agreement_notes(collected)}
    sfm = notes["Acceptance on bedroom-uneven-noisy: SfM on SpotlessGS's relit sequence at least as good as on the "
                "original"]
    assert sfm.status == "agrees" and "12 registered images" in sfm.text
    assert notes["Acceptance on bedroom-uneven-noisy: SpotlessGS beats Original on aligned metrics"].status == "agrees"
    # orderings that need methods not trained on the copy are not checked there (no "cannot check" noise)
    noisy_claims = [c for c in notes if "bedroom-uneven-noisy" in c]
    assert len(noisy_claims) == 2
    assert len(notes) - 2 == len(agreement_notes(_collected()))


def test_format_cell():
    assert format_cell(None) == "n/a" and format_cell(float("inf")) == "n/a" and format_cell(1.23456, 2) == "1.23"
    assert format_cell(3) == "3" and format_cell(True) == "yes"


def test_thread_env_is_set_in_workers(tmp_path, monkeypatch):
    monkeypatch.setenv("OMP_NUM_THREADS", "7")
    stage = Stage("env", f"{HERE}:thread_env", {})
    execute(StageGraph([stage]), tmp_path, jobs=2, cores=4)
    marker = read_marker(tmp_path, "env")
    assert marker["threads"] == 2 and marker["result"] == {"omp": "2", "threads_arg": 2}
    assert os.environ["OMP_NUM_THREADS"] == "7"  # the parent's environment is untouched


def test_report_errors_name_the_missing_piece(tmp_path):
    from spotlessgs.experiments.reproduce.report import collect, load_config

    with pytest.raises(FileNotFoundError, match="not a reproduction folder"):
        load_config(tmp_path)
    check_or_record_config(preset("tiny"), tmp_path)
    assert load_config(tmp_path) == preset("tiny")  # the recorded config reads back identically
    with pytest.raises(FileNotFoundError, match="stage 'cyclegan/train' has not finished"):
        collect(tmp_path, preset("tiny"))
    with pytest.raises(FileNotFoundError, match="stage 'eval-inputs/bedroom-uneven' has not finished"):
        collect(tmp_path, preset("tiny", baselines=()))
    write_marker(tmp_path, "eval-inputs/bedroom-uneven", {"result": {"metrics": {"psnr": 9.0}}})
    with pytest.raises(FileNotFoundError, match="stage 'ceiling/bedroom-uneven' has not finished"):
        collect(tmp_path, preset("tiny", baselines=()))
    write_marker(tmp_path, "ceiling/bedroom-uneven", {"result": {"skipped": "no albedo pass"}})
    with pytest.raises(FileNotFoundError, match="stage 'train/bedroom-uneven/3dgs' has not finished"):
        collect(tmp_path, preset("tiny", baselines=()))


def test_collect_reads_the_inputs_once_per_dataset_from_their_stage(tmp_path):
    """The Input rows (Tables I, III, IV, the agreement notes) come from each dataset's eval-inputs marker, not from
    a method's metrics."""
    from spotlessgs.experiments.reproduce.report import collect

    config = preset("tiny", methods=("3dgs", "spotless"), baselines=(), robot_camera=False)
    check_or_record_config(config, tmp_path)
    hand = _collected()["datasets"]["bedroom-uneven"]
    for variant, psnr in (("uneven", 11.0), ("saturated", 7.0)):
        ds = f"bedroom-{variant}"
        write_marker(tmp_path, f"eval-inputs/{ds}", {"result": {"metrics": _metrics(psnr, 0.5, 0.5,
                                                                                     _sfm(1.0, 350.0, 11))},
                                                      "seconds": 2.0, "peak_rss_mb": 1.0})
        ceiling = ({"metrics": {"albedo-sh": {"psnr_aligned_masked": 21.0}, "albedo": {"psnr_aligned_masked": 20.0}}}
                   if variant == "uneven" else {"skipped": "no albedo pass"})  # a dataset from before the passes
        write_marker(tmp_path, f"ceiling/{ds}", {"result": ceiling, "seconds": 1.0, "peak_rss_mb": 1.0})
        for method in config.methods:
            write_marker(tmp_path, f"train/{ds}/{method}", {"result": {k: v for k, v in hand["methods"][method].items()
                                                                      if k != "decisions"},
                                                            "seconds": 1.0, "peak_rss_mb": 1.0})
            write_json(tmp_path / "runs" / ds / method / "run.json", {"model": method})
    # the sensor-noise copy: its own inputs' evaluation and noise record, SpotlessGS only
    noisy = "bedroom-uneven-noisy"
    write_marker(tmp_path, f"noise/{noisy}", {"result": {"shot": 0.002, "read": 0.004, "written": 12},
                                              "seconds": 1.0, "peak_rss_mb": 1.0})
    write_marker(tmp_path, f"eval-inputs/{noisy}", {"result": {"metrics": _metrics(5.0, sfm=_sfm(0.4, 50.0, 3))},
                                                    "seconds": 2.0, "peak_rss_mb": 1.0})
    write_marker(tmp_path, f"ceiling/{noisy}", {"result": {"skipped": "no albedo pass"}, "seconds": 1.0,
                                                "peak_rss_mb": 1.0})
    write_marker(tmp_path, f"train/{noisy}/spotless", {"result": {k: v for k, v in hand["methods"]["spotless"].items()
                                                                 if k != "decisions"},
                                                       "seconds": 1.0, "peak_rss_mb": 1.0})
    write_json(tmp_path / "runs" / noisy / "spotless" / "run.json", {"model": "spotless"})
    collected = collect(tmp_path, config)
    assert list(collected["datasets"]) == ["bedroom-uneven", "bedroom-saturated", noisy]
    assert set(collected["datasets"][noisy]["methods"]) == {"spotless"}
    assert collected["datasets"][noisy]["sensor_noise"]["shot"] == 0.002
    assert collected["datasets"][noisy]["input"]["psnr_aligned"] == 5.0
    for variant, psnr in (("uneven", 11.0), ("saturated", 7.0)):
        ds = collected["datasets"][f"bedroom-{variant}"]
        assert ds["input"] == _metrics(psnr, 0.5, 0.5, _sfm(1.0, 350.0, 11))
        assert all("input" not in m["metrics"] for m in ds["methods"].values())
    t1 = table1(collected)
    assert [r[1:4] for r in t1.rows if r[1] == "Input (spotlight-lit)"] == [["Input (spotlight-lit)", 10.0, 0.4],
                                                                             ["Input (spotlight-lit)", 6.0, 0.4],
                                                                             ["Input (spotlight-lit)", 4.0, 0.4]]
    assert [r[1:4] for r in table3(collected).rows if r[1] == "Original (spotlight-lit)" and r[0].startswith("bed")] \
        == [["Original (spotlight-lit)", 1.0, 350.0]] * 2 + [["Original (spotlight-lit)", 0.4, 50.0]]
    notes = {n.claim: n for n in agreement_notes(collected)}
    beats = notes["Acceptance on bedroom-saturated: SpotlessGS beats Original on aligned metrics"]
    assert beats.status == "agrees" and "psnr_aligned 16.500 vs 7.000" in beats.text
    # the ceiling: only the dataset whose renders have the passes; SpotlessGS has no lamp-masked figures here
    assert collected["datasets"]["bedroom-saturated"]["ceiling"] == {}
    rows = [r for r in ceiling_table(collected).rows]
    assert {r[0] for r in rows} == {"bedroom-uneven"} and rows[0][1].startswith("Ceiling") and rows[0][-1] == 0.0
    assert rows[1][-1] == pytest.approx(1.0)  # albedo × one gain: 1 dB below the SH oracle
    ceiling_note = next(n for c, n in notes.items() if c.startswith("Ceiling on bedroom-uneven"))
    assert ceiling_note.status == "unknown"
    assert "ceiling" in [t.key for t in all_tables(collected)]


@pytest.mark.parametrize("name", ["tiny", "quick", "paper", "components"])
def test_every_preset_camera_loop_is_admissible(name):
    """The simulator can place every frame of every room a preset renders (the shipped bedroom, e.g., admits no
    40-48 or 316-frame loop with seed 0)."""
    from simulator.front3d import LoadOptions
    from simulator.render_pipeline import RenderConfig, plan_poses

    config = preset(name)
    rooms = [(r, config.frames) for r, _ in config.datasets()] + [(r, config.gan_frames) for r in config.gan_rooms]
    for room, frames in rooms:
        render = RenderConfig.from_preset("uneven", frames=frames, seed=config.seed)
        poses = plan_poses(config.scene_file(room), render, LoadOptions())[3]
        assert len(poses) == frames, room


def _start_pipeline(script: str, tmp_path: Path, **popen_kwargs):
    """Run ``script`` (a pipeline whose one stage is :func:`sleep_forever`) in a new Python process; return the
    process and the stage worker's pid once the stage runs. The script gets sys.argv = [tests dir, repository root,
    pid file, pipeline root]. SIGINT is restored to its default in the new process (a shell without job control
    that started the test suite in the background ignores SIGINT in it, and Python would then never raise
    KeyboardInterrupt)."""
    import signal
    import subprocess
    import sys

    pid_file = tmp_path / "pid"
    here, root = str(Path(__file__).parent), str(Path(__file__).parents[1])
    parent = subprocess.Popen([sys.executable, "-c", script, here, root, str(pid_file), str(tmp_path / "root")],
                              preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL), **popen_kwargs)
    deadline = time.time() + 60
    while not pid_file.exists() or not pid_file.read_text():
        assert time.time() < deadline and parent.poll() is None, "the stage never started"
        time.sleep(0.2)
    return parent, int(pid_file.read_text())


def test_workers_die_with_the_parent(tmp_path):
    """Killing the pipeline's process stops its running stage (no orphan keeps working without a parent)."""
    import signal

    script = (
        "import sys; sys.path[:0] = sys.argv[1:3]\n"
        "from spotlessgs.jobs.local import execute_local as execute\n"
        "from spotlessgs.jobs.graph import Stage, StageGraph\n"
        "if __name__ == '__main__':\n"
        "    execute(StageGraph([Stage('s', 'test_reproduce_units:sleep_forever', {'path': sys.argv[3]})]), "
        "sys.argv[4], jobs=1)\n"
    )
    parent, worker = _start_pipeline(script, tmp_path)
    parent.send_signal(signal.SIGKILL)
    parent.wait()
    deadline = time.time() + 10
    while time.time() < deadline:
        try:
            os.kill(worker, 0)
        except ProcessLookupError:
            break
        time.sleep(0.2)
    else:
        os.kill(worker, signal.SIGKILL)
        pytest.fail("the worker outlived its parent")
    assert not is_done(tmp_path / "root", "s")


def test_workers_drop_blender_script_paths_inherited_from_the_parent(monkeypatch):
    """A parent that imported bpy passes Blender's script folders to spawned children, where they would shadow the
    compiled bpy module ("No module named '_bpy'"); the worker initialiser removes them and nothing else."""
    import sys

    from spotlessgs.io.processes import drop_blender_script_paths as _drop_blender_script_paths

    fake = ["/x/site-packages/bpy/5.0/scripts/modules", "/x/site-packages/bpy/5.0/scripts/startup"]
    keep = ["/x/site-packages", "/work/bpy-notes", "/x/scripts"]
    monkeypatch.setattr(sys, "path", keep[:1] + fake + keep[1:])
    _drop_blender_script_paths()
    assert sys.path == keep


@pytest.mark.parametrize("signame", ["SIGTERM", "SIGINT"])
def test_a_stopped_pipeline_stops_its_workers_without_a_traceback(tmp_path, signame):
    """A signal to the pipeline's process ends the running stage's worker within seconds; the pool's own threads
    print nothing (a pool shut down before its workers were stopped failed in its manager thread)."""
    import signal
    import subprocess

    script = (
        "import sys; sys.path[:0] = sys.argv[1:3]\n"
        "from spotlessgs.io.signals import raise_on_sigterm\n"
        "from spotlessgs.jobs.local import execute_local as execute\n"
        "from spotlessgs.jobs.graph import Stage, StageGraph\n"
        "if __name__ == '__main__':\n"
        "    raise_on_sigterm()\n"
        "    try:\n"
        "        execute(StageGraph([Stage('s', 'test_reproduce_units:sleep_forever', {'path': sys.argv[3]})]), "
        "sys.argv[4], jobs=1)\n"
        "    except KeyboardInterrupt as exc:\n"
        "        print('stopped by', type(exc).__name__, file=sys.stderr)\n"
        "        sys.exit(3)\n"
    )
    parent, worker = _start_pipeline(script, tmp_path, stderr=subprocess.PIPE, text=True)
    parent.send_signal(getattr(signal, signame))
    _out, err = parent.communicate(timeout=30)
    assert parent.returncode == 3, err
    assert "stopped by" in err and "Traceback" not in err, err
    try:
        os.kill(worker, 0)
    except ProcessLookupError:
        pass
    else:
        os.kill(worker, signal.SIGKILL)
        pytest.fail("the worker outlived the stopped pipeline")
    assert not is_done(tmp_path / "root", "s")


def test_the_relight_process_measures_its_own_peak_memory_not_its_parents():
    """ru_maxrss is carried over from the parent across fork and exec: the relit peak memory column repeated the
    training process's peak in every row. VmHWM starts afresh with the process."""
    import resource
    import subprocess
    import sys

    import numpy as np

    ballast = np.ones(300 * 2**20 // 8)  # 300 MiB touched in this (the parent) process
    parent_peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0
    code = "from spotlessgs.experiments.reproduce.relight_process import _peak_rss_mb; print(_peak_rss_mb())"
    child_peak = float(subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                                      check=True).stdout)
    assert ballast.sum() > 0 and parent_peak > 300 and child_peak < parent_peak - 200, (parent_peak, child_peak)


def test_the_report_says_where_and_with_how_many_threads_the_stages_ran(tmp_path):
    """A folder resumed with another --jobs mixed thread counts, and the report never said so (its numbers depend on
    the thread count, its times on the machine)."""
    from spotlessgs.experiments.reproduce.report import _machine_lines

    write_marker(tmp_path, "a", {"result": {}, "seconds": 1.0, "threads": 1, "host": "node1", "deps": []})
    write_marker(tmp_path, "report", {"result": {}, "seconds": 1.0, "threads": 4, "host": "other", "deps": []})
    lines = _machine_lines(tmp_path)
    assert lines[0].startswith("Threads per stage: 1; host(s): node1; this report written on ")
    assert not any("Mixed" in line for line in lines)  # the report's own marker does not count
    write_marker(tmp_path, "b", {"result": {}, "seconds": 1.0, "threads": 2, "host": "node1", "deps": []})
    lines = _machine_lines(tmp_path)
    assert lines[0].startswith("Threads per stage: 1, 2; host(s): node1") and lines[1].startswith("**Mixed**")
