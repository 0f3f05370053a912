"""One entry point for the single-view 2D baselines: enhance every image of a folder with one method."""

from __future__ import annotations

import dataclasses
import os
import shutil
from pathlib import Path
from typing import Any, Callable

import numpy as np

from spotlessgs.baselines2d.clahe import ClaheConfig, clahe
from spotlessgs.baselines2d.folders import refuse_name_clashes
from spotlessgs.baselines2d.msrcr import MsrcrConfig, msrcr
from spotlessgs.io.atomic import partial_sibling, swap_in_folder, write_json
from spotlessgs.io.errors import write_error
from spotlessgs.io.images import list_image_files, read_image, write_png
from spotlessgs.io.paths import refuse_foreign_folder, refuse_overlap, refuse_working_directory
from spotlessgs.io.provenance import provenance, sha256_file

METHODS = ("clahe", "msrcr", "cyclegan")
PROVENANCE_NAME = "baseline2d_provenance.json"


def _classic(method: str, opts: dict[str, Any]) -> tuple[Callable[[np.ndarray], np.ndarray], dict[str, Any]]:
    config_type, function = {"clahe": (ClaheConfig, clahe), "msrcr": (MsrcrConfig, msrcr)}[method]
    known = {f.name for f in dataclasses.fields(config_type)}
    unknown = sorted(set(opts) - known)
    if unknown:
        raise ValueError(f"enhance_folder: unknown options {unknown} for method {method!r}; known: {sorted(known)}")
    if "sigma_fractions" in opts:
        opts = {**opts, "sigma_fractions": tuple(float(s) for s in opts["sigma_fractions"])}
    config = config_type(**opts)
    return (lambda img: function(img, config)), dataclasses.asdict(config)


def enhance_folder(method: str, in_dir: str | os.PathLike, out_dir: str | os.PathLike, **opts: Any) -> list[Path]:
    """Enhance every image of ``in_dir`` independently and write ``out_dir/<input stem>.png`` (same size).

    Every image is written into a hidden sibling folder that then replaces ``out_dir`` whole: a reader never sees a
    half-written output, an interrupted or failed run leaves ``out_dir`` as it was, and a rerun replaces an earlier
    output instead of mixing two (``out_dir`` may be new, empty, or an earlier output of this function: it holds
    baseline2d_provenance.json).

    Args:
        method: 'clahe', 'msrcr' (options: the fields of ClaheConfig / MsrcrConfig) or 'cyclegan' (options:
            ``checkpoint`` (required: a train-cyclegan folder or its checkpoint file; the provenance records its
            sha256), ``direction``, ``num_threads``; see ``translate_folder``).
        in_dir: folder of sRGB images (PNG/JPEG).
        out_dir: output folder (created); also receives baseline2d_provenance.json.
    Returns:
        the written image paths, in input order.
    Raises:
        ValueError for an unknown method or option, FileNotFoundError for a missing folder or checkpoint,
        OutputOverlapError when ``out_dir`` is, holds or lies inside ``in_dir`` (never write into an input),
        InputError when ``out_dir`` is a file or holds files but is not an earlier output.
    """
    if method not in METHODS:
        raise ValueError(f"enhance_folder: unknown method {method!r}; choose one of {list(METHODS)}")
    out_dir = Path(out_dir)
    refuse_overlap(out_dir, {"IN_DIR": in_dir}, "OUT_DIR")
    refuse_working_directory(out_dir, "OUT_DIR")
    refuse_foreign_folder(out_dir, [PROVENANCE_NAME], "OUT_DIR", "an earlier output of this command (the output "
                          "replaces the whole folder)", count_hidden=True)
    if method == "cyclegan" and "checkpoint" not in opts:
        raise ValueError("enhance_folder: method 'cyclegan' needs a checkpoint (--checkpoint: the folder or the "
                         "checkpoint file written by train-cyclegan)")
    out_dir.parent.mkdir(parents=True, exist_ok=True)
    tmp = partial_sibling(out_dir)
    try:
        tmp.mkdir()
    except OSError as exc:  # a read-only or full file system: say so of OUT_DIR, not of the hidden sibling
        raise (write_error(out_dir, exc) or exc) from None
    try:
        names, settings = _enhance_into(method, Path(in_dir), tmp, opts)
        write_json(tmp / PROVENANCE_NAME,
                   provenance(method=method, settings=settings, input_dir=str(in_dir), images=names))
        swap_in_folder(tmp, out_dir)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    return [out_dir / name for name in names]


def _enhance_into(method: str, in_dir: Path, out_dir: Path, opts: dict[str, Any]) -> tuple[list[str], dict]:
    """Write the enhanced images of ``in_dir`` into the existing folder ``out_dir``; (their names, the settings)."""
    if method == "cyclegan":
        # deferred: torch, only for Cycle-GAN
        from spotlessgs.baselines2d.cyclegan.checkpoint import checkpoint_file
        from spotlessgs.baselines2d.cyclegan.translate import translate_folder

        unknown = sorted(set(opts) - {"checkpoint", "direction", "num_threads"})
        if unknown:
            raise ValueError(f"enhance_folder: unknown options {unknown} for method 'cyclegan'")
        checkpoint = checkpoint_file(opts["checkpoint"])
        digest = sha256_file(checkpoint)  # which weights made the images, whatever happens to the file later
        written = translate_folder(checkpoint, in_dir, out_dir, opts.get("direction", "uneven_to_even"),
                                   opts.get("num_threads"))  # fmt: skip
        settings = {**{k: str(v) if isinstance(v, os.PathLike) else v for k, v in opts.items()},
                    "checkpoint": str(checkpoint), "checkpoint_sha256": digest}
        return [p.name for p in written], settings
    function, settings = _classic(method, opts)
    files = list_image_files(in_dir)
    refuse_name_clashes(files)
    names = []
    for path in files:
        write_png(out_dir / f"{path.stem}.png", function(read_image(path)))
        names.append(f"{path.stem}.png")
    return names, settings
