"""Differentiable Gaussian rasterizer: one function, three backends (gsplat CUDA, C++/OpenMP CPU, pure torch).

    from spotlessgs.rasterizer import rasterize
    out = rasterize(means, quats, scales, opacities, features, viewmat, K, width, height)
    out.image  # (H, W, C); out.alpha, out.depth (H, W); out.means2d_grad() after backward (densification)

Conventions: OpenCV camera axes and world-to-camera ``viewmat``; pixel (x, y) covers [x, x+1) × [y, y+1) in the
coordinates of K (its centre is x + 0.5); ``depth`` is the alpha-normalised planar (camera z) depth; alpha ≤ 0.99,
alpha < 1/255 skipped, compositing stops before transmittance reaches 1e-4 (3DGS / gsplat rules). Shading happens
per Gaussian before this call. Environment: ``SPOTLESSGS_RASTER_BACKEND=cpp|torch`` forces the CPU backend chosen
by ``backend="auto"``; ``SPOTLESSGS_NUM_THREADS`` sets the default thread count (use 1 on a busy machine).
"""

from .api import BACKEND_ENV, BACKENDS, THREADS_ENV, RasterOutput, rasterize, resolve_backend
from .cpp_kernel import KernelBuildError, load_kernel
from .projection import ProjectedGaussians, covariance_3d, may_touch_image, project_gaussians, quat_to_rotmat

__all__ = [
    "BACKENDS",
    "BACKEND_ENV",
    "THREADS_ENV",
    "KernelBuildError",
    "ProjectedGaussians",
    "RasterOutput",
    "covariance_3d",
    "load_kernel",
    "may_touch_image",
    "project_gaussians",
    "quat_to_rotmat",
    "rasterize",
    "resolve_backend",
]
