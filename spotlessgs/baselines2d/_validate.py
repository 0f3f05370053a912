"""Input checks shared by the 2D baselines: every method takes and returns float (H, W, 3) sRGB images in [0, 1]."""

from __future__ import annotations

import numpy as np


def check_rgb_image(img: np.ndarray, what: str = "image") -> np.ndarray:
    """Return ``img`` as float64 (H, W, 3) after checking shape and finiteness (values are clipped to [0, 1]).

    Args:
        img: (H, W, 3) array of sRGB values; H, W >= 1.
        what: a name for the array in error messages (e.g. the file it came from).
    Raises:
        ValueError: wrong shape, empty, non-float (e.g. uint8) or non-finite values.
    """
    arr = np.asarray(img)
    if arr.ndim != 3 or arr.shape[2] != 3 or arr.shape[0] == 0 or arr.shape[1] == 0:
        raise ValueError(f"{what}: expected an (H, W, 3) image, got shape {arr.shape}")
    if not np.issubdtype(arr.dtype, np.floating):
        hint = " (divide 8-bit data by 255)" if arr.dtype == np.uint8 else ""
        raise ValueError(f"{what}: expected float values in [0, 1], got dtype {arr.dtype}{hint}")
    arr = arr.astype(np.float64)
    if not np.isfinite(arr).all():
        raise ValueError(f"{what}: image contains NaN or inf ({int((~np.isfinite(arr)).sum())} values)")
    return np.clip(arr, 0.0, 1.0)
