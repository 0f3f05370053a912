"""Export a run as a standard 3DGS PLY (the layout of the original 3DGS code, read by common viewers):
x y z, nx ny nz, f_dc_0..2, f_rest_0..44, opacity (logit), scale_0..2 (log), rot_0..3 (w x y z).

The colour is the *relit* appearance (spotlight replaced by L0), sRGB-encoded and stored in the DC band, so a viewer
shows the evenly lit scene; higher bands are zero. For ``3dgs`` runs the model's own SH colour is exported.

Positions are the model's: relative to the dataset's working origin, which is the world origin unless the poses lie
far from it (:func:`spotlessgs.io.cameras.working_origin`, e.g. UTM coordinates). Such a file says so in a header
comment, ``comment world_origin X Y Z`` (metres, the point to add to every position for world coordinates)."""

from __future__ import annotations

from pathlib import Path
from typing import Sequence

import numpy as np
import torch

from spotlessgs.io.atomic import atomic_path
from spotlessgs.io.colorspace import linear_to_srgb
from spotlessgs.io.errors import InputError
from spotlessgs.io.paths import refuse_overlap, refuse_run_file
from spotlessgs.models.sh import SH_C0
from spotlessgs.models.shading import RELIGHT_L0_DEFAULT
from spotlessgs.training.checkpoint import read_run_info, resolve_data_dir
from spotlessgs.training.trainer import load_run


@torch.no_grad()
def export_ply(run_dir: str | Path, out_path: str | Path, l0: Sequence[float] = RELIGHT_L0_DEFAULT,
               data_dir: str | Path | None = None) -> Path:
    """Write the run's Gaussians to ``out_path``; returns the path. ``data_dir`` points at the run's dataset when it
    has moved (default: run.json's paths, see :func:`spotlessgs.training.checkpoint.resolve_data_dir`).

    Raises:
        OutputOverlapError: ``out_path`` is, holds or lies inside the dataset folder, the run's checkpoints folder,
            run.json or config.json, or would replace another file of the run or write into one of its folders
            than an earlier export (a ``.ply`` file directly in it) (checked before anything is loaded or written).
        InputError: ``out_path`` is an existing folder, or the dataset is not found (see ``--data``).
    """
    from plyfile import PlyData, PlyElement

    run_dir, out_path = Path(run_dir), Path(out_path)
    data_root = resolve_data_dir(run_dir, read_run_info(run_dir), data_dir)
    refuse_overlap(out_path, {"--data": data_root, "RUN/checkpoints": run_dir / "checkpoints", "RUN/run.json":
                              run_dir / "run.json", "RUN/config.json": run_dir / "config.json"}, "--out")
    if out_path.is_dir():
        raise InputError(f"{out_path}: --out is a folder; give the path of the PLY file to write")
    refuse_run_file(out_path, run_dir, "--out", own_suffix=".ply")
    scene, views, _config, _info = load_run(run_dir, device="cpu", data_dir=data_root)
    g = scene.gaussians
    n = len(g)
    if scene.config.light_model == "none":
        sh = g.sh_colour_coeffs().numpy()  # (N, 16, 3)
        f_dc, f_rest = sh[:, 0, :], sh[:, 1:, :]
    else:
        # relit colour per Gaussian, seen from the first camera (relit colours do not depend on the camera)
        colour = scene.colours(views.cameras.c2w[0], relight_l0=list(map(float, l0))).numpy()
        f_dc = (linear_to_srgb(colour) - 0.5) / SH_C0
        f_rest = np.zeros((n, 15, 3))
    cam0 = views.cameras.centres[0]
    fields = {
        **{k: g.means[:, i].numpy() for i, k in enumerate("xyz")},
        **{f"n{k}": g.normals(cam0)[:, i].numpy() for i, k in enumerate("xyz")},
        **{f"f_dc_{i}": f_dc[:, i] for i in range(3)},
        # 3DGS stores f_rest channel-major: all coefficients of R, then G, then B
        **{f"f_rest_{i}": f_rest.transpose(0, 2, 1).reshape(n, -1)[:, i] for i in range(45)},
        "opacity": g.params["opacity_logits"].numpy(),
        **{f"scale_{i}": g.params["log_scales"][:, i].numpy() for i in range(3)},
        **{f"rot_{i}": g.quats[:, i].numpy() for i in range(4)},
    }
    data = np.empty(n, dtype=[(k, "f4") for k in fields])
    for k, v in fields.items():
        data[k] = v
    origin = views.dataset.working_origin
    comments = [] if not origin.any() else ["world_origin " + " ".join(repr(float(v)) for v in origin)]
    with atomic_path(out_path) as tmp:
        PlyData([PlyElement.describe(data, "vertex")], comments=comments).write(str(tmp))
    return out_path
