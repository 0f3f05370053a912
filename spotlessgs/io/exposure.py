"""Known exposures of input frames: a sidecar JSON beside each image, or the image's EXIF.

The photometric camera (``spotlessgs.models.photometric``) starts each frame's exposure from these when every frame
has one. Only ratios matter: exposure = shutter time (s) × gain (a linear factor; EXIF: ISO / 100).

Sidecar: ``images/frame_00012.json`` beside ``images/frame_00012.png``::

    {"exposure_time": 0.008, "gain": 2.0}      # gain optional (default 1)
"""

from __future__ import annotations

import json
import math
from collections.abc import Sequence
from pathlib import Path

from PIL import Image

from spotlessgs.io.errors import InputError

_EXIF_IFD = 0x8769
_EXPOSURE_TIME = 0x829A
_ISO = 0x8827


def _positive(value: object, path: Path, key: str) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value) or value <= 0:
        raise InputError(f"{path}: '{key}' must be a positive number, got {value!r}")
    return float(value)


def exposure_sidecar(image: Path) -> Path:
    """The exposure record beside the frame ``image`` (``images/frame_00012.json`` for ``images/frame_00012.png``),
    whether or not it exists."""
    return Path(image).with_suffix(".json")


def _sidecar_exposure(path: Path) -> float | None:
    sidecar = exposure_sidecar(path)
    if not sidecar.is_file():
        return None
    try:
        data = json.loads(sidecar.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise InputError(f"{sidecar}: not a readable JSON exposure record ({exc})") from None
    if not isinstance(data, dict) or "exposure_time" not in data:
        raise InputError(f"{sidecar}: an exposure record needs 'exposure_time' (seconds) and optionally 'gain'")
    return _positive(data["exposure_time"], sidecar, "exposure_time") * _positive(data.get("gain", 1.0), sidecar,
                                                                                   "gain")


def _exif_exposure(path: Path) -> float | None:
    try:
        with Image.open(path) as image:
            exif = image.getexif().get_ifd(_EXIF_IFD)
    except OSError:
        return None
    time, iso = exif.get(_EXPOSURE_TIME), exif.get(_ISO)
    if time is None:
        return None
    try:
        seconds = float(time)
        gain = float(iso[0] if isinstance(iso, tuple) else iso) / 100.0 if iso else 1.0
    except (TypeError, ValueError, ZeroDivisionError):
        return None
    return seconds * gain if math.isfinite(seconds * gain) and seconds * gain > 0 else None


def frame_exposures(image_paths: Sequence[Path]) -> list[float] | None:
    """Exposure (shutter time × gain) of every frame, sidecar first, then EXIF; None unless every frame has one.

    Raises:
        InputError: a sidecar exists but is not a valid exposure record (names the file).
    """
    exposures = []
    for path in image_paths:
        value = _sidecar_exposure(Path(path))
        if value is None:
            value = _exif_exposure(Path(path))
        if value is None:
            return None
        exposures.append(value)
    return exposures
