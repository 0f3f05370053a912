"""Where a run's renderer puts points: small bright Gaussians placed on chosen camera rays of one view, rendered
through the run's own output path (``Run.render``), and the centroids of their blobs in the output image."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import torch

from spotlessgs.io.exr import read_exr
from spotlessgs.models.gaussians import GaussianParams
from spotlessgs.run import Run
from spotlessgs.training.checkpoint import load_checkpoint, save_checkpoint


def render_points_on_rays(run_dir: Path, view_name: str, c2w: np.ndarray, xy: np.ndarray, sigma_m: float,
                          depth_m: float = 1.5) -> np.ndarray:
    """Replace the run's Gaussians by one bright Gaussian of size ``sigma_m`` on each normalised ray ``xy`` (P, 2) of
    the view with camera-to-world ``c2w`` (4, 4, OpenCV axes), ``depth_m`` ahead; render the test views and return
    the (H, W) red channel of the view's linear EXR output."""
    cam = np.concatenate([depth_m * xy, np.full((len(xy), 1), depth_m)], axis=1)
    world = cam @ c2w[:3, :3].T + c2w[:3, 3]
    blobs = GaussianParams.from_point_cloud(world, np.full((len(world), 3), 255, np.uint8)).params
    blobs["log_scales"] = torch.full_like(blobs["log_scales"], math.log(sigma_m))
    blobs["opacity_logits"] = torch.full_like(blobs["opacity_logits"], 5.0)
    checkpoint = load_checkpoint(run_dir)
    checkpoint.pop("version")
    save_checkpoint(run_dir, {**checkpoint, "gaussians": {n: t.detach() for n, t in blobs.items()}})
    Run.load(run_dir).render("test", exr=True, progress=False)
    return read_exr(run_dir / "render" / f"{Path(view_name).stem}.exr")["R"]


def centroid_errors(image: np.ndarray, expected: np.ndarray, half_window: float) -> list[float]:
    """Distance (px) of the brightness centroid within ``half_window`` px of each expected position (P, 2) in
    continuous pixel coordinates (pixel centres at +0.5) from that position."""
    v, u = np.mgrid[0:image.shape[0], 0:image.shape[1]] + 0.5
    errors = []
    for ex, ey in expected:
        weight = image * ((np.abs(u - ex) < half_window) & (np.abs(v - ey) < half_window))
        centroid = np.array([(weight * u).sum(), (weight * v).sum()]) / weight.sum()
        errors.append(float(np.linalg.norm(centroid - (ex, ey))))
    return errors
