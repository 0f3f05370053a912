"""Slow, obvious references for the rasterizer tests (not used by the library).

- ``project_numpy``: EWA projection written independently in numpy, one Gaussian at a time.
- ``composite_reference``: every pixel against every in-range Gaussian in depth order, no tiles, no culling except
  near/far, with the same alpha rules as the kernels; differentiable through torch autograd.
- ``random_scene``: a reproducible small scene in front of an identity camera.
"""

from __future__ import annotations

import math

import numpy as np
import torch

from spotlessgs.io.seeding import torch_generator


def quat_to_rotmat_numpy(q: np.ndarray) -> np.ndarray:
    """(4,) quaternion (w, x, y, z), any non-zero norm → (3, 3) rotation, via the axis-angle (Rodrigues) formula."""
    q = q / np.linalg.norm(q)
    if q[0] < 0:
        q = -q
    w, v = q[0], q[1:]
    s = np.linalg.norm(v)
    if s < 1e-15:
        return np.eye(3)
    angle = 2.0 * math.atan2(s, w)
    axis = v / s
    k = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
    return np.eye(3) + math.sin(angle) * k + (1 - math.cos(angle)) * k @ k


def project_numpy(means, quats, scales, viewmat, K, width, height, eps2d=0.3):
    """Independent projection: returns means2d (N, 2), conics (N, 3), depths (N,), cov2d (N, 2, 2), all float64."""
    means, quats, scales = (np.asarray(a, dtype=np.float64) for a in (means, quats, scales))
    viewmat, K = np.asarray(viewmat, dtype=np.float64), np.asarray(K, dtype=np.float64)
    n = means.shape[0]
    out_m, out_c, out_d, out_cov = np.zeros((n, 2)), np.zeros((n, 3)), np.zeros(n), np.zeros((n, 2, 2))
    fx, fy, cx, cy = K[0, 0], K[1, 1], K[0, 2], K[1, 2]
    for i in range(n):
        rot = quat_to_rotmat_numpy(quats[i])
        sigma = rot @ np.diag(scales[i] ** 2) @ rot.T
        p = viewmat[:3, :3] @ means[i] + viewmat[:3, 3]
        sigma_c = viewmat[:3, :3] @ sigma @ viewmat[:3, :3].T
        x, y, z = p
        # Jacobian of (fx x/z + cx, fy y/z + cy), with x/z, y/z limited to 1.3x the half field of view.
        u = np.clip(x / z, -(cx / fx + 0.15 * width / fx), (width - cx) / fx + 0.15 * width / fx)
        v = np.clip(y / z, -(cy / fy + 0.15 * height / fy), (height - cy) / fy + 0.15 * height / fy)
        jac = np.array([[fx / z, 0.0, -fx * u / z], [0.0, fy / z, -fy * v / z]])
        cov = jac @ sigma_c @ jac.T + eps2d * np.eye(2)
        inv = np.linalg.inv(cov)
        out_m[i] = [fx * x / z + cx, fy * y / z + cy]
        out_c[i] = [inv[0, 0], inv[0, 1], inv[1, 1]]
        out_d[i] = z
        out_cov[i] = cov
    return out_m, out_c, out_d, out_cov


def composite_reference(means2d, conics, opacities, features, depths, width, height, near=0.01, far=1e4,
                        t_min=1e-4):
    """Dense per-pixel compositing of all Gaussians with near < depth < far, front to back (ties by index).

    ``t_min`` is the early-stop transmittance (0 disables the early stop).

    Args:
        means2d (N, 2), conics (N, 3), opacities (N,), features (N, C), depths (N,): torch tensors.
    Returns:
        color (H, W, C) without background and alpha (H, W), differentiable.
    """
    dtype = features.dtype
    ys, xs = torch.meshgrid(torch.arange(height, dtype=dtype), torch.arange(width, dtype=dtype), indexing="ij")
    px, py = xs.reshape(-1) + 0.5, ys.reshape(-1) + 0.5
    trans = torch.ones(px.shape[0], dtype=dtype)
    color = torch.zeros(px.shape[0], features.shape[1], dtype=dtype)
    done = torch.zeros(px.shape[0], dtype=torch.bool)
    d = depths.detach().tolist()
    order = sorted((i for i in range(len(d)) if near < d[i] < far), key=lambda i: (d[i], i))
    for i in order:
        dx, dy = means2d[i, 0] - px, means2d[i, 1] - py
        a, b, c = conics[i]
        sigma = 0.5 * (a * dx * dx + c * dy * dy) + b * dx * dy
        alpha = torch.clamp(opacities[i] * torch.exp(-sigma), max=0.99)
        use = (alpha >= 1.0 / 255.0) & ~done
        nxt = trans * (1.0 - alpha)
        stop = use & (nxt <= t_min)
        done = done | stop
        use = use & ~stop
        color = color + torch.where(use, alpha * trans, torch.zeros_like(alpha))[:, None] * features[i]
        trans = torch.where(use, nxt, trans)
    return color.reshape(height, width, -1), (1.0 - trans).reshape(height, width)


def random_scene(n, channels, seed=0, dtype=torch.float64, depth=4.0, log_scale=-2.5, spread=(1.0, 0.8, 0.6),
                 opacity_range=(0.1, 0.95)):
    """Reproducible Gaussians in front of the camera: means, quats, scales, opacities, features (all leaf tensors)."""
    gen = torch_generator(seed, "rasterizer-test-scene")
    means = torch.randn(n, 3, generator=gen, dtype=dtype) * torch.tensor(spread, dtype=dtype)
    means[:, 2] += depth
    quats = torch.randn(n, 4, generator=gen, dtype=dtype)
    scales = torch.exp(log_scale + 0.4 * torch.randn(n, 3, generator=gen, dtype=dtype))
    lo, hi = opacity_range
    opacities = lo + (hi - lo) * torch.rand(n, generator=gen, dtype=dtype)
    features = torch.rand(n, channels, generator=gen, dtype=dtype)
    return [t.requires_grad_() for t in (means, quats, scales, opacities, features)]


def camera(width, height, focal=None, dtype=torch.float64):
    """Identity view matrix and a centred pinhole K for a width×height image: (viewmat (4, 4), K (3, 3))."""
    f = focal if focal is not None else 1.1 * width
    K = torch.tensor([[f, 0.0, width / 2], [0.0, f, height / 2], [0.0, 0.0, 1.0]], dtype=dtype)
    return torch.eye(4, dtype=dtype), K
