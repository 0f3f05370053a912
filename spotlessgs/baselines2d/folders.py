"""Output-name checks shared by the 2D baselines (folders are listed with spotlessgs.io.images.list_image_files)."""

from __future__ import annotations

from pathlib import Path


def refuse_name_clashes(files: list[Path]) -> None:
    """Outputs are written as <stem>.png: two inputs with the same stem (a.png, a.jpg), or stems that differ only in
    case (a.png, A.jpg: one file on macOS and Windows), would collide, so refuse."""
    seen: dict[str, Path] = {}
    for path in files:
        key = path.stem.casefold()
        if key in seen:
            raise ValueError(f"{path}: has the same name as {seen[key]} (up to letter case) and would overwrite its "
                             "output PNG")
        seen[key] = path
