"""Differentiable Gaussian rasterizer: one function, three backends (gsplat CUDA, C++/OpenMP CPU, pure torch).

    from spotlessgs.rasterizer import rasterize
    out = rasterize(means, quats, scales, opacities, features, viewmat, K, width, height)
    out.image  # (H, W, C); out.alpha, out.depth (H, W); out.means2d_grad() after backward (densification)
"""

from .api import BACKEND_ENV, BACKENDS, THREADS_ENV, RasterOutput, rasterize, resolve_backend
from .cpp_kernel import KernelBuildError, load_kernel
from .projection import ProjectedGaussians, covariance_3d, project_gaussians, quat_to_rotmat

__all__ = [
    "BACKENDS",
    "BACKEND_ENV",
    "THREADS_ENV",
    "KernelBuildError",
    "ProjectedGaussians",
    "RasterOutput",
    "covariance_3d",
    "load_kernel",
    "project_gaussians",
    "quat_to_rotmat",
    "rasterize",
    "resolve_backend",
]
