"""How far test-view alignment pulls a pose away from the truth, per alignment loss: the camera-mounted spotlight
moves with every pose hypothesis, which can bias a photometric comparison.

    spotless benchmark poses --data DATA --out bench/poses --rows clean      # a model trained on the true poses
    python3 scripts/pose_alignment_bias.py bench/poses/clean/run

For each test view of the run (whose dataset poses are the truth), and for each loss (``texture``, ``photometric``),
the alignment (spotlessgs.training.pose_alignment.align_view, the run's settings: steps and learning rate) starts
(a) at the true pose: where it ends is the loss's bias on this model; (b) at the true pose moved by 3 cm in a random
direction and turned by 0.3 degrees about a random axis (seeded): where it ends is what alignment achieves. Prints
one line per loss and start: the mean centre error (cm) and rotation error (degrees) before and after, over the test
views, and each view's. The figures of docs/results.md ("Camera pose refinement") came from this command.
"""

from __future__ import annotations

import argparse
import math
import time

import numpy as np
import torch

from spotlessgs.io.camera_batch import Cameras
from spotlessgs.io.cameras import axis_angle_to_matrix
from spotlessgs.io.seeding import numpy_rng
from spotlessgs.models.pose import correction_matrix, rotation_angle_deg
from spotlessgs.training.pose_alignment import align_view
from spotlessgs.training.trainer import load_run


def _error(c2w: np.ndarray, true: np.ndarray) -> tuple[float, float]:
    """(centre error in cm, rotation error in degrees) of a camera-to-world pose (4, 4) against the truth."""
    rotation = float(rotation_angle_deg(torch.from_numpy(c2w[:3, :3].T @ true[:3, :3])))
    return 100.0 * float(np.linalg.norm(c2w[:3, 3] - true[:3, 3])), rotation


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("run", help="a run trained on the dataset's true poses")
    parser.add_argument("--losses", default="texture,photometric")
    parser.add_argument("--translation-cm", type=float, default=3.0)
    parser.add_argument("--rotation-deg", type=float, default=0.3)
    parser.add_argument("--seed", type=int, default=7)
    parser.add_argument("--threads", type=int, default=1)
    args = parser.parse_args()
    torch.set_num_threads(args.threads)
    scene, views, config, _info = load_run(args.run, device="cpu")
    rng = numpy_rng(args.seed, "alignment-bias")
    starts = {}
    for k in views.test:
        true = views.cameras.c2w[k].double().numpy()
        moved = true.copy()
        direction, axis = rng.normal(size=3), rng.normal(size=3)
        moved[:3, 3] += args.translation_cm / 100.0 * direction / np.linalg.norm(direction)
        turn = axis_angle_to_matrix(math.radians(args.rotation_deg) * axis / np.linalg.norm(axis))
        moved[:3, :3] = turn @ true[:3, :3]
        starts[k] = {"true": true, "moved": moved}
    for loss in args.losses.split(","):
        settings = config.replace(pose_align_loss=loss, num_threads=args.threads)
        for start in ("true", "moved"):
            t0 = time.perf_counter()
            rows = []
            for k in views.test:
                true, given = starts[k]["true"], starts[k][start]
                camera = Cameras(torch.tensor(given, dtype=torch.float32), views.cameras.camera(k))
                unseen = None if views.unseen is None else views.unseen[k]
                aligned = align_view(scene, camera, k, views.images[k], views.saturated[k], settings, unseen)
                final = given @ correction_matrix(aligned.delta.double()).numpy()
                rows.append((_error(given, true), _error(final, true)))
            before, after = np.mean([r[0] for r in rows], axis=0), np.mean([r[1] for r in rows], axis=0)
            views_after = ", ".join(f"{r[1][0]:.2f} cm / {r[1][1]:.3f}°" for r in rows)
            print(f"{loss:11s} start {start:5s}: {before[0]:.2f} cm / {before[1]:.3f}° -> {after[0]:.2f} cm / "
                  f"{after[1]:.3f}° ({settings.pose_align_steps} steps at {settings.pose_align_lr:g}, "
                  f"{time.perf_counter() - t0:.1f} s; per view {views_after})", flush=True)


if __name__ == "__main__":
    main()
