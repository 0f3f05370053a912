"""How well a view pins down where a camera-mounted lamp sits: its shadows' parallax and its shading's sensitivity.

Two cues carry the lamp's position relative to the camera (SpotLight.translation), and both are measured here from a
view's true geometry (a rendered dataset's depth and normals), without any model:

- **Shadows.** Beside a depth edge (an occluder at depth d over a surface at depth z) the lamp's shadow moves
  f (1/d - 1/z) pixels per metre of the lamp's sideways offset (:func:`edge_parallax`).
- **Shading.** The direct light a Lambertian point receives is proportional to cos θ / r², θ its angle to the lamp and
  r its distance. Moving the lamp by δ changes log(cos θ / r²) at each point; the lamp's power is learned, so only the
  change's spread over the points can tell the two positions apart (:func:`shading_sensitivity`). With free albedos
  (every Gaussian's is learned) even that spread is only a cue where one surface is seen from several distances.
"""

from __future__ import annotations

import numpy as np


def edge_parallax(depth: np.ndarray, focal_px: float, min_jump: float = 1.1) -> np.ndarray:
    """How far the lamp's shadows move in the image per metre of the lamp's sideways offset from the camera, at every
    depth edge of a view: f (1/d - 1/z) pixels per metre for each pair of neighbouring pixels (along a row or a
    column) at planar depths d < z with z ≥ ``min_jump`` · d (an occluder's silhouette over what lies behind it).

    The shadow beside such an edge is that wide for a lamp offset of one metre, up to the edge's orientation: it is
    how finely the image resolves the lamp's position from its shadows.

    Args:
        depth: (H, W) planar depth in metres; inf or NaN where nothing was hit (such pairs are skipped).
        focal_px: focal length in pixels.
        min_jump: depth ratio from which neighbouring pixels count as an edge.
    Returns:
        (M,) float64, one value per edge pair (empty for a view without depth edges).
    """
    depth = np.asarray(depth, dtype=np.float64)
    if depth.ndim != 2:
        raise ValueError(f"edge_parallax: depth must be (H, W), got shape {depth.shape}")
    values = []
    for a, b in ((depth[:, 1:], depth[:, :-1]), (depth[1:, :], depth[:-1, :])):
        near, far = np.minimum(a, b), np.maximum(a, b)
        edge = np.isfinite(far) & (near > 0) & (far >= min_jump * near)
        values.append(focal_px * (1.0 / near[edge] - 1.0 / far[edge]))
    return np.concatenate(values)


def _log_direct_light(points: np.ndarray, normals: np.ndarray, lamp: np.ndarray) -> np.ndarray:
    """log(cos θ / r²) (N,) of points (N, 3) with unit normals (N, 3) lit by a point lamp at ``lamp`` (3,)."""
    to_lamp = lamp[None] - points
    r2 = (to_lamp * to_lamp).sum(-1)
    cos = (normals * to_lamp).sum(-1) / np.sqrt(r2)
    return np.log(np.clip(cos, 1e-6, None) / r2)


def shading_sensitivity(points: np.ndarray, normals: np.ndarray, lamp: np.ndarray, step: float = 0.01,
                        min_cos: float = 0.3) -> np.ndarray:
    """The RMS change of the direct light's log (log cos θ / r², its mean change removed: the lamp's power is free)
    over points lit by a lamp at ``lamp``, when the lamp moves by ``step`` metres along each axis of the frame.

    Args:
        points: (N, 3) surface points, in the frame the lamp's position is given in (e.g. the camera's).
        normals: (N, 3) their unit normals, same frame.
        lamp: (3,) the lamp's position.
        step: how far the lamp moves, metres.
        min_cos: only points facing the lamp at least this much (cos θ ≥ min_cos at ``lamp``) count.
    Returns:
        (3,) RMS change along x, y, z (0 for a lamp move that changes every point's light by the same factor).
    """
    points = np.asarray(points, dtype=np.float64)
    normals = np.asarray(normals, dtype=np.float64)
    lamp = np.asarray(lamp, dtype=np.float64)
    if points.ndim != 2 or points.shape[1] != 3 or normals.shape != points.shape or lamp.shape != (3,):
        raise ValueError(f"shading_sensitivity: points and normals must be (N, 3) and lamp (3,), got "
                         f"{points.shape}, {normals.shape}, {lamp.shape}")
    base = _log_direct_light(points, normals, lamp)
    to_lamp = lamp[None] - points
    facing = (normals * to_lamp).sum(-1) >= min_cos * np.linalg.norm(to_lamp, axis=-1)
    result = np.zeros(3)
    if not facing.any():
        return result
    for axis in range(3):
        change = _log_direct_light(points, normals, lamp + step * np.eye(3)[axis]) - base
        change = change[facing]
        result[axis] = float(np.sqrt(np.mean((change - change.mean()) ** 2)))
    return result
