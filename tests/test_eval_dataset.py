"""Dataset-folder and run-folder readers, EXR depth, and the JSON/Markdown report."""

from __future__ import annotations

import json
import math

import numpy as np
import OpenEXR
import pytest

from evaluation.dataset import read_dataset, read_depth_exr
from evaluation.report import markdown_report, to_jsonable, write_results_json

INTR = {"fl_x": 100.0, "fl_y": 101.0, "cx": 40.0, "cy": 30.0, "w": 80, "h": 60}


def _transforms(root, frames, **extra):
    root.mkdir(parents=True, exist_ok=True)
    (root / "transforms.json").write_text(json.dumps({**INTR, "frames": frames, **extra}))


def _frame(i, **kw):
    return {"file_path": f"images/frame_{i:05d}.png", "transform_matrix": np.eye(4).tolist(), **kw}


def test_reads_fields_and_default_split(tmp_path):
    _transforms(tmp_path, [_frame(i, gt_file_path=f"gt/frame_{i:05d}.png") for i in range(23)])
    d = read_dataset(tmp_path)
    assert d.intrinsics.fx == 100.0 and d.intrinsics.height == 60
    assert d.test_indices == (0, 11, 22)
    assert d.frames[3].name == "frame_00003.png" and d.frames[3].gt_path == tmp_path / "gt/frame_00003.png"
    assert d.frames[0].depth_path is None
    assert [f.name for f in d.test_frames] == ["frame_00000.png", "frame_00011.png", "frame_00022.png"]


def _spotless(train, test):
    """A minimal valid "spotless" block with an explicit (non-rule) split."""
    return {"schema_version": 1, "scene_id": "s", "color_space": "srgb", "light": None,
            "split": {"rule": "custom", "test_every": 2, "train": train, "test": test}}


def test_explicit_split(tmp_path):
    _transforms(tmp_path, [_frame(i) for i in range(5)], spotless=_spotless([0, 2, 4], [1, 3]))
    assert read_dataset(tmp_path).test_indices == (1, 3)


def test_colmap_folder_has_no_ground_truth_and_every_11th_split(tmp_path):
    sparse = tmp_path / "sparse" / "0"
    sparse.mkdir(parents=True)
    (sparse / "cameras.txt").write_text("1 PINHOLE 80 60 100 101 40 30\n")
    # IMAGE_ID QW QX QY QZ TX TY TZ CAMERA_ID NAME, then an empty line of 2D points; identity rotations.
    (sparse / "images.txt").write_text("".join(f"{i + 1} 1 0 0 0 0 0 {0.1 * i} 1 f{i:02d}.png\n\n" for i in range(12)))
    (sparse / "points3D.txt").write_text("")
    d = read_dataset(tmp_path)
    assert d.intrinsics.fy == 101.0 and d.test_indices == (0, 11)
    assert d.frames[2].input_path == tmp_path / "images" / "f02.png" and d.frames[2].gt_path is None
    # COLMAP centre C = -R^T t: a world-to-camera translation of +0.2 z puts the camera at z = -0.2.
    np.testing.assert_allclose(d.frames[2].c2w_opengl[:3, 3], [0.0, 0.0, -0.2], atol=1e-12)


@pytest.mark.parametrize(
    "mutate,match",
    [
        (lambda m: m.pop("fl_x"), r"frames\[0\]: missing key 'fl_x'"),
        (lambda m: m.update(frames=[]), "missing or empty 'frames' list"),
        (lambda m: m["frames"][1].pop("transform_matrix"), r"frames\[1\]: missing key 'transform_matrix'"),
        (lambda m: m["frames"][0].update(transform_matrix=[[1, 0], [0, 1]]),
         r"frames\[0\].transform_matrix: must be 4x4"),
        (lambda m: m["frames"][1].update(file_path="other/frame_00000.png"),
         r"file names are not unique: frames\[0\] and frames\[1\] are both 'frame_00000.png'"),
        (lambda m: m.update(spotless=_spotless([1, 2], [0, 7])),
         r"split.test: indices \[7\] out of range for 3 frames"),
    ],
)
def test_transforms_errors(tmp_path, mutate, match):
    meta = {**INTR, "frames": [_frame(i) for i in range(3)]}
    mutate(meta)
    (tmp_path / "transforms.json").write_text(json.dumps(meta))
    with pytest.raises(ValueError, match=match):
        read_dataset(tmp_path)


def test_transforms_missing_or_invalid(tmp_path):
    with pytest.raises(FileNotFoundError, match="neither transforms.json nor a COLMAP sparse/ folder"):
        read_dataset(tmp_path)
    (tmp_path / "transforms.json").write_text("{nope")
    with pytest.raises(ValueError, match="transforms.json: not valid JSON"):
        read_dataset(tmp_path)


def test_depth_exr_single_and_multi_part(tmp_path):
    z = np.full((4, 5), 2.5, np.float32)
    z[0, 0] = np.inf
    header = {"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage}
    OpenEXR.File(header, {"RGB": np.zeros((4, 5, 3), np.float32), "depth.Z": z}).write(str(tmp_path / "a.exr"))
    got = read_depth_exr(tmp_path / "a.exr")
    assert got.dtype == np.float32 and np.isinf(got[0, 0]) and got[1, 1] == 2.5
    parts = [OpenEXR.Part(dict(header), {"RGB": np.zeros((4, 5, 3), np.float32)}, name="Combined"),
             OpenEXR.Part(dict(header), {"Z": z * 2}, name="depth")]
    OpenEXR.File(parts).write(str(tmp_path / "b.exr"))
    assert read_depth_exr(tmp_path / "b.exr")[1, 1] == 5.0
    OpenEXR.File(header, {"RGB": np.zeros((4, 5, 3), np.float32)}).write(str(tmp_path / "c.exr"))
    with pytest.raises(ValueError, match=r"c.exr: no depth channel .* channels are \['B', 'G', 'R'\]"):
        read_depth_exr(tmp_path / "c.exr")
    with pytest.raises(FileNotFoundError, match="none.exr: EXR file not found"):
        read_depth_exr(tmp_path / "none.exr")


def test_json_conversion_and_markdown(tmp_path):
    results = {"mode": "run", "psnr": math.inf, "ssim": np.float32(0.5), "lpips": float("nan"), "num_images": 2,
               "exposure_gain": 1.5, "per_image": [{"name": "a", "psnr": np.float64(3.0)}],
               "sfm": {"reprojection_error_px": 0.5, "observations_per_image": 100.0, "registered_images": 3,
                       "total_images": 4, "points3d": np.int64(10)},
               "input": {"psnr": 10.0, "ssim": None}}
    j = to_jsonable(results)
    assert j["psnr"] is None and j["lpips"] is None and j["ssim"] == 0.5 and j["sfm"]["points3d"] == 10
    write_results_json(tmp_path / "r.json", results)
    assert json.loads((tmp_path / "r.json").read_text())["per_image"][0]["psnr"] == 3.0
    md = markdown_report(results, "T")
    assert md.startswith("# T") and "| relit | ∞ | 0.5000 | — |" in md and "| input (uneven) | 10.00 | — | — |" in md
    assert "| relit | 0.500 | 100.0 | 3/4 | 10 |" in md and "exposure gain 1.5000" in md
