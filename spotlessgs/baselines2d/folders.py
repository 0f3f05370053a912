"""Listing the image files of a folder (shared by the 2D baselines)."""

from __future__ import annotations

import os
from pathlib import Path

from spotlessgs.io.images import IMAGE_SUFFIXES, is_image_name


def list_images(folder: str | os.PathLike) -> list[Path]:
    """Image files (:data:`spotlessgs.io.images.IMAGE_SUFFIXES`, case-insensitive) directly inside ``folder``, sorted
    by name; other files are skipped.

    Raises FileNotFoundError when the folder is missing and ValueError when it holds no image.
    """
    folder = Path(folder)
    if not folder.is_dir():
        raise FileNotFoundError(f"{folder}: image folder not found")
    files = sorted(p for p in folder.iterdir() if p.is_file() and is_image_name(p.name))
    if not files:
        raise ValueError(f"{folder}: no image files ({', '.join(IMAGE_SUFFIXES)}) in this folder")
    return files


def refuse_name_clashes(files: list[Path]) -> None:
    """Outputs are written as <stem>.png: two inputs with the same stem (a.png, a.jpg) would collide, so refuse."""
    seen: dict[str, Path] = {}
    for path in files:
        if path.stem in seen:
            raise ValueError(f"{path}: has the same name as {seen[path.stem]} and would overwrite its output PNG")
        seen[path.stem] = path
