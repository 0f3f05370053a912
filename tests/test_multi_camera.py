"""Several cameras in one COLMAP model: a barrel-distorted 64x48 camera and a smaller 48x36 pinhole with another focal
length, on different poses of the same ray-cast room. Each frame trains, renders and is scored through its own camera.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from rendered_points import centroid_errors, render_points_on_rays

from evaluation.synthetic import render_room_sequence
from spotlessgs.io import lens
from spotlessgs.io.colmap_text import ColmapModel, ColmapPoints, model_from_poses, write_colmap_text
from spotlessgs.io.images import read_image, write_png
from spotlessgs.run import RunSpec, train
from spotlessgs.training.data import load_training_views

pytestmark = pytest.mark.usefixtures("one_torch_thread")

BARREL = (-0.18, 0.03, 0.0, 0.0)


def _two_camera_folder(root):
    """A COLMAP folder: camera 1 (OPENCV 64x48, 14 frames ``a_*``), camera 2 (PINHOLE 48x36, 9 frames ``b_*``)."""
    a = render_room_sequence(num_frames=14, width=64, height=48, seed=3, lens="opencv", distortion=BARREL)
    b = render_room_sequence(num_frames=9, width=48, height=36, seed=3)
    models = []
    for prefix, seq in (("a", a), ("b", b)):
        names = [f"{prefix}_{k:03d}.png" for k in range(len(seq.spot))]
        for name, image in zip(names, seq.spot):
            write_png(root / "images" / name, image)
        models.append(model_from_poses(seq.intrinsics, names, seq.c2w_opengl, *_surface_points(seq)))
    first, second = models
    offset = len(first.images)
    camera2 = dataclasses.replace(second.cameras[1], camera_id=2)
    images = {**first.images, **{i + offset: dataclasses.replace(im, image_id=i + offset, camera_id=2)
                                 for i, im in second.images.items()}}
    points = ColmapPoints(np.arange(1, len(first.points.ids) + len(second.points.ids) + 1),
                          np.concatenate([first.points.xyz, second.points.xyz]),
                          np.concatenate([first.points.rgb, second.points.rgb]),
                          np.concatenate([first.points.errors, second.points.errors]),
                          first.points.tracks + second.points.tracks)
    write_colmap_text(root / "sparse" / "0", ColmapModel({1: first.cameras[1], 2: camera2}, images, points))
    return root, a.intrinsics, b.intrinsics


def _surface_points(seq, stride: int = 4) -> tuple[np.ndarray, np.ndarray]:
    """(P, 3) points on the room's surfaces seen by every third frame (each ``stride``-th pixel back-projected
    through the lens with its depth) and their (P, 3) uint8 colours: what SfM would give, denser."""
    intr = seq.intrinsics
    rows, cols = np.mgrid[0:intr.height:stride, 0:intr.width:stride]
    xy = lens.undistort(intr, np.stack([cols.ravel() + 0.5, rows.ravel() + 0.5], 1))
    xyz, rgb = [], []
    for k in range(0, len(seq.spot), 3):
        z = seq.depth[k][rows, cols].reshape(-1, 1)
        c2w = seq.c2w_opengl[k] @ np.diag([1.0, -1.0, -1.0, 1.0])  # OpenCV camera axes
        xyz.append(np.concatenate([xy * z, z], 1) @ c2w[:3, :3].T + c2w[:3, 3])
        rgb.append((255 * seq.spot[k][rows, cols].reshape(-1, 3)).astype(np.uint8))
    return np.concatenate(xyz), np.concatenate(rgb)


@pytest.fixture(scope="module")
def folder(tmp_path_factory):
    return _two_camera_folder(tmp_path_factory.mktemp("rig"))


def test_frames_of_two_cameras_share_one_canvas_with_the_rest_unseen(folder):
    data, cam_a, cam_b = folder
    views = load_training_views(data)
    assert views.cameras.per_view
    a = [k for k, n in enumerate(views.names) if n.startswith("a_")]
    b = [k for k, n in enumerate(views.names) if n.startswith("b_")]
    working_a = lens.working_camera(cam_a)  # the barrel lens's working image is the larger one: it sets the canvas
    assert (views.cameras.height, views.cameras.width) == (working_a.height, working_a.width)
    assert views.images.shape == (23, working_a.height, working_a.width, 3)
    assert views.cameras.camera(b[0]).fx == pytest.approx(cam_b.fx)  # its own focal length, drawn at the top-left
    unseen_b = views.unseen[b[0]]
    assert not unseen_b[:36, :48].any() and unseen_b[36:].all() and unseen_b[:, 48:].all()
    assert (views.images[b][:, 36:] == 0).all()  # the padding is never an input
    unseen_a = views.unseen[a[0]]
    assert unseen_a[0, working_a.width // 2] and not unseen_a[-1, -1]  # the barrel lens's own unseen edge
    # each camera's own geometry: the corner pixel's centre (0.5, 0.5) of the 48x36 pinhole, r = 1 at its corner
    assert float(views.radius[b[0], 0, 0]) == pytest.approx(math.hypot(23.5, 17.5) / 30.0, rel=1e-6)


def test_a_two_camera_folder_trains_and_each_frame_renders_in_its_own_camera(folder, tmp_path):
    """The renders of both cameras' frames, at each camera's size, match their inputs better than each input's own
    mean colour does, by about as much for either camera (measured: 20.2 dB against 17.7 dB for the distorted camera,
    20.9 dB against 18.3 dB for the pinhole). The photometric camera is off: the renders leave out what it learns."""
    data, cam_a, cam_b = folder
    run = train(RunSpec(data=data, model="3dgs", preset="tiny",
                        overrides=(("iterations", 600), ("num_threads", 1), ("log_every", 100),
                                   ("checkpoint_every", 600), ("photometric", "off"))), tmp_path / "run",
                progress=False)
    summary = run.render("all", progress=False)
    assert summary["sizes"] == [[48, 36], [64, 48]] and "width" not in summary
    psnr, flat = {}, {}
    for prefix, cam in (("a", cam_a), ("b", cam_b)):
        errors, spread = [], []
        for path in sorted((data / "images").glob(f"{prefix}_*.png")):
            render, image = read_image(tmp_path / "run" / "render" / path.name), read_image(path)
            assert render.shape == (cam.height, cam.width, 3)
            errors.append((render - image) ** 2)
            spread.append((image - image.mean(axis=(0, 1))) ** 2)
        psnr[prefix] = float(-10 * np.log10(np.mean(errors)))
        flat[prefix] = float(-10 * np.log10(np.mean(spread)))
    assert psnr["a"] > flat["a"] + 1.5 and psnr["b"] > flat["b"] + 1.5, (psnr, flat)


@pytest.mark.parametrize("prefix", ["a", "b"])
def test_rendered_points_land_where_each_frames_camera_projects_them(folder, tmp_path, prefix):
    """Small bright Gaussians ahead of a frame appear at their projection through that frame's camera (its lens, its
    focal length and size) within 0.1 px."""
    data, cam_a, cam_b = folder
    native = cam_a if prefix == "a" else cam_b
    run_dir = tmp_path / "run"
    train(RunSpec(data=data, model="3dgs", preset="tiny", overrides=(("iterations", 2), ("num_threads", 1))),
          run_dir, progress=False)
    views = load_training_views(data)
    k = next(k for k, n in enumerate(views.names) if n.startswith(f"{prefix}_") and k in views.test)
    c2w = views.cameras.c2w[k].double().numpy()
    pixels = np.stack(np.meshgrid(np.linspace(0.2, 0.8, 4) * native.width, np.linspace(0.2, 0.8, 4) * native.height),
                      -1).reshape(-1, 2)
    xy = lens.undistort(native, pixels)  # the rays of those pixels of this frame's camera
    image = render_points_on_rays(run_dir, views.names[k], c2w, xy, sigma_m=0.025)
    assert image.shape == (native.height, native.width)
    errors = centroid_errors(image, pixels, half_window=3)
    assert max(errors) < 0.1, errors
