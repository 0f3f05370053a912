"""Lens distortion through OpenCV's camera models: distort and undistort points, the pinhole working camera that
sees a distorted image whole, and the resampling maps between the two.

The trainer works in a pinhole *working camera* (:func:`working_camera`): input images are resampled into it
(:func:`undistort_maps`, with a mask of the working pixels that have an input sample), and images rendered in it are
resampled back into the input camera's own geometry (:func:`distort_maps`), so that outputs are pixel-aligned with the
input frames.

Pixel coordinates follow :mod:`spotlessgs.io.cameras` (image corner at (0, 0), pixel centres at +0.5, as COLMAP);
OpenCV puts pixel centres at integers, so its matrices use the principal point shifted by -0.5 (:func:`opencv_K`).
Normalised coordinates are (x / z, y / z) in OpenCV camera axes.
"""

from __future__ import annotations

import math

import cv2
import numpy as np

from spotlessgs.io.cameras import Intrinsics
from spotlessgs.io.errors import InputError

# Point undistortion: iterations and tolerance of OpenCV's fixed-point solver.
_UNDISTORT_CRITERIA = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 100, 1e-12)
# A lens is invertible over the image when undistorting and distorting again returns every sampled pixel within this
# many pixels.
ROUND_TRIP_TOLERANCE_PX = 0.01
# The working camera is at most this many times the input image's width and height (wide fisheye lenses: beyond it
# the working camera's focal length shrinks instead).
MAX_WORKING_SCALE = 2.0


def opencv_K(intr: Intrinsics) -> np.ndarray:
    """(3, 3) float64 camera matrix in OpenCV's pixel convention (pixel centres at integers)."""
    return np.array([[intr.fx, 0.0, intr.cx - 0.5], [0.0, intr.fy, intr.cy - 0.5], [0.0, 0.0, 1.0]])


def _coeffs(intr: Intrinsics) -> np.ndarray:
    return np.asarray(intr.distortion, dtype=np.float64)


def distort(intr: Intrinsics, xy: np.ndarray) -> np.ndarray:
    """Pixels (N, 2) of normalised points ``xy`` (N, 2) seen through the camera ``intr`` (its lens included)."""
    xy = np.asarray(xy, dtype=np.float64).reshape(-1, 2)
    if intr.is_pinhole or len(xy) == 0:
        return np.stack([intr.fx * xy[:, 0] + intr.cx, intr.fy * xy[:, 1] + intr.cy], axis=1)
    if intr.lens == "fisheye":
        px = cv2.fisheye.distortPoints(xy[:, None, :], opencv_K(intr), _coeffs(intr))
    else:
        points = np.concatenate([xy, np.ones((len(xy), 1))], axis=1)
        px, _ = cv2.projectPoints(points[:, None, :], np.zeros(3), np.zeros(3), opencv_K(intr), _coeffs(intr))
    return px.reshape(-1, 2) + 0.5


def undistort(intr: Intrinsics, pixels: np.ndarray) -> np.ndarray:
    """Normalised points (N, 2) whose image through ``intr`` is ``pixels`` (N, 2) (OpenCV's iterative inverse)."""
    pixels = np.asarray(pixels, dtype=np.float64).reshape(-1, 2)
    if intr.is_pinhole or len(pixels) == 0:
        return np.stack([(pixels[:, 0] - intr.cx) / intr.fx, (pixels[:, 1] - intr.cy) / intr.fy], axis=1)
    cv_pixels = (pixels - 0.5)[:, None, :]
    if intr.lens == "fisheye":
        xy = cv2.fisheye.undistortPoints(cv_pixels, opencv_K(intr), _coeffs(intr), criteria=_UNDISTORT_CRITERIA)
    else:
        xy = cv2.undistortPointsIter(cv_pixels, opencv_K(intr), _coeffs(intr), None, None, _UNDISTORT_CRITERIA)
    return xy.reshape(-1, 2)


def _border_pixels(width: int, height: int, per_side: int = 64) -> np.ndarray:
    """(M, 2) pixel positions along the four image edges (corners included)."""
    xs = np.linspace(0.0, width, per_side)
    ys = np.linspace(0.0, height, per_side)
    return np.concatenate([np.stack([xs, np.zeros_like(xs)], 1), np.stack([xs, np.full_like(xs, height)], 1),
                           np.stack([np.zeros_like(ys), ys], 1), np.stack([np.full_like(ys, width), ys], 1)])


def check_invertible(intr: Intrinsics, where: str) -> None:
    """InputError naming ``where`` when the lens cannot be inverted over the image: undistorting a grid of pixels
    (the edges included) and distorting them again must return each within :data:`ROUND_TRIP_TOLERANCE_PX`."""
    if intr.is_pinhole:
        return
    grid = np.stack(np.meshgrid(np.linspace(0, intr.width, 33), np.linspace(0, intr.height, 25)), -1).reshape(-1, 2)
    pixels = np.concatenate([grid, _border_pixels(intr.width, intr.height)])
    xy = undistort(intr, pixels)
    back = distort(intr, xy) if np.isfinite(xy).all() else np.full_like(pixels, np.inf)
    error = np.linalg.norm(back - pixels, axis=1)
    worst = int(np.argmax(np.where(np.isfinite(error), error, np.inf)))
    if not np.isfinite(error).all() or error[worst] > ROUND_TRIP_TOLERANCE_PX:
        u, v = pixels[worst]
        raise InputError(f"{where}: the {intr.lens} distortion {list(intr.distortion)} cannot be inverted over the "
                         f"{intr.width}x{intr.height} image (pixel ({u:.0f}, {v:.0f}) does not map back: error "
                         f"{error[worst]:.3g} px); check the calibration")


def working_camera(intr: Intrinsics) -> Intrinsics:
    """The pinhole camera, with the input's focal lengths where possible, whose image holds every input pixel's ray.

    Its size covers the undistorted image edges (a barrel lens needs more pixels than the input, a pincushion
    lens fewer), at most :data:`MAX_WORKING_SCALE` times the input's per axis (the focal lengths shrink beyond). A
    pinhole camera is its own working camera.
    """
    if intr.is_pinhole:
        return intr
    xy = undistort(intr, _border_pixels(intr.width, intr.height))
    x0, y0 = xy.min(axis=0)
    x1, y1 = xy.max(axis=0)
    fx = min(intr.fx, MAX_WORKING_SCALE * intr.width / (x1 - x0))
    fy = min(intr.fy, MAX_WORKING_SCALE * intr.height / (y1 - y0))
    width, height = math.ceil(fx * (x1 - x0)), math.ceil(fy * (y1 - y0))
    # centre the covered window in the whole-pixel image
    cx = -fx * x0 + 0.5 * (width - fx * (x1 - x0))
    cy = -fy * y0 + 0.5 * (height - fy * (y1 - y0))
    return Intrinsics(fx, fy, cx, cy, width, height)


def _pixel_centres(width: int, height: int) -> np.ndarray:
    """(H * W, 2) pixel centres, row by row."""
    u, v = np.meshgrid(np.arange(width) + 0.5, np.arange(height) + 0.5)
    return np.stack([u, v], -1).reshape(-1, 2)


def camera_points(intr: Intrinsics, depth: np.ndarray) -> np.ndarray:
    """(H, W, 3) camera-frame points (OpenCV axes, metres) of a planar depth map (H, W) (depth along the optical
    axis, as the simulator's EXRs hold it), each pixel centre's ray through the lens of ``intr``."""
    depth = np.asarray(depth, dtype=np.float64)
    if depth.shape != (intr.height, intr.width):
        raise ValueError(f"camera_points: depth {depth.shape} does not match the {intr.width}x{intr.height} camera")
    xy = undistort(intr, _pixel_centres(intr.width, intr.height)).reshape(intr.height, intr.width, 2)
    return np.concatenate([xy * depth[..., None], depth[..., None]], -1)


def _sampling_maps(rays: np.ndarray, source: Intrinsics, height: int, width: int,
                   ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Where the normalised ``rays`` (H * W, 2) of an H × W image land in an image of camera ``source``: map_x,
    map_y (H, W) float32 in OpenCV's convention and valid (H, W) bool (inside that image)."""
    px = distort(source, rays) - 0.5
    map_x = px[:, 0].reshape(height, width).astype(np.float32)
    map_y = px[:, 1].reshape(height, width).astype(np.float32)
    valid = (map_x >= -0.5) & (map_x <= source.width - 0.5) & (map_y >= -0.5) & (map_y <= source.height - 0.5)
    return map_x, map_y, valid


def undistort_maps(intr: Intrinsics, working: Intrinsics) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """For each pixel of the ``working`` (pinhole) image, where to sample the input image of camera ``intr``.

    Returns:
        map_x, map_y: (Hw, Ww) float32 positions in the input image in OpenCV's convention (for ``cv2.remap``);
        valid: (Hw, Ww) bool, True where that position lies inside the input image.
    """
    rays = undistort(working, _pixel_centres(working.width, working.height))
    return _sampling_maps(rays, intr, working.height, working.width)


def distort_maps(intr: Intrinsics, working: Intrinsics) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """For each pixel of the input camera ``intr``'s image, where to sample an image of the ``working`` camera.

    Returns ``map_x``, ``map_y`` (H, W) float32 (OpenCV's convention) and ``valid`` (H, W) bool as
    :func:`undistort_maps`.
    """
    rays = undistort(intr, _pixel_centres(intr.width, intr.height))
    return _sampling_maps(rays, working, intr.height, intr.width)


def remap_nearest(image: np.ndarray, map_x: np.ndarray, map_y: np.ndarray) -> np.ndarray:
    """``image`` (H, W[, C]) float32 sampled at the maps' nearest pixels (for depth and normals, which must not be
    blended across edges; inf passes through)."""
    return cv2.remap(np.ascontiguousarray(image, dtype=np.float32), map_x, map_y, interpolation=cv2.INTER_NEAREST,
                     borderMode=cv2.BORDER_REPLICATE)


def remap(image: np.ndarray, map_x: np.ndarray, map_y: np.ndarray) -> np.ndarray:
    """``image`` (H, W[, C]) float32 resampled bilinearly at the maps' positions (edge pixels repeated outside)."""
    return cv2.remap(np.ascontiguousarray(image, dtype=np.float32), map_x, map_y, interpolation=cv2.INTER_LINEAR,
                     borderMode=cv2.BORDER_REPLICATE)
