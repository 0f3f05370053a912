"""sRGB transfer functions (IEC 61966-2-1) and 8-bit quantisation, for numpy arrays of any shape.

Image files are sRGB-encoded; every model in the project works in linear RGB.
"""

from __future__ import annotations

import numpy as np

# IEC 61966-2-1 constants.
_ENCODE_THRESHOLD = 0.0031308  # linear value where the linear segment ends
_DECODE_THRESHOLD = 0.04045  # encoded value where the linear segment ends (= 12.92 * 0.0031308, rounded)
_SLOPE = 12.92
_A = 0.055
_GAMMA = 2.4


def _as_float(x: np.ndarray) -> np.ndarray:
    x = np.asarray(x)
    if not np.issubdtype(x.dtype, np.floating):
        x = x.astype(np.float64)
    return x


def srgb_to_linear(x: np.ndarray) -> np.ndarray:
    """sRGB-encoded values in [0, 1] -> linear values; inputs are clipped to [0, 1] first. Keeps float dtypes.

    Formula: ``x / 12.92`` for ``x <= 0.04045``, else ``((x + 0.055) / 1.055) ** 2.4``.
    """
    x = np.clip(_as_float(x), 0.0, 1.0)
    return np.where(x <= _DECODE_THRESHOLD, x / _SLOPE, ((x + _A) / (1.0 + _A)) ** _GAMMA).astype(x.dtype, copy=False)


def linear_to_srgb(x: np.ndarray) -> np.ndarray:
    """Linear values -> sRGB-encoded values in [0, 1]; inputs are clipped to [0, 1] first. Keeps float dtypes.

    Formula: ``12.92 x`` for ``x <= 0.0031308``, else ``1.055 x ** (1 / 2.4) - 0.055`` (evaluated as
    ``1 + 1.055 (x ** (1 / 2.4) - 1)`` so that 1 maps to exactly 1).
    """
    x = np.clip(_as_float(x), 0.0, 1.0)
    curve = 1.0 + (1.0 + _A) * (x ** (1.0 / _GAMMA) - 1.0)
    return np.where(x <= _ENCODE_THRESHOLD, x * _SLOPE, curve).astype(x.dtype, copy=False)


def to_uint8(x: np.ndarray) -> np.ndarray:
    """Values in [0, 1] (any shape) -> uint8 by clipping and rounding half to even of ``255 x`` (no dithering)."""
    x = np.asarray(x, dtype=np.float64)
    if np.isnan(x).any():
        raise ValueError("to_uint8: input contains NaN")
    return np.rint(np.clip(x, 0.0, 1.0) * 255.0).astype(np.uint8)
