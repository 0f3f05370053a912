"""Make a dataset the model explains exactly, with the lamp at its true pose: does training then find the lamp?

    python3 scripts/lamp_self_consistency.py RUN OUT [--physical-falloff]

RUN is a finished run trained at its dataset's own size on a ``spotless-sim render`` dataset (the dataset's
``transforms.json`` holds the true lamp). The run's model is kept as it is (Gaussians, albedo, normals, BRDF,
low-frequency light, the lamp's angular profile and fall-off) except the lamp's pose, which is set to the truth
(``--physical-falloff`` also sets the fall-off to the inverse square law, γ = 1, τ = the lamp's radius squared). Every
view is rendered with that model and written as 8-bit sRGB PNG in place of the frame of the same name in OUT, a copy of
the dataset folder (everything else, poses, points, ground truth and the light truth, unchanged), with
``self_consistency.json`` recording where the images came from.

Training on OUT from the usual start (the lamp at the camera centre) separates the causes of a lamp that ends away from
the truth: these images fit the model exactly with the lamp at the truth, so a lamp that still ends away is pulled
there by the optimisation (its regularisers, the angular profile's freedom, the schedule), not by a mismatch between the
model and Blender's light transport. docs/results.md ("What limits the learned lamp's position") came from this.
"""

from __future__ import annotations

import argparse
import math
import shutil
from pathlib import Path

import numpy as np
import torch

from spotlessgs.io.atomic import write_json
from spotlessgs.io.colorspace import linear_to_srgb
from spotlessgs.io.images import write_png
from spotlessgs.io.provenance import provenance
from spotlessgs.models.geometry import so3_log
from spotlessgs.training.trainer import load_run

#: τ (m²) of the inverse square law for a point lamp (radius 0): small against any squared distance in a room.
POINT_LAMP_TAU = 1e-4


def set_lamp_to_truth(scene, truth, physical_falloff: bool) -> None:
    """Move ``scene``'s spotlight to ``truth`` (a LightTruth); with ``physical_falloff`` its fall-off becomes 1/d²."""
    light = scene.appearance.light
    if light is None:
        raise SystemExit("the run's model has no spotlight")
    with torch.no_grad():
        light.translation.copy_(torch.tensor(np.array(truth.position_in_camera), dtype=light.translation.dtype))
        light.rotvec.copy_(torch.as_tensor(so3_log(truth.rotation_in_camera), dtype=light.rotvec.dtype))
        if physical_falloff:
            light.log_gamma.fill_(0.0)
            light.log_tau.fill_(math.log(max(truth.radius_m**2, POINT_LAMP_TAU)))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("run", type=Path, help="finished run folder on a rendered dataset")
    parser.add_argument("out", type=Path, help="new dataset folder (must not exist)")
    parser.add_argument("--physical-falloff", action="store_true", help="also set the fall-off to 1/d^2")
    args = parser.parse_args()
    if args.out.exists():
        raise SystemExit(f"{args.out}: exists; choose a new folder")
    scene, views, _config, info = load_run(args.run, device="cpu")
    if views.light is None:
        raise SystemExit(f"{views.dataset.source}: no light truth in transforms.json")
    for index, (native, image_path) in enumerate(zip(views.dataset.cameras, views.dataset.image_paths)):
        trained = views.cameras[index]
        if (trained.width, trained.height) != (native.width, native.height):
            raise SystemExit(f"{args.run}: trained at {trained.width}x{trained.height}, the dataset's frames are "
                             f"{native.width}x{native.height}: train at the dataset's own size")
        if Path(image_path).suffix.lower() != ".png":
            raise SystemExit(f"{image_path}: a PNG frame is expected (the copy keeps each frame's name)")
    set_lamp_to_truth(scene, views.light, args.physical_falloff)
    source = Path(views.dataset.root)
    partial = args.out.with_name(args.out.name + ".partial")
    if partial.exists():
        shutil.rmtree(partial)
    shutil.copytree(source, partial)
    with torch.no_grad():
        for index, image_path in enumerate(views.dataset.image_paths):
            image = scene.render(views.cameras[index]).image.clamp_min(0).numpy()
            write_png(partial / Path(image_path).relative_to(source), np.clip(linear_to_srgb(image), 0.0, 1.0))
    light = scene.appearance.light
    write_json(partial / "self_consistency.json", {
        "source_run": str(args.run.resolve()), "source_dataset": str(source.resolve()),
        "model": info.get("model"), "physical_falloff": args.physical_falloff,
        "lamp": {"position_in_camera_m": light.translation.tolist(), "rotvec": light.rotvec.tolist(),
                 "falloff_gamma": float(light.gamma.detach()), "falloff_tau_m2": float(light.tau.detach())},
        "provenance": provenance(),
    })
    partial.rename(args.out)
    print(f"{args.out}: {len(views.dataset.image_paths)} frames rendered with the lamp at the truth "
          f"(γ {float(light.gamma.detach()):.3f}, τ {float(light.tau.detach()):.4f} m²)")


if __name__ == "__main__":
    main()
