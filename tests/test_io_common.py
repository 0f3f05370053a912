"""Atomic writes, per-stage seeds and provenance."""

from __future__ import annotations

import json

import numpy as np
import pytest

from spotlessgs.io.atomic import atomic_open, write_json
from spotlessgs.io.provenance import provenance
from spotlessgs.io.seeding import numpy_rng, stage_seed


def test_atomic_write_keeps_old_file_on_error(tmp_path):
    target = tmp_path / "a.json"
    write_json(target, {"v": 1})
    with pytest.raises(RuntimeError):
        with atomic_open(target) as fh:
            fh.write('{"v": 2')  # half a file
            raise RuntimeError("interrupted")
    assert json.loads(target.read_text()) == {"v": 1}
    assert [p.name for p in tmp_path.iterdir()] == ["a.json"]  # no temporary left behind


def test_write_json_rejects_nan(tmp_path):
    with pytest.raises(ValueError):
        write_json(tmp_path / "b.json", {"x": float("nan")})
    assert not (tmp_path / "b.json").exists()


def test_stage_seeds_are_independent_and_reproducible():
    assert stage_seed(0, "poses") == stage_seed(0, "poses")
    assert stage_seed(0, "poses") != stage_seed(0, "noise")
    assert stage_seed(0, "poses") != stage_seed(1, "poses")
    a = numpy_rng(3, "x").normal(size=5)
    b = numpy_rng(3, "x").normal(size=5)
    np.testing.assert_array_equal(a, b)


def test_provenance_records_seed_and_versions():
    rec = provenance(seed=7, extra_packages=("click",), note="x")
    assert rec["seed"] == 7 and rec["note"] == "x"
    assert "numpy" in rec["packages"] and "click" in rec["packages"]
    json.dumps(rec)
