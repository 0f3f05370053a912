"""Trajectory comparison: Umeyama similarity alignment, absolute translation error, relative rotation error.

Poses are camera-to-world 4×4 matrices (any consistent camera-axis convention shared by both trajectories).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class Sim3:
    """A similarity transform x ↦ scale · R x + t."""

    scale: float  # uniform scale factor (> 0)
    rotation: np.ndarray  # (3, 3) proper rotation
    translation: np.ndarray  # (3,)

    def apply(self, points: np.ndarray) -> np.ndarray:
        """Transform (N, 3) points → (N, 3)."""
        return self.scale * points @ self.rotation.T + self.translation


def umeyama(src: np.ndarray, dst: np.ndarray, with_scale: bool = True) -> Sim3:
    """Least-squares similarity aligning ``src`` onto ``dst`` (Umeyama 1991): argmin Σ ‖dst_i − (s R src_i + t)‖².

    Args:
        src: (N, 3) points.
        dst: (N, 3) corresponding points.
        with_scale: estimate the scale (False: rigid, s = 1).

    Raises:
        ValueError: shapes differ, fewer than 3 points, or the source points are all identical.
    """
    src, dst = np.asarray(src, dtype=np.float64), np.asarray(dst, dtype=np.float64)
    if src.shape != dst.shape or src.ndim != 2 or src.shape[1] != 3:
        raise ValueError(f"expected two (N, 3) arrays of the same shape, got {src.shape} and {dst.shape}")
    if len(src) < 3:
        raise ValueError(f"a similarity alignment needs at least 3 points, got {len(src)}")
    mu_s, mu_d = src.mean(0), dst.mean(0)
    xs, xd = src - mu_s, dst - mu_d
    var_s = (xs**2).sum() / len(src)
    if var_s <= 1e-24:
        raise ValueError("source points are all identical: the alignment is undefined")
    cov = xd.T @ xs / len(src)
    u, d, vt = np.linalg.svd(cov)
    s_fix = np.eye(3)
    if np.linalg.det(u) * np.linalg.det(vt) < 0:
        s_fix[2, 2] = -1.0
    rot = u @ s_fix @ vt
    scale = float(np.trace(np.diag(d) @ s_fix) / var_s) if with_scale else 1.0
    trans = mu_d - scale * rot @ mu_s
    return Sim3(scale, rot, trans)


def rotation_angle_deg(r: np.ndarray) -> np.ndarray:
    """Rotation angle in degrees of (..., 3, 3) rotation matrices → (...,), numerically safe near 0 and 180°."""
    tr = np.clip((np.trace(r, axis1=-2, axis2=-1) - 1.0) / 2.0, -1.0, 1.0)
    skew = np.stack([r[..., 2, 1] - r[..., 1, 2], r[..., 0, 2] - r[..., 2, 0], r[..., 1, 0] - r[..., 0, 1]], -1)
    sin = np.linalg.norm(skew, axis=-1) / 2.0
    return np.degrees(np.arctan2(sin, tr))


@dataclass(frozen=True)
class TrajectoryErrors:
    """Errors of an estimated trajectory against the true one after a similarity alignment."""

    ate_rmse: float  # root-mean-square camera-centre error after Sim3 alignment (true-pose units, e.g. metres)
    ate_mean: float  # mean camera-centre error after alignment
    rre_mean_deg: float  # mean relative rotation error between consecutive frames (degrees, alignment-free)
    num_poses: int  # number of poses compared
    alignment: Sim3  # the estimate-to-truth similarity


def trajectory_errors(est_c2w: np.ndarray, true_c2w: np.ndarray) -> TrajectoryErrors:
    """Compare two trajectories of corresponding poses.

    Args:
        est_c2w: (N, 4, 4) estimated camera-to-world poses, in time order.
        true_c2w: (N, 4, 4) true camera-to-world poses (same camera-axis convention), same order.

    Returns:
        ATE after Umeyama Sim3 on camera centres, and RRE: for consecutive frames k, k+1 the angle of
        (Rtrue_k⁻¹ Rtrue_k+1)⁻¹ (Rest_k⁻¹ Rest_k+1), averaged.

    Raises:
        ValueError: shapes differ or fewer than 3 poses.
    """
    est, true = np.asarray(est_c2w, dtype=np.float64), np.asarray(true_c2w, dtype=np.float64)
    if est.shape != true.shape or est.ndim != 3 or est.shape[1:] != (4, 4):
        raise ValueError(f"expected two (N, 4, 4) pose arrays of the same shape, got {est.shape} and {true.shape}")
    sim = umeyama(est[:, :3, 3], true[:, :3, 3])
    err = np.linalg.norm(sim.apply(est[:, :3, 3]) - true[:, :3, 3], axis=1)
    r_est, r_true = est[:, :3, :3], true[:, :3, :3]
    rel_est = np.swapaxes(r_est[:-1], 1, 2) @ r_est[1:]
    rel_true = np.swapaxes(r_true[:-1], 1, 2) @ r_true[1:]
    rre = rotation_angle_deg(np.swapaxes(rel_true, 1, 2) @ rel_est)
    return TrajectoryErrors(
        ate_rmse=float(np.sqrt((err**2).mean())),
        ate_mean=float(err.mean()),
        rre_mean_deg=float(rre.mean()),
        num_poses=len(est),
        alignment=sim,
    )



def pool_trajectory_errors(parts: Sequence[TrajectoryErrors]) -> TrajectoryErrors:
    """Errors of several sub-trajectories, each aligned on its own (e.g. the sub-models of one SfM run), pooled over
    all their poses: ATE RMSE and mean over every pose, RRE over every consecutive pair within a part; the alignment
    is that of the part with the most poses.

    Raises:
        ValueError: no parts.
    """
    if not parts:
        raise ValueError("pool_trajectory_errors: no trajectories to pool")
    n = np.array([p.num_poses for p in parts], dtype=np.float64)
    pairs = n - 1
    rmse = np.array([p.ate_rmse for p in parts])
    return TrajectoryErrors(
        ate_rmse=float(np.sqrt((n * rmse**2).sum() / n.sum())),
        ate_mean=float((n * np.array([p.ate_mean for p in parts])).sum() / n.sum()),
        rre_mean_deg=float((pairs * np.array([p.rre_mean_deg for p in parts])).sum() / pairs.sum()),
        num_poses=int(n.sum()),
        alignment=max(parts, key=lambda p: p.num_poses).alignment,
    )
