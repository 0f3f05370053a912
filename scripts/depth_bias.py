"""How far in front of (or behind) the true surfaces a trained model's Gaussians sit, as the views see them.

    python3 scripts/depth_bias.py RUN [RUN ...]

RUN is a run folder trained on a dataset of ``spotless-sim render`` (its EXRs hold the true planar depth). For every
third view, the model's depth (the rasterizer's compositing-weighted mean depth of the Gaussians along each pixel's
ray: the depth at which the pixel's colour is shaded, so the distance the spotlight's fall-off sees) is divided by the
true depth at the pixels the model covers (accumulated opacity above 0.95) away from depth edges (true depth within
5 % over each 3x3 neighbourhood). Prints the median, mean and quartiles of that ratio, the median difference in
centimetres by true depth, and the median spread of the Gaussians' depths along a pixel's ray (standard deviation over
mean: RelightableScene.render_with_depth_moments, losses.ray_depth_statistics). The figures of docs/results.md ("What
limits the learned lamp's position") came from this command.
"""

from __future__ import annotations

import argparse

import numpy as np
import torch
from scipy.ndimage import maximum_filter, minimum_filter

from spotlessgs.io.exr import read_frame_exr
from spotlessgs.training.losses import ray_depth_statistics
from spotlessgs.training.trainer import load_run

#: Pixels count where the model's accumulated opacity exceeds this and the true depth varies less than EDGE_RATIO.
MIN_ALPHA = 0.95
EDGE_RATIO = 1.05
#: True-depth bands (metres) of the difference's breakdown.
DEPTH_BANDS = ((0.0, 1.5), (1.5, 2.5), (2.5, 3.5), (3.5, 4.5), (4.5, float("inf")))


def depth_comparison(run: str) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Over the counted pixels of every third view of ``run``: the model's depth (M,), the true depth (M,), and the
    spread of the Gaussians' depths along the pixel's ray, standard deviation over mean (M,)."""
    scene, views, _config, _info = load_run(run, device="cpu")
    model_depths, true_depths, spreads = [], [], []
    with torch.no_grad():
        for index in range(0, len(views.names), 3):
            exr = views.dataset.exr_paths[index]
            if exr is None:
                raise SystemExit(f"{views.dataset.source}: frame {index} has no EXR (no true depth)")
            true = read_frame_exr(exr).depth
            out, moments = scene.render_with_depth_moments(views.cameras[index])
            model, alpha = out.depth.numpy(), out.alpha.numpy()
            if model.shape != true.shape:
                raise SystemExit(f"{run}: trained at {model.shape[1]}x{model.shape[0]}, the EXRs are "
                                 f"{true.shape[1]}x{true.shape[0]}: the ratio needs the dataset's own size")
            finite = np.isfinite(true) & (true > 0)
            safe = np.where(finite, true, 1.0)
            smooth = maximum_filter(safe, 3) / minimum_filter(safe, 3) < EDGE_RATIO
            keep = finite & smooth & (alpha > MIN_ALPHA)
            mean, variance = ray_depth_statistics(moments, out.alpha, torch.from_numpy(keep))
            model_depths.append(model[keep])
            true_depths.append(true[keep])
            spreads.append((variance.sqrt() / mean).numpy())
    return np.concatenate(model_depths), np.concatenate(true_depths), np.concatenate(spreads)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("runs", nargs="+", help="run folders trained on rendered datasets")
    args = parser.parse_args()
    for run in args.runs:
        model, true, spread = depth_comparison(run)
        if model.size == 0:
            print(f"{run}: no pixel to compare")
            continue
        ratio = model / true
        q25, q50, q75 = np.percentile(ratio, [25, 50, 75])
        print(f"{run}: model depth / true depth median {q50:.4f}, mean {ratio.mean():.4f}, quartiles {q25:.4f} / "
              f"{q75:.4f} ({ratio.size} pixels); depth spread along a ray (std / mean) median {np.median(spread):.3f}")
        bands = []
        for low, high in DEPTH_BANDS:
            band = (true >= low) & (true < high)
            if band.any():
                bands.append(f"{low:g}-{high:g} m: {100 * np.median(model[band] - true[band]):+.1f} cm")
        print("  model - true depth, median by true depth: " + ", ".join(bands))

if __name__ == "__main__":
    main()
