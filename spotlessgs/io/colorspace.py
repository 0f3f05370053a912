"""sRGB transfer functions (IEC 61966-2-1) and 8-bit quantisation, for numpy arrays and torch tensors of any shape.

Image files are sRGB-encoded; every model in the project works in linear RGB. This module is the project's only
implementation of the sRGB formula: :func:`srgb_to_linear` and :func:`linear_to_srgb` take numpy arrays (or anything
``np.asarray`` accepts) and torch tensors alike and return the same kind. On tensors they are differentiable, with
finite gradients everywhere in [0, 1] (the power branch never sees an argument at or below its threshold).
"""

from __future__ import annotations

from typing import Any

import numpy as np

# IEC 61966-2-1 constants.
_ENCODE_THRESHOLD = 0.0031308  # linear value where the linear segment ends
_DECODE_THRESHOLD = 0.04045  # encoded value where the linear segment ends (= 12.92 * 0.0031308, rounded)
_SLOPE = 12.92
_A = 0.055
_GAMMA = 2.4


def _is_tensor(x: Any) -> bool:
    """True for a torch tensor (checked by type, so that numpy-only callers never import torch)."""
    return type(x).__module__.startswith("torch") and hasattr(x, "is_floating_point")


def _prepare(x: Any):
    """``x`` as a floating array/tensor clipped to [0, 1], plus the backend's ``where`` and ``clip``.

    Float dtypes are kept; integer and boolean inputs become float64.
    """
    if _is_tensor(x):
        import torch

        if not x.is_floating_point():
            x = x.double()
        return x.clamp(0.0, 1.0), torch.where, lambda v, lo, hi: v.clamp(lo, hi)
    x = np.asarray(x)
    if not np.issubdtype(x.dtype, np.floating):
        x = x.astype(np.float64)
    return np.clip(x, 0.0, 1.0), np.where, np.clip


def srgb_to_linear(x):
    """sRGB-encoded values in [0, 1] -> linear values; inputs are clipped to [0, 1] first. Keeps float dtypes.

    Args:
        x: numpy array (any shape, or a scalar/list) or torch tensor (any shape, any device).

    Returns:
        the same shape and kind (numpy array or torch tensor): ``x / 12.92`` for ``x <= 0.04045``, else
        ``((x + 0.055) / 1.055) ** 2.4``.
    """
    x, where, clip = _prepare(x)
    curve = ((clip(x, _DECODE_THRESHOLD, 1.0) + _A) / (1.0 + _A)) ** _GAMMA
    out = where(x <= _DECODE_THRESHOLD, x / _SLOPE, curve)
    return out if _is_tensor(out) else out.astype(x.dtype, copy=False)


def linear_to_srgb(x):
    """Linear values -> sRGB-encoded values in [0, 1]; inputs are clipped to [0, 1] first. Keeps float dtypes.

    Args:
        x: numpy array (any shape, or a scalar/list) or torch tensor (any shape, any device).

    Returns:
        the same shape and kind: ``12.92 x`` for ``x <= 0.0031308``, else ``1.055 x ** (1 / 2.4) - 0.055`` (evaluated
        as ``1 + 1.055 (x ** (1 / 2.4) - 1)`` so that 1 maps to exactly 1).
    """
    x, where, clip = _prepare(x)
    curve = 1.0 + (1.0 + _A) * (clip(x, _ENCODE_THRESHOLD, 1.0) ** (1.0 / _GAMMA) - 1.0)
    out = where(x <= _ENCODE_THRESHOLD, x * _SLOPE, curve)
    return out if _is_tensor(out) else out.astype(x.dtype, copy=False)


def to_uint8(x: np.ndarray) -> np.ndarray:
    """Values in [0, 1] (any shape) -> uint8 by clipping and rounding half to even of ``255 x`` (no dithering)."""
    x = np.asarray(x, dtype=np.float64)
    if np.isnan(x).any():
        raise ValueError("to_uint8: input contains NaN")
    return np.rint(np.clip(x, 0.0, 1.0) * 255.0).astype(np.uint8)
