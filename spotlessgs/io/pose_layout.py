"""Checks of a dataset's poses and start points against each other, before training.

Poses from VIO, GNSS or another SfM run, and points from another tool, are easily in different frames or units. Each
check here warns in one line that names the dataset; none refuses it (a warning is a hint, the data may still train):

* poses far from the world origin (UTM-like coordinates) are trained about their mean instead
  (:func:`spotlessgs.io.cameras.working_origin`): said once, with the origin, so that exported positions can be placed;
* every camera at one position (a camera that only turned): no parallax, the geometry is a guess;
* a start point cloud that most cameras cannot see (points behind the cameras or outside every image): the points and
  the poses are likely in different frames or scales.
"""

from __future__ import annotations

import logging

import numpy as np

from spotlessgs.io.ply import PointCloud
from spotlessgs.io.transforms import DatasetDescription

log = logging.getLogger(__name__)

#: The start cloud is warned about when fewer than this fraction of its points lie inside some camera's image.
MIN_SEEN_FRACTION = 0.5
#: At most this many points (evenly strided) are projected for the check.
SEEN_CHECK_POINTS = 20_000


def warn_pose_layout(dataset: DatasetDescription) -> None:
    """Log the working origin of poses far from the world origin, and warn when every camera has one position."""
    origin = dataset.working_origin
    if origin.any():
        log.info("%s: the poses lie far from the world origin; coordinates are taken relative to (%.3f, %.3f, %.3f) "
                 "(their mean camera centre) so that float32 keeps them exact", dataset.source, *origin)
    centres = dataset.c2w_opencv[:, :3, 3]
    if dataset.n_frames > 1 and np.ptp(centres, axis=0).max() <= 1e-9 * max(np.abs(centres).max(), 1.0):
        log.warning("%s: all %d cameras are at one position (%.3f, %.3f, %.3f): without parallax the geometry is a "
                    "guess; are the poses' translations missing?", dataset.source, dataset.n_frames, *centres[0])


def seen_fraction(dataset: DatasetDescription, points: PointCloud, max_points: int = SEEN_CHECK_POINTS) -> float:
    """The fraction of ``points`` (relative to the dataset's working origin, as
    :func:`~spotlessgs.io.dataset.load_initial_points` gives them) in front of some camera and inside its image
    (pinhole projection, lens distortion ignored); at most ``max_points`` of them, evenly strided, are projected."""
    xyz = points.xyz.astype(np.float64)
    if len(xyz) == 0:
        return 1.0
    xyz = xyz[:: -(-len(xyz) // max_points)]
    w2c = dataset.view_matrices()
    xyz = xyz + dataset.working_origin
    seen = np.zeros(len(xyz), dtype=bool)
    for k, camera in enumerate(dataset.cameras):
        p = xyz @ w2c[k, :3, :3].T + w2c[k, :3, 3]
        z = p[:, 2]
        ahead = z > 1e-9
        u = camera.fx * p[ahead, 0] / z[ahead] + camera.cx
        v = camera.fy * p[ahead, 1] / z[ahead] + camera.cy
        seen[np.flatnonzero(ahead)[(u >= 0) & (u <= camera.width) & (v >= 0) & (v <= camera.height)]] = True
    return float(seen.mean())


def warn_unseen_points(dataset: DatasetDescription, points: PointCloud, source: str) -> None:
    """Warn when fewer than :data:`MIN_SEEN_FRACTION` of the start points ``points`` (read from ``source``) lie inside
    some camera's image."""
    fraction = seen_fraction(dataset, points)
    if fraction < MIN_SEEN_FRACTION:
        log.warning("%s: only %.0f %% of the start points lie inside some camera's image: the points and the poses "
                    "may be in different frames or scales", source, 100 * fraction)
