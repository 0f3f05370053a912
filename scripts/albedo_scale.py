"""Where a run's learned albedo stands on the albedo/light scale, against the true albedo of a rendered dataset.

    python3 scripts/albedo_scale.py RUN [RUN ...] [--views test|train]

The images fix only the product of albedo and light, so a learned albedo is the true one times an unknown factor k.
The albedo is capped at 1: every surface whose true albedo exceeds 1/k is flattened to 1 (training.light_unit). For
each run, on its dataset's views (the dataset's EXRs must carry the diffuse-colour pass, simulated datasets since
2026-11-24): the learned albedo composited like an image (the albedo of every Gaussian through the rasterizer, at the
training resolution) against the EXR's albedo pass area-averaged to that size, on the pixels whose true albedo is
above 0.02 (mean over channels). Prints k, the median of learned / true over those pixels where the learned albedo is
below 0.9 in every channel; the share of those pixels that k × the truth puts above 1 in some channel (what the cap
flattens); the share rendered at the cap (above 0.95 in some channel); and the spread (standard deviation) of
log(learned / true) where below the cap. docs/results.md ("The albedo's cap and the light's unit") quotes it.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
import torch
import torch.nn.functional as F

from spotlessgs.io.exr import read_frame_exr
from spotlessgs.rasterizer import rasterize
from spotlessgs.training.trainer import load_run

#: Pixels whose true albedo (mean over channels) is below this are left out (lamps' emitters, black gaps).
MIN_TRUE_ALBEDO = 0.02
#: Learned albedo below this in every channel: clear of the cap (the pixels k is measured on).
BELOW_CAP = 0.9
#: Learned albedo above this in some channel: at the cap.
AT_CAP = 0.95


@torch.no_grad()
def albedo_image(scene, camera) -> torch.Tensor:
    """The Gaussians' albedo composited for one view, (H, W, 3)."""
    g = scene.gaussians
    return rasterize(g.means, g.quats, g.scales, g.opacities, g.albedo, camera.viewmat, camera.K, camera.width,
                     camera.height).image


def albedo_scale_stats(learned: np.ndarray, true: np.ndarray) -> dict[str, float]:
    """From learned and true albedo of the same pixels, (P, 3) each: k, the share of pixels that k x the truth puts
    above 1 (``flattened``), the share at the cap (``at_cap``; both over the pixels with a true albedo), and the
    spread of log(learned / true) below the cap (module docstring)."""
    lit = true.mean(1) > MIN_TRUE_ALBEDO
    clear = lit & (learned.max(1) < BELOW_CAP)
    if not clear.any():
        raise ValueError("albedo_scale_stats: no pixel with a true albedo has a learned one below the cap")
    ratio = learned[clear].mean(1) / true[clear].mean(1)
    k = float(np.median(ratio))
    return {"k": k, "flattened": float(((k * true[lit]).max(1) > 1.0).mean()),
            "at_cap": float((learned[lit].max(1) > AT_CAP).mean()), "spread": float(np.std(np.log(ratio)))}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("runs", nargs="+", type=Path)
    parser.add_argument("--views", choices=("test", "train"), default="test")
    args = parser.parse_args()
    torch.set_num_threads(2)
    for run in args.runs:
        scene, views, _config, _info = load_run(run, device="cpu")
        if scene.appearance.light is None:
            raise SystemExit(f"{run}: a 3DGS run has no albedo")
        if not all(camera.is_pinhole for camera in views.dataset.distinct_cameras()):
            raise SystemExit(f"{run}: its dataset's lens is distorted; the EXR passes are in the distorted image, "
                             "not in the working camera this script renders")
        learned, true = [], []
        for k in views.test if args.views == "test" else views.train:
            exr = views.dataset.exr_paths[k]
            albedo = None if exr is None else read_frame_exr(exr).albedo
            if albedo is None:
                raise SystemExit(f"{run}: frame {views.names[k]} has no EXR with a diffuse-colour pass")
            image = albedo_image(scene, views.cameras[k])
            truth = torch.from_numpy(np.ascontiguousarray(albedo, dtype=np.float32)).permute(2, 0, 1)[None]
            truth = F.adaptive_avg_pool2d(truth, tuple(image.shape[:2]))[0].permute(1, 2, 0)
            learned.append(image.reshape(-1, 3).numpy())
            true.append(truth.reshape(-1, 3).numpy())
        stats = albedo_scale_stats(np.concatenate(learned), np.concatenate(true))
        print(f"{run}: k {stats['k']:.2f}, k x truth above 1 on {100 * stats['flattened']:.1f} % of the pixels, at "
              f"the cap {100 * stats['at_cap']:.1f} %, spread of log(learned / true) {stats['spread']:.3f}")


if __name__ == "__main__":
    main()
