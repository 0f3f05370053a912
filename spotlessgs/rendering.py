"""Render a trained run's views: relit (spotlight replaced by a constant L0, paper eq. 8) or under the learned
spotlight (to compare with the inputs). PNGs are named like the dataset's images; nothing is clipped silently: the
fraction of pixels above 1 (clipped by 8-bit PNG) is reported and warned about, and ``exr=True`` also writes the
unclipped linear values. By default L0 is chosen automatically (white, about 1% of pixels reaching 1)."""

from __future__ import annotations

import dataclasses
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
from spotlessgs.models.shading import shade
from spotlessgs.rasterizer import rasterize

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


#: ``l0="auto"`` scales a white L0 so that this percentile of relit luminance (over sampled views) ...
AUTO_L0_PERCENTILE = 99.0
#: ... lands at this linear value (sRGB ~0.95): bright, with about 1% of pixels at most reaching 1.
AUTO_L0_TARGET = 0.9
#: Views sampled (evenly along the sequence) to choose the automatic L0.
AUTO_L0_VIEWS = 16


class RelitColours:
    """Per-Gaussian relit colours for every view from one evaluation of the reflectance.

    Relit colours c = R·(L0 + L_lf(n̂)) depend on the camera only through the two-sided normal: n̂ is flipped towards
    the camera. So R and R·L_lf are computed once for the normals as stored and once for the flipped normals, and each
    view picks per Gaussian the side it sees — the same choice ``shading.orient_normals`` makes. (The camera also
    enters a stored normal of length ~0 through its fallback direction; those rare Gaussians use the fallback towards
    the first view.) Compositing is linear in the colours, so rendering [R, R·L_lf] as six channels gives
    image = I_R·L0 + I_low for any L0.
    """

    def __init__(self, scene, c2w_ref: torch.Tensor) -> None:
        cfg = dataclasses.replace(scene.config, two_sided_normals=False)
        app, g = scene.appearance, scene.gaussians
        self.scene = scene
        self.front = self._parts(cfg, app, g, c2w_ref)
        self.back = None
        if scene.config.two_sided_normals:
            flipped = g.subset(torch.arange(len(g), device=g.means.device))
            flipped.params["normals_raw"] = -g.params["normals_raw"]
            self.back = self._parts(cfg, app, flipped, c2w_ref)

    @staticmethod
    def _parts(cfg, app, g, c2w) -> torch.Tensor:
        with_l0 = shade(cfg, g, app.light, app.lf_light, app.brdf, c2w, relight_l0=[1.0, 1.0, 1.0])
        low = shade(cfg, g, app.light, app.lf_light, app.brdf, c2w, relight_l0=[0.0, 0.0, 0.0])
        return torch.cat([with_l0 - low, low], dim=1)  # (N, 6): R, R·L_lf

    def features(self, c2w: torch.Tensor) -> torch.Tensor:
        """(N, 6) [R, R·L_lf] of every Gaussian as seen from camera ``c2w``."""
        if self.back is None:
            return self.front
        g = self.scene.gaussians
        center = c2w[:3, 3]
        normals = g.normals(center)
        facing_away = ((center - g.means) * normals).sum(-1, keepdim=True) < 0
        return torch.where(facing_away, self.back, self.front)


def auto_l0(images_r: list[np.ndarray], images_low: list[np.ndarray]) -> list[float]:
    """A white L0 = s·(1, 1, 1) that puts the AUTO_L0_PERCENTILE of relit luminance at AUTO_L0_TARGET.

    Args:
        images_r: rendered R·1 images (H, W, 3) of a few views; images_low: their R·L_lf images.
    """
    lum_r = np.concatenate([im.mean(axis=2).ravel() for im in images_r])
    lum_low = np.concatenate([im.mean(axis=2).ravel() for im in images_low])
    lo, hi = 0.0, 1.0
    def level(scale: float) -> float:
        return float(np.percentile(scale * lum_r + lum_low, AUTO_L0_PERCENTILE))
    while level(hi) < AUTO_L0_TARGET and hi < 1e6:
        hi *= 2.0
    if level(lo) >= AUTO_L0_TARGET:  # the low-frequency light alone is already that bright
        return [0.0, 0.0, 0.0]
    for _ in range(50):  # bisection: level() is monotone in the scale
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if level(mid) < AUTO_L0_TARGET else (lo, mid)
    return [0.5 * (lo + hi)] * 3


@torch.no_grad()
def render_run(
    run_dir: str | Path,
    mode: str = "relit",
    which: str = "all",
    out_dir: str | Path | None = None,
    l0: Sequence[float] | str = "auto",
    exr: bool = False,
    progress: bool = True,
    device: str = "auto",
    low_frequency: bool = True,
) -> dict[str, Any]:
    """Render views of a run at the dataset's native resolution.

    Args:
        run_dir: the training run.
        mode: ``relit`` (constant L0 + the learned low-frequency light) or ``spot`` (the learned spotlight).
        which: ``test``, ``train`` or ``all``.
        out_dir: output folder; default ``RUN/relit`` or ``RUN/render``.
        l0: linear RGB relighting radiance (relit mode), or ``"auto"``: white, scaled so that about 1% of relit
            pixels reach 1 (see AUTO_L0_*); the value used is reported.
        exr: also write linear float EXR files (``<name>.exr`` with channels R, G, B).
        low_frequency: relit mode: False leaves the learned low-frequency light out (image = R·L0 alone), to see what
            the reflectance alone gives; the automatic L0 is then chosen for that image.
    Returns:
        a summary (views, L0, seconds per view, frames per second, clipped fraction), also written as
        ``RUN/<relit|render>.json`` (outside the image folder, which holds images only).
    """
    from tqdm import tqdm

    from spotlessgs.training.trainer import load_run

    if mode not in ("relit", "spot"):
        raise ValueError(f"mode must be relit or spot, got {mode!r}")
    if mode != "relit" and not low_frequency:
        raise ValueError("low_frequency=False only applies to relit mode")
    if isinstance(l0, str) and l0 != "auto":
        raise ValueError(f"l0 must be 'auto' or three numbers, got {l0!r}")
    run_dir = Path(run_dir)
    scene, views, config, _info = load_run(run_dir, device=device)
    dev = scene.gaussians.means.device
    native = views.dataset.intrinsics
    K = torch.as_tensor(native.K(), dtype=torch.float32, device=dev)
    width, height = int(native.width), int(native.height)
    out = Path(out_dir) if out_dir is not None else run_dir / ("relit" if mode == "relit" else "render")
    indices = select_views(views, which)
    g = scene.gaussians
    start = time.perf_counter()
    parts = None
    if mode == "relit" and scene.config.light_model != "none":  # 3dgs "relit" = its ordinary render
        parts = RelitColours(scene, views.c2w[indices[0]].to(dev))

    def raster(k: int, feats: torch.Tensor) -> np.ndarray:
        res = rasterize(g.means, g.quats, g.scales, g.opacities, feats, views.viewmats[k].to(dev), K, width, height,
                        backend=config.raster_backend, num_threads=config.num_threads)
        return res.image.float().cpu().numpy()

    def relit_image(k: int, light: list[float] | None) -> np.ndarray:
        if parts is None:  # 3dgs: its ordinary render
            res = scene.render(views.c2w[k].to(dev), views.viewmats[k].to(dev), K, width, height,
                               relight_l0=[1.0, 1.0, 1.0], backend=config.raster_backend,
                               num_threads=config.num_threads)
            return res.image.float().cpu().numpy()
        both = raster(k, parts.features(views.c2w[k].to(dev)))
        return both[..., :3] * np.asarray(light, dtype=np.float32) + low_part(both)

    def low_part(both: np.ndarray) -> np.ndarray:
        """The R·L_lf channels of a six-channel render, zero when the low-frequency light is left out."""
        return both[..., 3:] if low_frequency else np.zeros_like(both[..., 3:])

    relight: list[float] | None = None
    if mode == "relit" and parts is not None:
        if isinstance(l0, str):
            sample = [indices[i] for i in np.linspace(0, len(indices) - 1, min(AUTO_L0_VIEWS, len(indices))).astype(int)]
            both = [raster(k, parts.features(views.c2w[k].to(dev))) for k in sample]
            relight = auto_l0([b[..., :3] for b in both], [low_part(b) for b in both])
        else:
            relight = [float(v) for v in l0]
            if len(relight) != 3 or any(not np.isfinite(v) or v < 0 for v in relight):
                raise ValueError(f"l0 must be three finite non-negative numbers, got {l0!r}")
    clipped, total = 0, 0
    for k in tqdm(indices, desc=f"{mode} {run_dir.name}", disable=not progress, unit="view"):
        if mode == "relit":
            img = relit_image(k, relight)
        else:
            res = scene.render(views.c2w[k].to(dev), views.viewmats[k].to(dev), K, width, height,
                               backend=config.raster_backend, num_threads=config.num_threads)
            img = res.image.float().cpu().numpy()
        clipped += int((img.max(axis=2) > 1.0).sum())
        total += img.shape[0] * img.shape[1]
        write_png(out / views.names[k], linear_to_srgb(img))
        if exr:
            write_exr(out / (Path(views.names[k]).stem + ".exr"), {c: img[..., i] for i, c in enumerate("RGB")})
    seconds = time.perf_counter() - start
    fraction = clipped / max(total, 1)
    if mode == "relit" and fraction > CLIP_WARN_FRACTION:
        log.warning("%.2f%% of relit pixels exceed 1 and are clipped in the PNGs; lower --l0 (now %s) or use --exr",
                    100 * fraction, relight)
    summary = {"mode": mode, "views": which, "count": len(indices), "l0": relight, "low_frequency": low_frequency,
               "l0_mode": "auto" if isinstance(l0, str) else "given", "width": width, "height": height,
               "seconds_per_view": seconds / max(len(indices), 1), "fps": len(indices) / max(seconds, 1e-9),
               "clipped_fraction": fraction, "num_gaussians": len(g), "device": str(dev), "out_dir": str(out)}
    write_json(run_dir / f"{'relit' if mode == 'relit' else 'render'}.json", summary)
    return summary
