"""Where a relighting's error lies on a rendered room: on its metals or on the rest, against the uniform ground truth.

    python3 scripts/relit_error_by_material.py DATA RUN/relit_test [RUN2/relit_test ...]

DATA is a dataset of ``spotless-sim render --gt uniform``; each folder holds relit test views named like its images
(``spotless benchmark models`` writes them to ``RUN/relit_test``; ``spotless relight RUN --views test``). The
predictions are exposure-aligned as ``spotless eval`` aligns them (one linear-light gain for the sequence,
evaluation.alignment). A pixel counts as metal where the renderer's diffuse colour (the EXR's albedo pass) is below
0.03 in every channel's mean and the uniform ground truth above 0.15 (sRGB): a surface that reflects even light but
has no diffuse colour. Prints the metals' share of the pixels and the uniform ground truth's mean on them and on the
rest (sRGB), then per folder the PSNR of the squared error pooled over the views, the metals' share of that error, the
PSNR were the metals exact, and the mean aligned prediction on the metals and on the rest. The figures of
docs/results.md ("The glossy room's metals") came from this command.
"""

from __future__ import annotations

import argparse
import math

import numpy as np
import torch

from evaluation.alignment import apply_gain, exposure_gain
from evaluation.folders import read_named_images
from spotlessgs.io.dataset import ground_truth_paths, read_dataset
from spotlessgs.io.exr import read_frame_exr
from spotlessgs.io.images import read_image

#: Diffuse colour below this (the mean over channels, linear) and uniform ground truth above METAL_MIN_GT (sRGB): metal.
METAL_MAX_DIFFUSE = 0.03
METAL_MIN_GT = 0.15


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("data", help="a dataset rendered with --gt uniform")
    parser.add_argument("relit", nargs="+", help="folders of relit test views")
    args = parser.parse_args()
    dataset = read_dataset(args.data)
    uniform = ground_truth_paths(dataset, "uniform")
    views = list(dataset.split.test)
    gts, metal = [], []
    for index in views:
        if uniform[index] is None or dataset.exr_paths[index] is None:
            raise SystemExit(f"{dataset.source}: frame {index} lacks its uniform ground truth or its EXR")
        gt = read_image(uniform[index])
        gts.append(gt)
        diffuse = read_frame_exr(dataset.exr_paths[index]).albedo
        if diffuse is None:
            raise SystemExit(f"{dataset.exr_paths[index]}: no diffuse colour pass (rendered before 2026-11-24)")
        metal.append((diffuse.mean(-1) < METAL_MAX_DIFFUSE) & (gt.mean(-1) > METAL_MIN_GT))
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
        print(f"{folder}: PSNR of the pooled aligned error {-10 * math.log10(error.mean()):.2f} dB; metal holds "
              f"{100 * error[metal_all].sum() / error.sum():.0f} % of the squared error (with exact metals "
              f"{-10 * math.log10(error[~metal_all].sum() / error.size):.2f} dB); relit metal "
              f"{aligned[metal_all].mean():.3f}, other {aligned[~metal_all].mean():.3f}")


if __name__ == "__main__":
    main()
