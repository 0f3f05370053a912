"""``spotless prepare --points DATA``: sparse 3D points for a posed dataset that has no point cloud.

A robot's dataset has poses (VIO, odometry, a motion-capture system) but no depth: without points the trainer would
start from random Gaussians in the camera frusta. This triangulates SIFT matches of the training frames with the
poses and the camera held fixed (``evaluation.sfm.triangulate_known_poses``, COLMAP's point triangulator) on
brightened copies of the frames (:func:`spotlessgs.prepare.images.brighten`), writes them as ``DATA/sfm_points.ply``
(positions and colours, no normals: the trainer estimates them) and points the dataset's ``transforms.json`` at it.
Only the training frames are used, so the test views' inputs take no part in the start.

    DATA/sfm_points.ply            the triangulated points
    DATA/sfm/points/               the brightened copies and COLMAP's work folder
    DATA/prepare.json              "points": how many, their reprojection error, the settings
    DATA/transforms.json           gets "ply_file_path": "sfm_points.ply" (rewritten atomically, nothing else changes)
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from evaluation.sfm import SfmConfig, triangulate_known_poses
from spotlessgs.io.atomic import write_json
from spotlessgs.io.colorspace import linear_to_srgb
from spotlessgs.io.dataset import read_dataset
from spotlessgs.io.errors import InputError
from spotlessgs.io.images import read_image
from spotlessgs.io.json_files import read_json
from spotlessgs.io.ply import write_point_cloud
from spotlessgs.io.provenance import provenance
from spotlessgs.io.transforms import DatasetDescription
from spotlessgs.prepare.images import NOISE_SAMPLE, SUMMARY_FILE, brightening_blur, write_brightened_copies
from spotlessgs.training.validation import evenly_spaced

POINTS_FILE = "sfm_points.ply"


def add_sfm_points(
    data: str | Path, matcher: str = "sequential", threads: int = 1, seed: int = 0,
    progress: Callable[[str], None] | None = None,
) -> dict[str, Any]:
    """Triangulate sparse points for the posed dataset ``data`` (a ``transforms.json`` without ``ply_file_path``)
    and make them its initial point cloud (see the module docstring).

    Args:
        data: the dataset folder.
        matcher: ``sequential`` (video order) or ``exhaustive`` image pairs.
        threads, seed: COLMAP's threads and random seed.
        progress: called with each step's name.
    Returns:
        the ``points`` summary also written into ``data/prepare.json``.
    Raises:
        InputError: ``data`` has no ``transforms.json``, already names a point cloud, or no point could be
            triangulated (the dataset is then left as it was).
    """
    data = Path(data)
    transforms = data / "transforms.json"
    if not transforms.is_file():
        raise InputError(f"{data}: --points needs a posed dataset with transforms.json (a COLMAP folder has its "
                         "points in sparse/0 already)")
    dataset = read_dataset(transforms, check_files=True)
    if dataset.ply_path is not None:
        raise InputError(f"{transforms}: already names a point cloud ({dataset.ply_path.name}); nothing to do")
    step = progress or (lambda _name: None)
    work = data / "sfm" / "points"
    copies = work / "input"
    train = training_frames(dataset, transforms)
    step(f"brightened copies of {len(train)} training frames")

    def frame(path: Path) -> np.ndarray:
        image = read_image(path)
        if dataset.meta.get("linear_images"):
            image = linear_to_srgb(np.clip(image, 0.0, 1.0)).astype(np.float32)
        return image

    noise, blur = brightening_blur([frame(dataset.image_paths[k]) for k in evenly_spaced(train, NOISE_SAMPLE)])
    names = [f"{k:05d}.png" for k in train]
    write_brightened_copies(copies, [(name, dataset.image_paths[k]) for name, k in zip(names, train)], frame, blur)
    config = SfmConfig(matcher=matcher, num_threads=threads, seed=seed)
    result = triangulate_known_poses(copies, names, dataset.c2w_opencv[train], dataset.intrinsics, work / "colmap",
                                     config, progress=step)
    model = result.models[0]
    summary = {"file": POINTS_FILE, "points": result.points3d, "frames": len(names), "matcher": matcher,
               "brightening": {"noise_level": noise, "blur_sigma_px": blur},
               "reprojection_error_px": result.reprojection_error_px,
               "observations_per_image": result.observations_per_image,
               "provenance": provenance(seed=seed, extra_packages=("pycolmap",))}
    if result.points3d == 0:
        raise InputError(f"{data}: no point could be triangulated from {len(names)} training frames with their poses "
                         "(too dark, too few matches, or poses that disagree with the images)")
    adopt_start_cloud(data, POINTS_FILE, model.points_xyz, model.points_rgb, None, summary)
    return summary


def training_frames(dataset: DatasetDescription, transforms: Path) -> list[int]:
    """The indices of ``dataset``'s training frames; InputError naming ``transforms`` where there are none (a dataset
    of one frame: the split puts it in the test set)."""
    train = list(dataset.split.train)
    if not train:
        raise InputError(f"{transforms}: no training frame ({len(dataset.image_paths)} frame(s), all in the test "
                         "split); a start cloud needs training frames")
    return train


def adopt_start_cloud(data: Path, file: str, xyz: np.ndarray, rgb: np.ndarray, normals: np.ndarray | None,
                      summary: dict[str, Any]) -> None:
    """Make a point cloud the initial one of the posed dataset ``data``: write it to ``data/file`` (positions (N, 3),
    uint8 colours (N, 3), normals (N, 3) or None), record ``summary`` as ``prepare.json``'s ``points`` and point
    ``transforms.json``'s ``ply_file_path`` at it (rewritten atomically, nothing else changes). Both JSON files are
    read before anything is written, and ``transforms.json`` is written last: an interrupted or refused run leaves a
    dataset that a rerun completes."""
    transforms, summary_path = data / "transforms.json", data / SUMMARY_FILE
    record = read_json(transforms, "a dataset's camera poses")
    whole = read_json(summary_path, "the summary of spotless prepare") if summary_path.is_file() else {}
    write_point_cloud(data / file, xyz, rgb, normals)
    write_json(summary_path, {**whole, "points": summary})
    write_json(transforms, {**record, "ply_file_path": file})

