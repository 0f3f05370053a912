"""Full-reference image metrics in torch: PSNR and SSIM (Gaussian 11×11 window, σ = 1.5, as in Wang et al. 2004).

Both take batches of images shaped (B, C, H, W) (or a single (C, H, W) image) with values in [0, data_range] and
return one value per image, shape (B,). SSIM follows the standard definition used by scikit-image
(``gaussian_weights=True, sigma=1.5, use_sample_covariance=False``): the SSIM map is computed on the "valid" region
(no padding, a 5-pixel border is dropped) and averaged over pixels and channels.
"""

from __future__ import annotations

import math

import torch
import torch.nn.functional as F
from torch import Tensor, nn

#: SSIM stabilisers K1, K2 of Wang et al. (2004).
SSIM_K1, SSIM_K2 = 0.01, 0.03


def check_image_pair(pred: Tensor, gt: Tensor, min_size: int = 1) -> tuple[Tensor, Tensor]:
    """Validate two image batches and return them as (B, C, H, W) floating tensors.

    Args:
        pred: (B, C, H, W) or (C, H, W).
        gt: same shape as ``pred``.
        min_size: the smallest allowed height and width.

    Raises:
        TypeError: an input is not a tensor.
        ValueError: ranks or shapes differ, an input is empty or smaller than ``min_size``, or holds NaN/inf.
    """
    for name, t in (("pred", pred), ("gt", gt)):
        if not isinstance(t, Tensor):
            raise TypeError(f"{name} must be a torch.Tensor, got {type(t).__name__}")
        if t.ndim not in (3, 4):
            raise ValueError(f"{name} must have shape (B, C, H, W) or (C, H, W), got {tuple(t.shape)}")
    if pred.shape != gt.shape:
        raise ValueError(f"pred and gt shapes differ: {tuple(pred.shape)} vs {tuple(gt.shape)}")
    if pred.ndim == 3:
        pred, gt = pred[None], gt[None]
    if pred.numel() == 0:
        raise ValueError(f"empty images: shape {tuple(pred.shape)}")
    h, w = pred.shape[-2:]
    if h < min_size or w < min_size:
        raise ValueError(f"images of {h}x{w} pixels are smaller than the {min_size}x{min_size} window")
    if not pred.is_floating_point():
        pred = pred.float()
    if not gt.is_floating_point():
        gt = gt.float()
    gt = gt.to(pred.dtype)
    for name, t in (("pred", pred), ("gt", gt)):
        if not torch.isfinite(t).all():
            raise ValueError(f"{name} contains NaN or infinite values")
    return pred, gt


def psnr(pred: Tensor, gt: Tensor, data_range: float = 1.0) -> Tensor:
    """Peak signal-to-noise ratio per image, 10·log10(data_range² / MSE), in dB.

    Args:
        pred: (B, C, H, W) or (C, H, W), values in [0, data_range].
        gt: same shape as ``pred``.
        data_range: the value range of the images (1.0 for [0, 1]).

    Returns:
        (B,) PSNR per image; +inf where the images are identical.
    """
    if data_range <= 0:
        raise ValueError(f"data_range must be positive, got {data_range}")
    pred, gt = check_image_pair(pred, gt)
    mse = (pred - gt).pow(2).flatten(1).mean(dim=1, dtype=torch.float64)  # accumulate in float64
    out = 10.0 * torch.log10(data_range**2 / mse)  # mse == 0 gives +inf
    return out.to(pred.dtype)


def psnr_from_mse(mse: float, data_range: float = 1.0) -> float:
    """10·log10(data_range² / mse) in dB for a mean squared error already computed (pooled over pixels or views);
    +inf for mse 0."""
    return math.inf if mse <= 0 else 10.0 * math.log10(data_range**2 / mse)


def gaussian_kernel1d(window_size: int = 11, sigma: float = 1.5, dtype: torch.dtype = torch.float32) -> Tensor:
    """Normalised 1-D Gaussian window, shape (window_size,)."""
    if window_size < 1 or window_size % 2 == 0:
        raise ValueError(f"window_size must be a positive odd integer, got {window_size}")
    if not sigma > 0:
        raise ValueError(f"sigma must be positive, got {sigma}")
    x = torch.arange(window_size, dtype=torch.float64) - (window_size - 1) / 2
    g = torch.exp(-(x**2) / (2 * sigma**2))
    return (g / g.sum()).to(dtype)


def _filter_valid(x: Tensor, kernel: Tensor) -> Tensor:
    """Separable 2-D filtering of every channel of (B, C, H, W) with ``kernel`` (K,), no padding → (B, C, H-K+1, W-K+1)."""
    c = x.shape[1]
    k = kernel.to(device=x.device, dtype=x.dtype)
    x = F.conv2d(x, k.view(1, 1, 1, -1).expand(c, 1, 1, -1), groups=c)
    return F.conv2d(x, k.view(1, 1, -1, 1).expand(c, 1, -1, 1), groups=c)


def ssim_map(
    pred: Tensor, gt: Tensor, data_range: float = 1.0, window_size: int = 11, sigma: float = 1.5
) -> Tensor:
    """Per-pixel, per-channel SSIM on the valid region.

    Args:
        pred: (B, C, H, W) or (C, H, W), values in [0, data_range].
        gt: same shape as ``pred``.
        data_range: value range of the images.
        window_size: odd side of the Gaussian window.
        sigma: standard deviation of the Gaussian window, in pixels.

    Returns:
        (B, C, H - window_size + 1, W - window_size + 1) SSIM map.
    """
    if data_range <= 0:
        raise ValueError(f"data_range must be positive, got {data_range}")
    kernel = gaussian_kernel1d(window_size, sigma, dtype=torch.float64)
    pred, gt = check_image_pair(pred, gt, min_size=window_size)
    c1 = (SSIM_K1 * data_range) ** 2
    c2 = (SSIM_K2 * data_range) ** 2
    c = pred.shape[1]
    stats = _filter_valid(torch.cat([pred, gt, pred * pred, gt * gt, pred * gt], dim=1), kernel)
    mu_x, mu_y, e_xx, e_yy, e_xy = stats.split(c, dim=1)
    var_x = e_xx - mu_x * mu_x
    var_y = e_yy - mu_y * mu_y
    cov = e_xy - mu_x * mu_y
    num = (2 * mu_x * mu_y + c1) * (2 * cov + c2)
    den = (mu_x * mu_x + mu_y * mu_y + c1) * (var_x + var_y + c2)
    return num / den


def ssim(pred: Tensor, gt: Tensor, data_range: float = 1.0, window_size: int = 11, sigma: float = 1.5) -> Tensor:
    """Structural similarity per image: the mean of :func:`ssim_map` over channels and valid pixels.

    Args:
        pred: (B, C, H, W) or (C, H, W), values in [0, data_range]; H and W at least ``window_size``.
        gt: same shape as ``pred``.
        data_range: value range of the images.
        window_size: odd side of the Gaussian window (11 in the standard definition).
        sigma: standard deviation of the window (1.5 in the standard definition).

    Returns:
        (B,) SSIM per image, 1 for identical images.
    """
    return ssim_map(pred, gt, data_range, window_size, sigma).flatten(1).mean(dim=1)


class PSNR(nn.Module):
    """Module form of :func:`psnr`: forward(pred (B,C,H,W), gt (B,C,H,W)) → (B,)."""

    def __init__(self, data_range: float = 1.0) -> None:
        super().__init__()
        self.data_range = float(data_range)

    def forward(self, pred: Tensor, gt: Tensor) -> Tensor:
        return psnr(pred, gt, self.data_range)


class SSIM(nn.Module):
    """Module form of :func:`ssim`: forward(pred (B,C,H,W), gt (B,C,H,W)) → (B,)."""

    def __init__(self, data_range: float = 1.0, window_size: int = 11, sigma: float = 1.5) -> None:
        super().__init__()
        gaussian_kernel1d(window_size, sigma)  # validate early
        self.data_range, self.window_size, self.sigma = float(data_range), int(window_size), float(sigma)

    def forward(self, pred: Tensor, gt: Tensor) -> Tensor:
        return ssim(pred, gt, self.data_range, self.window_size, self.sigma)


def masked_psnr(pred: Tensor, gt: Tensor, mask: Tensor, data_range: float = 1.0) -> float:
    """PSNR over the pixels where ``mask`` is true.

    Args:
        pred: (C, H, W); gt: (C, H, W); mask: (H, W) bool.

    Raises:
        ValueError: the mask is empty or its shape does not match.
    """
    pred, gt = check_image_pair(pred, gt)
    if mask.shape != pred.shape[-2:]:
        raise ValueError(f"mask shape {tuple(mask.shape)} does not match image size {tuple(pred.shape[-2:])}")
    n = int(mask.sum())
    if n == 0:
        raise ValueError("no valid pixels to score")
    diff = (pred[0].double() - gt[0].double())[:, mask]
    return psnr_from_mse(float(diff.pow(2).mean()), data_range)


def masked_ssim(pred: Tensor, gt: Tensor, mask: Tensor, window_size: int = 11, sigma: float = 1.5) -> float:
    """Mean SSIM over the pixels whose whole window lies in ``mask``.

    Args:
        pred: (C, H, W); gt: (C, H, W); mask: (H, W) bool.

    Raises:
        ValueError: no window fits entirely inside the mask, or the mask shape does not match.
    """
    if mask.shape != pred.shape[-2:]:
        raise ValueError(f"mask shape {tuple(mask.shape)} does not match image size {tuple(pred.shape[-2:])}")
    smap = ssim_map(pred, gt, window_size=window_size, sigma=sigma)[0]  # (C, H', W')
    box = torch.ones(window_size, dtype=torch.float64, device=mask.device)
    m = mask.to(torch.float64)[None, None]
    inside = F.conv2d(F.conv2d(m, box.view(1, 1, 1, -1)), box.view(1, 1, -1, 1))[0, 0] >= window_size**2 - 0.5
    n = int(inside.sum())
    if n == 0:
        raise ValueError(f"no {window_size}x{window_size} window lies entirely inside the valid pixels")
    return float(smap[:, inside].double().mean())
