"""MSRCR: multi-scale Retinex with colour restoration (Jobson, Rahman & Woodell 1997), then a simplest colour balance.

For each channel c and scale sigma_k (k = 1..K, equal weights):

    R_c     = (1 / K) sum_k [ log(I_c + eps) - log(G_sigma_k * (I_c + eps)) ]   (multi-scale Retinex)
    C_c     = beta * [ log(alpha (I_c + eps)) - log(sum_c' (I_c' + eps)) ]       (colour restoration)
    MSRCR_c = C_c * R_c

then each channel is clipped at its ``low_percent`` / ``high_percent`` percentiles and stretched to [0, 1] (the
"simplest colour balance" of Limare et al. 2011), which also replaces the gain/offset of the original paper. The
Retinex runs on sRGB-encoded values, as in the literature on 8-bit images.

The Gaussian surround ``G_sigma * I`` is computed, for sigma > 8 px, with three successive box filters (Wells 1986;
widths from Kovesi 2010), whose cost does not depend on sigma; boundaries are mirrored. Sigmas scale with the image: they are given as
fractions of the longer image side (defaults 15, 80 and 250 pixels at a 512-pixel side).

A channel whose percentile range is empty (a flat channel: black or saturated frames) has no contrast to stretch and is
passed through unchanged.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.ndimage import gaussian_filter, uniform_filter1d

from spotlessgs.baselines2d._validate import check_rgb_image

_REFERENCE_SIDE = 512.0  # image side at which the classic sigmas 15, 80, 250 px apply
_EXACT_SIGMA_MAX = 8.0  # up to this sigma a sampled Gaussian kernel is cheap; above, box filters are used


@dataclass(frozen=True)
class MsrcrConfig:
    # Surround scales as fractions of the longer image side (classic 15, 80, 250 px at a 512-px side).
    sigma_fractions: tuple[float, ...] = (15.0 / _REFERENCE_SIDE, 80.0 / _REFERENCE_SIDE, 250.0 / _REFERENCE_SIDE)
    # Colour-restoration gain inside the log (Jobson et al.: 125).
    alpha: float = 125.0
    # Colour-restoration multiplier (Jobson et al.: 46).
    beta: float = 46.0
    # Offset added to intensities in [0, 1] before taking logs (1/255: one 8-bit level, as "I + 1" in the paper).
    offset: float = 1.0 / 255.0
    # Percentile clipped to black in the simplest colour balance, per channel.
    low_percent: float = 1.0
    # Percentile clipped to white in the simplest colour balance, per channel.
    high_percent: float = 99.0

    def __post_init__(self) -> None:
        if len(self.sigma_fractions) == 0 or any(not (np.isfinite(s) and s > 0) for s in self.sigma_fractions):
            raise ValueError(f"MsrcrConfig.sigma_fractions must be positive numbers, got {self.sigma_fractions}")
        for name in ("alpha", "beta", "offset"):
            value = getattr(self, name)
            if not (np.isfinite(value) and value > 0):
                raise ValueError(f"MsrcrConfig.{name} must be a positive number, got {value}")
        if not 0.0 <= self.low_percent < self.high_percent <= 100.0:
            raise ValueError(
                f"MsrcrConfig needs 0 <= low_percent < high_percent <= 100, got {self.low_percent}, {self.high_percent}"
            )


def box_widths_for_gaussian(sigma: float, passes: int = 3) -> list[int]:
    """Odd box widths whose ``passes``-fold convolution has standard deviation close to ``sigma`` (Kovesi 2010)."""
    ideal = np.sqrt(12.0 * sigma**2 / passes + 1.0)
    lower = int(np.floor(ideal))
    if lower % 2 == 0:
        lower -= 1
    upper = lower + 2
    n_lower = round((12.0 * sigma**2 - passes * lower**2 - 4.0 * passes * lower - 3.0 * passes) / (-4.0 * lower - 4.0))
    n_lower = min(max(n_lower, 0), passes)
    return [lower] * n_lower + [upper] * (passes - n_lower)


def gaussian_blur(img: np.ndarray, sigma: float) -> np.ndarray:
    """Gaussian blur of the first two axes with mirrored ('reflect') borders.

    Exact (sampled kernel, scipy) for ``sigma <= 8``; above, three box filters (error < 0.3 % of the data range).

    Args:
        img: (H, W) or (H, W, C) float array.
        sigma: standard deviation in pixels (> 0).
    Returns:
        array of the same shape, float64.
    """
    out = np.asarray(img, dtype=np.float64)
    if sigma <= _EXACT_SIGMA_MAX:
        return gaussian_filter(out, sigma=(sigma, sigma) + (0,) * (out.ndim - 2), mode="reflect", truncate=4.0)
    for width in box_widths_for_gaussian(sigma):
        for axis in (0, 1):
            out = _box_filter(out, width, axis)
    return out


def _box_filter(arr: np.ndarray, width: int, axis: int) -> np.ndarray:
    """Mean over a centred window of odd ``width`` along ``axis``, mirrored borders, for any width vs size."""
    if width <= 1:
        return arr
    size = arr.shape[axis]
    half = width // 2
    if half < size:
        return uniform_filter1d(arr, width, axis=axis, mode="reflect")
    # Window wider than the image: mirror-extend explicitly (numpy repeats the reflection as often as needed).
    pad = [(0, 0)] * arr.ndim
    pad[axis] = (half, half)
    padded = np.pad(arr, pad, mode="symmetric")
    csum = np.cumsum(padded, axis=axis)
    zero_shape = list(csum.shape)
    zero_shape[axis] = 1
    csum = np.concatenate([np.zeros(zero_shape), csum], axis=axis)
    hi = np.take(csum, np.arange(width, width + size), axis=axis)
    lo = np.take(csum, np.arange(0, size), axis=axis)
    return (hi - lo) / width


def simplest_colour_balance(values: np.ndarray, low_percent: float, high_percent: float) -> np.ndarray | None:
    """Clip one channel at its percentiles and stretch linearly to [0, 1]; None when the range is empty.

    Args:
        values: (H, W) float array.
    """
    lo, hi = np.percentile(values, [low_percent, high_percent])
    span = hi - lo
    if not span > 1e-12 * max(1.0, abs(hi), abs(lo)):
        return None
    return np.clip((values - lo) / span, 0.0, 1.0)


def msrcr(img: np.ndarray, config: MsrcrConfig = MsrcrConfig()) -> np.ndarray:
    """Multi-scale Retinex with colour restoration and simplest colour balance.

    Args:
        img: (H, W, 3) sRGB values in [0, 1].
    Returns:
        (H, W, 3) float32 sRGB values in [0, 1].
    """
    rgb = check_rgb_image(img, "msrcr input")
    intensity = rgb + config.offset
    log_intensity = np.log(intensity)
    side = float(max(rgb.shape[0], rgb.shape[1]))
    retinex = np.zeros_like(rgb)
    for fraction in config.sigma_fractions:
        retinex += log_intensity - np.log(gaussian_blur(intensity, fraction * side))
    retinex /= len(config.sigma_fractions)
    restoration = config.beta * (np.log(config.alpha * intensity) - np.log(intensity.sum(axis=2, keepdims=True)))
    combined = restoration * retinex
    out = np.empty_like(rgb)
    for c in range(3):
        balanced = simplest_colour_balance(combined[..., c], config.low_percent, config.high_percent)
        out[..., c] = rgb[..., c] if balanced is None else balanced
    return out.astype(np.float32)
