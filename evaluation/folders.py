"""Pairing the images of two folders by file name, and reading a folder's named images, with checks that name the
offending files."""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path
from typing import Sequence

import numpy as np

from spotlessgs.io.images import list_image_files, read_image


@dataclass(frozen=True)
class ImagePair:
    """One prediction and its reference, matched by file name."""

    name: str  # file name shared by both images, e.g. "frame_00000.png"
    pred: Path  # path of the predicted (e.g. relit) image
    gt: Path  # path of the reference (ground-truth) image
    # the frame's EXR (spotlessgs.io.exr), whose emission pass marks the ground truth's lamps: the *_masked metrics
    # leave them out; None (or an EXR without the pass): no masked metrics
    exr: Path | None = None


def image_names(folder: str | os.PathLike, non_images: str = "error") -> list[str]:
    """Sorted image file names in ``folder``; a folder holding other files is refused (see
    :func:`spotlessgs.io.images.list_image_files` with ``non_images="error"``, which raises FileNotFoundError /
    ValueError naming the folder and the files), or with ``non_images="skip"`` (a folder whose manifest vouches for
    every file, e.g. ``spotless relight --exr``'s EXR files) they are left out."""
    return [p.name for p in list_image_files(folder, non_images=non_images)]


def match_folders(
    pred_dir: str | os.PathLike, gt_dir: str | os.PathLike, names: Sequence[str] | None = None,
    non_images: tuple[str, str] = ("error", "error"),
) -> list[ImagePair]:
    """Pair the images of ``pred_dir`` and ``gt_dir`` by file name.

    Args:
        pred_dir: folder of predicted images.
        gt_dir: folder of reference images.
        names: when given, exactly these file names are paired (both folders may hold more); otherwise both folders
            must hold the same set of image names.
        non_images: what :func:`image_names` does with other files in ``pred_dir`` and in ``gt_dir``.

    Returns:
        the pairs, in the order of ``names`` or in the natural order of the names (``frame_2`` before ``frame_10``).

    Raises:
        ValueError: the folders hold different image counts or names (missing and extra names are listed), or a
            requested name is absent from a folder.
    """
    pred_names, gt_names = image_names(pred_dir, non_images[0]), image_names(gt_dir, non_images[1])
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


def read_named_images(folder: str | os.PathLike, names: Sequence[str]) -> np.ndarray:
    """(N, H, W, 3) float32 sRGB in [0, 1]: the images ``names`` of ``folder``, in that order (e.g. a run's relit
    test views, named like the dataset's images).

    Raises:
        FileNotFoundError: an image is missing (the path is named); ValueError: an image cannot be decoded, or the
            images differ in size (the folder is named).
    """
    images = [read_image(Path(folder) / name) for name in names]
    if len({image.shape for image in images}) > 1:
        raise ValueError(f"{folder}: the images {_short(list(names))} differ in size")
    return np.stack(images)


def _short(names: Sequence[str], limit: int = 5) -> str:
    """``names`` joined for an error message, at most ``limit`` of them; '(none)' when empty."""
    if not names:
        return "(none)"
    return ", ".join(names[:limit]) + (f" (and {len(names) - limit} more)" if len(names) > limit else "")
