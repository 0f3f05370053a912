"""How far in front of (or behind) the true surfaces a trained model's Gaussians sit, as the views see them.

    python3 scripts/depth_bias.py RUN [RUN ...]

RUN is a run folder trained on a dataset of ``spotless-sim render`` (its EXRs hold the true planar depth). For every
third view, the model's depth (the rasterizer's compositing-weighted mean depth of the Gaussians along each pixel's
ray: the depth at which the pixel's colour is shaded, so the distance the spotlight's fall-off sees) is divided by the
true depth at the pixels the model covers (accumulated opacity above 0.95) away from depth edges (true depth within
5 % over each 3x3 neighbourhood). Prints the median, mean and quartiles of that ratio. The figures of
docs/results.md ("What limits the learned lamp's position") came from this command.
"""

from __future__ import annotations

import argparse

import numpy as np
import torch
from scipy.ndimage import maximum_filter, minimum_filter

from spotlessgs.io.exr import read_frame_exr
from spotlessgs.training.trainer import load_run

#: Pixels count where the model's accumulated opacity exceeds this and the true depth varies less than EDGE_RATIO.
MIN_ALPHA = 0.95
EDGE_RATIO = 1.05


def depth_ratios(run: str) -> np.ndarray:
    """(M,) model depth / true depth over the counted pixels of every third view of ``run``."""
    scene, views, _config, _info = load_run(run, device="cpu")
    ratios = []
    with torch.no_grad():
        for index in range(0, len(views.names), 3):
            exr = views.dataset.exr_paths[index]
            if exr is None:
                raise SystemExit(f"{views.dataset.source}: frame {index} has no EXR (no true depth)")
            true = read_frame_exr(exr).depth
            out = scene.render(views.cameras[index])
            model, alpha = out.depth.numpy(), out.alpha.numpy()
            if model.shape != true.shape:
                raise SystemExit(f"{run}: trained at {model.shape[1]}x{model.shape[0]}, the EXRs are "
                                 f"{true.shape[1]}x{true.shape[0]}: the ratio needs the dataset's own size")
            finite = np.isfinite(true) & (true > 0)
            safe = np.where(finite, true, 1.0)
            smooth = maximum_filter(safe, 3) / minimum_filter(safe, 3) < EDGE_RATIO
            keep = finite & smooth & (alpha > MIN_ALPHA)
            ratios.append(model[keep] / true[keep])
    return np.concatenate(ratios)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("runs", nargs="+", help="run folders trained on rendered datasets")
    args = parser.parse_args()
    for run in args.runs:
        ratio = depth_ratios(run)
        if ratio.size == 0:
            print(f"{run}: no pixel to compare")
            continue
        q25, q50, q75 = np.percentile(ratio, [25, 50, 75])
        print(f"{run}: model depth / true depth median {q50:.4f}, mean {ratio.mean():.4f}, quartiles {q25:.4f} / "
              f"{q75:.4f} ({ratio.size} pixels)")


if __name__ == "__main__":
    main()
