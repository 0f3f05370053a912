"""The C++/OpenMP projection (``csrc/projection.cpp``) as an autograd Function: same maths and outputs as
:func:`spotlessgs.rasterizer.projection.project_gaussians`, about ten times cheaper than the torch version.

Gradients flow to means, quats and scales. The view matrix and intrinsics get no gradient here: :func:`rasterize`
uses the torch projection whenever either of them requires a gradient (camera pose optimisation).
"""

from __future__ import annotations

import torch
from torch import Tensor

from .cpp_kernel import load_kernel
from .cpp_kernel import pointer as _p
from .projection import RADIUS_LIMIT, ProjectedGaussians


def _camera_arrays(viewmat: Tensor, K: Tensor) -> tuple[Tensor, Tensor]:
    view = torch.cat([viewmat[:3, :3].reshape(-1), viewmat[:3, 3]]).detach().to(torch.float64).cpu().contiguous()
    intr = torch.stack([K[0, 0], K[1, 1], K[0, 2], K[1, 2]]).detach().to(torch.float64).cpu().contiguous()
    return view, intr


class _ProjectFunction(torch.autograd.Function):
    @staticmethod
    def forward(ctx, means, quats, scales, opacities, viewmat, K, width, height, near, far, eps2d, num_threads):
        kernel = load_kernel(raise_errors=True)
        dtype = means.dtype
        suffix = {torch.float32: "f32", torch.float64: "f64"}[dtype]
        means, quats, scales, opacities = (t.detach().contiguous() for t in (means, quats, scales, opacities))
        view, intr = _camera_arrays(viewmat, K)
        n = means.shape[0]
        means2d = torch.empty(n, 2, dtype=dtype)
        conics = torch.empty(n, 3, dtype=dtype)
        depths = torch.empty(n, dtype=dtype)
        cov2d = torch.empty(n, 3, dtype=dtype)
        radii = torch.empty(n, 2, dtype=torch.int32)
        getattr(kernel.lib, f"spotless_project_forward_{suffix}")(
            _p(means), _p(quats), _p(scales), _p(opacities), _p(view), _p(intr), n, width, height,
            float(near), float(far), float(eps2d), float(RADIUS_LIMIT),
            _p(means2d), _p(conics), _p(depths), _p(cov2d), _p(radii), num_threads,
        )
        ctx.save_for_backward(means, quats, scales, view, intr)
        ctx.settings = (suffix, width, height, float(near), float(far), float(eps2d), num_threads)
        ctx.mark_non_differentiable(cov2d, radii)
        return means2d, conics, depths, cov2d, radii

    @staticmethod
    def backward(ctx, g_means2d, g_conics, g_depths, _g_cov2d, _g_radii):
        means, quats, scales, view, intr = ctx.saved_tensors
        suffix, width, height, near, far, eps2d, num_threads = ctx.settings
        kernel = load_kernel(raise_errors=True)
        n, dtype = means.shape[0], means.dtype

        def grad_or_zeros(g, shape):
            return torch.zeros(shape, dtype=dtype) if g is None else g.to(dtype).contiguous()

        g_means2d = grad_or_zeros(g_means2d, (n, 2))
        g_conics = grad_or_zeros(g_conics, (n, 3))
        g_depths = grad_or_zeros(g_depths, (n,))
        g_means = torch.empty(n, 3, dtype=dtype)
        g_quats = torch.empty(n, 4, dtype=dtype)
        g_scales = torch.empty(n, 3, dtype=dtype)
        getattr(kernel.lib, f"spotless_project_backward_{suffix}")(
            _p(means), _p(quats), _p(scales), _p(view), _p(intr), n, width, height, near, far, eps2d,
            _p(g_means2d), _p(g_conics), _p(g_depths), _p(g_means), _p(g_quats), _p(g_scales), num_threads,
        )
        return g_means, g_quats, g_scales, None, None, None, None, None, None, None, None, None


def project_gaussians_cpp(
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
    num_threads: int = 1,
) -> ProjectedGaussians:
    """C++ projection of N Gaussians into one view (CPU tensors, float32 or float64; computed in float64).

    Args: as :func:`spotlessgs.rasterizer.projection.project_gaussians`, plus ``num_threads`` (OpenMP threads).
    Returns:
        ProjectedGaussians; means2d, conics and depths are differentiable w.r.t. means, quats and scales, cov2d is not.
    Raises:
        spotlessgs.rasterizer.cpp_kernel.KernelBuildError: the kernel is not available.
    """
    means2d, conics, depths, cov2d, radii = _ProjectFunction.apply(
        means, quats, scales, opacities, viewmat, K, width, height, near, far, eps2d, num_threads
    )
    cov = torch.stack([cov2d[:, 0], cov2d[:, 1], cov2d[:, 1], cov2d[:, 2]], dim=-1).reshape(-1, 2, 2)
    return ProjectedGaussians(means2d=means2d, conics=conics, depths=depths, radii=radii, cov2d=cov)


__all__ = ["project_gaussians_cpp"]
