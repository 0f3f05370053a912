"""Depth images of an RGB-D camera: single-channel 16-bit PNGs of integer depth units (the format of RealSense's and
Azure Kinect's ROS drivers, the TUM RGB-D benchmark and nerfstudio's ``depth_file_path``).

A pixel holds planar depth along the optical axis (camera z) in units of ``scale`` metres (nerfstudio's
``depth_unit_scale_factor``; 0.001, millimetres, by default); 0 means no measurement. The image is registered to the
colour image it belongs to: the same size, pixel grid and lens (RealSense's ``aligned_depth_to_color``).
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from spotlessgs.io.atomic import atomic_path
from spotlessgs.io.errors import InputError

#: Metres per depth unit when a dataset does not say (millimetres, as nerfstudio's default).
DEFAULT_DEPTH_SCALE = 0.001
#: The largest depth unit a 16-bit image can hold; depths beyond it are written as 0 (no measurement).
MAX_DEPTH_UNITS = 65535


def read_depth_image(path: str | os.PathLike, scale: float = DEFAULT_DEPTH_SCALE) -> np.ndarray:
    """(H, W) float64 planar depth in metres from a 16-bit single-channel PNG of depth units of ``scale`` metres; NaN
    where the pixel holds 0 (no measurement).

    Raises:
        InputError: naming ``path``, when it is missing, not a PNG OpenCV can decode, or not 16-bit single-channel.
    """
    import cv2

    path = Path(path)
    if not path.is_file():
        raise InputError(f"{path}: depth image not found")
    data = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    if data is None:
        raise InputError(f"{path}: not a readable image (a depth image is a 16-bit single-channel PNG)")
    if data.dtype != np.uint16 or data.ndim != 2:
        channels = 1 if data.ndim == 2 else data.shape[2]
        raise InputError(f"{path}: a depth image must be 16-bit single-channel, got {data.dtype} with {channels} "
                         "channel(s)")
    depth = data.astype(np.float64) * float(scale)
    depth[data == 0] = np.nan
    return depth


def depth_units(depth: np.ndarray, scale: float = DEFAULT_DEPTH_SCALE) -> np.ndarray:
    """(H, W) uint16 depth units of ``scale`` metres of a planar depth map (H, W) in metres, rounded; 0 where the
    depth is not finite, not positive, or beyond what 16 bits hold (MAX_DEPTH_UNITS units)."""
    depth = np.asarray(depth, dtype=np.float64)
    if depth.ndim != 2:
        raise ValueError(f"depth_units: expected an (H, W) depth map, got shape {depth.shape}")
    if not scale > 0:
        raise ValueError(f"depth_units: scale must be positive, got {scale}")
    with np.errstate(invalid="ignore", over="ignore"):
        units = np.rint(depth / scale)
    valid = np.isfinite(units) & (units >= 1) & (units <= MAX_DEPTH_UNITS)
    return np.where(valid, units, 0).astype(np.uint16)


def write_depth_image(path: str | os.PathLike, depth: np.ndarray, scale: float = DEFAULT_DEPTH_SCALE) -> None:
    """Write a planar depth map (H, W) in metres as a 16-bit single-channel PNG of :func:`depth_units`, atomically
    (parent folders are created)."""
    import cv2

    units = depth_units(depth, scale)
    with atomic_path(path, suffix=".png") as tmp:
        if not cv2.imwrite(str(tmp), units):
            raise OSError(f"{path}: OpenCV could not write the depth image")
