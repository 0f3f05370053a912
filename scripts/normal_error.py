"""How far a trained model's normals are from the true surface normals, as the test views see them.

    python3 scripts/normal_error.py RUN [RUN ...]

RUN is a run folder trained on a dataset of ``spotless-sim render`` (its EXRs hold the true world normals; for a
distorted lens they are resampled into the training's pinhole working camera by their nearest sample). For every test
view the model's shading normals (as shading turns them, towards the camera) are composited like a colour and
normalised; at the pixels the model covers (accumulated opacity above MIN_ALPHA) that have a true normal, the angle
between the two (either sign of the true normal) is taken. The same for the normals of the surface the model's depth
map traces (the rasterizer's compositing-weighted depth, back-projected, its normals as an RGB-D start's:
``prepare.depth_points.surface_normals``): how well the learned geometry itself, not its shading normals, follows the
true surfaces. Prints the median and quartiles of each angle
over all counted pixels, and the share of pixels within 10° and 20°. docs/results.md ("A depth-normal consistency
term for sparse starts") quotes it.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
import torch

from spotlessgs.io.cameras import Intrinsics
from spotlessgs.io.exr import read_frame_exr
from spotlessgs.io.lens import camera_points, remap_nearest, undistort_maps, working_camera
from spotlessgs.prepare.depth_points import surface_normals
from spotlessgs.rasterizer import rasterize
from spotlessgs.training.trainer import load_run

#: Pixels count where the model's accumulated opacity exceeds this.
MIN_ALPHA = 0.95


def true_normals_in_view(exr_path: Path, native: Intrinsics, height: int, width: int) -> np.ndarray:
    """(H, W, 3) the EXR's world normals as the training camera (``height`` × ``width``, the working camera of the
    dataset's camera ``native``) sees them: resampled by nearest sample through a distorted lens."""
    normals = read_frame_exr(exr_path).normal
    if not native.is_pinhole:
        map_x, map_y, _ = undistort_maps(native, working_camera(native))
        normals = remap_nearest(normals, map_x, map_y)
    if normals.shape[:2] != (height, width):
        raise SystemExit(f"{exr_path}: the EXR's normals are {normals.shape[1]}x{normals.shape[0]}, the run trained "
                         f"at {width}x{height}: the comparison needs the dataset's own size")
    return normals


def _angles(normals: np.ndarray, true: np.ndarray, keep: np.ndarray) -> np.ndarray:
    """(M,) degrees between unit ``normals`` and ``true`` (H, W, 3) at the ``keep`` (H, W) pixels, either sign (NaN
    where ``normals`` is)."""
    return np.degrees(np.arccos(np.abs((normals[keep] * true[keep]).sum(-1)).clip(0.0, 1.0)))


def normal_angles(run: str) -> tuple[np.ndarray, np.ndarray]:
    """(M,) angles (degrees) between the model's composited normals and the true ones over the counted pixels of
    every test view of ``run``, and (M',) those of the normals of the model's depth map (its inner pixels)."""
    scene, views, _config, _info = load_run(run, device="cpu")
    g = scene.gaussians
    angles, depth_angles = [], []
    with torch.no_grad():
        for index in views.test:
            exr = views.dataset.exr_paths[index]
            if exr is None:
                raise SystemExit(f"{views.dataset.source}: frame {index} has no EXR (no true normals)")
            camera = views.cameras[index]
            out = rasterize(g.means, g.quats, g.scales, g.opacities, scene.camera_normals(camera.c2w),
                            camera.viewmat, camera.K, camera.width, camera.height)
            model = torch.nn.functional.normalize(out.image, dim=-1).numpy()  # camera frame
            world = true_normals_in_view(exr, views.dataset.cameras[index], camera.height, camera.width)
            true = world @ camera.c2w[:3, :3].double().numpy()  # into the camera frame
            keep = (out.alpha.numpy() > MIN_ALPHA) & (np.linalg.norm(true, axis=-1) > 0.5)
            if views.unseen is not None:
                keep &= ~views.unseen[index].numpy()
            angles.append(_angles(model, true, keep))
            from_depth = surface_normals(camera_points(views.cameras.camera(index), out.depth.numpy()))
            depth_angles.append(_angles(from_depth, true, keep & np.isfinite(from_depth).all(-1)))
    return np.concatenate(angles), np.concatenate(depth_angles)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("runs", nargs="+", help="run folders trained on rendered datasets")
    args = parser.parse_args()
    for run in args.runs:
        for what, angles in zip(("normals", "depth map's normals"), normal_angles(run)):
            if angles.size == 0:
                print(f"{run}: no pixel to compare")
                break
            q25, q50, q75 = np.percentile(angles, [25, 50, 75])
            print(f"{run}: {what}: error median {q50:.1f}°, quartiles {q25:.1f}° / {q75:.1f}°, within 10° "
                  f"{100 * np.mean(angles < 10):.0f} %, within 20° {100 * np.mean(angles < 20):.0f} % "
                  f"({angles.size} pixels)")


if __name__ == "__main__":
    main()
