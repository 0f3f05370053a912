"""Poses and start points in frames that training must cope with: far from the origin (UTM-like coordinates, which
float32 rounds by a quarter metre), every camera at one position, points the cameras cannot see.

Each test builds a tiny ray-cast dataset (no Blender) and a copy of it moved or damaged the way real data is.
"""

from __future__ import annotations

import json
import logging
import shutil
from pathlib import Path

import numpy as np
import pytest
import torch

from tests.conftest import synthetic_box_dataset

pytestmark = pytest.mark.usefixtures("one_torch_thread")

#: A UTM-like offset (metres): float32's spacing at 4e6 is 0.25 m.
FAR = np.array([500_123.25, 4_000_456.5, 31.0])


@pytest.fixture(scope="module")
def box_with_points(tmp_path_factory) -> Path:
    """The box dataset with a start cloud: a grid of pixels of view 0 unprojected to 2 m (every point seen)."""
    from spotlessgs.io.ply import write_point_cloud
    from spotlessgs.io.transforms import read_transforms

    root = synthetic_box_dataset(tmp_path_factory, "pose-layout-box", seed=3)
    dataset = read_transforms(root / "transforms.json")
    cam, c2w = dataset.cameras[0], dataset.c2w_opencv[0]
    u, v = np.meshgrid(np.linspace(2, cam.width - 2, 8), np.linspace(2, cam.height - 2, 6))
    rays = np.stack([(u.ravel() - cam.cx) / cam.fx, (v.ravel() - cam.cy) / cam.fy, np.ones(u.size)], axis=1)
    xyz = (2.0 * rays) @ c2w[:3, :3].T + c2w[:3, 3]
    write_point_cloud(root / "points.ply", xyz, np.full((len(xyz), 3), 128, np.uint8))
    meta = json.loads((root / "transforms.json").read_text())
    (root / "transforms.json").write_text(json.dumps({**meta, "ply_file_path": "points.ply"}))
    return root


def _moved_copy(root: Path, where: Path, offset: np.ndarray) -> Path:
    """A copy of the dataset ``root`` with every pose and start point moved by ``offset`` (float64 throughout)."""
    from spotlessgs.io.ply import read_point_cloud, write_point_cloud

    shutil.copytree(root, where)
    meta = json.loads((root / "transforms.json").read_text())
    for frame in meta["frames"]:
        matrix = np.array(frame["transform_matrix"], dtype=np.float64)
        matrix[:3, 3] += offset
        frame["transform_matrix"] = matrix.tolist()
    (where / "transforms.json").write_text(json.dumps(meta))
    cloud = read_point_cloud(root / "points.ply")
    write_point_cloud(where / "points.ply", cloud.xyz.astype(np.float64) + offset, cloud.rgb, cloud.normals)
    return where


def _in_cameras(views, points) -> torch.Tensor:
    """(V, P, 3) the start points in every view's camera frame (metres), in float32 as training computes them."""
    xyz = torch.as_tensor(points.xyz, dtype=torch.float32)
    return (views.cameras.viewmat[:, None, :3, :3] @ xyz[None, :, :, None])[..., 0] + views.cameras.viewmat[:, None, :3, 3]


def test_working_origin_is_zero_near_the_origin_and_the_mean_centre_far_from_it():
    from spotlessgs.io.cameras import working_origin

    c2w = np.tile(np.eye(4), (3, 1, 1))
    c2w[:, :3, 3] = [[1.0, 2.0, 1.5], [-1.0, 0.5, 1.5], [0.0, -2.0, 1.0]]
    assert working_origin(c2w).tolist() == [0.0, 0.0, 0.0]
    c2w[:, :3, 3] += FAR
    np.testing.assert_allclose(working_origin(c2w), FAR + [0.0, 0.5 / 3, 4.0 / 3], rtol=0, atol=1e-9)


def test_utm_scale_poses_train_on_the_same_pixels_as_the_poses_near_the_origin(box_with_points, tmp_path):
    """The copy 4,000 km from the origin puts every start point where the original puts it in every camera's frame,
    to 10 µm (a thousandth of a pixel at 2 m); a plain float32 cast of its poses would move the cameras by up to a
    quarter metre."""
    from spotlessgs.training.data import load_training_views

    moved = _moved_copy(box_with_points, tmp_path / "moved", FAR)
    near, far = load_training_views(box_with_points), load_training_views(moved)
    assert not near.dataset.working_origin.any() and far.dataset.working_origin.any()
    torch.testing.assert_close(_in_cameras(far, far.start_points), _in_cameras(near, near.start_points), rtol=0,
                               atol=1e-5)
    naive = np.abs(far.dataset.c2w_opencv[:, :3, 3].astype(np.float32) - far.dataset.c2w_opencv[:, :3, 3]).max()
    assert naive > 0.01  # what the working origin avoids
    # the start PLY kept its far positions exactly: written as float64
    assert b"property double x" in (moved / "points.ply").read_bytes()[:400]
    assert b"property float x" in (box_with_points / "points.ply").read_bytes()[:400]


def test_a_run_on_far_poses_exports_its_world_origin(box_with_points, tmp_path):
    from plyfile import PlyData

    from spotlessgs.export import export_ply
    from spotlessgs.training.config import preset
    from spotlessgs.training.trainer import train

    moved = _moved_copy(box_with_points, tmp_path / "moved", FAR)
    cfg = preset("tiny", iterations=2, image_width=40, num_threads=1, validation_blocks=0, log_every=1)
    train(moved, tmp_path / "run", "darkgs", cfg, seed=0, progress=False)
    ply = PlyData.read(str(export_ply(tmp_path / "run", tmp_path / "model.ply")))
    [comment] = [c for c in ply.comments if c.startswith("world_origin ")]
    origin = np.array([float(v) for v in comment.split()[1:]])
    from spotlessgs.io.transforms import read_transforms

    np.testing.assert_array_equal(origin, read_transforms(moved / "transforms.json").working_origin)
    means = np.stack([ply["vertex"][k] for k in "xyz"], axis=1).astype(np.float64)
    assert np.abs(means).max() < 100.0  # the model's positions are near the working origin, in float32's range
    assert np.linalg.norm(means.mean(0) + origin - FAR) < 50.0  # placed back, they lie where the room is


def test_cameras_at_one_position_and_points_no_camera_sees_are_warned_about(box_with_points, tmp_path, caplog):
    from spotlessgs.io.pose_layout import seen_fraction
    from spotlessgs.training.data import load_training_views

    with caplog.at_level(logging.INFO, logger="spotlessgs"):
        views = load_training_views(box_with_points)
        assert views.start_points is not None
    assert not [r for r in caplog.records if r.levelno >= logging.INFO and "pose_layout" in r.name]
    assert seen_fraction(views.dataset, views.start_points) == 1.0

    # points in another frame: moved 100 m up from poses that stayed (the cameras look about level)
    shifted = shutil.copytree(box_with_points, tmp_path / "shifted")
    cloud_only = _moved_copy(box_with_points, tmp_path / "cloud-moved", np.array([0.0, 0.0, 100.0]))
    shutil.copy(cloud_only / "points.ply", shifted / "points.ply")
    caplog.clear()
    with caplog.at_level(logging.WARNING, logger="spotlessgs"):
        assert load_training_views(shifted).start_points is not None
    [line] = [r.getMessage() for r in caplog.records]
    assert line.endswith("points.ply: only 0 % of the start points lie inside some camera's image: the points and "
                         "the poses may be in different frames or scales")

    # every camera at one position (a rotation-only trajectory, or translations lost)
    turned = shutil.copytree(box_with_points, tmp_path / "turned")
    meta = json.loads((turned / "transforms.json").read_text())
    for frame in meta["frames"]:
        frame["transform_matrix"] = [row[:3] + [v] for row, v in zip(frame["transform_matrix"], (1.0, 2.0, 3.0, 1.0))]
    (turned / "transforms.json").write_text(json.dumps(meta))
    caplog.clear()
    with caplog.at_level(logging.WARNING, logger="spotlessgs"):
        load_training_views(turned)
    assert any("all 14 cameras are at one position (1.000, " in r.getMessage() for r in caplog.records)


def _masked_copy(root: Path, where: Path, under_mask: str, clear_frame: int | None = None) -> Path:
    """A copy of ``root`` whose frames are RGBA PNGs, transparent in their left 10 columns, storing ``under_mask``
    ("kept": the frame's own colour, "white") there; frame ``clear_frame`` transparent everywhere."""
    from PIL import Image

    shutil.copytree(root, where)
    for k, path in enumerate(sorted((where / "images").glob("*.png"))):
        rgb = np.asarray(Image.open(path).convert("RGB")).copy()
        alpha = np.full(rgb.shape[:2], 255, np.uint8)
        alpha[:, :10] = 0
        if under_mask == "white":
            rgb[:, :10] = 255
        if k == clear_frame:
            alpha[:] = 0
        Image.fromarray(np.dstack([rgb, alpha]), "RGBA").save(path)
    return where


def test_an_alpha_mask_leaves_its_pixels_out_whatever_colour_they_store(box_with_points, tmp_path, caplog):
    """Training frames with an alpha mask (the robot's own body cut out): two copies that differ only in the colour
    stored under the mask train to the same model, bit for bit; a fully transparent frame is left out with a
    warning naming it."""
    from spotlessgs.io.tensor_file import load_tree
    from spotlessgs.training.checkpoint import CHECKPOINT_FORMAT, checkpoint_path
    from spotlessgs.training.config import preset
    from spotlessgs.training.data import load_training_views
    from spotlessgs.training.trainer import train

    kept = _masked_copy(box_with_points, tmp_path / "kept", "kept", clear_frame=1)
    white = _masked_copy(box_with_points, tmp_path / "white", "white", clear_frame=1)
    with caplog.at_level(logging.WARNING, logger="spotlessgs"):
        views = load_training_views(kept)
    assert views.unseen is not None and views.unseen[:, :, :10].all() and not views.unseen[0, :, 10:].any()
    assert views.unseen[1].all() and 1 not in views.train
    assert any("1 fully transparent (alpha 0 everywhere) frame(s) left out of training: frame_00001.png"
               in r.getMessage() for r in caplog.records)
    cfg = preset("tiny", iterations=4, image_width=40, num_threads=1, validation_blocks=0, log_every=1)
    for data in (kept, white):
        train(data, tmp_path / f"run-{data.name}", "darkgs", cfg, seed=0, progress=False)
    a, b = (load_tree(checkpoint_path(tmp_path / f"run-{n}"), CHECKPOINT_FORMAT) for n in ("kept", "white"))
    for table in ("gaussians", "appearance"):
        for name, tensor in a[table].items():
            assert torch.equal(tensor, b[table][name]), f"{table}.{name}"
    # the inputs differ under the mask (white there): only the mask keeps them out of the fit
    assert not torch.equal(load_training_views(white).images, views.images)
