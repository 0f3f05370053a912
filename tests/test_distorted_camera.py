"""Training on the images of a distorted camera: no manual undistortion, outputs in the input camera's own geometry.

The datasets are ray cast through the lens itself (evaluation.synthetic with a lens), inputs and ground truth alike,
as a real distorted camera sees the room.
"""

from __future__ import annotations

import json

import numpy as np
import pytest

from rendered_points import centroid_errors, render_points_on_rays

from evaluation.synthetic import render_room_sequence, write_dataset_folder
from spotlessgs.io import lens
from spotlessgs.io.cameras import Intrinsics
from spotlessgs.io.colmap_text import model_from_poses, write_colmap_text
from spotlessgs.io.images import read_image, write_png
from spotlessgs.run import RunSpec, train
from spotlessgs.training.data import load_training_views

pytestmark = pytest.mark.usefixtures("one_torch_thread")

WIDTH, HEIGHT = 64, 48
BARREL = (-0.18, 0.03, 0.0, 0.0)  # OpenCV k1, k2, p1, p2: a robot camera's wide lens
TRAIN = (("iterations", 600), ("num_threads", 1), ("log_every", 100),
         ("checkpoint_every", 600))


def _dataset(root, lens: str, distortion: tuple[float, ...]):
    seq = render_room_sequence(num_frames=14, width=WIDTH, height=HEIGHT, seed=3, lens=lens, distortion=distortion)
    write_dataset_folder(seq, root, with_depth=False)
    return root


@pytest.fixture(scope="module")
def datasets(tmp_path_factory):
    root = tmp_path_factory.mktemp("lens")
    return {"pinhole": _dataset(root / "pinhole", "pinhole", ()), "opencv": _dataset(root / "opencv", "opencv", BARREL)}


def test_views_of_a_distorted_camera_are_resampled_into_its_working_camera(datasets):
    views = load_training_views(datasets["opencv"])
    cams = views.cameras
    assert cams.intrinsics.is_pinhole and (cams.width, cams.height) > (WIDTH, HEIGHT)
    assert views.dataset.intrinsics.distortion == BARREL  # the input camera is kept for the outputs
    assert views.unseen.shape == (len(views.names), cams.height, cams.width)
    assert (views.unseen == views.unseen[0]).all()  # one camera: the same pixels in every view
    unseen = views.unseen[0].numpy()
    # barrel: the input's corners reach the working image's corners, its edges bow inwards: no sample there
    assert not unseen[0, 0] and not unseen[-1, -1]
    assert unseen[0, cams.width // 2] and unseen[cams.height // 2, 0] and unseen[cams.height // 2, -1]
    assert not unseen[2:-2, 2:-2].any() and 0.02 < unseen.mean() < 0.2
    assert load_training_views(datasets["pinhole"]).unseen is None


def _render_psnr(data, run_dir) -> float:
    """Train 3DGS, render every view into ``run_dir/render``; PSNR (dB) of those renders against the input images."""
    run = train(RunSpec(data=data, model="3dgs", preset="tiny", overrides=TRAIN), run_dir, progress=False)
    summary = run.render("all", progress=False)
    assert (summary["width"], summary["height"]) == (WIDTH, HEIGHT)
    errors = [(read_image(run_dir / "render" / path.name) - read_image(path)) ** 2
              for path in sorted((data / "images").iterdir())]
    return float(-10 * np.log10(np.mean(errors)))


def test_a_distorted_camera_trains_and_renders_in_its_own_geometry(datasets, tmp_path):
    """Renders of the distorted camera come out at its size and match its input images about as well as renders of
    the same room through a pinhole match theirs (measured: 22.1 and 22.7 dB). These smooth textures barely notice a
    one-pixel shift (0.1 dB); the alignment itself is pinned by test_rendered_points_land_where_the_lens_projects_them."""
    distorted = _render_psnr(datasets["opencv"], tmp_path / "opencv")
    pinhole = _render_psnr(datasets["pinhole"], tmp_path / "pinhole")
    assert distorted > pinhole - 1.0, (distorted, pinhole)


def test_a_plain_colmap_folder_with_an_opencv_camera_trains_without_a_manual_step(datasets, tmp_path):
    source = load_training_views(datasets["opencv"]).dataset
    folder = tmp_path / "colmap"
    names = [p.name for p in source.image_paths]
    write_colmap_text(folder / "sparse" / "0", model_from_poses(source.intrinsics, names, source.c2w_opengl))
    for path in source.image_paths:
        write_png(folder / "images" / path.name, read_image(path))
    cameras = (folder / "sparse" / "0" / "cameras.txt").read_text()
    assert "OPENCV 64 48" in cameras
    run = train(RunSpec(data=folder, model="3dgs", preset="tiny", overrides=TRAIN), tmp_path / "run", progress=False)
    summary = run.relight("test", progress=False)
    assert (summary["width"], summary["height"]) == (WIDTH, HEIGHT) and summary["count"] == 2
    assert json.loads((tmp_path / "run" / "run.json").read_text())["model"] == "3dgs"


def test_rendered_points_land_where_the_lens_projects_them(datasets, tmp_path):
    """End to end through the run's renderer: small bright Gaussians in front of a test view appear, in the
    distorted output image, at their projection through the lens (OpenCV's, checked against pycolmap's in
    test_lens.py) within 0.1 px; a pinhole projection would put the corner ones more than a pixel away."""
    data = datasets["opencv"]
    run_dir = tmp_path / "run"
    train(RunSpec(data=data, model="3dgs", preset="tiny", overrides=(("iterations", 2), ("num_threads", 1))),
          run_dir, progress=False)
    views = load_training_views(data)
    native = views.dataset.intrinsics
    k = views.test[0]
    c2w = views.cameras.c2w[k].double().numpy()
    # a 5 x 5 grid of points 1.5 m ahead of the camera, out to 80 % of the image's half-width and half-height
    gx, gy = np.meshgrid(np.linspace(-0.8, 0.8, 5) * native.cx / native.fx, np.linspace(-0.8, 0.8, 5) * native.cy /
                         native.fy)
    xy_pinhole = np.stack([gx.ravel(), gy.ravel()], 1)
    xy = lens.undistort(native, lens.distort(Intrinsics(native.fx, native.fy, native.cx, native.cy, native.width,
                                                        native.height), xy_pinhole))  # the rays of those pixels
    image = render_points_on_rays(run_dir, views.names[k], c2w, xy, sigma_m=0.03)  # sigma ~1.15 px at 1.5 m
    expected = lens.distort(native, xy)
    pinhole_guess = np.stack([native.fx * xy[:, 0] + native.cx, native.fy * xy[:, 1] + native.cy], 1)
    assert np.abs(pinhole_guess - expected).max() > 1.0  # the lens matters at these points
    errors = centroid_errors(image, expected, half_window=4)
    assert max(errors) < 0.1, errors
