"""render-many's planning (scenes, dataset names, frame ranges, the task graph), frame parts and its command-line
errors; the renders themselves run in tests/test_ray_executor.py (on a Ray cluster and locally)."""

from __future__ import annotations

from pathlib import Path

import pytest
from click.testing import CliRunner

from simulator.cli import main as sim_main
from simulator.render_many import build_render_graph, find_scenes, frame_ranges, plan_jobs, render_config
from simulator.render_pipeline import FramePart, scratch_dir
from spotlessgs.io.errors import InputError

ROOT = Path(__file__).resolve().parents[1]
SCENES = ROOT / "scenes"


def test_scenes_from_globs_paths_comma_lists_and_list_files(tmp_path):
    everything = find_scenes([str(SCENES / "*" / "house.json")])
    assert [p.parent.name for p in everything] == ["bedroom", "corridor", "living_room", "office", "storage_room",
                                                   "white_room"]
    listed = tmp_path / "rooms.txt"
    listed.write_text(f"# two rooms\n{SCENES / 'office' / 'house.json'}\n\n{SCENES / 'bedroom' / 'house.json'}  # x\n")
    assert [p.parent.name for p in find_scenes([str(listed)])] == ["office", "bedroom"]
    both = f"{SCENES / 'office' / 'house.json'},{SCENES / 'office' / 'house.json'}"
    assert len(find_scenes([both])) == 1  # a room named twice renders once
    with pytest.raises(InputError, match="no house file matches this pattern"):
        find_scenes([str(SCENES / "*" / "missing.json")])
    with pytest.raises(InputError, match="no such house file"):
        find_scenes([str(tmp_path / "nothing.json")])


def test_dataset_names_and_a_clash_between_two_rooms(tmp_path):
    jobs = plan_jobs(find_scenes([str(SCENES / "office" / "house.json")]), ["uneven", "saturated"], tmp_path)
    assert [j.out_dir for j in jobs] == [tmp_path / "office-uneven", tmp_path / "office-saturated"]
    other = tmp_path / "b" / "office.json"  # a 3D-FRONT file is named after its house: office
    other.parent.mkdir()
    other.write_text("{}")
    with pytest.raises(InputError, match="its room name 'office' is also that of"):
        plan_jobs([SCENES / "office" / "house.json", other], ["uneven"], tmp_path)


def test_frame_ranges_and_the_task_graph(tmp_path):
    assert frame_ranges(5, 2) == [(0, 2), (2, 4), (4, 5)]
    assert frame_ranges(4, 10) == [(0, 4)]
    jobs = plan_jobs([SCENES / "bedroom" / "house.json"], ["uneven", "saturated"], tmp_path)
    graph = build_render_graph(jobs, {"frames": 5, "width": 32, "height": 24, "samples": 2}, frames_per_task=2)
    finish = graph["finish/bedroom-saturated"]
    assert finish.deps == ("render/bedroom-saturated/frames-0-2", "render/bedroom-saturated/frames-2-4",
                           "render/bedroom-saturated/frames-4-5")
    task = graph["render/bedroom-uneven/frames-2-4"]
    assert task.kwargs["frame_range"] == [2, 4] and not task.clean_on_retry and task.resources.memory_mb > 0
    assert len(graph) == 2 * 4
    from simulator.trajectory import PATHS

    robot = render_config("saturated", {"frames": 5, "path": "robot"})
    assert robot.trajectory == PATHS["robot"] and robot.preset == "saturated" and robot.frames == 5
    with pytest.raises(ValueError, match="unknown render setting"):
        render_config("uneven", {"frame": 5})


def test_frame_parts():
    assert FramePart().frames(5) == [0, 1, 2, 3, 4] and FramePart().owns_folder
    assert FramePart((1, 2)).frames(5) == [1, 3] and FramePart((1, 2)).label == "1of2"
    part = FramePart(frame_range=(2, 4))
    assert part.frames(5) == [2, 3] and part.label == "frames-2-4" and not part.owns_folder
    assert scratch_dir("/d", part) == Path("/d/.render-scratch-frames-2-4") == scratch_dir("/d", part)
    assert scratch_dir("/d", (1, 2)) == Path("/d/.render-scratch-1of2")
    with pytest.raises(ValueError, match="beyond the dataset's 3 frames"):
        part.frames(3)
    with pytest.raises(ValueError, match="cannot be combined"):
        FramePart((0, 2), (0, 1))
    with pytest.raises(ValueError, match="need 0 <= start < stop"):
        FramePart(frame_range=(3, 3))


@pytest.mark.parametrize("args, message", [
    (["--scenes", "nowhere/*/house.json"], "nowhere/*/house.json: no house file matches this pattern"),
    (["--scenes", str(SCENES / "office" / "house.json"), "--variants", "uneven,dim"], "unknown variant(s) ['dim']"),
    (["--scenes", str(SCENES / "office" / "house.json"), "--frames-per-task", "0"], "--frames-per-task"),
    (["--scenes", str(SCENES / "office" / "house.json"), "--executor", "slurm"], "--executor"),
])
def test_bad_command_lines_are_one_clear_line_and_write_nothing(tmp_path, args, message):
    out = tmp_path / "out"
    result = CliRunner().invoke(sim_main, ["render-many", "--out", str(out), *args])
    assert result.exit_code == 2, result.output
    assert message in result.output
    assert not out.exists()


def _closed_port() -> int:
    import socket

    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        return sock.getsockname()[1]  # nothing listens once the socket is closed


@pytest.mark.parametrize("command", ["render", "render-many"])
def test_another_tools_dataset_is_never_rendered_into(tmp_path, command):
    """`render --out` over a dataset of another tool replaced its first frames and transforms.json and kept the rest:
    two datasets in one folder. A folder of files without our plan.json is refused before Blender starts."""
    scene = SCENES / "white_room" / "house.json"
    other = tmp_path / "out" / "white_room-uneven"
    (other / "images").mkdir(parents=True)
    (other / "images" / "frame_00000.png").write_bytes(b"theirs")
    (other / "transforms.json").write_text("{}")
    before = {p: p.read_bytes() for p in other.rglob("*") if p.is_file()}
    args = (["render", "--scene", str(scene), "--out", str(other)] if command == "render" else
            ["render-many", "--scenes", str(scene), "--out", str(tmp_path / "out"), "--variants", "uneven"])
    result = CliRunner().invoke(sim_main, [*args, "--frames", "2", "--width", "16", "--height", "16", "--samples", "1"])
    assert result.exit_code == 2, result.output
    assert "white_room-uneven: holds files but no plan.json (images, transforms.json): not a dataset this renderer " \
        "began" in result.output
    assert {p: p.read_bytes() for p in other.rglob("*") if p.is_file()} == before


def test_a_cluster_that_is_not_there_is_said_at_once_and_nothing_is_written(tmp_path):
    pytest.importorskip("ray")
    address = f"127.0.0.1:{_closed_port()}"
    out = tmp_path / "renders"
    result = CliRunner().invoke(sim_main, ["render-many", "--scenes", str(SCENES / "office" / "house.json"), "--out",
                                           str(out), "--executor", "ray", "--ray-address", address])
    assert result.exit_code == 1 and f"{address}: no Ray cluster answers there" in result.output
    assert not out.exists()
    from spotlessgs.cli import main

    repro = tmp_path / "repro"
    result = CliRunner().invoke(main, ["reproduce", "--preset", "tiny", "--out", str(repro), "--executor", "ray",
                                       "--ray-address", address])
    assert result.exit_code == 1 and "no Ray cluster answers there" in result.output
    assert not repro.exists()


def test_a_rerun_with_other_settings_is_refused_before_any_task_runs(tmp_path):
    """A dataset of the root rendered with other settings (its plan.json says which) is refused in one line naming
    it and the settings, before any task runs: a rerun would otherwise skip the finished tasks and report the old
    dataset complete."""
    import json

    from simulator.render_pipeline import _fingerprint

    scene = SCENES / "white_room" / "house.json"
    first = {"frames": 2, "width": 16, "height": 16, "samples": 1, "seed": 0, "path": "paper"}
    dataset = tmp_path / "out" / "white_room-uneven"
    dataset.mkdir(parents=True)
    plan = {"schema": 1, "fingerprint": _fingerprint(scene, render_config("uneven", first), None), "poses": []}
    (dataset / "plan.json").write_text(json.dumps(plan))
    base = ["render-many", "--scenes", str(scene), "--out", str(tmp_path / "out"), "--frames", "2", "--samples", "1",
            "--path", "paper"]
    result = CliRunner().invoke(sim_main, [*base, "--width", "32", "--height", "24", "--seed", "7"])
    assert result.exit_code != 0 and len(result.output.strip().splitlines()) == 1, result.output
    assert "white_room-uneven holds a dataset rendered with other settings (differs in: height, seed, width)" in \
        result.output
    assert sorted(p.name for p in (tmp_path / "out").iterdir()) == ["white_room-uneven"]
    assert json.loads((dataset / "plan.json").read_text()) == plan


def test_scene_lists_that_name_themselves_or_are_not_text_are_one_line(tmp_path):
    loop = tmp_path / "a.txt"
    loop.write_text("b.txt\n")
    (tmp_path / "b.txt").write_text("a.txt  # back to the first\n")
    with pytest.raises(InputError, match=r"a\.txt: the scene list names itself \(through .*b\.txt\)"):
        find_scenes([str(loop)])
    binary = tmp_path / "c.txt"
    binary.write_bytes(b"\xff\xfe\x00scenes")
    with pytest.raises(InputError, match=r"c\.txt: the scene list is not UTF-8 text"):
        find_scenes([str(binary)])


def test_benchmark_refuses_sample_counts_below_one(tmp_path):
    result = CliRunner().invoke(sim_main, ["benchmark", "--scene", str(SCENES / "office" / "house.json"),
                                           "--out", str(tmp_path / "bench"), "--samples", "4,0,-3"])
    assert result.exit_code == 2 and "expected sample counts of at least 1" in result.output, result.output
    assert not (tmp_path / "bench").exists()
    # found after minutes of rendering: an --out under a file, counts twice or at the reference's
    (tmp_path / "house.json").write_text("{}")
    for out, samples, problem in ((tmp_path / "house.json" / "bench", "4", "--out cannot be made a folder"),
                                  (tmp_path / "b2", "4,4", "each count once and below --reference-samples"),
                                  (tmp_path / "b3", "4,512", "each count once and below --reference-samples (512)")):
        result = CliRunner().invoke(sim_main, ["benchmark", "--scene", str(SCENES / "office" / "house.json"),
                                               "--out", str(out), "--samples", samples, "--reference-samples", "512"])
        assert result.exit_code == 2 and problem in result.output, result.output


@pytest.mark.parametrize("plan, problem", [
    ("[1]", r"plan\.json: .*not a JSON object|plan\.json: .*expected"),
    ("{not json", r"plan\.json: .*JSON"),
    ('{"fingerprint": {}, "poses": "abc"}', r"plan\.json: damaged render plan: 'poses'"),
])
def test_a_damaged_plan_json_is_one_line_naming_it(tmp_path, plan, problem):
    """A render into a folder whose plan.json is damaged names the file (was a KeyError or AttributeError)."""
    import json

    from simulator.render_pipeline import ExecutionOptions, _fingerprint, render_dataset

    scene = SCENES / "white_room" / "house.json"
    config = render_config("uneven", {"frames": 2, "width": 16, "height": 16, "samples": 1})
    out = tmp_path / "out"
    out.mkdir()
    if "poses" in plan:  # the settings match: only the poses are damaged
        plan = json.dumps({**json.loads(plan), "fingerprint": _fingerprint(scene, config, None)})
    (out / "plan.json").write_text(plan)
    with pytest.raises((InputError, RuntimeError), match=problem):
        render_dataset(scene, out, config, execution=ExecutionOptions(progress=False))
    assert (out / "plan.json").read_text() == plan
