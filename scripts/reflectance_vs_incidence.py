"""How Lambertian a rendered room is under its lamp: the input over the Lambertian prediction, by cosine of incidence.

    python3 scripts/reflectance_vs_incidence.py DATA [--every 4]

DATA: a simulator render with direct light only (``spotless-sim render --bounces 0``: no indirect light to separate),
EXRs with depth, normals and the diffuse-colour pass, its true lamp in transforms.json, a pinhole camera. For every
``--every``-th training view, on the pixels above the 30th percentile of the prediction: the linear input divided by
the true diffuse colour × cone profile × cos of incidence / distance² (``evaluation.lamp_light.true_direct_light``),
normalised by its median where the cosine exceeds 0.9, and its median per cosine bin of 0.1. A Lambertian room gives
1 in every bin; a surface brighter than Lambert at grazing light (a rough or glossy one lit from the camera) gives more
at low cosines. docs/results.md ("A bounce light from the model's geometry") quotes it.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from evaluation.lamp_light import true_direct_light
from spotlessgs.io.dataset import read_dataset
from spotlessgs.io.exr import read_frame_exr
from spotlessgs.io.lens import camera_points

#: Width of a cosine bin.
COSINE_BIN = 0.1
#: Bins with fewer pixels than this are left out.
MIN_BIN_PIXELS = 100


def ratio_by_cosine(cosine: np.ndarray, ratio: np.ndarray) -> list[tuple[float, float, int]]:
    """[(bin's lower edge, median of ``ratio`` / its median where the cosine > 0.9, pixels)] per cosine bin, from
    per-pixel cosines of incidence (P,) and input / prediction ratios (P,)."""
    ratio = ratio / np.median(ratio[cosine > 0.9])
    rows = []
    for low in np.arange(0.0, 1.0, COSINE_BIN):
        chosen = (cosine >= low) & (cosine < low + COSINE_BIN)
        if chosen.sum() >= MIN_BIN_PIXELS:
            rows.append((float(low), float(np.median(ratio[chosen])), int(chosen.sum())))
    return rows


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("data", type=Path)
    parser.add_argument("--every", type=int, default=4, help="every N-th training view (default 4)")
    args = parser.parse_args()
    dataset = read_dataset(args.data)
    if dataset.light is None:
        raise SystemExit(f"{args.data}: needs its true lamp in transforms.json")
    cosines, ratios = [], []
    for k in list(dataset.split.train)[:: args.every]:
        frame = None if dataset.exr_paths[k] is None else read_frame_exr(dataset.exr_paths[k])
        if frame is None or frame.albedo is None or frame.normal is None or frame.depth is None:
            raise SystemExit(f"{args.data}: frame {k} has no EXR with depth, normals and diffuse colour")
        c2w = dataset.c2w_opencv[k]
        points = camera_points(dataset.cameras[k], frame.depth)
        normals = frame.normal @ c2w[:3, :3]
        diffuse = frame.albedo.mean(-1)
        predicted = true_direct_light(points, normals, diffuse, dataset.light)
        to_point = points - np.asarray(dataset.light.position_in_camera, dtype=np.float64)
        cosine = np.abs((normals * to_point).sum(-1)) / np.maximum(np.linalg.norm(to_point, axis=-1), 1e-9)
        seen = np.isfinite(frame.depth) & (diffuse > 0.05)
        chosen = seen & (predicted > np.quantile(predicted[seen], 0.3))
        cosines.append(cosine[chosen])
        ratios.append(frame.uneven.mean(-1)[chosen] / predicted[chosen])
    print(f"{args.data}: cosine of incidence | input / Lambertian prediction (median, 1 at cos > 0.9) | pixels")
    for low, ratio, count in ratio_by_cosine(np.concatenate(cosines), np.concatenate(ratios)):
        print(f"  {low:.1f}-{low + COSINE_BIN:.1f}: {ratio:.3f} | {count}")


if __name__ == "__main__":
    main()
