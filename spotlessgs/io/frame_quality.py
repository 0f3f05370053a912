"""Degenerate input frames: black, fully saturated, fully transparent (an alpha mask keeping no pixel), or all alike.

A camera that was covered, a lamp that was off, an exposure that clipped everything, or a dataset written with one
frame copied N times trains to nonsense that looks fine (an all-black sequence reaches "55 dB"). These checks run on
the images as read from their files (values in [0, 1] in the file's encoding) before training; frames that carry no
usable signal are named in one warning and left out of the fit, and when nothing usable is left it is an error.

The black level is a brightness as displayed (sRGB encoding): the brightness of a linear file (``--linear``, RAW
developed without a tone curve) is converted to sRGB before the test, so that a dark but valid linear frame (2/255 in
sRGB is about 0.0006 linear) is not taken for a black one.
"""

from __future__ import annotations

import hashlib
import logging
from collections import defaultdict
from dataclasses import dataclass
from typing import Sequence

import numpy as np

from spotlessgs.io.colorspace import linear_to_srgb
from spotlessgs.io.errors import InputError

log = logging.getLogger(__name__)

#: A frame is black when its 99th-percentile pixel (brightest channel) is below this (sRGB encoding): 2 / 255.
BLACK_LEVEL = 2.0 / 255.0
#: A frame is saturated when at least this fraction of its pixels is clipped.
SATURATED_FRACTION = 0.98


@dataclass(frozen=True)
class FrameStats:
    """What the checks need of one frame (kept instead of the image)."""

    bright_level: float  # 99th percentile over pixels of the brightest channel, sRGB encoding
    saturated_fraction: float  # fraction of clipped pixels
    digest: str  # sha256 of the decoded pixels
    opaque_fraction: float = 1.0  # fraction of pixels an alpha mask keeps (1 without one)


def frame_stats(image: np.ndarray, saturated: np.ndarray, linear: bool = False,
                opaque: np.ndarray | None = None) -> FrameStats:
    """Statistics of one (H, W, 3) image in [0, 1] (as read from its file) and its (H, W) clipped mask.

    Args:
        image: the pixels in the file's encoding.
        saturated: True where a pixel is clipped.
        linear: the file holds linear values (``--linear``), not sRGB-encoded ones: its brightness is converted to
            sRGB for the black-frame test.
        opaque: (H, W) bool, the pixels an alpha mask keeps (None: all); the brightness and the clipped fraction are
            those of these pixels.
    """
    kept = (slice(None),) if opaque is None or not opaque.any() else (opaque,)
    brightest = image.max(axis=2)[kept]
    level = float(np.percentile(brightest, 99.0))
    if linear:  # monotonic: the converted percentile is that of the converted pixels (up to interpolation)
        level = float(linear_to_srgb(np.float64(level)))
    digest = hashlib.sha256(np.ascontiguousarray(image, dtype=np.float32).tobytes())
    if opaque is not None:  # two frames alike in colour but masked otherwise are not one image
        digest.update(np.packbits(opaque).tobytes())
    return FrameStats(
        bright_level=level,
        saturated_fraction=float(saturated[kept].mean()),
        digest=digest.hexdigest(),
        opaque_fraction=1.0 if opaque is None else float(opaque.mean()),
    )


def problem(stats: FrameStats) -> str | None:
    """``"transparent"`` (an alpha mask keeps no pixel), ``"black"``, ``"saturated"`` or None for a usable frame."""
    if stats.opaque_fraction == 0.0:
        return "transparent"
    if stats.bright_level < BLACK_LEVEL:
        return "black"
    if stats.saturated_fraction >= SATURATED_FRACTION:
        return "saturated"
    return None


def _listing(names: Sequence[str], limit: int = 8) -> str:
    shown = ", ".join(names[:limit])
    return shown + (f" and {len(names) - limit} more" if len(names) > limit else "")


def usable_frames(source: str, names: Sequence[str], stats: Sequence[FrameStats], candidates: Sequence[int]) -> list[int]:
    """The indices among ``candidates`` whose frames carry signal; warns naming the others.

    Args:
        source: the dataset folder, for messages.
        names: every frame's file name; ``stats``: every frame's :func:`frame_stats`.
        candidates: the indices to filter (the training views).

    Raises:
        InputError: every candidate is black or saturated, or every frame of the dataset is the same image.
    """
    copies: dict[str, list[str]] = defaultdict(list)
    for name, s in zip(names, stats):
        copies[s.digest].append(name)
    repeated = [group for group in copies.values() if len(group) > 1]
    if repeated:
        log.warning("%s: %d group(s) of identical frames, e.g. %s (a stalled camera or a copying error?)", source,
                    len(repeated), _listing(repeated[0]))
    bad = _warn_bad_frames(source, names, stats, candidates, "%s: %d {what} frame(s) left out of training: %s")
    usable = [k for k in candidates if k not in bad]
    if candidates and not usable:
        kinds = " or ".join(sorted(set(bad.values())))
        raise InputError(f"{source}: every training frame is {kinds} (e.g. {names[candidates[0]]}): nothing usable "
                         "to train on; check the exposure, the lamp and the lens cap")
    if len(stats) > 1 and len({s.digest for s in stats}) == 1:
        raise InputError(f"{source}: all {len(stats)} frames are the same image ({names[0]} repeated): "
                         "nothing to reconstruct from")
    if len(candidates) > 1 and len(usable) == 1:
        log.warning("%s: only one usable training frame (%s): a single view does not constrain the geometry", source,
                    names[usable[0]])
    return usable


def warn_unusable_test_frames(source: str, names: Sequence[str], stats: Sequence[FrameStats],
                              test: Sequence[int]) -> None:
    """Warn naming the test frames (indices ``test``) that are black or fully saturated: a score against them says
    nothing of the model (``source``, ``names``, ``stats`` as in :func:`usable_frames`)."""
    _warn_bad_frames(source, names, stats, test,
                     "%s: %d test frame(s) are {what}; scores against them say nothing of the model: %s")


def _warn_bad_frames(source: str, names: Sequence[str], stats: Sequence[FrameStats], indices: Sequence[int],
                     message: str) -> dict[int, str]:
    """{index: "black", "saturated" or "transparent"} of the frames among ``indices`` that :func:`problem` rejects,
    and one warning
    per kind: ``message`` with ``{what}`` (the kind in words) and %-placeholders for the source, the count and the
    listed names."""
    bad = {k: why for k in indices if (why := problem(stats[k])) is not None}
    words = {"black": "black (no signal)", "saturated": "fully saturated (clipped)",
             "transparent": "fully transparent (alpha 0 everywhere)"}
    for why, what in words.items():
        hit = [names[k] for k, w in bad.items() if w == why]
        if hit:
            log.warning(message.format(what=what), source, len(hit), _listing(hit))
    return bad


def noise_level(image: np.ndarray) -> float:
    """Standard deviation of the sensor noise of an (H, W, 3) image in [0, 1] (its grey level), by Immerkær's
    estimator (1996): the image filtered with the difference of two Laplacians, which cancels smooth image content,
    and the mean absolute response scaled to a Gaussian's standard deviation. Clean renders measure 0.003-0.007 (the
    texture that the mask does not cancel), the robot-camera copies 0.017.
    """
    import cv2

    grey = cv2.cvtColor(np.ascontiguousarray(image, dtype=np.float32), cv2.COLOR_RGB2GRAY)
    h, w = grey.shape
    if h < 3 or w < 3:
        return 0.0
    mask = np.array([[1, -2, 1], [-2, 4, -2], [1, -2, 1]], np.float32)
    response = cv2.filter2D(grey, -1, mask)[1:-1, 1:-1]
    return float(np.sqrt(np.pi / 2) * np.abs(response, dtype=np.float64).sum() / (6 * (w - 2) * (h - 2)))
