"""Where a relighting's error lies on a rendered room: on its metals or on the rest (or on its floor, ceiling and
walls), against the uniform ground truth.

    python3 scripts/relit_error_by_material.py DATA RUN/relit_test [RUN2/relit_test ...] [--by metal|surface]

DATA is a dataset of ``spotless-sim render --gt uniform``; each folder holds relit test views named like its images
(``spotless benchmark models`` writes them to ``RUN/relit_test``; ``spotless relight RUN --views test``). The
predictions are exposure-aligned as ``spotless eval`` aligns them (one linear-light gain for the sequence,
evaluation.alignment). A pixel counts as metal where the renderer's diffuse colour (the EXR's albedo pass) is below
0.03 in every channel's mean and the uniform ground truth above 0.15 (sRGB): a surface that reflects even light but
has no diffuse colour. Prints the metals' share of the pixels and the uniform ground truth's mean on them and on the
rest (sRGB), then per folder the PSNR of the squared error pooled over the views, the metals' share of that error, the
PSNR were the metals exact, and the mean aligned prediction on the metals and on the rest. The figures of
docs/results.md ("The glossy room's metals") came from this command.

``--by surface`` splits the pixels by the EXR's world normal instead: floor (z > SURFACE_Z), ceiling (z < -SURFACE_Z)
and the rest (walls and the sides of objects), and prints per folder each part's share of the pixels and of the
squared error, its mean squared error, and the mean aligned prediction over the ground truth's mean there (sRGB)
(docs/results.md, "A bounce light from the model's geometry"). ``--by cone`` splits them by where the dataset's true
lamp puts the surface the pixel sees (the EXR's planar depth, through the camera's lens): inside its cone (angle off its axis
below half the cone angle) or outside it, where the spotlit input holds only the lamp's bounce light; pixels that see
no surface are left out (docs/results.md, "Where the glossy room's SpotlessGS loses against DarkGS").
"""

from __future__ import annotations

import argparse
import math

import numpy as np
import torch

from evaluation.alignment import apply_gain, exposure_gain
from evaluation.folders import read_named_images
from spotlessgs.io.cameras import Intrinsics
from spotlessgs.io.dataset import ground_truth_paths, read_dataset
from spotlessgs.io.exr import read_frame_exr
from spotlessgs.io.images import read_image
from spotlessgs.io.lens import camera_points
from spotlessgs.io.transforms import LightTruth

#: Diffuse colour below this (the mean over channels, linear) and uniform ground truth above METAL_MIN_GT (sRGB): metal.
METAL_MAX_DIFFUSE = 0.03
METAL_MIN_GT = 0.15
#: |world normal z| above this: a floor (facing up) or a ceiling (facing down).
SURFACE_Z = 0.8
SURFACES = ("floor", "ceiling", "walls and sides")
CONE_REGIONS = ("inside the lamp's cone", "outside it")


def surface_labels(normals: np.ndarray) -> np.ndarray:
    """(H, W) int: 0 floor, 1 ceiling, 2 the rest, from world normals (H, W, 3) (world z up)."""
    labels = np.full(normals.shape[:2], 2)
    labels[normals[..., 2] > SURFACE_Z] = 0
    labels[normals[..., 2] < -SURFACE_Z] = 1
    return labels


def cone_labels(depth: np.ndarray, intrinsics: Intrinsics, light: LightTruth) -> np.ndarray:
    """(H, W) int: 0 where the surface seen at a pixel lies inside the ``light``'s cone, 1 outside it, -1 where the
    planar ``depth`` (H, W) is not finite (no surface). Back-projected through the lens of ``intrinsics``."""
    finite = np.isfinite(depth)
    points = camera_points(intrinsics, np.where(finite, depth, 1.0))  # (H, W, 3), camera frame (OpenCV)
    to_surface = points - light.position_in_camera
    axis = light.rotation_in_camera[:, 2]
    cosine = (to_surface @ axis) / np.linalg.norm(to_surface, axis=-1)
    inside = cosine > math.cos(math.radians(light.cone_angle_deg) / 2.0)
    return np.where(finite, np.where(inside, 0, 1), -1)


def region_shares(error: np.ndarray, labels: np.ndarray, names: tuple[str, ...], aligned: np.ndarray,
                  gt: np.ndarray) -> list[tuple[str, float, float, float, float]]:
    """[(region, share of the pixels, share of the squared error, mean squared error, brightness ratio)] for
    per-pixel squared errors ``error`` (...) and region ``labels`` (...) of the same shape (region i named
    ``names[i]``; other labels in no region); the ratio is the mean ``aligned`` prediction over the mean ``gt``
    (both (..., 3)) in the region. Shares are of all pixels and of the whole error."""
    rows = []
    for i, name in enumerate(names):
        part = labels == i
        if not part.any():
            rows.append((name, 0.0, 0.0, float("nan"), float("nan")))
            continue
        rows.append((name, float(part.mean()), float(error[part].sum() / error.sum()), float(error[part].mean()),
                     float(aligned[part].mean() / gt[part].mean())))
    return rows


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("data", help="a dataset rendered with --gt uniform")
    parser.add_argument("relit", nargs="+", help="folders of relit test views")
    parser.add_argument("--by", choices=("metal", "surface", "cone"), default="metal",
                        help="split the pixels into metals and the rest (default), by surface orientation, or by "
                             "whether the true lamp's cone reaches the surface")
    args = parser.parse_args()
    dataset = read_dataset(args.data)
    uniform = ground_truth_paths(dataset, "uniform")
    views = list(dataset.split.test)
    if args.by == "cone" and dataset.light is None:
        raise SystemExit(f"{dataset.source}: --by cone needs the true lamp (a spotless-sim render)")
    gts, metal, regions = [], [], []
    for index in views:
        if uniform[index] is None or dataset.exr_paths[index] is None:
            raise SystemExit(f"{dataset.source}: frame {index} lacks its uniform ground truth or its EXR")
        gt = read_image(uniform[index])
        gts.append(gt)
        frame = read_frame_exr(dataset.exr_paths[index])
        if frame.albedo is None or frame.normal is None:
            raise SystemExit(f"{dataset.exr_paths[index]}: no diffuse colour or normal pass (rendered before "
                             "2026-11-24)")
        metal.append((frame.albedo.mean(-1) < METAL_MAX_DIFFUSE) & (gt.mean(-1) > METAL_MIN_GT))
        regions.append(cone_labels(frame.depth, dataset.cameras[index], dataset.light) if args.by == "cone"
                       else surface_labels(frame.normal))
    gt_all = torch.from_numpy(np.stack(gts)).double()
    metal_all = np.stack(metal)
    print(f"{args.data}: {len(views)} test views, metal {100 * metal_all.mean():.1f} % of the pixels "
          f"(uniform ground truth there {gt_all.numpy()[metal_all].mean():.3f}, elsewhere "
          f"{gt_all.numpy()[~metal_all].mean():.3f})")
    for folder in args.relit:
        try:
            pred = read_named_images(folder, [dataset.image_paths[i].name for i in views])
        except (FileNotFoundError, ValueError) as error:  # one line naming the missing or unreadable file
            raise SystemExit(str(error)) from None
        pred = torch.from_numpy(pred).double()
        aligned = apply_gain(pred, exposure_gain(pred, gt_all)).numpy()
        error = ((aligned - gt_all.numpy()) ** 2).mean(-1)
        if args.by != "metal":
            names = SURFACES if args.by == "surface" else CONE_REGIONS
            shares = region_shares(error, np.stack(regions), names, aligned, gt_all.numpy())
            print(f"{folder}: PSNR of the pooled aligned error {-10 * math.log10(error.mean()):.2f} dB; "
                  + "; ".join(f"{name} {100 * pixels:.0f} % of the pixels, {100 * share:.0f} % of the error, "
                              f"MSE {mse:.4f}, relit at {ratio:.3f} of the truth"
                              for name, pixels, share, mse, ratio in shares))
            continue
        print(f"{folder}: PSNR of the pooled aligned error {-10 * math.log10(error.mean()):.2f} dB; metal holds "
              f"{100 * error[metal_all].sum() / error.sum():.0f} % of the squared error (with exact metals "
              f"{-10 * math.log10(error[~metal_all].sum() / error.size):.2f} dB); relit metal "
              f"{aligned[metal_all].mean():.3f}, other {aligned[~metal_all].mean():.3f}")


if __name__ == "__main__":
    main()
