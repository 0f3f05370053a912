"""The relighting ceiling (``spotless ceiling``): the renderer's albedo scored against the ground truth like a method."""

from __future__ import annotations

import json

import numpy as np
import pytest
from click.testing import CliRunner

from spotlessgs.cli import main
from spotlessgs.io.cameras import Intrinsics
from spotlessgs.io.colorspace import linear_to_srgb
from spotlessgs.io.errors import InputError
from spotlessgs.io.exr import FrameEXR, write_frame_exr
from spotlessgs.io.images import read_image, write_png
from spotlessgs.io.transforms import DatasetMeta, FrameRecord, write_transforms


def _dataset(root, with_albedo=True, frames=12):
    """``frames`` views of 16 x 12 pixels (test views 0 and 11): each frame's ground truth is its albedo (random
    colours) times 0.5, lit evenly; the input is a dimmer copy."""
    rng = np.random.default_rng(1)
    records = []
    for k in range(frames):
        name = f"frame_{k:05d}"
        albedo = rng.uniform(0.05, 0.95, (12, 16, 3)).astype(np.float32)
        gt = 0.5 * albedo
        write_frame_exr(root / "exr" / f"{name}.exr", FrameEXR(
            uneven=0.2 * gt, gt=gt, depth=np.ones((12, 16), np.float32), normal=np.zeros((12, 16, 3), np.float32),
            albedo=albedo if with_albedo else None))
        write_png(root / "images" / f"{name}.png", linear_to_srgb(0.2 * gt))
        write_png(root / "gt" / f"{name}.png", linear_to_srgb(gt))
        records.append(FrameRecord(f"images/{name}.png", np.eye(4), gt_file_path=f"gt/{name}.png",
                                   exr_file_path=f"exr/{name}.exr"))
    write_transforms(root / "transforms.json", Intrinsics.from_fov(60.0, 16, 12), records,
                     DatasetMeta(scene_id="ceiling", test_every=11))
    return root


def test_albedo_times_one_gain_is_scored_on_the_test_views(tmp_path):
    """The ground truth is exactly albedo x 0.5: the oracle's aligned gain is 0.5 and its aligned PSNR is limited only
    by the 8-bit images; without the gain (plain PSNR) it is far lower."""
    data = _dataset(tmp_path / "data")
    result = CliRunner().invoke(main, ["ceiling", str(data), "--out", str(tmp_path / "ceiling"), "--no-lpips",
                                       "--quiet"])
    assert result.exit_code == 0, result.output + repr(result.exception)
    scores = json.loads((tmp_path / "ceiling" / "eval" / "results.json").read_text())
    assert sorted(p.name for p in (tmp_path / "ceiling" / "pred").iterdir()) == ["frame_00000.png", "frame_00011.png"]
    assert scores["exposure_gain"] == pytest.approx(0.5, rel=0.01)
    assert scores["psnr_aligned"] > 40.0 and scores["psnr"] < scores["psnr_aligned"] - 10.0
    np.testing.assert_array_equal(read_image(tmp_path / "ceiling" / "gt" / "frame_00011.png"),
                                  read_image(data / "gt" / "frame_00011.png"))


def test_a_dataset_without_the_albedo_pass_is_refused_naming_the_file(tmp_path):
    from evaluation.ceiling import write_albedo_oracle

    data = _dataset(tmp_path / "old", with_albedo=False)
    with pytest.raises(InputError, match=r"frame_00000.exr: no albedo pass .* render the dataset again"):
        write_albedo_oracle(data, tmp_path / "ceiling")
    result = CliRunner().invoke(main, ["ceiling", str(data), "--out", str(tmp_path / "c2"), "--quiet"])
    assert result.exit_code != 0 and "no albedo pass" in result.output
