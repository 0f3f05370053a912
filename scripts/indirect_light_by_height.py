"""How a run's low-frequency light compares with the true indirect light, by height in a rendered room.

    python3 scripts/indirect_light_by_height.py RUN [RUN ...] [--every 3]

For every ``--every``-th training view of the run's dataset (a simulator render: EXRs with depth, normals, the
diffuse-colour pass and the linear spotlit image; its true lamp in transforms.json; a pinhole camera), on walls and
objects (normals within 25° of horizontal, world z up):
- the true **direct** light of the lamp: diffuse colour × cone profile (``evaluation.lamp_light.true_direct_light``) × cosine of
  incidence / distance², times one gain, the median ratio of the spotlit image to it on the 20 % most directly lit
  pixels (the lamp's shadows are ignored); the **indirect** light is the spotlit image less that, at least 0;
- the run's render split into its spotlight and low-frequency parts (``RelightableScene.render(...,
  split_lights=True)``), and its albedo composited like an image;
- the one-bounce light that the true geometry gives (``models.lamp_bounce.one_bounce_irradiance`` of the true direct
  light at the EXR's depth and normals: what a bounce light computed from geometry can learn at best), and the world
  z of the run's normals composited like an image (walls: 0; a tilt towards the camera's height shows as a positive
  value low in the room and a negative one high up).

Per height band of HEIGHT_BAND metres: the indirect share of the spotlit image and the low-frequency share of the
run's render; the true indirect and the model's low-frequency irradiance (each divided by its albedo, the true or the
learned one), the true and the model's spotlight irradiance, the true geometry's one-bounce irradiance, each relative
to its mean over the pixels; the mean log of learned / true albedo less its median; and the learned normals' mean
world z. docs/results.md ("What the lamps-on ground truth rewards") quotes it.
"""

from __future__ import annotations

import argparse
import math
from pathlib import Path

import numpy as np
import torch

from evaluation.lamp_light import true_direct_light
from spotlessgs.io.exr import read_frame_exr
from spotlessgs.io.lens import camera_points
from spotlessgs.models.lamp_bounce import one_bounce_irradiance
from spotlessgs.rasterizer import rasterize
from spotlessgs.training.trainer import load_run

#: Height bands (metres).
HEIGHT_BAND = 0.4
#: |normal z| below this: a wall's or an object's side.
MAX_VERTICAL_NORMAL = math.sin(math.radians(25.0))
#: The direct light's gain is fitted on the pixels above this quantile of the (unscaled) direct light.
GAIN_QUANTILE = 0.8
#: Bands with fewer pixels than this are left out.
MIN_BAND_PIXELS = 200


def true_one_bounce(points: np.ndarray, normals: np.ndarray, radiance: np.ndarray, K: torch.Tensor) -> np.ndarray:
    """(H, W) the one-bounce irradiance (``models.lamp_bounce.one_bounce_irradiance``) of a grey ``radiance`` (H, W)
    sent by the true geometry: camera-frame ``points`` (H, W, 3) and unit ``normals`` (H, W, 3), either way round;
    ``K`` (3, 3) the view's pinhole (0 where the depth is not finite)."""
    surface = np.isfinite(points).all(-1)
    facing = np.where((normals * points).sum(-1, keepdims=True) > 0, -normals, normals)
    as_tensor = {k: torch.from_numpy(np.nan_to_num(v)).float() for k, v in
                 (("depth", points[..., 2]), ("normals", facing), ("radiance", np.repeat(radiance[..., None], 3, -1)))}
    return one_bounce_irradiance(as_tensor["radiance"], as_tensor["depth"], as_tensor["normals"],
                                 torch.from_numpy(surface), K.float())[..., 0].numpy()


def band_table(height: np.ndarray, observed: np.ndarray, direct: np.ndarray, true_albedo: np.ndarray,
               model_spot: np.ndarray, model_low: np.ndarray, learned_albedo: np.ndarray,
               bounce_true: np.ndarray | None = None, normal_z: np.ndarray | None = None) -> list[dict]:
    """Per height band, from per-pixel values (P,) each (see the module docstring): ``low``, ``share_true``,
    ``share_model``, ``indirect_true``, ``low_model``, ``spot_true``, ``spot_model``, ``albedo_log_ratio``, and when
    given ``bounce_true`` (the true geometry's one-bounce irradiance, relative to its mean) and ``normal_z`` (the
    learned normals' world z, as it is)."""
    strong = direct > np.quantile(direct, GAIN_QUANTILE)
    gain = float(np.median(observed[strong] / direct[strong]))
    indirect = np.clip(observed - gain * direct, 0.0, None)
    learned = np.maximum(learned_albedo, 1e-4)
    irradiance = {"indirect_true": indirect / true_albedo, "low_model": model_low / learned,
                  "spot_true": gain * direct / true_albedo, "spot_model": model_spot / learned}
    if bounce_true is not None:
        irradiance["bounce_true"] = bounce_true
    irradiance = {k: v / v.mean() for k, v in irradiance.items()}
    if normal_z is not None:
        irradiance["normal_z"] = normal_z
    log_ratio = np.log(learned / true_albedo)
    log_ratio -= np.median(log_ratio)
    band = np.floor(height / HEIGHT_BAND).astype(int)
    rows = []
    for b in np.unique(band):
        chosen = band == b
        if chosen.sum() < MIN_BAND_PIXELS:
            continue
        row = {"low": HEIGHT_BAND * b, "share_true": float(indirect[chosen].sum() / observed[chosen].sum()),
               "share_model": float(model_low[chosen].sum() / (model_spot[chosen] + model_low[chosen]).sum()),
               "albedo_log_ratio": float(log_ratio[chosen].mean())}
        row.update({k: float(v[chosen].mean()) for k, v in irradiance.items()})
        rows.append(row)
    return rows


@torch.no_grad()
def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("runs", nargs="+", type=Path)
    parser.add_argument("--every", type=int, default=3, help="every N-th training view (default 3)")
    args = parser.parse_args()
    torch.set_num_threads(2)
    for run in args.runs:
        scene, views, _config, _info = load_run(run, device="cpu")
        dataset = views.dataset
        if scene.appearance.light is None or dataset.light is None:
            raise SystemExit(f"{run}: needs a model with a spotlight and a dataset with its true lamp")
        if not all(camera.is_pinhole for camera in dataset.distinct_cameras()):
            raise SystemExit(f"{run}: its dataset's lens is distorted; the EXR passes are in the distorted image, "
                             "not in the working camera this script renders")
        columns = {k: [] for k in ("height", "observed", "direct", "true_albedo", "spot", "low", "albedo", "bounce",
                                   "normal_z")}
        g = scene.gaussians
        for k in list(views.train)[:: args.every]:
            exr = dataset.exr_paths[k]
            frame = None if exr is None else read_frame_exr(exr)
            if frame is None or frame.albedo is None or frame.normal is None or frame.depth is None:
                raise SystemExit(f"{run}: frame {views.names[k]} has no EXR with depth, normals and diffuse colour")
            c2w = dataset.c2w_opencv[k]
            points = camera_points(dataset.cameras[k], frame.depth)
            diffuse = frame.albedo.mean(-1)
            direct = true_direct_light(points, frame.normal @ c2w[:3, :3], diffuse, dataset.light)
            observed = frame.uneven.mean(-1)
            walls = ((np.abs(frame.normal[..., 2]) < MAX_VERTICAL_NORMAL) & np.isfinite(frame.depth)
                     & (diffuse > 0.02) & (observed > 1e-5))
            camera = views.cameras[k]
            split = scene.render(camera, split_lights=True).image.numpy()
            albedo_and_normals = rasterize(g.means, g.quats, g.scales, g.opacities,
                                           torch.cat([g.albedo, scene.camera_normals(camera.c2w)], 1), camera.viewmat,
                                           camera.K, camera.width, camera.height).image.numpy()
            albedo, normals = albedo_and_normals[..., :3], albedo_and_normals[..., 3:] @ c2w[:3, :3].T
            bounce = true_one_bounce(points, frame.normal @ c2w[:3, :3], direct, camera.K)
            for name, value in (("height", points @ c2w[2, :3] + c2w[2, 3]), ("observed", observed),
                                ("direct", direct), ("true_albedo", diffuse), ("spot", split[..., :3].mean(-1)),
                                ("low", split[..., 3:].mean(-1)), ("albedo", albedo.mean(-1)), ("bounce", bounce),
                                ("normal_z", normals[..., 2] / np.maximum(np.linalg.norm(normals, axis=-1), 1e-9))):
                columns[name].append(value[walls])
        c = {k: np.concatenate(v) for k, v in columns.items()}
        rows = band_table(c["height"], c["observed"], c["direct"], c["true_albedo"], c["spot"], c["low"], c["albedo"],
                          c["bounce"], c["normal_z"])
        print(f"{run}: height (m) | indirect share true / model | indirect irradiance true / model's low-frequency "
              "| spotlight irradiance true / model | log(learned / true albedo) | true geometry's one bounce | "
              "learned normals' world z")
        for r in rows:
            print(f"  {r['low']:.1f}: {r['share_true']:.3f} / {r['share_model']:.3f} | {r['indirect_true']:.2f} / "
                  f"{r['low_model']:.2f} | {r['spot_true']:.2f} / {r['spot_model']:.2f} | {r['albedo_log_ratio']:+.3f} | "
                  f"{r['bounce_true']:.2f} | {r['normal_z']:+.2f}")


if __name__ == "__main__":
    main()
