"""Reading and writing sRGB image files (PNG/JPEG, 8 or 16 bit) as float arrays in [0, 1].

Pillow reads 16-bit *colour* PNGs only at 8-bit precision, so those (colour types 2, 4 and 6 at bit depth 16) are
decoded with OpenCV (exact; 6.7 ms for a 640x480 RGB image with Paeth/Average-filtered rows, where the numpy decoder
it replaced took 1.75 s); everything else goes through Pillow.

Alpha: by default an alpha channel is dropped (the colour is kept as stored). ``alpha="over_black"`` composites it
over black instead (straight alpha: ``rgb * a``), so transparent pixels become black and opaque ones are unchanged; the
evaluation reads every image this way, because renderers with a transparent film write exactly this convention.
:func:`read_image_with_alpha` returns the colour as stored and the alpha channel apart (training takes transparent
pixels as a mask: pixels left out of the fit).

:data:`IMAGE_SUFFIXES` lists the file suffixes the project treats as images when it lists a folder.
"""

from __future__ import annotations

import os
import re
from pathlib import Path

import cv2
import numpy as np

from spotlessgs.io.atomic import atomic_path
from spotlessgs.io.colorspace import to_uint8

_PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"
# How read_image treats an alpha channel (see the module docstring).
_ALPHA_MODES = ("drop", "over_black")

_DIGIT_RUNS = re.compile(r"(\d+)")

#: File suffixes (lower case) of the image files the project reads from folders.
IMAGE_SUFFIXES: tuple[str, ...] = (".png", ".jpg", ".jpeg", ".tif", ".tiff", ".bmp", ".webp")


def is_image_name(name: str | os.PathLike) -> bool:
    """True when ``name`` ends with one of :data:`IMAGE_SUFFIXES` (case-insensitive)."""
    return Path(name).suffix.lower() in IMAGE_SUFFIXES


def natural_order(name: str) -> tuple:
    """Sort key of a file name in natural order: runs of digits compare as numbers, so that ``frame_2.png`` comes
    before ``frame_10.png`` (video frames numbered without leading zeros); zero-padded names keep their text order."""
    return tuple((0, int(part), part) if part.isdigit() else (1, 0, part) for part in _DIGIT_RUNS.split(name) if part)


def list_image_files(folder: str | os.PathLike, non_images: str = "skip") -> list[Path]:
    """The image files (:data:`IMAGE_SUFFIXES`) directly inside ``folder``, in the :func:`natural_order` of their
    names.

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
    for entry in sorted(folder.iterdir(), key=lambda entry: natural_order(entry.name)):
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
    return _to_rgb(_decode(path), path, alpha)


def read_image_with_alpha(path: str | os.PathLike) -> tuple[np.ndarray, np.ndarray | None]:
    """Read an image file as :func:`read_image` does (alpha dropped: the colour as stored), and its alpha channel.

    Returns:
        (H, W, 3) float32 sRGB values in [0, 1], and (H, W) float32 alpha in [0, 1] (straight alpha, 1 = opaque), or
        None for a file without an alpha channel.

    Raises:
        As :func:`read_image`.
    """
    path = Path(path)
    data = _decode(path)
    alpha = np.ascontiguousarray(data[:, :, -1], dtype=np.float32) if data.ndim == 3 and data.shape[2] in (2, 4) \
        else None
    return _to_rgb(data, path, "drop"), alpha


def _decode(path: Path) -> np.ndarray:
    """The pixels of an image file as float32 (H, W) or (H, W, C) in [0, 1], C = 1..4 (alpha last when present)."""
    if not path.is_file():
        raise FileNotFoundError(f"{path}: image file not found")
    with open(path, "rb") as fh:
        head = fh.read(33)
    if head.startswith(_PNG_SIGNATURE) and len(head) >= 33 and head[12:16] == b"IHDR":
        bit_depth, colour_type = head[24], head[25]
        if bit_depth == 16 and colour_type in (2, 4, 6):
            _refuse_bomb(path, int.from_bytes(head[16:20], "big"), int.from_bytes(head[20:24], "big"))
            return _decode_png16(path)
    if head[:4] in (b"II*\x00", b"MM\x00*"):  # TIFF: Pillow reads 16-bit colour as 8-bit, OpenCV keeps the bits
        from PIL import Image

        try:
            with Image.open(path) as im:  # the header only
                width, height = im.size
        except Image.DecompressionBombError as exc:
            raise ValueError(f"{path}: cannot decode image ({exc})") from None
        except Exception:  # noqa: BLE001 - a TIFF Pillow cannot open: OpenCV or Pillow below names the problem
            width = height = 0
        _refuse_bomb(path, width, height)
        tiff16 = _decode_tiff16(path)
        if tiff16 is not None:
            return tiff16
    return _read_with_pillow(path)


def _refuse_bomb(path: Path, width: int, height: int) -> None:
    """ValueError naming ``path`` when its header's size exceeds Pillow's decompression-bomb limit (the files OpenCV
    decodes, 16-bit PNGs and TIFFs, bypass Pillow's own check)."""
    from PIL import Image

    limit = Image.MAX_IMAGE_PIXELS
    if limit is not None and width * height > limit:
        raise ValueError(f"{path}: cannot decode image ({width}x{height} = {width * height} pixels exceeds the limit "
                         f"of {limit} pixels: a decompression bomb?)")


def _decode_tiff16(path: Path) -> np.ndarray | None:
    """A 16-bit TIFF as float32 (H, W) or (H, W, C) in [0, 1] (C = 3 or 4, RGB(A) order), decoded by OpenCV; None for
    any other TIFF (8-bit ones decode alike with Pillow, which also reads what OpenCV cannot)."""
    import cv2

    data = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    if data is None or data.dtype != np.uint16 or data.ndim not in (2, 3) or (data.ndim == 3
                                                                             and data.shape[2] not in (1, 3, 4)):
        return None
    if data.ndim == 3 and data.shape[2] >= 3:
        data = cv2.cvtColor(data, cv2.COLOR_BGR2RGB if data.shape[2] == 3 else cv2.COLOR_BGRA2RGBA)
    return data.astype(np.float32) / 65535.0


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
    except (UnidentifiedImageError, OSError, SyntaxError, Image.DecompressionBombError) as exc:
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
    """Decode a 16-bit PNG with OpenCV into float32 (H, W, C) in [0, 1]: RGB or RGBA (alpha last); grey + alpha comes
    back from OpenCV as grey repeated in RGB plus alpha."""
    data = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    if data is None:
        raise ValueError(f"{path}: cannot decode image (a damaged or truncated PNG)")
    if data.dtype != np.uint16:
        raise ValueError(f"{path}: expected 16-bit samples, OpenCV decoded {data.dtype}")
    if data.ndim == 3 and data.shape[2] in (3, 4):  # OpenCV's channel order is BGR(A)
        data = data[:, :, [2, 1, 0, 3][: data.shape[2]]]
    return data.astype(np.float32) / 65535.0


def write_png(path: str | os.PathLike, img: np.ndarray, bits: int | None = 8) -> None:
    """Write an RGB PNG atomically.

    Args:
        path: output file (parent folders are created).
        img: (H, W, 3) uint8, or float in [0, 1] (clipped, rounded without dithering; already sRGB-encoded).
        bits: 8, 16, or None: 16 where a float image holds finer levels than 8 bits do (a 12- or 16-bit camera's
            frame, whose shadow detail 8 bits would cut), else 8.
    """
    from PIL import Image

    arr = np.asarray(img)
    if arr.ndim != 3 or arr.shape[2] != 3 or arr.shape[0] == 0 or arr.shape[1] == 0:
        raise ValueError(f"{path}: write_png expects an (H, W, 3) image, got shape {arr.shape}")
    if bits not in (8, 16, None):
        raise ValueError(f"{path}: write_png writes 8 or 16 bits, got {bits}")
    if arr.dtype != np.uint8:
        if not np.issubdtype(arr.dtype, np.floating):
            raise ValueError(f"{path}: write_png expects uint8 or float data, got {arr.dtype}")
        if not np.isfinite(arr).all():
            raise ValueError(f"{path}: write_png image contains NaN or inf")
        if bits == 16 or (bits is None and not _on_8_bit_levels(arr)):
            import cv2

            deep = np.round(np.clip(arr, 0.0, 1.0) * 65535.0).astype(np.uint16)
            with atomic_path(path, suffix=".png") as tmp:
                if not cv2.imwrite(str(tmp), cv2.cvtColor(np.ascontiguousarray(deep), cv2.COLOR_RGB2BGR)):
                    raise OSError(f"{path}: cannot write the 16-bit PNG")
            return
        arr = to_uint8(arr)
    with atomic_path(path, suffix=".png") as tmp:
        Image.fromarray(np.ascontiguousarray(arr), mode="RGB").save(tmp, format="PNG")


def _on_8_bit_levels(img: np.ndarray) -> bool:
    """Whether every value of a float image in [0, 1] is one of the 256 levels of 8 bits (k / 255, to float32's
    precision): an 8-bit source, which 8 bits store exactly."""
    scaled = np.clip(img, 0.0, 1.0).astype(np.float64) * 255.0
    return bool(np.abs(scaled - np.round(scaled)).max() < 1e-3)
