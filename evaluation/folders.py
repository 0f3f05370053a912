"""Pairing the images of two folders by file name, with checks that name the offending files."""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path
from typing import Sequence

from spotlessgs.io.images import IMAGE_SUFFIXES, is_image_name


@dataclass(frozen=True)
class ImagePair:
    """One prediction and its reference, matched by file name."""

    name: str  # file name shared by both images, e.g. "frame_00000.png"
    pred: Path  # path of the predicted (e.g. relit) image
    gt: Path  # path of the reference (ground-truth) image


def list_images(folder: str | os.PathLike) -> list[str]:
    """Sorted image file names in ``folder`` (not recursive; hidden files and sub-folders are skipped).

    Raises:
        FileNotFoundError: ``folder`` does not exist or is not a directory.
        ValueError: the folder holds non-image files (their names are listed) or no image at all.
    """
    folder = Path(folder)
    if not folder.is_dir():
        raise FileNotFoundError(f"{folder}: not a directory")
    names, others = [], []
    for entry in sorted(folder.iterdir()):
        if entry.name.startswith(".") or entry.is_dir():
            continue
        (names if is_image_name(entry.name) else others).append(entry.name)
    if others:
        shown = ", ".join(others[:5]) + (f" (and {len(others) - 5} more)" if len(others) > 5 else "")
        raise ValueError(f"{folder}: non-image files found: {shown}; expected only {', '.join(IMAGE_SUFFIXES)}")
    if not names:
        raise ValueError(f"{folder}: no image files")
    return names


def match_folders(
    pred_dir: str | os.PathLike, gt_dir: str | os.PathLike, names: Sequence[str] | None = None
) -> list[ImagePair]:
    """Pair the images of ``pred_dir`` and ``gt_dir`` by file name.

    Args:
        pred_dir: folder of predicted images.
        gt_dir: folder of reference images.
        names: when given, exactly these file names are paired (both folders may hold more); otherwise both folders
            must hold the same set of image names.

    Returns:
        the pairs, in the order of ``names`` or sorted by name.

    Raises:
        ValueError: the folders hold different image counts or names (missing and extra names are listed), or a
            requested name is absent from a folder.
    """
    pred_names, gt_names = list_images(pred_dir), list_images(gt_dir)
    pred_set, gt_set = set(pred_names), set(gt_names)
    if names is None:
        if pred_set != gt_set:
            missing = sorted(gt_set - pred_set)
            extra = sorted(pred_set - gt_set)
            raise ValueError(
                f"{pred_dir} holds {len(pred_names)} images and {gt_dir} holds {len(gt_names)}; "
                f"missing from predictions: {_short(missing)}; extra in predictions: {_short(extra)}"
            )
        selected = pred_names
    else:
        selected = list(names)
        if len(set(selected)) != len(selected):
            raise ValueError("requested image names contain duplicates")
        for folder, have in ((pred_dir, pred_set), (gt_dir, gt_set)):
            absent = [n for n in selected if n not in have]
            if absent:
                raise ValueError(f"{folder}: missing requested images: {_short(absent)}")
    return [ImagePair(n, Path(pred_dir) / n, Path(gt_dir) / n) for n in selected]


def _short(names: Sequence[str], limit: int = 5) -> str:
    """``names`` joined for an error message, at most ``limit`` of them; '(none)' when empty."""
    if not names:
        return "(none)"
    return ", ".join(names[:limit]) + (f" (and {len(names) - limit} more)" if len(names) > limit else "")
