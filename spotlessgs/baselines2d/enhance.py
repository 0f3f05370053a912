"""One entry point for the single-view 2D baselines: enhance every image of a folder with one method."""

from __future__ import annotations

import dataclasses
import os
from pathlib import Path
from typing import Any, Callable

import numpy as np

from spotlessgs.baselines2d.clahe import ClaheConfig, clahe
from spotlessgs.baselines2d.folders import refuse_name_clashes
from spotlessgs.baselines2d.msrcr import MsrcrConfig, msrcr
from spotlessgs.io.atomic import write_json
from spotlessgs.io.images import list_image_files, read_image, write_png
from spotlessgs.io.paths import refuse_overlap
from spotlessgs.io.provenance import provenance

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

    Args:
        method: 'clahe', 'msrcr' (options: the fields of ClaheConfig / MsrcrConfig) or 'cyclegan' (options:
            ``checkpoint`` (required), ``direction``, ``num_threads``; see ``translate_folder``).
        in_dir: folder of sRGB images (PNG/JPEG).
        out_dir: output folder (created); also receives baseline2d_provenance.json.
    Returns:
        the written image paths, in input order.
    Raises:
        ValueError for an unknown method or option, FileNotFoundError for a missing folder or checkpoint,
        OutputOverlapError when ``out_dir`` is, holds or lies inside ``in_dir`` (never write into an input).
    """
    if method not in METHODS:
        raise ValueError(f"enhance_folder: unknown method {method!r}; choose one of {list(METHODS)}")
    out_dir = Path(out_dir)
    refuse_overlap(out_dir, {"IN_DIR": in_dir}, "OUT_DIR")
    if method == "cyclegan":
        from spotlessgs.baselines2d.cyclegan.translate import translate_folder  # deferred: torch, only for Cycle-GAN

        if "checkpoint" not in opts:
            raise ValueError("enhance_folder: method 'cyclegan' needs checkpoint=<path of a trained checkpoint.pt>")
        unknown = sorted(set(opts) - {"checkpoint", "direction", "num_threads"})
        if unknown:
            raise ValueError(f"enhance_folder: unknown options {unknown} for method 'cyclegan'")
        written = translate_folder(opts["checkpoint"], in_dir, out_dir, opts.get("direction", "uneven_to_even"),
                                   opts.get("num_threads"))  # fmt: skip
        settings = {k: str(v) if isinstance(v, os.PathLike) else v for k, v in opts.items()}
    else:
        function, settings = _classic(method, opts)
        files = list_image_files(in_dir)
        refuse_name_clashes(files)
        written = []
        for path in files:
            out_path = out_dir / f"{path.stem}.png"
            write_png(out_path, function(read_image(path)))
            written.append(out_path)
    write_json(
        out_dir / PROVENANCE_NAME,
        provenance(method=method, settings=settings, input_dir=str(in_dir), images=[p.name for p in written]),
    )
    return written
