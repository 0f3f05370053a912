"""The CUDA backend: gsplat 1.5.3's fused projection and tile rasterizer (optional dependency ``spotlessgs[gpu]``).

gsplat uses the same model as the CPU backends (pinhole EWA projection with the 0.3 px² dilation, 1.3× field-of-view
clamp of the Jacobian, alpha ≤ 0.99, skip alpha < 1/255, stop at T ≤ 1e-4, pixel centres at +0.5, planar depth), so
the backends agree up to float rounding and gsplat's tile-size-dependent culling.
"""

from __future__ import annotations

import importlib.util

import torch
from torch import Tensor


def gsplat_available() -> bool:
    """True when gsplat is importable and CUDA is present."""
    return importlib.util.find_spec("gsplat") is not None and torch.cuda.is_available()


def rasterize_gsplat(
    means: Tensor,
    quats: Tensor,
    scales: Tensor,
    opacities: Tensor,
    features: Tensor,
    viewmat: Tensor,
    K: Tensor,
    width: int,
    height: int,
    *,
    near: float,
    far: float,
    eps2d: float,
    tile_size: int,
) -> tuple[Tensor, Tensor, Tensor, Tensor, Tensor, Tensor]:
    """Render with gsplat on CUDA tensors.

    Args: as :func:`spotlessgs.rasterizer.rasterize` (all tensors on one CUDA device).
    Returns:
        color (H, W, C) without background, alpha (H, W), expected depth (H, W) (Σ w z / max(alpha, 1e-10)),
        means2d (1, N, 2) pixel centres with ``retain_grad`` set (its ``.grad[0]`` is the screen-space gradient),
        radii (N, 2) int32, depths (N,) camera z.
    """
    from gsplat import rasterization

    colors, alphas, meta = rasterization(
        means, quats, scales, opacities, features, viewmat[None], K[None], width, height,
        near_plane=near, far_plane=far, eps2d=eps2d, packed=False, tile_size=tile_size,
        render_mode="RGB+ED", rasterize_mode="classic",
    )
    means2d = meta["means2d"]  # (1, N, 2): the tensor gsplat's kernels consume, so its .grad is filled
    if means2d.requires_grad:
        means2d.retain_grad()
    channels = features.shape[-1]
    return (
        colors[0, ..., :channels],
        alphas[0, ..., 0],
        colors[0, ..., channels],
        means2d,
        meta["radii"][0].to(torch.int32),
        meta["depths"][0],
    )


__all__ = ["gsplat_available", "rasterize_gsplat"]
