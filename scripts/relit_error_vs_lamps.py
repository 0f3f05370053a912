"""How much of a relighting's error looks like the room's own lamps: what the lamps-on ground truth rewards.

    python3 scripts/relit_error_vs_lamps.py DATA RUN/relit_test [RUN2/relit_test ...]

DATA is a dataset of ``spotless-sim render --gt uniform`` (both ground truths, EXRs with depth, normals and the
emission pass); each folder holds relit test views named like its images (``spotless benchmark models`` writes them
to ``RUN/relit_test``). The lamps-on ground truth is the uniform one times the room lamps' light: their fall-off,
shadows and bounce, a field ``F = lin(lamps-on) / lin(uniform)`` per pixel (mean over channels). A relighting whose
error ``e = log(lin(relit) / lin(uniform))`` leans toward ``log F`` scores better against the lamps-on ground truth
without being closer to the scene's albedo.

On the pixels that are not emitters, whose uniform ground truth is above 0.02 and lamps-on and relit values above
0.002 (linear), pooled over the test views, per folder (predictions exposure-aligned like ``spotless eval``, one
linear-light gain per ground truth): the correlation of ``e`` with ``log F``; the joint least-squares slopes of ``e``
on ``log F``, the log of the depth and the log of the uniform ground truth (so that the lamps' part is not depth's
or albedo's); the mean ``e`` and the mean squared error (sRGB, × 1000) against each ground truth on the thirds of
those pixels that ``F`` ranks darkest, middle and brightest, walls and objects only (normals within 25° of
horizontal; the ceiling's and floor's terciles differ by construction); and the aligned PSNR against the lamps-on
ground truth before and after dividing the relit views by ``F`` to the power of the lamps' slope (the error's
lamps-like part removed). On walls and objects, where ``F`` is mostly the height in the room (lamps on the ceiling):
the slopes on ``log F`` and the surface's height (world z, metres; the simulator's rooms are z-up) together, and the
mean ``e`` and ``log F`` (each less its mean) in height bands of HEIGHT_BAND metres. docs/results.md ("What the
lamps-on ground truth rewards") quotes it.
"""

from __future__ import annotations

import argparse
import math

import numpy as np
import torch

from evaluation.alignment import apply_gain, exposure_gain
from evaluation.folders import read_named_images
from spotlessgs.io.colorspace import linear_to_srgb, srgb_to_linear
from spotlessgs.io.dataset import ground_truth_paths, read_dataset
from spotlessgs.io.exr import read_frame_exr
from spotlessgs.io.images import read_image
from spotlessgs.io.lens import camera_points

#: Uniform ground truth (linear, mean over channels) below this: left out (black gaps, near-black surfaces).
MIN_UNIFORM = 0.02
#: Lamps-on ground truth or relit value (linear) below this: left out (the log is noise there).
MIN_VALUE = 0.002
#: |normal z| below this: a wall's or an object's side (world z up).
MAX_VERTICAL_NORMAL = math.sin(math.radians(25.0))
#: Height bands (metres) of the error-by-height table.
HEIGHT_BAND = 0.4


def luminance(srgb: np.ndarray) -> np.ndarray:
    """(..., 3) sRGB in [0, 1] → (...) linear light, the mean over channels."""
    return srgb_to_linear(srgb.astype(np.float64)).mean(-1)


def psnr(pred: np.ndarray, gt: np.ndarray) -> float:
    """PSNR of the pooled squared error of (N, H, W, 3) sRGB stacks, exposure-aligned."""
    p, g = torch.from_numpy(pred).double(), torch.from_numpy(gt).double()
    aligned = apply_gain(p, exposure_gain(p, g))
    return -10.0 * math.log10(float(((aligned - g) ** 2).mean()))


def world_height(dataset, index: int, depth: np.ndarray) -> np.ndarray:
    """(H, W) world z of each pixel's surface, from the frame's planar depth (H, W) through its camera, lens
    included (pixel centres at +0.5)."""
    c2w = dataset.c2w_opencv[index]
    return camera_points(dataset.cameras[index], depth) @ c2w[2, :3] + c2w[2, 3]


def lamps_like_error(pred: np.ndarray, lamps: np.ndarray, uniform: np.ndarray, depth: np.ndarray, side: np.ndarray,
                     emitter: np.ndarray, height: np.ndarray | None = None) -> dict:
    """The relit views' error against the lamps' field (see the module docstring).

    Args:
        pred, lamps, uniform: (N, H, W, 3) sRGB in [0, 1]: relit views and the two ground truths.
        depth: (N, H, W) metres; side: (N, H, W) bool, walls and objects; emitter: (N, H, W) bool.
        height: (N, H, W) world z in metres, or None (no height figures).

    Returns:
        ``corr``, ``slopes`` (log F, log depth, log albedo), ``thirds`` (darkest, middle, brightest third of F on
        the walls: mean e, MSE against the lamps-on and the uniform ground truth), ``psnr_lamps``,
        ``psnr_lamps_removed``, ``psnr_uniform``; with ``height`` also ``wall_slopes`` (log F, height on the
        walls) and ``bands`` (lower edge, mean e, mean log F on the walls, each less its mean over the walls).
    """
    lin_uniform, lin_lamps, lin_pred = luminance(uniform), luminance(lamps), luminance(pred)
    mask = (~emitter & (lin_uniform > MIN_UNIFORM) & (lin_lamps > MIN_VALUE) & (lin_pred > MIN_VALUE)
            & np.isfinite(depth) & (depth > 0))
    e = np.log(lin_pred[mask] / lin_uniform[mask])
    e -= e.mean()
    f = np.log(lin_lamps[mask] / lin_uniform[mask])
    f -= f.mean()
    covariates = np.stack([f, np.log(depth[mask]), np.log(lin_uniform[mask])], 1)
    covariates -= covariates.mean(0)
    slopes = np.linalg.lstsq(covariates, e, rcond=None)[0]
    squared = {}
    for name, gt in (("lamps", lamps), ("uniform", uniform)):
        p, g = torch.from_numpy(pred).double(), torch.from_numpy(gt).double()
        squared[name] = ((apply_gain(p, exposure_gain(p, g)) - g) ** 2).numpy().mean(-1)[mask]
    walls = side[mask]
    rank = np.digitize(f, np.quantile(f[walls], [1 / 3, 2 / 3]))
    thirds = []
    for third in range(3):
        chosen = walls & (rank == third)
        thirds.append((float(e[chosen].mean()), float(squared["lamps"][chosen].mean()),
                       float(squared["uniform"][chosen].mean())))
    removed = srgb_to_linear(pred.astype(np.float64))
    removed[mask] *= np.exp(-slopes[0] * f)[:, None]
    result = {"corr": float(np.corrcoef(e, f)[0, 1]), "slopes": tuple(float(x) for x in slopes), "thirds": thirds,
              "psnr_lamps": psnr(pred, lamps), "psnr_lamps_removed": psnr(linear_to_srgb(removed), lamps),
              "psnr_uniform": psnr(pred, uniform)}
    if height is not None:
        e_wall, f_wall, h_wall = e[walls] - e[walls].mean(), f[walls] - f[walls].mean(), height[mask][walls]
        on_walls = np.stack([f_wall, h_wall - h_wall.mean()], 1)
        result["wall_slopes"] = tuple(float(x) for x in np.linalg.lstsq(on_walls, e_wall, rcond=None)[0])
        band = np.floor(h_wall / HEIGHT_BAND).astype(int)
        result["bands"] = [(HEIGHT_BAND * b, float(e_wall[band == b].mean()), float(f_wall[band == b].mean()))
                           for b in np.unique(band) if (band == b).sum() >= 100]
    return result


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("data", help="a dataset rendered with --gt uniform")
    parser.add_argument("relit", nargs="+", help="folders of relit test views")
    args = parser.parse_args()
    dataset = read_dataset(args.data)
    uniform_paths, lamps_paths = ground_truth_paths(dataset, "uniform"), ground_truth_paths(dataset, "lamps")
    views = list(dataset.split.test)
    uniform, lamps, depth, side, emitter, height = [], [], [], [], [], []
    for index in views:
        if uniform_paths[index] is None or dataset.exr_paths[index] is None:
            raise SystemExit(f"{dataset.source}: frame {index} lacks its uniform ground truth or its EXR")
        frame = read_frame_exr(dataset.exr_paths[index])
        if frame.emission is None or frame.normal is None or frame.depth is None:
            raise SystemExit(f"{dataset.exr_paths[index]}: needs the depth, normal and emission passes")
        uniform.append(read_image(uniform_paths[index]))
        lamps.append(read_image(lamps_paths[index]))
        depth.append(frame.depth)
        height.append(world_height(dataset, index, depth[-1]))
        side.append(np.abs(frame.normal[..., 2]) < MAX_VERTICAL_NORMAL)
        emitter.append(frame.emitters())
    uniform, lamps, depth, side, emitter, height = map(np.stack, (uniform, lamps, depth, side, emitter, height))
    print(f"{args.data}: {len(views)} test views")
    for folder in args.relit:
        try:
            pred = read_named_images(folder, [dataset.image_paths[i].name for i in views])
        except (FileNotFoundError, ValueError) as error:  # one line naming the missing or unreadable file
            raise SystemExit(str(error)) from None
        r = lamps_like_error(pred, lamps, uniform, depth, side, emitter, height)
        thirds = "; ".join(f"{label} third of F: e {e:+.3f}, MSE lamps-on {1e3 * lamp:.2f} uniform {1e3 * uni:.2f}"
                           for label, (e, lamp, uni) in zip(("darkest", "middle", "brightest"), r["thirds"]))
        print(f"{folder}: corr(e, log F) {r['corr']:+.3f}; slopes on log F {r['slopes'][0]:+.3f}, log depth "
              f"{r['slopes'][1]:+.3f}, log albedo {r['slopes'][2]:+.3f}\n    walls and objects: {thirds}\n"
              f"    PSNR lamps-on {r['psnr_lamps']:.2f} dB, the lamps-like part removed {r['psnr_lamps_removed']:.2f} "
              f"dB; uniform {r['psnr_uniform']:.2f} dB")
        bands = " ".join(f"{low:.1f}: {e:+.3f} / {f:+.2f}" for low, e, f in r["bands"])
        print(f"    walls and objects: slopes on log F {r['wall_slopes'][0]:+.3f} and height {r['wall_slopes'][1]:+.3f}"
              f" per metre; by height (m): e / log F {bands}")


if __name__ == "__main__":
    main()
