"""What pose refinement costs per training step, measured in one process so that the machine's load is shared alike.

    spotless benchmark poses --data DATA --out bench/poses --rows clean
    python3 scripts/pose_step_cost.py bench/poses/clean/run

The run's final model (the quick preset: about 20k Gaussians, 160×120) is trained on for 8 interleaved blocks of 25
steps in each mode: ``off`` (the dataset's poses), ``refine`` (the view's correction in the render, the refinement's
texture term and penalty, the lazy SparseAdam step: what a step costs after ``pose_refine_from``), and
``refine-torch-projection`` (the same through the torch projection, which differentiates the view matrix itself:
what the C++ path's camera gradient, spotlessgs/rasterizer/camera_grad.py, saves). Prints the median and minimum
CPU time (this process, one thread) and wall time per step of each mode.
"""

from __future__ import annotations

import argparse
import contextlib
import time
from typing import Iterator

import torch

import spotlessgs.rasterizer.api as raster_api

from spotlessgs.models.pose import PoseCorrection, corrected_camera
from spotlessgs.training.losses import photometric_loss, pose_refinement_terms
from spotlessgs.training.trainer import build_optimizers, load_run, pose_optimizer

MODES = ("off", "refine", "refine-torch-projection")


@contextlib.contextmanager
def torch_projection() -> Iterator[None]:
    """The rasterizer without its camera-gradient path: a view matrix that requires a gradient goes through the torch
    projection (the compositing stays C++)."""
    real = raster_api.camera_motion_on_gaussians
    raster_api.camera_motion_on_gaussians = lambda means, quats, viewmat: (means, quats, viewmat)
    try:
        yield
    finally:
        raster_api.camera_motion_on_gaussians = real


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("run")
    parser.add_argument("--blocks", type=int, default=8)
    parser.add_argument("--steps", type=int, default=25)
    args = parser.parse_args()
    torch.set_num_threads(1)
    scene, views, config, _info = load_run(args.run, device="cpu")
    scene.train()
    poses = PoseCorrection(len(views.names))
    opts = build_optimizers(scene, config, views.scene_extent(), None)
    opts["pose"] = pose_optimizer(poses, config)

    def step(k: int, mode: str) -> None:
        row = poses.row(k) if mode != "off" else None
        camera = views.cameras[k] if row is None else corrected_camera(views.cameras[k], row)
        with torch_projection() if mode == "refine-torch-projection" else contextlib.nullcontext():
            out = scene.render(camera, backend=config.raster_backend, num_threads=1)
        loss = photometric_loss(out.image, views.images[k], views.saturated[k], config.ssim_lambda)[0]
        if row is not None:
            loss = loss + pose_refinement_terms(out.image, views.images[k], views.saturated[k], row,
                                                config.pose_texture_weight, config.pose_penalty)
        loss.backward()
        for opt in opts.values():
            opt.step()
            opt.zero_grad(set_to_none=True)

    times: dict[str, list[tuple[float, float]]] = {m: [] for m in MODES}
    for block in range(args.blocks):
        for mode in MODES if block % 2 == 0 else MODES[::-1]:
            cpu, wall = time.process_time(), time.perf_counter()
            for i in range(args.steps):
                step(views.train[(block * args.steps + i) % len(views.train)], mode)
            times[mode].append((1000 * (time.process_time() - cpu) / args.steps,
                                1000 * (time.perf_counter() - wall) / args.steps))
    for mode, values in times.items():
        cpu, wall = sorted(v[0] for v in values), sorted(v[1] for v in values)
        print(f"{mode:24s} CPU {cpu[len(cpu) // 2]:.1f} ms/step (min {cpu[0]:.1f}), wall {wall[len(wall) // 2]:.1f} "
              f"(min {wall[0]:.1f}); {len(scene.gaussians)} Gaussians, {views.cameras.width}x{views.cameras.height}")


if __name__ == "__main__":
    main()
