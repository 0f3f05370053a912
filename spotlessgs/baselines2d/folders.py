"""Output-name checks shared by the 2D baselines (folders are listed with spotlessgs.io.images.list_image_files)."""

from __future__ import annotations

from pathlib import Path


def refuse_name_clashes(files: list[Path]) -> None:
    """Outputs are written as <stem>.png: two inputs with the same stem (a.png, a.jpg) would collide, so refuse."""
    seen: dict[str, Path] = {}
    for path in files:
        if path.stem in seen:
            raise ValueError(f"{path}: has the same name as {seen[path.stem]} and would overwrite its output PNG")
        seen[path.stem] = path
