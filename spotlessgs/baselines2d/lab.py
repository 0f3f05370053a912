"""sRGB <-> CIE L*a*b* (D65 white) for float images, so that CLAHE can change lightness and keep chroma.

Same definitions as scikit-image's ``rgb2lab``/``lab2rgb`` with the D65 2-degree illuminant (tested against it).
"""

from __future__ import annotations

import numpy as np

from spotlessgs.io.colorspace import linear_to_srgb, srgb_to_linear

# Linear sRGB -> CIE XYZ (D65), IEC 61966-2-1.
_RGB_TO_XYZ = np.array(
    [
        [0.412453, 0.357580, 0.180423],
        [0.212671, 0.715160, 0.072169],
        [0.019334, 0.119193, 0.950227],
    ]
)
_XYZ_TO_RGB = np.linalg.inv(_RGB_TO_XYZ)
# Reference white: XYZ of linear RGB (1, 1, 1), so that sRGB white maps to L* = 100, a* = b* = 0 exactly.
_WHITE = _RGB_TO_XYZ.sum(axis=1)
_EPSILON = (6.0 / 29.0) ** 3  # CIE: below this the cube root is replaced by a line
_KAPPA_SLOPE = (29.0 / 6.0) ** 2 / 3.0  # slope of that line
_OFFSET = 4.0 / 29.0


def srgb_to_lab(img: np.ndarray) -> np.ndarray:
    """(..., 3) sRGB values in [0, 1] -> (..., 3) L* in [0, 100], a*, b* (float64)."""
    xyz = srgb_to_linear(np.asarray(img, dtype=np.float64)) @ _RGB_TO_XYZ.T / _WHITE
    f = np.where(xyz > _EPSILON, np.cbrt(xyz), _KAPPA_SLOPE * xyz + _OFFSET)
    lightness = 116.0 * f[..., 1] - 16.0
    a = 500.0 * (f[..., 0] - f[..., 1])
    b = 200.0 * (f[..., 1] - f[..., 2])
    return np.stack([lightness, a, b], axis=-1)


def lab_to_srgb(lab: np.ndarray) -> np.ndarray:
    """(..., 3) L*, a*, b* -> (..., 3) sRGB values, clipped to [0, 1] (out-of-gamut colours are clipped per channel)."""
    lab = np.asarray(lab, dtype=np.float64)
    fy = (lab[..., 0] + 16.0) / 116.0
    fx = fy + lab[..., 1] / 500.0
    fz = fy - lab[..., 2] / 200.0
    f = np.stack([fx, fy, fz], axis=-1)
    xyz = np.where(f > 6.0 / 29.0, f**3, (f - _OFFSET) / _KAPPA_SLOPE) * _WHITE
    return linear_to_srgb(np.clip(xyz @ _XYZ_TO_RGB.T, 0.0, 1.0))
