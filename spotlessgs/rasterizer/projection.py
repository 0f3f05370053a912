"""Projection of 3D Gaussians to screen-space 2D Gaussians (EWA splatting), in pure torch.

Autograd provides the gradients. The maths follows 3DGS / gsplat's pinhole model:

    R = rot(q / |q|),  Σ = R S Sᵀ Rᵀ                          (3D covariance, S = diag(scales))
    t = V[:3,:3] μ + V[:3,3],  Σ_c = V[:3,:3] Σ V[:3,:3]ᵀ       (camera frame, OpenCV axes: x right, y down, z forward)
    μ2d = (fx tx / tz + cx, fy ty / tz + cy)                   (pixels; pixel (i, j) covers [i, i+1)×[j, j+1))
    J = [[fx/tz, 0, -fx tx'/tz²], [0, fy/tz, -fy ty'/tz²]]     (tx', ty' clamped to 1.3× the field of view)
    Σ2d = J Σ_c Jᵀ + eps2d I = (J M_c)(J M_c)ᵀ + eps2d I       (M_c = V R S; low-pass dilation 0.3 px² like 3DGS)
    conic = Σ2d⁻¹ stored as (a, b, c) = (Σ2d⁻¹_xx, Σ2d⁻¹_xy, Σ2d⁻¹_yy)

The screen-space extent is opacity-aware: outside the ellipse of Mahalanobis radius r = sqrt(2 ln(255 o)) the
Gaussian's alpha o·exp(-r²/2) is below the 1/255 skip threshold, so tile culling with that bounding box changes no
pixel (the rasterizer equals the dense definition exactly). r ≤ 3.33 (the 3.33-sigma radius of gsplat) since o < 1.

The covariance part is evaluated in float64 (then cast back) so that huge (1e3 m) and tiny (1e-8 m) scales give
finite conics; zero-norm quaternions map to the identity rotation with a zero (finite) gradient.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch
from torch import Tensor

ALPHA_MIN = 1.0 / 255.0  # alpha below which a Gaussian is skipped at a pixel (shared with the compositing kernels)
_QUAT_EPS = 1e-12  # quaternion norm below which the identity rotation is used
RADIUS_LIMIT = 1 << 20  # screen radii are clamped to this (px) so huge Gaussians stay finite integers; the tile
# rectangles are clipped to the image, so a huge Gaussian costs at most one entry per tile


@dataclass(frozen=True)
class ProjectedGaussians:
    """Screen-space Gaussians for one view; N is the number of input Gaussians (culled ones keep their slot)."""

    means2d: Tensor  # (N, 2) pixel coordinates of the projected centres, differentiable; 0 where culled
    conics: Tensor  # (N, 3) inverse 2D covariance (a, b, c): sigma = ½(a dx² + c dy²) + b dx dy; 0 where culled
    depths: Tensor  # (N,) camera-frame z in metres (planar depth), differentiable
    radii: Tensor  # (N, 2) int32 half-extent of the screen bounding box in pixels (x, y); 0 = culled / not visible
    cov2d: Tensor  # (N, 2, 2) dilated 2D covariance in px² (for inspection and tests; differentiable in torch only)

    @property
    def visible(self) -> Tensor:
        """(N,) bool: the Gaussian touches the image and passed the near/far/opacity tests."""
        return (self.radii > 0).all(dim=-1)


def quat_to_rotmat(quats: Tensor) -> Tensor:
    """Rotation matrices from quaternions (w, x, y, z), any norm; a zero quaternion gives the identity.

    Args:
        quats: (N, 4) quaternions, w first; normalised here.
    Returns:
        (N, 3, 3) rotation matrices. The gradient is finite everywhere (zero at a zero quaternion).
    """
    norm = torch.linalg.vector_norm(quats, dim=-1, keepdim=True)
    ok = norm > _QUAT_EPS
    identity = torch.zeros_like(quats)
    identity[..., 0] = 1.0
    q = torch.where(ok, quats / torch.where(ok, norm, torch.ones_like(norm)), identity)
    w, x, y, z = q.unbind(-1)
    rot = torch.stack(
        [
            1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y),
            2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x),
            2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y),
        ],
        dim=-1,
    )
    return rot.reshape(quats.shape[:-1] + (3, 3))


def covariance_3d(quats: Tensor, scales: Tensor) -> Tensor:
    """World-space covariance Σ = R diag(s)² Rᵀ.

    Args:
        quats: (N, 4) quaternions (w, x, y, z), any norm.
        scales: (N, 3) standard deviations along the local axes in metres (already activated, > 0).
    Returns:
        (N, 3, 3) symmetric positive semi-definite covariances in m².
    """
    m = quat_to_rotmat(quats) * scales[:, None, :]
    return m @ m.transpose(-1, -2)


def project_gaussians(
    means: Tensor,
    quats: Tensor,
    scales: Tensor,
    opacities: Tensor,
    viewmat: Tensor,
    K: Tensor,
    width: int,
    height: int,
    *,
    near: float = 0.01,
    far: float = 1e4,
    eps2d: float = 0.3,
) -> ProjectedGaussians:
    """Project 3D Gaussians into one pinhole view.

    Args:
        means: (N, 3) world positions in metres.
        quats: (N, 4) rotations (w, x, y, z), unnormalised is fine.
        scales: (N, 3) activated standard deviations in metres.
        opacities: (N,) opacities in (0, 1); used only for the screen extent (no gradient flows through it here).
        viewmat: (4, 4) world-to-camera transform, OpenCV axes (x right, y down, z forward).
        K: (3, 3) intrinsics [[fx, 0, cx], [0, fy, cy], [0, 0, 1]] in pixels.
        width, height: image size in pixels.
        near, far: Gaussians whose camera z is not inside (near, far) are culled.
        eps2d: isotropic dilation of the 2D covariance in px² (anti-aliasing low-pass filter).
    Returns:
        ProjectedGaussians with tensors in the dtype of ``means``.
    """
    out_dtype = means.dtype
    work = torch.float64
    mean_w = means.to(work)
    rot_v = viewmat[:3, :3].to(work)
    trans_v = viewmat[:3, 3].to(work)
    fx, fy = K[0, 0].to(work), K[1, 1].to(work)
    cx, cy = K[0, 2].to(work), K[1, 2].to(work)

    mean_c = mean_w @ rot_v.T + trans_v  # (N, 3)
    # Camera-frame square root of the covariance, M_c = V R S (Σ_c = M_c M_cᵀ), without batched tiny matmuls.
    m_world = quat_to_rotmat(quats.to(work)) * scales.to(work)[:, None, :]  # (N, 3, 3), R S
    m_c = (m_world.transpose(1, 2) @ rot_v.T).transpose(1, 2)  # V R S; a 2D right operand folds into one mm
    tz_raw = mean_c[:, 2]
    in_depth = (tz_raw > near) & (tz_raw < far)
    # Culled Gaussians get a harmless depth so that no inf/NaN reaches the (masked) gradient.
    tz = torch.where(in_depth, tz_raw, torch.ones_like(tz_raw))

    u, v = _clamped_tangents(mean_c, tz, fx, fy, cx, cy, width, height)

    # Rows of J M_c with J = [[fx/z, 0, -fx u/z], [0, fy/z, -fy v/z]]; Σ2d = (J M_c)(J M_c)ᵀ is PSD by construction.
    row_x = (fx / tz)[:, None] * (m_c[:, 0, :] - u[:, None] * m_c[:, 2, :])  # (N, 3)
    row_y = (fy / tz)[:, None] * (m_c[:, 1, :] - v[:, None] * m_c[:, 2, :])
    cxx = (row_x * row_x).sum(-1) + eps2d
    cyy = (row_y * row_y).sum(-1) + eps2d
    cxy = (row_x * row_y).sum(-1)
    cov2d = torch.stack([cxx, cxy, cxy, cyy], dim=-1).reshape(-1, 2, 2)
    det = cxx * cyy - cxy * cxy
    det_ok = det > 0
    safe_det = torch.where(det_ok, det, torch.ones_like(det))
    conics = torch.stack([cyy, -cxy, cxx], dim=-1) / safe_det[:, None]

    means2d = torch.stack([fx * mean_c[:, 0] / tz + cx, fy * mean_c[:, 1] / tz + cy], dim=-1)
    # Culled Gaussians report zeros (and pass no gradient), as the C++ projection does.
    valid = in_depth & det_ok
    means2d = torch.where(valid[:, None], means2d, torch.zeros_like(means2d))
    conics = torch.where(valid[:, None], conics, torch.zeros_like(conics))

    with torch.no_grad():
        radii = _screen_radii(means2d, cov2d, opacities.detach().to(work), valid, width, height)

    return ProjectedGaussians(
        means2d=means2d.to(out_dtype),
        conics=conics.to(out_dtype),
        depths=tz_raw.to(out_dtype),
        radii=radii,
        cov2d=cov2d.to(out_dtype),
    )


def _clamped_tangents(mean_c: Tensor, tz: Tensor, fx: Tensor, fy: Tensor, cx: Tensor, cy: Tensor, width: int,
                      height: int) -> tuple[Tensor, Tensor]:
    """x/z and y/z (N,) each of camera-frame means (N, 3) at depths ``tz`` (N,), limited to 1.3× the field of view
    (the Jacobian's, as 3DGS limits it)."""
    tan_x = 0.5 * width / fx
    tan_y = 0.5 * height / fy
    u = torch.clamp(mean_c[:, 0] / tz, min=-(cx / fx + 0.3 * tan_x), max=(width - cx) / fx + 0.3 * tan_x)
    v = torch.clamp(mean_c[:, 1] / tz, min=-(cy / fy + 0.3 * tan_y), max=(height - cy) / fy + 0.3 * tan_y)
    return u, v


def may_touch_image(
    means: Tensor, scales: Tensor, viewmat: Tensor, K: Tensor, width: int, height: int, *, near: float = 0.01,
    far: float = 1e4, eps2d: float = 0.3,
) -> Tensor:
    """(N,) bool, conservative: False only for Gaussians that :func:`project_gaussians` culls or gives no pixel of
    the image, whatever their rotation and opacity (the bounding box of the largest scale along every axis, at
    opacity 1: the Mahalanobis radius sqrt(2 ln 255), and a pixel for the rounding). A caller that shades only
    these Gaussians changes no pixel.

    Args:
        means: (N, 3) world positions; scales: (N, 3) standard deviations (m); viewmat: (4, 4) world-to-camera
        (OpenCV); K: (3, 3); width, height: image size (px); near, far, eps2d: as :func:`project_gaussians`'.
    """
    with torch.no_grad():
        work = torch.float64
        mean_c = means.to(work) @ viewmat[:3, :3].to(work).T + viewmat[:3, 3].to(work)
        tz_raw = mean_c[:, 2]
        in_depth = (tz_raw > near) & (tz_raw < far)
        tz = torch.where(in_depth, tz_raw, torch.ones_like(tz_raw))
        fx, fy, cx, cy = (K[0, 0].to(work), K[1, 1].to(work), K[0, 2].to(work), K[1, 2].to(work))
        u, v = _clamped_tangents(mean_c, tz, fx, fy, cx, cy, width, height)
        largest = scales.to(work).max(dim=1).values / tz
        # a row of J M_c is (f / z)(m_0 - u m_2): no longer than (f / z) s_max sqrt(1 + u²)
        extent = math.sqrt(2.0 * math.log(1.0 / ALPHA_MIN))
        radius_x = extent * torch.sqrt((fx * largest) ** 2 * (1.0 + u * u) + eps2d) + 1.0
        radius_y = extent * torch.sqrt((fy * largest) ** 2 * (1.0 + v * v) + eps2d) + 1.0
        x, y = fx * mean_c[:, 0] / tz + cx, fy * mean_c[:, 1] / tz + cy
        return in_depth & (x + radius_x > 0) & (x - radius_x < width) & (y + radius_y > 0) & (y - radius_y < height)


def _screen_radii(means2d: Tensor, cov2d: Tensor, opacities: Tensor, valid: Tensor, width: int, height: int) -> Tensor:
    """(N, 2) int32 half-extents of the opacity-aware bounding boxes; 0 where culled or off-screen."""
    log_term = torch.log(torch.clamp(opacities, min=0.0) / ALPHA_MIN)
    extent = torch.sqrt(torch.clamp(2.0 * log_term, min=0.0))  # Mahalanobis radius where alpha hits 1/255
    sd = torch.sqrt(torch.clamp(torch.diagonal(cov2d, dim1=-2, dim2=-1), min=0.0))  # (N, 2)
    radius = torch.clamp(torch.ceil(extent[:, None] * sd), max=float(RADIUS_LIMIT))
    finite = torch.isfinite(means2d).all(dim=-1) & torch.isfinite(radius).all(dim=-1)
    keep = valid & finite & (opacities > ALPHA_MIN) & (radius > 0).all(dim=-1)
    safe_means = torch.where(finite[:, None], means2d, torch.zeros_like(means2d))
    inside = (
        (safe_means[:, 0] + radius[:, 0] > 0)
        & (safe_means[:, 0] - radius[:, 0] < width)
        & (safe_means[:, 1] + radius[:, 1] > 0)
        & (safe_means[:, 1] - radius[:, 1] < height)
    )
    keep = keep & inside
    radius = torch.where(keep[:, None], torch.nan_to_num(radius, nan=0.0), torch.zeros_like(radius))
    return radius.to(torch.int32)


__all__ = [
    "ALPHA_MIN",
    "ProjectedGaussians",
    "covariance_3d",
    "RADIUS_LIMIT",
    "project_gaussians",
    "quat_to_rotmat",
]
