"""Render a trained run's views: relit (spotlight replaced by a constant L0, paper eq. 8) or under the learned
spotlight (to compare with the inputs). PNGs are named like the dataset's images; nothing is clipped silently: the
fraction of pixels above 1 (clipped by 8-bit PNG) is reported and warned about, and ``exr=True`` also writes the
unclipped linear values."""

from __future__ import annotations

import logging
import time
from pathlib import Path
from typing import Any, Sequence

import numpy as np
import torch

from spotlessgs.io.atomic import write_json
from spotlessgs.io.colorspace import linear_to_srgb
from spotlessgs.io.exr import write_exr
from spotlessgs.io.images import write_png
from spotlessgs.models.shading import RELIGHT_L0_DEFAULT

log = logging.getLogger(__name__)

#: Warn when more than this fraction of relit pixels exceeds 1 (clipped in 8-bit output).
CLIP_WARN_FRACTION = 0.005


def select_views(views, which: str) -> list[int]:
    """Indices of ``test``, ``train`` or ``all`` views."""
    if which == "test":
        return list(views.test)
    if which == "train":
        return list(views.train)
    if which == "all":
        return list(range(len(views.names)))
    raise ValueError(f"views must be test, train or all, got {which!r}")


@torch.no_grad()
def render_run(
    run_dir: str | Path,
    mode: str = "relit",
    which: str = "all",
    out_dir: str | Path | None = None,
    l0: Sequence[float] = RELIGHT_L0_DEFAULT,
    exr: bool = False,
    progress: bool = True,
    device: str = "auto",
) -> dict[str, Any]:
    """Render views of a run at the dataset's native resolution.

    Args:
        run_dir: the training run.
        mode: ``relit`` (constant L0 + the learned low-frequency light) or ``spot`` (the learned spotlight).
        which: ``test``, ``train`` or ``all``.
        out_dir: output folder; default ``RUN/relit`` or ``RUN/render``.
        l0: linear RGB relighting radiance (relit mode).
        exr: also write linear float EXR files (``<name>.exr`` with channels R, G, B).
    Returns:
        a summary (views, seconds per view, frames per second, clipped fraction) also written as ``render.json``.
    """
    from tqdm import tqdm

    from spotlessgs.training.trainer import load_run

    if mode not in ("relit", "spot"):
        raise ValueError(f"mode must be relit or spot, got {mode!r}")
    run_dir = Path(run_dir)
    scene, views, config, _info = load_run(run_dir, device=device)
    dev = scene.gaussians.means.device
    native = views.dataset.intrinsics
    K = torch.as_tensor(native.K(), dtype=torch.float32, device=dev)
    out = Path(out_dir) if out_dir is not None else run_dir / ("relit" if mode == "relit" else "render")
    relight = list(map(float, l0)) if mode == "relit" else None
    indices = select_views(views, which)
    clipped, total, seconds = 0, 0, 0.0
    for k in tqdm(indices, desc=f"{mode} {run_dir.name}", disable=not progress, unit="view"):
        start = time.perf_counter()
        res = scene.render(views.c2w[k].to(dev), views.viewmats[k].to(dev), K, int(native.width), int(native.height),
                           relight_l0=relight, backend=config.raster_backend, num_threads=config.num_threads)
        img = res.image.float().cpu().numpy()
        seconds += time.perf_counter() - start
        clipped += int((img.max(axis=2) > 1.0).sum())
        total += img.shape[0] * img.shape[1]
        write_png(out / views.names[k], linear_to_srgb(img))
        if exr:
            write_exr(out / (Path(views.names[k]).stem + ".exr"), {c: img[..., i] for i, c in enumerate("RGB")})
    fraction = clipped / max(total, 1)
    if mode == "relit" and fraction > CLIP_WARN_FRACTION:
        log.warning("%.2f%% of relit pixels exceed 1 and are clipped in the PNGs; lower --l0 (now %s) or use --exr",
                    100 * fraction, relight)
    summary = {"mode": mode, "views": which, "count": len(indices), "l0": relight,
               "width": int(native.width), "height": int(native.height),
               "seconds_per_view": seconds / max(len(indices), 1), "fps": len(indices) / max(seconds, 1e-9),
               "clipped_fraction": fraction, "num_gaussians": len(scene.gaussians), "device": str(dev)}
    write_json(out / "render.json", summary)
    return summary
