"""Initial point clouds from rendered depth maps: back-projection and voxel merging (bpy-free).

Pixel (row i, column j) is the ray through its centre (u, v) = (j + 0.5, i + 0.5); with planar depth d the point in the
OpenCV camera frame is (x d, y d, d), (x, y) the centre undistorted through the camera's lens (a pinhole's
((u - cx) / fx, (v - cy) / fy)), then mapped to the world by the camera-to-world pose.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from spotlessgs.io.cameras import Intrinsics, opengl_to_opencv_c2w
from spotlessgs.io.lens import undistort


class Points(NamedTuple):
    """Points with colours and optional normals.

    Attributes:
        xyz: (P, 3) float64 world positions, metres.
        rgb: (P, 3) uint8 colours.
        normals: (P, 3) float64 unit normals, or None.
    """

    xyz: np.ndarray
    rgb: np.ndarray
    normals: np.ndarray | None


def backproject_depth(
    depth: np.ndarray,
    rgb: np.ndarray,
    normals: np.ndarray | None,
    intrinsics: Intrinsics,
    c2w_opengl: np.ndarray,
    stride: int = 1,
    max_points: int | None = None,
    rng: np.random.Generator | None = None,
    max_depth: float = np.inf,
) -> Points:
    """Lift the valid pixels of a planar depth map to world points.

    Args:
        depth: (H, W) planar depth along the optical axis, metres; inf, NaN and values <= 0 are skipped.
        rgb: (H, W, 3) uint8 colours.
        normals: (H, W, 3) world-space normals (normalised here; zero-length ones are skipped), or None.
        intrinsics: the camera (its size must be W x H; any lens the dataset contract allows).
        c2w_opengl: (4, 4) camera-to-world pose, OpenGL camera axes.
        stride: keep every ``stride``-th row and column (1 = all pixels).
        max_points: after striding, keep at most this many valid points, chosen uniformly without replacement by
            ``rng`` (required then), in pixel order.
        rng: random generator for ``max_points``.
        max_depth: depths above this are skipped too (e.g. Blender's 1e10 background if not converted to inf).

    Returns:
        :class:`Points` with P valid points.
    """
    depth = np.asarray(depth)
    height, width = intrinsics.height, intrinsics.width
    if depth.shape != (height, width):
        raise ValueError(f"backproject_depth: depth shape {depth.shape} does not match intrinsics {height}x{width}")
    rgb = np.asarray(rgb)
    if rgb.shape != (height, width, 3) or rgb.dtype != np.uint8:
        raise ValueError(f"backproject_depth: rgb must be uint8 ({height}, {width}, 3), got {rgb.dtype} {rgb.shape}")
    if normals is not None and np.asarray(normals).shape != (height, width, 3):
        raise ValueError(f"backproject_depth: normals must be ({height}, {width}, 3), got {np.asarray(normals).shape}")
    if stride < 1:
        raise ValueError(f"backproject_depth: stride must be >= 1, got {stride}")
    if max_points is not None and (max_points < 0 or rng is None):
        raise ValueError("backproject_depth: max_points needs a non-negative value and an rng")
    c2w = opengl_to_opencv_c2w(c2w_opengl)

    rows, cols = np.mgrid[0:height:stride, 0:width:stride]
    d = depth[rows, cols].astype(np.float64)
    valid = np.isfinite(d) & (d > 0) & (d <= max_depth)
    if normals is not None:
        n = np.asarray(normals, dtype=np.float64)[rows, cols]
        n_len = np.linalg.norm(n, axis=-1)
        valid &= np.isfinite(n_len) & (n_len > 1e-12)
    rows, cols, d = rows[valid], cols[valid], d[valid]
    if max_points is not None and len(d) > max_points:
        keep = np.sort(rng.choice(len(d), size=max_points, replace=False))
        rows, cols, d = rows[keep], cols[keep], d[keep]
    # each pixel centre's ray through the lens (a pinhole's: ((u - cx) / fx, (v - cy) / fy))
    rays = undistort(intrinsics, np.stack([cols + 0.5, rows + 0.5], axis=1))
    cam = np.concatenate([rays * d[:, None], d[:, None]], axis=1)
    xyz = cam @ c2w[:3, :3].T + c2w[:3, 3]
    out_normals = None
    if normals is not None:
        nn = np.asarray(normals, dtype=np.float64)[rows, cols]
        out_normals = nn / np.linalg.norm(nn, axis=1, keepdims=True)
    return Points(xyz, rgb[rows, cols], out_normals)


def merge_point_clouds(
    clouds: list[Points],
    voxel_size: float,
    max_points: int | None,
    rng: np.random.Generator,
) -> Points:
    """Concatenate point clouds, average them per voxel, and cap the count.

    Args:
        clouds: point clouds; either all have normals or none do.
        voxel_size: edge length of the cubic voxels, metres (> 0); each occupied voxel yields one point: the mean
            position, the rounded mean colour and the normalised mean normal (voxels whose normals cancel keep the
            first normal seen).
        max_points: keep at most this many voxel points, chosen uniformly without replacement by ``rng``; None = all.
        rng: random generator for the cap.

    Returns:
        :class:`Points` ordered by voxel index.
    """
    if not clouds:
        raise ValueError("merge_point_clouds: no point clouds given")
    if not voxel_size > 0:
        raise ValueError(f"merge_point_clouds: voxel_size must be positive, got {voxel_size}")
    with_normals = [c.normals is not None for c in clouds]
    if any(with_normals) and not all(with_normals):
        raise ValueError("merge_point_clouds: some clouds have normals and others do not")
    xyz = np.concatenate([np.asarray(c.xyz, np.float64).reshape(-1, 3) for c in clouds])
    rgb = np.concatenate([np.asarray(c.rgb).reshape(-1, 3) for c in clouds]).astype(np.float64)
    normals = None
    if all(with_normals):
        normals = np.concatenate([np.asarray(c.normals, np.float64).reshape(-1, 3) for c in clouds])
    if len(xyz) == 0:
        return Points(np.zeros((0, 3)), np.zeros((0, 3), np.uint8), None if normals is None else np.zeros((0, 3)))
    keys = np.floor(xyz / voxel_size).astype(np.int64)
    _, first, inverse, counts = np.unique(keys, axis=0, return_index=True, return_inverse=True, return_counts=True)
    inverse = inverse.reshape(-1)

    def voxel_mean(values: np.ndarray) -> np.ndarray:
        sums = np.zeros((len(counts), values.shape[1]))
        np.add.at(sums, inverse, values)
        return sums / counts[:, None]

    out_xyz = voxel_mean(xyz)
    out_rgb = np.clip(np.rint(voxel_mean(rgb)), 0, 255).astype(np.uint8)
    out_normals = None
    if normals is not None:
        mean_n = voxel_mean(normals)
        length = np.linalg.norm(mean_n, axis=1, keepdims=True)
        degenerate = length[:, 0] < 1e-9
        mean_n[degenerate] = normals[first[degenerate]]
        length[degenerate] = np.linalg.norm(mean_n[degenerate], axis=1, keepdims=True)
        out_normals = mean_n / length
    if max_points is not None and len(out_xyz) > max_points:
        keep = np.sort(rng.choice(len(out_xyz), size=max_points, replace=False))
        out_xyz, out_rgb = out_xyz[keep], out_rgb[keep]
        out_normals = None if out_normals is None else out_normals[keep]
    return Points(out_xyz, out_rgb, out_normals)
