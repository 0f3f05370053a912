"""Reading and writing sRGB image files (PNG/JPEG, 8 or 16 bit) as float arrays in [0, 1].

Pillow reads 16-bit *colour* PNGs only at 8-bit precision, so those (colour types 2, 4 and 6 at bit depth 16) are
decoded here with zlib and numpy (exact, but slow for Average/Paeth-filtered rows: about 3 s for a 640x480 image);
everything else goes through Pillow.

Alpha: by default an alpha channel is dropped (the colour is kept as stored). ``alpha="over_black"`` composites it
over black instead (straight alpha: ``rgb * a``), so transparent pixels become black and opaque ones are unchanged; the
evaluation reads every image this way, because renderers with a transparent film write exactly this convention.

:data:`IMAGE_SUFFIXES` lists the file suffixes the project treats as images when it lists a folder.
"""

from __future__ import annotations

import os
import struct
import zlib
from pathlib import Path

import numpy as np

from spotlessgs.io.atomic import atomic_path
from spotlessgs.io.colorspace import to_uint8

_PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"
# PNG colour type -> samples per pixel (for the types decoded here).
_PNG_CHANNELS = {0: 1, 2: 3, 4: 2, 6: 4}
# How read_image treats an alpha channel (see the module docstring).
_ALPHA_MODES = ("drop", "over_black")

#: File suffixes (lower case) of the image files the project reads from folders.
IMAGE_SUFFIXES: tuple[str, ...] = (".png", ".jpg", ".jpeg", ".tif", ".tiff", ".bmp", ".webp")


def is_image_name(name: str | os.PathLike) -> bool:
    """True when ``name`` ends with one of :data:`IMAGE_SUFFIXES` (case-insensitive)."""
    return Path(name).suffix.lower() in IMAGE_SUFFIXES


def list_image_files(folder: str | os.PathLike, non_images: str = "skip") -> list[Path]:
    """The image files (:data:`IMAGE_SUFFIXES`) directly inside ``folder``, sorted by name.

    Hidden files (names starting with ".") and sub-folders are always passed over.

    Args:
        folder: the folder to list (not recursive).
        non_images: ``"skip"`` passes over other files; ``"error"`` refuses a folder that holds any (they are named).

    Raises:
        FileNotFoundError: ``folder`` does not exist or is not a folder.
        ValueError: no image file in the folder, or (``non_images="error"``) other files in it.
    """
    if non_images not in ("skip", "error"):
        raise ValueError(f"list_image_files: non_images must be 'skip' or 'error', got {non_images!r}")
    folder = Path(folder)
    if not folder.is_dir():
        raise FileNotFoundError(f"{folder}: image folder not found")
    images, others = [], []
    for entry in sorted(folder.iterdir()):
        if entry.name.startswith(".") or entry.is_dir():
            continue
        (images if is_image_name(entry.name) else others).append(entry)
    if others and non_images == "error":
        shown = ", ".join(p.name for p in others[:5]) + (f" (and {len(others) - 5} more)" if len(others) > 5 else "")
        raise ValueError(f"{folder}: non-image files found: {shown}; expected only {', '.join(IMAGE_SUFFIXES)}")
    if not images:
        raise ValueError(f"{folder}: no image files ({', '.join(IMAGE_SUFFIXES)}) in this folder")
    return images


def read_image(path: str | os.PathLike, alpha: str = "drop") -> np.ndarray:
    """Read an image file as float32 (H, W, 3) sRGB values in [0, 1].

    8-bit data is divided by 255, 16-bit data by 65535 (16-bit colour PNGs are decoded exactly). Grey is repeated to
    three channels; palette images are expanded.

    Args:
        path: an image file (8- or 16-bit; grey, RGB, with or without alpha, or palette).
        alpha: ``"drop"`` (default) ignores an alpha channel; ``"over_black"`` composites the colour over black.

    Raises:
        FileNotFoundError: the file is missing.
        ValueError: the file cannot be decoded or has an unsupported pixel format (e.g. float); the file is named.
    """
    if alpha not in _ALPHA_MODES:
        raise ValueError(f"read_image: alpha must be one of {_ALPHA_MODES}, got {alpha!r}")
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"{path}: image file not found")
    with open(path, "rb") as fh:
        head = fh.read(33)
    if head.startswith(_PNG_SIGNATURE) and len(head) >= 33 and head[12:16] == b"IHDR":
        bit_depth, colour_type = head[24], head[25]
        if bit_depth == 16 and colour_type in (2, 4, 6):
            return _to_rgb(_decode_png16(path), path, alpha)
    return _to_rgb(_read_with_pillow(path), path, alpha)


def _read_with_pillow(path: Path) -> np.ndarray:
    """Decode with Pillow into float32 (H, W) or (H, W, C) in [0, 1], C = 1..4 (alpha last when present)."""
    from PIL import Image, UnidentifiedImageError

    try:
        with Image.open(path) as im:
            im.load()
            mode = im.mode
            if mode in ("I;16", "I;16B", "I;16L", "I;16N"):
                data = np.asarray(im, dtype=np.uint16).astype(np.float32) / 65535.0
            elif mode == "I":
                # Pillow opens some 16-bit grey PNGs as 32-bit integer images holding 16-bit values.
                values = np.asarray(im, dtype=np.int64)
                if values.size and (values.min() < 0 or values.max() > 65535):
                    raise ValueError(f"{path}: 32-bit integer image with values outside [0, 65535] is not supported")
                data = values.astype(np.float32) / 65535.0
            elif mode in ("L", "LA", "RGB", "RGBA"):
                data = np.asarray(im, dtype=np.uint8).astype(np.float32) / 255.0
            elif mode in ("P", "PA", "1", "CMYK", "YCbCr", "LAB", "HSV"):
                data = np.asarray(im.convert("RGBA" if "A" in mode or "transparency" in im.info else "RGB"))
                data = data.astype(np.float32) / 255.0
            else:
                raise ValueError(f"{path}: unsupported image mode {mode!r}")
    except (UnidentifiedImageError, OSError, SyntaxError) as exc:
        raise ValueError(f"{path}: cannot decode image ({exc})") from exc
    return data


def _to_rgb(data: np.ndarray, path: Path, alpha: str) -> np.ndarray:
    """(H, W), (H, W, 1|2|3|4) float -> (H, W, 3) float32 (grey repeated; alpha dropped or composited over black)."""
    if data.ndim == 2:
        data = data[:, :, None]
    channels = data.shape[2]
    if channels not in (1, 2, 3, 4):
        raise ValueError(f"{path}: unsupported number of channels {channels}")
    colour = data[:, :, :1] if channels in (1, 2) else data[:, :, :3]
    if channels in (2, 4) and alpha == "over_black":
        colour = colour * data[:, :, -1:]
    if colour.shape[2] == 1:
        colour = np.repeat(colour, 3, axis=2)
    data = colour
    if data.shape[0] == 0 or data.shape[1] == 0:
        raise ValueError(f"{path}: empty image")
    return np.ascontiguousarray(data, dtype=np.float32)


def _decode_png16(path: Path) -> np.ndarray:
    """Decode a non-interlaced 16-bit PNG into float32 (H, W, C) in [0, 1] (C = samples per pixel)."""
    blob = path.read_bytes()
    pos = len(_PNG_SIGNATURE)
    header = None
    idat = []
    while pos + 8 <= len(blob):
        (length,) = struct.unpack(">I", blob[pos : pos + 4])
        kind = blob[pos + 4 : pos + 8]
        body = blob[pos + 8 : pos + 8 + length]
        if len(body) != length:
            raise ValueError(f"{path}: truncated PNG chunk {kind!r}")
        if kind == b"IHDR":
            header = struct.unpack(">IIBBBBB", body)
        elif kind == b"IDAT":
            idat.append(body)
        elif kind == b"IEND":
            break
        pos += 12 + length
    if header is None or not idat:
        raise ValueError(f"{path}: PNG without IHDR or IDAT chunk")
    width, height, bit_depth, colour_type, _, _, interlace = header
    if interlace != 0:
        raise ValueError(f"{path}: interlaced 16-bit PNG files are not supported")
    channels = _PNG_CHANNELS[colour_type]
    bpp = 2 * channels
    stride = width * bpp
    try:
        raw = np.frombuffer(zlib.decompress(b"".join(idat)), dtype=np.uint8)
    except zlib.error as exc:
        raise ValueError(f"{path}: corrupt PNG image data ({exc})") from exc
    if raw.size != height * (stride + 1):
        raise ValueError(f"{path}: PNG image data has {raw.size} bytes, expected {height * (stride + 1)}")
    rows = raw.reshape(height, stride + 1)
    out = np.zeros((height, stride), dtype=np.uint8)
    prev = np.zeros(stride, dtype=np.uint8)
    for y in range(height):
        kind, line = rows[y, 0], rows[y, 1:]
        out[y] = _unfilter_row(kind, line, prev, bpp, path, y)
        prev = out[y]
    values = out.view(">u2").reshape(height, width, channels)
    return values.astype(np.float32) / 65535.0


def _unfilter_row(kind: int, line: np.ndarray, prev: np.ndarray, bpp: int, path: Path, y: int) -> np.ndarray:
    """Undo one PNG scanline filter (types 0-4) and return the reconstructed (stride,) uint8 row."""
    if kind == 0:
        return line
    if kind == 1:  # Sub: cumulative sum along pixels, modulo 256
        return np.cumsum(line.reshape(-1, bpp), axis=0, dtype=np.uint8).reshape(-1)
    if kind == 2:  # Up
        return line + prev
    if kind not in (3, 4):
        raise ValueError(f"{path}: unknown PNG filter type {kind} in row {y}")
    cur = line.astype(np.int32).reshape(-1, bpp)
    up = prev.astype(np.int32).reshape(-1, bpp)
    left = np.zeros(bpp, dtype=np.int32)
    up_left = np.zeros(bpp, dtype=np.int32)
    for x in range(cur.shape[0]):
        if kind == 3:  # Average
            cur[x] = (cur[x] + ((left + up[x]) >> 1)) & 0xFF
        else:  # Paeth
            p = left + up[x] - up_left
            pa, pb, pc = np.abs(p - left), np.abs(p - up[x]), np.abs(p - up_left)
            pred = np.where((pa <= pb) & (pa <= pc), left, np.where(pb <= pc, up[x], up_left))
            cur[x] = (cur[x] + pred) & 0xFF
        left = cur[x]
        up_left = up[x]
    return cur.reshape(-1).astype(np.uint8)


def write_png(path: str | os.PathLike, img: np.ndarray) -> None:
    """Write an 8-bit RGB PNG atomically.

    Args:
        path: output file (parent folders are created).
        img: (H, W, 3) uint8, or float in [0, 1] (clipped, rounded to 8 bits without dithering; already sRGB-encoded).
    """
    from PIL import Image

    arr = np.asarray(img)
    if arr.ndim != 3 or arr.shape[2] != 3 or arr.shape[0] == 0 or arr.shape[1] == 0:
        raise ValueError(f"{path}: write_png expects an (H, W, 3) image, got shape {arr.shape}")
    if arr.dtype != np.uint8:
        if not np.issubdtype(arr.dtype, np.floating):
            raise ValueError(f"{path}: write_png expects uint8 or float data, got {arr.dtype}")
        if not np.isfinite(arr).all():
            raise ValueError(f"{path}: write_png image contains NaN or inf")
        arr = to_uint8(arr)
    with atomic_path(path, suffix=".png") as tmp:
        Image.fromarray(np.ascontiguousarray(arr), mode="RGB").save(tmp, format="PNG")
