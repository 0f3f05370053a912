"""The one entry point: render Gaussians with per-Gaussian N-channel features to an image, alpha and depth.

Backends (``backend=``):
  ``"gsplat"``  gsplat's CUDA kernels (CUDA tensors; optional dependency ``spotlessgs[gpu]``);
  ``"cpp"``     our C++/OpenMP projection and tile compositing with hand-written backward passes (CPU; compiled
                on first use in about 2 s; the torch projection is used when viewmat or K requires a gradient, except
                with ``rigid_camera_grad``: then a viewmat's gradient along rigid motions reaches the C++ projection
                through the Gaussians, ``camera_grad.py``);
  ``"torch"``   the same maths in pure PyTorch (CPU or any device; slower, always available);
  ``"auto"``    gsplat for CUDA tensors; on the CPU ``$SPOTLESSGS_RASTER_BACKEND`` (``cpp`` or ``torch``) if set,
                else ``cpp`` when the kernel builds and ``torch`` (with one logged warning) when it does not.
Shading happens per Gaussian before this call (``features``), so the rasterizer knows nothing about lights.
"""

from __future__ import annotations

import contextlib
import os
from dataclasses import dataclass
from typing import Iterator

import torch
from torch import Tensor

from .backend_gsplat import gsplat_available, rasterize_gsplat
from .binning import bin_gaussians, bin_gaussians_cpp
from .camera_grad import camera_motion_on_gaussians
from .composite_cpp import composite_cpp
from .composite_torch import composite_torch
from .cpp_kernel import load_kernel
from .projection import project_gaussians
from .projection_cpp import project_gaussians_cpp

BACKENDS = ("auto", "cpp", "torch", "gsplat")
#: The smallest 2D covariance dilation (px²) accepted: below it a needle Gaussian's 2D covariance (condition number
#: past ~1e7) becomes indefinite in float32, giving NaN gradients (torch) and a wrong image (both backends); at 1e-4
#: both backends render such a needle as float64 does. Training uses 0.3 (3DGS's).
MIN_EPS2D = 1e-4
BACKEND_ENV = "SPOTLESSGS_RASTER_BACKEND"  # forces the CPU backend chosen by "auto": "cpp" or "torch"
THREADS_ENV = "SPOTLESSGS_NUM_THREADS"  # default thread count of the CPU backends
_DEPTH_EPS = 1e-10  # alpha below which the expected depth is reported as 0
# The C++ projection costs ~0.1 µs per Gaussian; below this many Gaussians it runs on one thread, because every
# parallel region waits for its slowest thread and on a busy machine that wait costs more than the work.
_PARALLEL_PROJECTION_MIN = 100_000


@dataclass(frozen=True)
class RasterOutput:
    """What :func:`rasterize` returns for one view (N Gaussians, H×W pixels, C channels)."""

    image: Tensor  # (H, W, C) Σ f_i α_i T_i + T_final · background
    alpha: Tensor  # (H, W) accumulated opacity 1 - T_final
    depth: Tensor  # (H, W) alpha-normalised expected planar depth Σ z_i α_i T_i / alpha (0 where alpha < 1e-10)
    means2d: Tensor  # (N, 2) projected centres in pixels (pixel (x, y) spans [x, x+1) × [y, y+1))
    radii: Tensor  # (N,) int32 screen radius in pixels (max over x and y); 0 = not visible in this view
    depths: Tensor  # (N,) camera-frame z of each Gaussian in metres
    backend: str  # the backend that rendered: "cpp", "torch" or "gsplat"
    screen_tensor: Tensor  # the tensor whose .grad holds the screen-space gradient ((N, 2), or (1, N, 2) on gsplat)

    @property
    def visible(self) -> Tensor:
        """(N,) bool: Gaussians that touch the image."""
        return self.radii > 0

    def means2d_grad(self) -> Tensor | None:
        """(N, 2) gradient of the loss w.r.t. ``means2d`` in pixels (after ``backward()``), for densification.

        None when nothing required a gradient or backward has not run.
        """
        grad = self.screen_tensor.grad
        if grad is None:
            return None
        return grad.reshape(-1, 2)


def rasterize(
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
    background: Tensor | None = None,
    near: float = 0.01,
    far: float = 1e4,
    eps2d: float = 0.3,
    backend: str = "auto",
    tile_size: int = 8,
    num_threads: int | None = None,
    rigid_camera_grad: bool = False,
) -> RasterOutput:
    """Render N Gaussians into one pinhole view.

    Args:
        means: (N, 3) world positions in metres.
        quats: (N, 4) rotations as quaternions (w, x, y, z); need not be normalised; zero → identity.
        scales: (N, 3) activated standard deviations along the local axes, metres (> 0).
        opacities: (N,) activated opacities in (0, 1).
        features: (N, C) per-Gaussian features (shaded colours or anything else), C ≥ 1; its dtype (float32 or
            float64) is the compute dtype and every other float tensor must have it too.
        viewmat: (4, 4) world-to-camera transform, OpenCV camera axes (x right, y down, z forward).
        K: (3, 3) pinhole intrinsics [[fx, 0, cx], [0, fy, cy], [0, 0, 1]] in pixels.
        width, height: image size in pixels.
        background: (C,) colour where the image is not covered (added as T_final · background), or None (zeros).
        near, far: Gaussians with camera z outside (near, far) metres are culled.
        eps2d: 2D covariance dilation in px² (anti-aliasing low-pass, as in 3DGS).
        backend: "auto", "cpp", "torch" or "gsplat" (see the module docstring).
        tile_size: tile side in pixels for binning (8 suits the CPU; gsplat is usually run with 16).
        num_threads: threads of the CPU backends; None → ``$SPOTLESSGS_NUM_THREADS`` or ``torch.get_num_threads()``.
        rigid_camera_grad: ``viewmat`` only moves by rigid motions (a camera pose being refined): on the ``cpp``
            backend its gradient is then exact along those motions only, through the C++ projection (about 1 ms
            instead of 13 ms more per 160×120 render of 20k Gaussians); without it every entry's gradient is exact.
    Returns:
        RasterOutput (image, alpha, depth differentiable w.r.t. means, quats, scales, opacities, features, viewmat).
    Raises:
        ValueError: a shape, dtype, device, size or option is invalid (the message names the argument and value).
        spotlessgs.rasterizer.KernelBuildError: ``backend="cpp"`` and the kernel cannot be built.
    """
    _check_inputs(means, quats, scales, opacities, features, viewmat, K, width, height, background,
                  near, far, eps2d, tile_size)
    threads = _resolve_threads(num_threads)
    chosen = _resolve_backend(backend, features.device)
    channels = features.shape[1]

    if chosen == "gsplat":
        color, alpha, depth, screen, radii_xy, depths = rasterize_gsplat(
            means, quats, scales, opacities, features, viewmat, K, width, height,
            near=near, far=far, eps2d=eps2d, tile_size=tile_size,
        )
        means2d = screen.detach().reshape(-1, 2)
    else:
        if rigid_camera_grad and chosen == "cpp" and viewmat.requires_grad and not K.requires_grad:
            means, quats, viewmat = camera_motion_on_gaussians(means, quats, viewmat)  # the same render, faster
        if chosen == "cpp" and not (viewmat.requires_grad or K.requires_grad):
            proj_threads = threads if features.shape[0] >= _PARALLEL_PROJECTION_MIN else 1
            proj = project_gaussians_cpp(means, quats, scales, opacities, viewmat, K, width, height,
                                         near=near, far=far, eps2d=eps2d, num_threads=proj_threads)
        else:  # torch maths (also when the camera itself is being optimised)
            with _torch_threads(threads):
                proj = project_gaussians(means, quats, scales, opacities, viewmat, K, width, height,
                                         near=near, far=far, eps2d=eps2d)
        screen = proj.means2d
        if screen.requires_grad:
            screen.retain_grad()
        means2d = screen
        depths = proj.depths
        radii_xy = proj.radii
        binner = bin_gaussians_cpp if chosen == "cpp" else bin_gaussians
        bins = binner(screen, radii_xy, depths, width, height, tile_size)
        stacked = torch.cat([features, depths[:, None]], dim=1)  # depth rides along as one more channel
        if chosen == "cpp":
            color_d, alpha = composite_cpp(screen, proj.conics, opacities, stacked, bins, width, height, threads)
        else:
            with _torch_threads(threads):
                color_d, alpha = composite_torch(screen, proj.conics, opacities, stacked, bins, width, height)
        color = color_d[..., :channels]
        depth = color_d[..., channels] / torch.clamp(alpha, min=_DEPTH_EPS)

    if background is not None:
        color = color + (1.0 - alpha)[..., None] * background
    radii = radii_xy.max(dim=-1).values.to(torch.int32) if radii_xy.numel() else radii_xy.new_zeros(0).int()
    return RasterOutput(image=color, alpha=alpha, depth=depth, means2d=means2d, radii=radii, depths=depths,
                        backend=chosen, screen_tensor=screen)


def resolve_backend(backend: str = "auto", device: torch.device | str = "cpu") -> str:
    """The backend that :func:`rasterize` would use for tensors on ``device`` ("cpp", "torch" or "gsplat")."""
    return _resolve_backend(backend, torch.device(device))


def _resolve_backend(backend: str, device: torch.device) -> str:
    if backend not in BACKENDS:
        raise ValueError(f"backend must be one of {BACKENDS}, got {backend!r}")
    if backend == "auto":
        if device.type == "cuda":
            if gsplat_available():
                return "gsplat"
            return "torch"
        forced = os.environ.get(BACKEND_ENV, "").strip().lower()
        if forced:
            if forced not in ("cpp", "torch"):
                raise ValueError(f"${BACKEND_ENV} must be 'cpp' or 'torch', got {forced!r}")
            backend = forced
        else:
            return "cpp" if load_kernel() is not None else "torch"
    if backend == "cpp" and device.type != "cpu":
        raise ValueError(f"backend 'cpp' needs CPU tensors, got tensors on {device}")
    if backend == "gsplat" and device.type != "cuda":
        raise ValueError(f"backend 'gsplat' needs CUDA tensors, got tensors on {device}")
    return backend


def _resolve_threads(num_threads: int | None) -> int:
    if num_threads is None:
        env = os.environ.get(THREADS_ENV, "").strip()
        if env:
            try:
                num_threads = int(env)
            except ValueError:
                raise ValueError(f"${THREADS_ENV} must be a positive integer, got {env!r}") from None
            if num_threads < 1:
                raise ValueError(f"${THREADS_ENV} must be a positive integer, got {env!r}")
        else:
            num_threads = torch.get_num_threads()
    if isinstance(num_threads, bool) or not isinstance(num_threads, int) or num_threads < 1:
        raise ValueError(f"num_threads must be a positive integer or None, got {num_threads!r}")
    return num_threads


@contextlib.contextmanager
def _torch_threads(n: int) -> Iterator[None]:
    previous = torch.get_num_threads()
    if n != previous:
        torch.set_num_threads(n)
    try:
        yield
    finally:
        if n != previous:
            torch.set_num_threads(previous)


def _check_inputs(means, quats, scales, opacities, features, viewmat, K, width, height, background,
                  near, far, eps2d, tile_size) -> None:
    if features.dim() != 2 or features.shape[1] < 1:
        raise ValueError(f"features must have shape (N, C) with C >= 1, got {tuple(features.shape)}")
    n = features.shape[0]
    expected = {"means": (means, (n, 3)), "quats": (quats, (n, 4)), "scales": (scales, (n, 3)),
                "opacities": (opacities, (n,)), "viewmat": (viewmat, (4, 4)), "K": (K, (3, 3))}
    if background is not None:
        expected["background"] = (background, (features.shape[1],))
    if features.dtype not in (torch.float32, torch.float64):
        raise ValueError(f"features must be float32 or float64, got {features.dtype}")
    for name, (tensor, shape) in expected.items():
        if not isinstance(tensor, Tensor):
            raise ValueError(f"{name} must be a torch.Tensor, got {type(tensor).__name__}")
        if tuple(tensor.shape) != shape:
            raise ValueError(f"{name} must have shape {shape} (N={n} from features), got {tuple(tensor.shape)}")
        if tensor.dtype != features.dtype:
            raise ValueError(f"{name} has dtype {tensor.dtype} but features has {features.dtype}; use one dtype")
        if tensor.device != features.device:
            raise ValueError(f"{name} is on {tensor.device} but features is on {features.device}")
    for name, value in (("width", width), ("height", height)):
        if isinstance(value, bool) or not isinstance(value, int) or value < 1:
            raise ValueError(f"{name} must be a positive integer, got {value!r}")
    if isinstance(tile_size, bool) or not isinstance(tile_size, int) or not 1 <= tile_size <= 64:
        raise ValueError(f"tile_size must be an integer in [1, 64], got {tile_size!r}")
    if not (near > 0 and far > near):
        raise ValueError(f"need 0 < near < far, got near={near!r}, far={far!r}")
    if not MIN_EPS2D <= eps2d < float("inf"):
        raise ValueError(f"eps2d must be at least {MIN_EPS2D:g} px² and finite, got {eps2d!r} (without the dilation a "
                         "needle or flat Gaussian's 2D covariance is singular to float32: NaN gradients, and the "
                         "backends disagree)")


__all__ = ["BACKENDS", "BACKEND_ENV", "THREADS_ENV", "RasterOutput", "rasterize", "resolve_backend"]
