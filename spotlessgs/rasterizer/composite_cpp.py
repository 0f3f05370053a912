"""The autograd Function around the C++ compositing kernel (``csrc/composite.cpp``)."""

from __future__ import annotations

import torch
from torch import Tensor

from .binning import TileBins
from .cpp_kernel import load_kernel
from .cpp_kernel import pointer as _p


class _CompositeFunction(torch.autograd.Function):
    @staticmethod
    def forward(ctx, means2d, conics, opacities, features, bins: TileBins, width: int, height: int, num_threads: int):
        kernel = load_kernel(raise_errors=True)
        dtype = features.dtype
        suffix = {torch.float32: "f32", torch.float64: "f64"}[dtype]
        means2d, conics, opacities, features = (
            t.detach().to(dtype).contiguous() for t in (means2d, conics, opacities, features)
        )
        channels = features.shape[1]
        color = torch.empty(height, width, channels, dtype=dtype)
        trans = torch.empty(height, width, dtype=dtype)
        counts = torch.empty(height, width, dtype=torch.int32)
        getattr(kernel.lib, f"spotless_composite_forward_{suffix}")(
            _p(means2d), _p(conics), _p(opacities), _p(features), _p(bins.tile_offsets), _p(bins.gauss_ids),
            channels, width, height, bins.tile_size, bins.tiles_x, bins.tiles_y,
            _p(color), _p(trans), _p(counts), num_threads,
        )
        ctx.save_for_backward(means2d, conics, opacities, features, trans, counts)
        ctx.bins, ctx.width, ctx.height, ctx.num_threads, ctx.suffix = bins, width, height, num_threads, suffix
        alpha = 1.0 - trans
        ctx.mark_non_differentiable(counts)
        return color, alpha

    @staticmethod
    def backward(ctx, grad_color, grad_alpha):
        means2d, conics, opacities, features, trans, counts = ctx.saved_tensors
        bins: TileBins = ctx.bins
        kernel = load_kernel(raise_errors=True)
        dtype = features.dtype
        n, channels = features.shape
        stride = 6 + channels
        grad_color = (torch.zeros_like(trans)[..., None].expand(-1, -1, channels) if grad_color is None
                      else grad_color).to(dtype).contiguous()
        grad_alpha = (torch.zeros_like(trans) if grad_alpha is None else grad_alpha).to(dtype).contiguous()
        pair_grads = torch.zeros(bins.num_pairs, stride, dtype=dtype)
        getattr(kernel.lib, f"spotless_composite_backward_{ctx.suffix}")(
            _p(means2d), _p(conics), _p(opacities), _p(features), _p(bins.tile_offsets), _p(bins.gauss_ids),
            channels, ctx.width, ctx.height, bins.tile_size, bins.tiles_x, bins.tiles_y,
            _p(trans), _p(counts), _p(grad_color), _p(grad_alpha), _p(pair_grads), ctx.num_threads,
        )
        grads = torch.zeros(n, stride, dtype=dtype)
        getattr(kernel.lib, f"spotless_reduce_pairs_{ctx.suffix}")(
            _p(pair_grads), _p(bins.gauss_ids), bins.num_pairs, stride, _p(grads)
        )
        return grads[:, 0:2], grads[:, 2:5], grads[:, 5], grads[:, 6:], None, None, None, None


def composite_cpp(
    means2d: Tensor,
    conics: Tensor,
    opacities: Tensor,
    features: Tensor,
    bins: TileBins,
    width: int,
    height: int,
    num_threads: int,
) -> tuple[Tensor, Tensor]:
    """Alpha-composite screen-space Gaussians with the C++ kernel (CPU tensors, float32 or float64).

    Args:
        means2d: (N, 2) pixel-coordinate centres.
        conics: (N, 3) inverse 2D covariances (a, b, c).
        opacities: (N,) opacities in (0, 1).
        features: (N, C) per-Gaussian features; its dtype is the compute dtype.
        bins: tile lists from :func:`spotlessgs.rasterizer.binning.bin_gaussians`.
        width, height: image size in pixels.
        num_threads: OpenMP threads for this call.
    Returns:
        color (H, W, C) and alpha (H, W), without background; differentiable w.r.t. the first four inputs.
    Raises:
        spotlessgs.rasterizer.cpp_kernel.KernelBuildError: the kernel is not available.
    """
    return _CompositeFunction.apply(means2d, conics, opacities, features, bins, width, height, num_threads)


__all__ = ["composite_cpp"]
