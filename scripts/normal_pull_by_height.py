"""Which way the photometric loss turns a run's wall normals, by height in the room, and through which light.

    python3 scripts/normal_pull_by_height.py RUN [RUN ...] [--every 2]

For every ``--every``-th training view the run's render is scored with the training loss (``losses.photometric_loss``)
and its gradient with respect to every Gaussian's raw normal is summed over the views. Per height band of HEIGHT_BAND
metres, on the Gaussians whose normal is within 17° of horizontal (walls and objects' sides), it prints the summed
descent direction's world z after projection on each normal's tangent plane (positive: the loss turns the normals up),
once with every path and once with the low-frequency light's path cut (``ModelConfig.low_frequency_turns_normals``
false); their difference is what the SH light and the SH bounce light pull. On a run whose normals were held at the
true ones (``--set lr_normals=0`` on a simulator room) this is the pull that tilts learned normals towards the
camera's height. docs/results.md ("A bounce light from the model's geometry") quotes it.
"""

from __future__ import annotations

import argparse
import dataclasses
from pathlib import Path

import numpy as np
import torch

from spotlessgs.training.losses import photometric_loss
from spotlessgs.training.trainer import load_run

#: Height bands (metres).
HEIGHT_BAND = 0.4
#: |normal z| below this: a wall's or an object's side.
MAX_VERTICAL_NORMAL = 0.3
#: Bands with fewer Gaussians than this are left out.
MIN_BAND_GAUSSIANS = 50


def descent_z_by_band(gradient: np.ndarray, normals: np.ndarray, heights: np.ndarray) -> list[tuple[float, float]]:
    """[(band's lower edge (m), Σ z of the tangent descent direction)] over the near-horizontal ``normals`` (N, 3)
    (unit, world frame) at ``heights`` (N,), of a loss ``gradient`` (N, 3) with respect to the normals."""
    descent = -gradient
    descent = descent - (descent * normals).sum(-1, keepdims=True) * normals
    side = np.abs(normals[:, 2]) < MAX_VERTICAL_NORMAL
    band = np.floor(heights / HEIGHT_BAND).astype(int)
    rows = []
    for b in np.unique(band[side]):
        chosen = side & (band == b)
        if chosen.sum() >= MIN_BAND_GAUSSIANS:
            rows.append((HEIGHT_BAND * b, float(descent[chosen, 2].sum())))
    return rows


def normal_gradient(scene, views, config, every: int) -> np.ndarray:
    """(N, 3) the training loss's gradient with respect to the raw normals, summed over every ``every``-th training
    view."""
    raw = scene.gaussians.params["normals_raw"]
    total = torch.zeros_like(raw)
    for k in list(views.train)[::every]:
        out = scene.render(views.cameras[k])
        loss, _ = photometric_loss(out.image, views.images[k], views.saturated[k], config.ssim_lambda,
                                   config.loss_space)
        raw.grad = None
        loss.backward()
        total += raw.grad
    raw.grad = None
    return total.numpy()


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("runs", nargs="+", type=Path)
    parser.add_argument("--every", type=int, default=2, help="every N-th training view (default 2)")
    args = parser.parse_args()
    torch.set_num_threads(2)
    for run in args.runs:
        scene, views, config, _info = load_run(run, device="cpu")
        if scene.appearance.light is None:
            raise SystemExit(f"{run}: needs a model with a spotlight (3DGS has no normals)")
        g = scene.gaussians
        with torch.no_grad():
            normals = torch.nn.functional.normalize(g.params["normals_raw"], dim=-1).numpy()
            heights = g.means[:, 2].numpy()
        every_path = descent_z_by_band(normal_gradient(scene, views, config, args.every), normals, heights)
        scene.config = dataclasses.replace(scene.config, low_frequency_turns_normals=False)
        without_low = descent_z_by_band(normal_gradient(scene, views, config, args.every), normals, heights)
        print(f"{run}: height (m) | summed descent z ×1e3 on walls: every path / without the low-frequency light's "
              "/ the low-frequency light's own")
        for (low, full), (_, cut) in zip(every_path, without_low):
            print(f"  {low:.1f}: {1e3 * full:+.2f} / {1e3 * cut:+.2f} / {1e3 * (full - cut):+.2f}")


if __name__ == "__main__":
    main()
