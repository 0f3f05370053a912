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


def test_png_keeps_the_levels_of_a_deep_camera_and_8_bits_of_an_8_bit_one(tmp_path):
    """A 12-bit camera's frame (a bag's mono16, a 16-bit TIFF) was cut to 8 bits in the prepared dataset: 4096
    levels became 17 in its dark frames. bits=None writes 16 bits where the image needs them."""
    import numpy as np

    from spotlessgs.io.images import read_image, write_png

    deep = (np.arange(4096, dtype=np.float32).reshape(64, 64)[..., None].repeat(3, -1)) / 65535.0  # 12-bit levels
    write_png(tmp_path / "deep.png", deep, bits=None)
    np.testing.assert_array_equal(read_image(tmp_path / "deep.png"), deep)
    write_png(tmp_path / "cut.png", deep)  # 8 bits as asked
    assert len(np.unique(read_image(tmp_path / "cut.png"))) == 17
    shallow = np.arange(256, dtype=np.float32).reshape(16, 16)[..., None].repeat(3, -1) / 255.0
    write_png(tmp_path / "shallow.png", shallow, bits=None)
    assert (tmp_path / "shallow.png").read_bytes()[24] == 8  # an 8-bit source stays an 8-bit PNG (IHDR bit depth)
    np.testing.assert_array_equal(read_image(tmp_path / "shallow.png"), shallow)
    assert (tmp_path / "deep.png").read_bytes()[24] == 16
    colour = np.stack([deep[..., 0], 0.5 * deep[..., 0], np.full_like(deep[..., 0], 7 / 65535)], -1)
    write_png(tmp_path / "colour.png", colour, bits=None)  # red, green and blue stay in their channels
    np.testing.assert_array_equal(read_image(tmp_path / "colour.png"), np.round(colour * 65535) / 65535)
