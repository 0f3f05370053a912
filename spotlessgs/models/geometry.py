"""Small differentiable geometry helpers shared by the appearance models: safe normalisation, so(3) exponential and
logarithm, camera frames, orthonormal bases. Every function is finite in value and gradient at its degenerate inputs.

Camera convention (trainer): OpenCV axes (x right, y down, z forward); `c2w` (4, 4) maps camera to world, so its
rotation block R_cw has the camera axes as columns and its translation is the camera centre C.
"""

from __future__ import annotations

import numpy as np
import torch

# Squared norms below this are treated as zero length by `safe_normalize` (i.e. lengths below 1e-12).
ZERO_LENGTH_SQ = 1e-24
# Below this squared angle (rad²) so3_exp uses its Taylor expansion, avoiding 0/0 in sin θ / θ.
SO3_TAYLOR_SQ = 1e-8


def safe_normalize(v: torch.Tensor, fallback: torch.Tensor | None = None) -> torch.Tensor:
    """Unit vectors along `v`, with `fallback` where `v` has (near) zero length.

    The zero-length rows are routed through a `where` on both sides so that their gradient is exactly 0 and never NaN.

    Args:
        v: (..., 3) vectors.
        fallback: (..., 3) or broadcastable unit vectors used where |v| < 1e-12; default +z.
    Returns:
        (..., 3) unit vectors.
    """
    if fallback is None:
        fallback = torch.zeros_like(v)
        fallback[..., 2] = 1.0
    sq = (v * v).sum(dim=-1, keepdim=True)
    ok = sq > ZERO_LENGTH_SQ
    safe_sq = torch.where(ok, sq, torch.ones_like(sq))
    return torch.where(ok, v * torch.rsqrt(safe_sq), fallback.expand_as(v).to(v.dtype))


def _skew(w: torch.Tensor) -> torch.Tensor:
    """(3,) → (3, 3) cross-product matrix [w]×."""
    zero = torch.zeros((), dtype=w.dtype, device=w.device)
    wx, wy, wz = w.unbind(-1)
    return torch.stack(
        [torch.stack([zero, -wz, wy]), torch.stack([wz, zero, -wx]), torch.stack([-wy, wx, zero])]
    )


def so3_exp(w: torch.Tensor) -> torch.Tensor:
    """Rotation matrix of an axis-angle vector (Rodrigues), finite with finite gradient at w = 0.

    R = I + A [w]× + B [w]×², A = sin θ / θ, B = (1 - cos θ) / θ², θ = |w|; Taylor series for θ² < 1e-8.

    Args:
        w: (3,) axis-angle vector, radians.
    Returns:
        (3, 3) rotation matrix.
    """
    if w.shape != (3,):
        raise ValueError(f"so3_exp expects a (3,) axis-angle vector, got shape {tuple(w.shape)}")
    theta_sq = (w * w).sum()
    small = theta_sq < SO3_TAYLOR_SQ
    safe_sq = torch.where(small, torch.ones_like(theta_sq), theta_sq)
    theta = torch.sqrt(safe_sq)
    a = torch.where(small, 1.0 - theta_sq / 6.0, torch.sin(theta) / theta)
    b = torch.where(small, 0.5 - theta_sq / 24.0, (1.0 - torch.cos(theta)) / safe_sq)
    k = _skew(w)
    eye = torch.eye(3, dtype=w.dtype, device=w.device)
    return eye + a * k + b * (k @ k)


def so3_log(rotation) -> np.ndarray:
    """Axis-angle vector (3,) of a rotation matrix (3, 3) (no gradient; used to initialise parameters).

    Raises ValueError when the matrix is not a rotation (orthonormal with determinant +1, tolerance 1e-4).
    """
    from scipy.spatial.transform import Rotation

    r = np.asarray(rotation, dtype=np.float64)
    if r.shape != (3, 3):
        raise ValueError(f"so3_log expects a (3, 3) rotation matrix, got shape {r.shape}")
    if not np.allclose(r @ r.T, np.eye(3), atol=1e-4) or np.linalg.det(r) < 0:
        raise ValueError(f"so3_log: matrix is not a proper rotation (R Rᵀ != I or det < 0):\n{r}")
    return Rotation.from_matrix(r).as_rotvec()


def check_c2w(c2w: torch.Tensor) -> None:
    """Raise ValueError unless `c2w` is a (4, 4) tensor."""
    if not isinstance(c2w, torch.Tensor) or c2w.shape != (4, 4):
        shape = tuple(c2w.shape) if hasattr(c2w, "shape") else type(c2w).__name__
        raise ValueError(f"c2w must be a (4, 4) camera-to-world tensor (OpenCV axes), got {shape}")


def viewmat_to_c2w(viewmat: torch.Tensor) -> torch.Tensor:
    """World-to-camera (4, 4) → camera-to-world (4, 4), using the rigid-transform inverse [Rᵀ | -Rᵀ t]."""
    check_c2w(viewmat)
    r = viewmat[:3, :3]
    t = viewmat[:3, 3]
    out = torch.eye(4, dtype=viewmat.dtype, device=viewmat.device)
    out[:3, :3] = r.T
    out[:3, 3] = -(r.T @ t)
    return out


def points_in_view(points: torch.Tensor, view: torch.Tensor) -> torch.Tensor:
    """World points (N, 3) in the frame of a view matrix ``view`` (4, 4) (world-to-camera, or world-to-lamp), (N, 3):
    R x + t."""
    return points @ view[:3, :3].T + view[:3, 3]


def pinhole_pixels(points_cam: torch.Tensor, K: torch.Tensor, near: float) -> tuple[torch.Tensor, torch.Tensor]:
    """Pixel coordinates (u, v), (N,) each, of camera-frame points (N, 3) under the intrinsics K (3, 3), with the
    depth clamped at ``near`` (m) so that points behind the camera stay finite (the caller masks them)."""
    z = points_cam[:, 2].clamp(min=near)
    return K[0, 0] * points_cam[:, 0] / z + K[0, 2], K[1, 1] * points_cam[:, 1] / z + K[1, 2]


def world_to_camera(points: torch.Tensor, c2w: torch.Tensor) -> torch.Tensor:
    """Points (N, 3) in world → camera coordinates (N, 3): x_cam = R_cwᵀ (x - C)."""
    return (points - c2w[:3, 3]) @ c2w[:3, :3]


def orthonormal_basis(n: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """Two tangents (t1, t2), each (..., 3), completing unit normals n (..., 3) to a right-handed frame.

    Branch-free construction of Duff et al. (2017, "Building an orthonormal basis, revisited"), stable for all n.
    """
    x, y, z = n.unbind(-1)
    sign = torch.where(z >= 0, torch.ones_like(z), -torch.ones_like(z))
    a = -1.0 / (sign + z)
    b = x * y * a
    t1 = torch.stack([1.0 + sign * x * x * a, sign * b, -sign * x], dim=-1)
    t2 = torch.stack([b, sign + y * y * a, -y], dim=-1)
    return t1, t2
