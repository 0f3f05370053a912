"""Lens models: COLMAP and nerfstudio cameras read into OpenCV's models, checked against pycolmap's projection; the
working camera and the resampling maps between it and a distorted camera."""

from __future__ import annotations

import json

import numpy as np
import pycolmap
import pytest

from spotlessgs.io import lens
from spotlessgs.io.cameras import Intrinsics
from spotlessgs.io.colmap_text import ColmapCamera
from spotlessgs.io.errors import InputError
from spotlessgs.io.transforms import DatasetError, FrameRecord, read_transforms, write_transforms

# COLMAP cameras of a robot-like 320 x 240 camera, one per supported distortion model.
COLMAP_CAMERAS = {
    "SIMPLE_RADIAL": [300.0, 160.5, 119.25, -0.18],
    "RADIAL": [300.0, 160.5, 119.25, -0.18, 0.03],
    "OPENCV": [300.0, 310.0, 160.5, 119.25, -0.18, 0.03, 0.001, -0.002],
    "FULL_OPENCV": [300.0, 310.0, 160.5, 119.25, -0.18, 0.03, 0.001, -0.002, 0.01, 0.02, 0.003, 0.004],
    "OPENCV_FISHEYE": [300.0, 310.0, 160.5, 119.25, 0.05, -0.01, 0.002, -0.001],
}


@pytest.mark.parametrize("model", sorted(COLMAP_CAMERAS))
def test_colmap_cameras_project_as_pycolmap_does(model):
    """Independent reference: pycolmap's own projection of normalised points through the same COLMAP camera."""
    params = COLMAP_CAMERAS[model]
    intr = ColmapCamera(1, model, 320, 240, tuple(params)).to_intrinsics()
    assert not intr.is_pinhole and intr.lens == ("fisheye" if model == "OPENCV_FISHEYE" else "opencv")
    xy = np.random.default_rng(0).uniform(-0.5, 0.5, (200, 2))
    expected = pycolmap.Camera(model=model, width=320, height=240, params=params).img_from_cam(
        np.concatenate([xy, np.ones((200, 1))], axis=1))
    pixels = lens.distort(intr, xy)
    np.testing.assert_allclose(pixels, expected, atol=1e-9)
    np.testing.assert_allclose(lens.undistort(intr, pixels), xy, atol=1e-9)
    lens.check_invertible(intr, "cameras.txt")  # these lenses are fine over the whole image


def test_nerfstudio_distortion_round_trips_and_matches_colmap(tmp_path):
    frames = [FrameRecord(f"images/{i}.png", np.eye(4)) for i in range(2)]
    opencv = ColmapCamera(1, "OPENCV", 320, 240, tuple(COLMAP_CAMERAS["OPENCV"])).to_intrinsics()
    fisheye = ColmapCamera(1, "OPENCV_FISHEYE", 320, 240, tuple(COLMAP_CAMERAS["OPENCV_FISHEYE"])).to_intrinsics()
    with_k3 = Intrinsics(300.0, 310.0, 160.5, 119.25, 320, 240, "opencv", (-0.18, 0.03, 0.001, -0.002, 0.01))
    for intr, model in ((opencv, "OPENCV"), (fisheye, "OPENCV_FISHEYE"), (with_k3, "OPENCV")):
        write_transforms(tmp_path / "transforms.json", intr, frames, None)
        stored = json.loads((tmp_path / "transforms.json").read_text())
        assert stored["camera_model"] == model
        assert read_transforms(tmp_path / "transforms.json").intrinsics == intr
    # nerfstudio's OPENCV keys k1 k2 p1 p2 k3 are OpenCV's order k1 k2 p1 p2 k3
    assert stored["k3"] == 0.01 and stored["p1"] == 0.001 and stored["p2"] == -0.002
    full = ColmapCamera(1, "FULL_OPENCV", 320, 240, tuple(COLMAP_CAMERAS["FULL_OPENCV"])).to_intrinsics()
    with pytest.raises(DatasetError, match="cannot hold the 8-coefficient"):
        write_transforms(tmp_path / "full.json", full, frames, None)


def test_lens_coefficients_are_checked_and_kept_in_their_shortest_form():
    assert Intrinsics(5, 5, 5, 4, 10, 8, "opencv", (0.1, 0, 0, 0, 0, 0, 0, 0)).distortion == (0.1, 0.0, 0.0, 0.0)
    assert Intrinsics(5, 5, 5, 4, 10, 8, "opencv", (0.0,) * 5) == Intrinsics(5, 5, 5, 4, 10, 8)
    scaled = Intrinsics(5, 5, 5, 4, 10, 8, "fisheye", (0.1, 0, 0, 0)).scaled(2.0)
    assert scaled.lens == "fisheye" and scaled.distortion == (0.1, 0.0, 0.0, 0.0) and scaled.fx == 10.0
    with pytest.raises(ValueError, match="unknown lens model 'fov'"):
        Intrinsics(5, 5, 5, 4, 10, 8, "fov", (0.1,))
    with pytest.raises(ValueError, match="a fisheye lens takes 4 distortion coefficients, got 2"):
        Intrinsics(5, 5, 5, 4, 10, 8, "fisheye", (0.1, 0.2))
    with pytest.raises(ValueError, match="must be finite"):
        Intrinsics(5, 5, 5, 4, 10, 8, "opencv", (float("nan"), 0, 0, 0))


def test_a_folding_lens_is_refused_with_the_file_name():
    folding = Intrinsics(50.0, 50.0, 32.0, 24.0, 64, 48, "opencv", (-0.9, 0.0, 0.0, 0.0))
    with pytest.raises(InputError, match=r"cameras\.txt: the opencv distortion \[-0\.9, 0\.0, 0\.0, 0\.0\] cannot "
                                         r"be inverted over the 64x48 image"):
        lens.check_invertible(folding, "cameras.txt")


def _checkerboard(intr: Intrinsics, square: float = 0.25) -> np.ndarray:
    """(H, W) float32 image of a fronto-parallel checkerboard of ``square``-unit squares at depth 1, seen through
    ``intr``: 4 x 4 samples per pixel, averaged (area sampling)."""
    sub = (np.arange(4) + 0.5) / 4
    u = (np.arange(intr.width)[:, None] + sub[None]).reshape(-1)
    v = (np.arange(intr.height)[:, None] + sub[None]).reshape(-1)
    uu, vv = np.meshgrid(u, v)
    xy = lens.undistort(intr, np.stack([uu.ravel(), vv.ravel()], 1))
    xy = xy + 0.037  # off-centre, so that no pixel straddles an edge exactly in half
    board = ((np.floor(xy[:, 0] / square) + np.floor(xy[:, 1] / square)) % 2).astype(np.float32)
    return board.reshape(intr.height, 4, intr.width, 4).mean(axis=(1, 3))


def _edge_columns(row: np.ndarray, min_step: float = 0.0) -> np.ndarray:
    """Sub-pixel positions (pixel units, corner at 0) where a row crosses 0.5 (linear interpolation), with a step of
    more than ``min_step`` between the two pixels (a sharp edge across the row, not one along it)."""
    i = np.nonzero(((row[:-1] - 0.5) * (row[1:] - 0.5) < 0) & (np.abs(row[1:] - row[:-1]) > min_step))[0]
    return i + 0.5 + (0.5 - row[i]) / (row[i + 1] - row[i])


@pytest.mark.parametrize("model", ["OPENCV", "OPENCV_FISHEYE"])
def test_maps_carry_a_checkerboard_between_the_lens_and_its_working_camera(model):
    """Undistorting a distorted view of a checkerboard gives the working pinhole camera's view of it, and
    distorting that back lands every edge within 0.5 px of the distorted view's own (the acceptance bound)."""
    intr = ColmapCamera(1, model, 160, 120, tuple(np.array(COLMAP_CAMERAS[model]) * ([0.5] * 4 + [1] * (
        len(COLMAP_CAMERAS[model]) - 4)))).to_intrinsics()
    working = lens.working_camera(intr)
    assert working.is_pinhole and (working.fx, working.fy) == (intr.fx, intr.fy)
    assert working.width >= intr.width and working.height >= intr.height  # barrel: more pixels at the same focus
    distorted = _checkerboard(intr)
    map_x, map_y, valid = lens.undistort_maps(intr, working)
    undistorted = lens.remap(distorted, map_x, map_y)
    truth = _checkerboard(working)
    assert 0.7 < valid.mean() < 1.0  # the working image's corners have no input sample
    inner = valid & np.pad(np.ones((working.height - 8, working.width - 8), bool), 4)
    assert np.abs(undistorted - truth)[inner].mean() < 0.03
    back_x, back_y, back_valid = lens.distort_maps(intr, working)
    assert back_valid.all()  # the working camera holds every input pixel's ray
    again = lens.remap(undistorted, back_x, back_y)
    offsets = [np.abs(_edge_columns(again[r]) - x).min() for r in range(intr.height)
               for x in _edge_columns(distorted[r], min_step=0.6)]
    assert len(offsets) > 200 and max(offsets) < 0.25  # measured 0.11 px; a half-pixel error gives 0.6-0.8


@pytest.mark.parametrize("model", sorted(COLMAP_CAMERAS))
def test_colmap_cameras_round_trip_through_intrinsics(model):
    camera = ColmapCamera(1, model, 320, 240, tuple(COLMAP_CAMERAS[model]))
    intr = camera.to_intrinsics()
    back = ColmapCamera.from_intrinsics(7, intr)
    assert back.to_intrinsics() == intr and back.camera_id == 7
    # the written camera projects like the read one (pycolmap as the reference)
    xyz = np.concatenate([np.random.default_rng(1).uniform(-0.4, 0.4, (50, 2)), np.ones((50, 1))], axis=1)
    np.testing.assert_allclose(pycolmap.Camera(model=back.model, width=320, height=240, params=back.params)
                               .img_from_cam(xyz), lens.distort(intr, xyz[:, :2]), atol=1e-9)
