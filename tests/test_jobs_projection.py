"""The projection of a finished job onto N nodes (spotlessgs.jobs.projection), against schedules worked out by hand."""

from __future__ import annotations

import pytest
from click.testing import CliRunner

from spotlessgs.cli import main
from spotlessgs.io.errors import InputError
from spotlessgs.jobs.graph import write_marker
from spotlessgs.jobs.projection import MeasuredStage, critical_path, project, read_measured_stages

# a(10) and b(20) feed c(5); d(8) is independent
STAGES = [MeasuredStage("render/a", 10.0, 1, ()), MeasuredStage("render/b", 20.0, 1, ()),
          MeasuredStage("train/c", 5.0, 1, ("render/a", "render/b")), MeasuredStage("eval/d", 8.0, 1, ())]


def test_critical_path_is_the_longest_chain():
    assert critical_path(STAGES) == (25.0, ["render/b", "train/c"])
    assert critical_path(STAGES, {"eval/*": 4.0}) == (32.0, ["eval/d"])


def test_one_slot_runs_everything_in_a_row_and_two_slots_reach_the_critical_path():
    one = project(STAGES, nodes=1, cores_per_node=1)
    assert one.wall_seconds == 43.0 and one.busy_fraction == 1.0
    # two slots, longest remaining chain first: b (25 to the end) and a (15) start; a ends at 10 and d runs to 18;
    # b ends at 20 and c runs to 25
    two = project(STAGES, nodes=2, cores_per_node=1)
    assert two.wall_seconds == 25.0 and two.busy_fraction == pytest.approx(43 / 50)
    assert project(STAGES, nodes=1, cores_per_node=2, threads=1).wall_seconds == 25.0  # two slots on one node
    assert project(STAGES, nodes=1, cores_per_node=2, threads=2).wall_seconds == 43.0  # a stage takes both cores
    # a scale factor lengthens the matching stages: a (now 25 to the end) and b start and end at 20, then c runs to
    # 25 and d to 28
    assert project(STAGES, nodes=2, cores_per_node=1, scales={"render/a": 2.0}).wall_seconds == 28.0


def test_read_from_markers_and_refuse_markers_without_dependencies(tmp_path):
    for stage in STAGES:
        write_marker(tmp_path, stage.name, {"stage": stage.name, "seconds": stage.seconds, "threads": 1,
                                            "deps": list(stage.deps)})
    assert sorted(read_measured_stages(tmp_path), key=lambda s: s.name) == sorted(STAGES, key=lambda s: s.name)
    result = CliRunner().invoke(main, ["cluster-projection", str(tmp_path), "--nodes", "1,2", "--cores-per-node", "1"])
    assert result.exit_code == 0, result.output
    assert "| 1 | 1 | 0.7 min | 100 % | 0.4 min |" in result.output  # 43 s; critical path 25 s
    assert "| 2 | 2 | 0.4 min | 86 % | 0.4 min |" in result.output
    assert "Critical path: render/b (0.3 min) -> train/c (0.1 min)" in result.output
    write_marker(tmp_path, "old", {"stage": "old", "seconds": 1.0})
    with pytest.raises(InputError, match="does not record its stage's dependencies"):
        read_measured_stages(tmp_path)
    bad = CliRunner().invoke(main, ["cluster-projection", str(tmp_path), "--scale", "render/*"])
    assert bad.exit_code == 2 and "is not PATTERN=FACTOR" in bad.output
    for factor in ("nan", "inf", "0"):  # NaN and inf printed "nan h" / "inf h" projections and exited 0
        bad = CliRunner().invoke(main, ["cluster-projection", str(tmp_path), "--scale", f"render/*={factor}"])
        assert bad.exit_code == 2 and "need a stage name pattern and a finite factor > 0" in bad.output, bad.output


def test_a_killed_writes_temporary_marker_is_skipped_and_a_damaged_one_named(tmp_path):
    write_marker(tmp_path, "a", {"stage": "a", "result": {}, "seconds": 2.0, "threads": 1, "deps": []})
    (tmp_path / ".stages" / ".b.json.partial-1234.json").write_text('{"stage": "b"')  # a write cut short
    assert [s.name for s in read_measured_stages(tmp_path)] == ["a"]
    for bad in ({"deps": 5}, {"stage": ["a"]}, {"seconds": "abc"}, {"threads": 0}):
        write_marker(tmp_path, "c", {"stage": "c", "result": {}, "seconds": 1.0, "threads": 1, "deps": [], **bad})
        with pytest.raises(InputError, match=r"\.stages/c\.json: damaged done-marker"):
            read_measured_stages(tmp_path)
