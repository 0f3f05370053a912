"""Reading images for evaluation: any common 8/16-bit file to float sRGB in [0, 1], shape (H, W, 3).

Rules (the same for every metric, so that two methods are always read alike):
- 8-bit files are divided by 255, 16-bit greyscale files by 65535. Pillow reads 16-bit RGB(A) PNGs at 8-bit precision
  (their high byte); the error is below 1/255 and far below any metric difference that matters.
- Greyscale is replicated to three channels; palette images are expanded.
- An alpha channel is composited over black (straight alpha): transparent pixels become black, opaque pixels are kept.
  Renderers with a transparent film write exactly this convention; a fully opaque alpha changes nothing.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

#: File suffixes (lower case) that are treated as images.
IMAGE_SUFFIXES: tuple[str, ...] = (".png", ".jpg", ".jpeg", ".tif", ".tiff", ".bmp", ".webp")


def is_image_name(name: str) -> bool:
    """True when ``name`` has one of :data:`IMAGE_SUFFIXES` (case-insensitive)."""
    return Path(name).suffix.lower() in IMAGE_SUFFIXES


def load_image(path: str | os.PathLike) -> np.ndarray:
    """Read an image file as float32 sRGB in [0, 1].

    Args:
        path: an image file (8- or 16-bit; greyscale, RGB, with or without alpha, or palette).

    Returns:
        float32 array, shape (H, W, 3), values in [0, 1].

    Raises:
        FileNotFoundError: the file does not exist.
        ValueError: the file is not a decodable image, or its pixel format is unsupported (e.g. float or CMYK).
    """
    from PIL import Image, UnidentifiedImageError

    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"{path}: no such image file")
    try:
        with Image.open(path) as im:
            im.load()
            return _pil_to_float_rgb(im, path)
    except UnidentifiedImageError as exc:
        raise ValueError(f"{path}: not an image file that Pillow can decode") from exc
    except OSError as exc:  # truncated or corrupt data
        raise ValueError(f"{path}: cannot decode image ({exc})") from exc


def _pil_to_float_rgb(im, path: Path) -> np.ndarray:
    """Convert an opened PIL image to float32 (H, W, 3) in [0, 1] following the module's rules."""
    mode = im.mode
    if mode in ("I;16", "I;16B", "I;16L", "I;16N"):
        grey = np.asarray(im, dtype=np.float32) / 65535.0
        return np.repeat(grey[..., None], 3, axis=2)
    if mode == "I":  # 32-bit integer; PNG stores 16-bit greyscale this way in some Pillow versions
        grey = np.asarray(im, dtype=np.float64)
        if grey.size and (grey.min() < 0 or grey.max() > 65535):
            raise ValueError(f"{path}: 32-bit integer image with values outside [0, 65535] is not supported")
        return np.repeat((grey / 65535.0).astype(np.float32)[..., None], 3, axis=2)
    if mode in ("F", "CMYK", "YCbCr", "LAB", "HSV"):
        raise ValueError(f"{path}: pixel format {mode!r} is not supported (expected 8/16-bit greyscale or RGB)")
    if mode == "P":
        im = im.convert("RGBA")
        mode = "RGBA"
    if mode == "1":
        im = im.convert("L")
        mode = "L"
    if mode == "LA":
        im = im.convert("RGBA")
        mode = "RGBA"
    if mode == "L":
        grey = np.asarray(im, dtype=np.float32) / 255.0
        return np.repeat(grey[..., None], 3, axis=2)
    if mode == "RGBA":
        rgba = np.asarray(im, dtype=np.float32) / 255.0
        return np.ascontiguousarray(rgba[..., :3] * rgba[..., 3:4])
    if mode != "RGB":
        im = im.convert("RGB")
    return np.asarray(im, dtype=np.float32) / 255.0
