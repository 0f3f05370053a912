"""Write a generated room as a 3D-FRONT house folder, all at once.

Layout written::

    <out_dir>/house.json                          3D-FRONT house (y up, metres)
    <out_dir>/models/<jid>/raw_model.obj|model.mtl|texture.png   3D-FUTURE models
    <out_dir>/models/model_info.json              3D-FUTURE model list
    <out_dir>/textures/<material jid>/texture.png architecture textures (3D-FRONT-texture layout)

Everything is written into a fresh sibling folder which then replaces ``out_dir`` by renames, so a reader never sees a
half-written room and a failed run leaves the previous room untouched.
"""

from __future__ import annotations

import json
import os
import shutil
import tempfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from spotlessgs.io.atomic import swap_in_folder, write_json
from spotlessgs.io.paths import refuse_working_directory

from .furniture import FurnitureModel, model_info, save_png, write_model


@dataclass(frozen=True)
class HouseFiles:
    """Everything a house folder holds.

    Attributes:
        house: the house JSON object.
        models: furniture models with their texture images ((H, W, 3) uint8).
        textures: architecture textures by material jid, (H, W, 3) uint8.
    """

    house: dict
    models: tuple[tuple[FurnitureModel, np.ndarray], ...]
    textures: tuple[tuple[str, np.ndarray], ...]


#: What a generated room's folder holds (:func:`write_house`); a folder with anything else is not replaced.
ROOM_ENTRIES = frozenset({"house.json", "models", "textures"})


def _refusal(out_dir: Path) -> str | None:
    """Why ``out_dir`` may not be replaced, or None: an absent or empty folder, or one holding a room made by this
    generator (its house.json has our ``spotlessgs`` block) and nothing else, may be; anything else (a real 3D-FRONT
    house, user files, a dataset rendered into the room's folder) may not."""
    if not out_dir.exists():
        return None
    if not out_dir.is_dir() or any(out_dir.iterdir()):
        try:
            house = json.loads((out_dir / "house.json").read_text(encoding="utf-8"))
        except (OSError, ValueError):
            house = None
        if not (isinstance(house, dict) and isinstance(house.get("spotlessgs"), dict)):
            return "exists and is not a room made by this generator"
        others = sorted(p.name for p in out_dir.iterdir() if p.name not in ROOM_ENTRIES)
        if others:
            shown = ", ".join(others[:5]) + (f" and {len(others) - 5} more" if len(others) > 5 else "")
            return f"holds a generated room and also {shown}, which replacing the room would delete"
    return None


def write_house(out_dir: Path, files: HouseFiles) -> Path:
    """Write ``files`` into ``out_dir`` (replacing a previously generated room there); returns ``house.json``'s path.

    Raises:
        FileExistsError: ``out_dir`` exists and is neither empty nor a room made by this generator, or holds other
            entries than :data:`ROOM_ENTRIES` beside one. OutputOverlapError: ``out_dir`` is or holds the current
            directory.
    """
    out_dir = Path(out_dir)
    refuse_working_directory(out_dir, "--out")
    refusal = _refusal(out_dir)
    if refusal is not None:
        raise FileExistsError(f"{out_dir}: {refusal}; refusing to replace it (use another --out)")
    out_dir.parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=f".{out_dir.name}.tmp-", dir=out_dir.parent))
    try:
        for model, image in files.models:
            write_model(model, tmp / "models", image)
        write_json(tmp / "models" / "model_info.json", [model_info(m) for m, _ in files.models])
        for jid, image in files.textures:
            save_png(tmp / "textures" / jid / "texture.png", image)
        write_json(tmp / "house.json", files.house)
        _make_readable(tmp)
        swap_in_folder(tmp, out_dir)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    return out_dir / "house.json"


def _make_readable(root: Path) -> None:
    """Give the new tree ordinary permissions (temporary files and folders are created private): 0644/0755 less
    the process umask."""
    mask = os.umask(0)
    os.umask(mask)
    for path in [root, *root.rglob("*")]:
        path.chmod((0o755 if path.is_dir() else 0o644) & ~mask)
