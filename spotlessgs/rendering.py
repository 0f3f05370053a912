"""Render a trained run's views: relit (spotlight replaced by a constant L0, paper eq. 8) or under the learned
spotlight (to compare with the inputs). PNGs are named like the dataset's images; nothing is clipped silently: the
fraction of pixels above 1 (clipped by 8-bit PNG) is reported and warned about, and ``exr=True`` also writes the
unclipped linear values. By default L0 is chosen automatically (white, about 1% of pixels reaching 1).

An output folder always holds exactly one render's files: they are written into a hidden ``.<name>.partial-...``
folder beside it, with a manifest (``.manifest.json``: checkpoint step and sha256, options, dataset, every file's
sha256; see :mod:`spotlessgs.manifest`), and swapped in when complete, so a second relight with other options or views
replaces the first one's frames instead of mixing with them, and an interrupted one leaves the previous folder as it
was (or gets it back on the next run). An existing non-empty folder is replaced only when it is an earlier render's
(its manifest says so, or it is the run's own RUN/relit or RUN/render); any other folder is refused. The run folder's
write lock is held meanwhile (one writer per run: no relight while it trains)."""

from __future__ import annotations

import contextlib
import dataclasses
import logging
import os
import shutil
import time
from pathlib import Path
from typing import Any, Iterable, Sequence

import numpy as np
import torch

from spotlessgs.io.atomic import PARTIAL_MARK, is_partial_name, partial_sibling, swap_in_folder, write_json
from spotlessgs.io.cameras import Intrinsics
from spotlessgs.io.colorspace import linear_to_srgb
from spotlessgs.io.errors import InputError, OutputOverlapError
from spotlessgs.io.exr import write_exr
from spotlessgs.io.folder_lock import source_and_output_locks
from spotlessgs.io.images import is_image_name, write_png
from spotlessgs.io.lens import distort_maps, remap, working_camera
from spotlessgs.io.paths import refuse_overlap, refuse_working_directory
from spotlessgs.manifest import (
    MANIFEST_NAME, checkpoint_identity, dataset_record, hash_frames, manifest_path, read_manifest, write_manifest,
)
from spotlessgs.models.pose import corrected_cameras
from spotlessgs.models.shading import lambert_cosine, shade, shading_normals, view_directions
from spotlessgs.rasterizer import rasterize
from spotlessgs.training.checkpoint import RUN_SCHEMA_VERSION, read_run_info, resolve_data_dir
from spotlessgs.training.pose_alignment import align_views
from spotlessgs.training.trainer import load_pose_correction, load_run, unrefined_views

log = logging.getLogger(__name__)

#: Warn when more than this fraction of relit pixels exceeds 1 (clipped in 8-bit output).
CLIP_WARN_FRACTION = 0.005


def select_views(views, which: str) -> list[int]:
    """Indices of ``test``, ``train`` or ``all`` views."""
    if which == "test":
        return list(views.test)
    if which == "train":
        return list(views.train)
    if which == "all":
        return list(range(len(views.names)))
    raise ValueError(f"views must be test, train or all, got {which!r}")


#: ``l0="auto"`` scales a white L0 so that this percentile of relit luminance (over sampled views) ...
AUTO_L0_PERCENTILE = 99.0
#: ... lands at this linear value (sRGB ~0.95): bright, with about 1% of pixels at most reaching 1.
AUTO_L0_TARGET = 0.9
#: Views sampled (evenly along the sequence) to choose the automatic L0, and training views over which
#: :func:`lamp_irradiance` averages.
AUTO_L0_VIEWS = 16
#: What ``l0`` may name instead of three numbers: "auto", white scaled for exposure (AUTO_L0_*); "lamp", white at the
#: learned lamp's own mean irradiance (:func:`lamp_irradiance`), the relit view then scaled for exposure as a whole.
L0_RULES = ("auto", "lamp")


class RelitColours:
    """Per-Gaussian relit colours for every view from one evaluation of the reflectance.

    Relit colours c = R·(L0 + L_lf(n̂)) depend on the camera only through the two-sided normal: n̂ is flipped towards
    the camera. So R and R·L_lf are computed once for the normals as stored and once for the flipped normals, and each
    view picks per Gaussian the side it sees — the same choice ``shading.orient_normals`` makes. (The camera also
    enters a stored normal of length ~0 through its fallback direction; those rare Gaussians use the fallback towards
    the first view.) Compositing is linear in the colours, so rendering [R, R·L_lf] as six channels gives
    image = I_R·L0 + I_low for any L0.
    """

    def __init__(self, scene, c2w_ref: torch.Tensor) -> None:
        cfg = dataclasses.replace(scene.config, two_sided_normals=False)
        app, g = scene.appearance, scene.gaussians
        self.scene = scene
        self.front = self._parts(cfg, app, g, c2w_ref)
        self.back = None
        if scene.config.two_sided_normals:
            flipped = g.subset(torch.arange(len(g), device=g.means.device))
            flipped.params["normals_raw"] = -g.params["normals_raw"]
            self.back = self._parts(cfg, app, flipped, c2w_ref)

    @staticmethod
    def _parts(cfg, app, g, c2w) -> torch.Tensor:
        with_l0 = shade(cfg, g, app.light, app.lf_light, app.brdf, c2w, relight_l0=[1.0, 1.0, 1.0])
        low = shade(cfg, g, app.light, app.lf_light, app.brdf, c2w, relight_l0=[0.0, 0.0, 0.0])
        return torch.cat([with_l0 - low, low], dim=1)  # (N, 6): R, R·L_lf

    def features(self, c2w: torch.Tensor) -> torch.Tensor:
        """(N, 6) [R, R·L_lf] of every Gaussian as seen from camera ``c2w``."""
        if self.back is None:
            return self.front
        g = self.scene.gaussians
        center = c2w[:3, 3]
        normals = g.normals(center)
        facing_away = ((center - g.means) * normals).sum(-1, keepdim=True) < 0
        return torch.where(facing_away, self.back, self.front)

    def render(self, camera, config) -> torch.Tensor:
        """(H, W, 6) the images [I_R, I_low] of [R, R·L_lf] seen by ``camera`` (one view of a camera batch, on the
        model's device; ``config``: the run's TrainConfig, for the rasterizer backend and threads): the relit image is
        I_R·L0 + I_low, or I_R·L0 without the low-frequency light."""
        g = self.scene.gaussians
        return rasterize(g.means, g.quats, g.scales, g.opacities, self.features(camera.c2w), camera.viewmat, camera.K,
                         camera.width, camera.height, backend=config.raster_backend,
                         num_threads=config.num_threads).image


def evenly_spaced(indices: Sequence[int], count: int) -> list[int]:
    """At most ``count`` of ``indices``, evenly along them (the first and the last included)."""
    indices = list(indices)
    return [indices[i] for i in np.linspace(0, len(indices) - 1, min(count, len(indices))).astype(int)]


def _luminance(images: list[np.ndarray]) -> np.ndarray:
    """The channel mean of every pixel of ``images`` (H, W, 3 each), flattened into one array."""
    return np.concatenate([im.mean(axis=2).ravel() for im in images])


def auto_l0(images_r: list[np.ndarray], images_low: list[np.ndarray]) -> list[float]:
    """A white L0 = s·(1, 1, 1) that puts the AUTO_L0_PERCENTILE of relit luminance at AUTO_L0_TARGET.

    Args:
        images_r: rendered R·1 images (H, W, 3) of a few views; images_low: their R·L_lf images.
    """
    lum_r, lum_low = _luminance(images_r), _luminance(images_low)
    lo, hi = 0.0, 1.0
    def level(scale: float) -> float:
        return float(np.percentile(scale * lum_r + lum_low, AUTO_L0_PERCENTILE))
    while level(hi) < AUTO_L0_TARGET and hi < 1e6:
        hi *= 2.0
    if level(lo) >= AUTO_L0_TARGET:  # the low-frequency light alone is already that bright
        return [0.0, 0.0, 0.0]
    for _ in range(50):  # bisection: level() is monotone in the scale
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if level(mid) < AUTO_L0_TARGET else (lo, mid)
    return [0.5 * (lo + hi)] * 3


def exposure_gain(images: list[np.ndarray]) -> float:
    """The gain g that puts the AUTO_L0_PERCENTILE of the luminance of g·``images`` (H, W, 3 each) at AUTO_L0_TARGET;
    1 for images that are black there."""
    level = float(np.percentile(_luminance(images), AUTO_L0_PERCENTILE))
    return AUTO_L0_TARGET / level if level > 0 else 1.0


@torch.no_grad()
def lamp_irradiance(scene, cameras, indices: Sequence[int], config, count: int = AUTO_L0_VIEWS) -> float:
    """The learned lamp's mean irradiance on what views see: per Gaussian E = s Ψ Φ max(0, n̂·l̂) (the spotlight's
    radiance at it times the cosine at its shading normal, as training shades it; no shadows), composited into
    ``count`` of the views ``indices`` of ``cameras`` (evenly along them) and averaged over their pixels weighted by
    coverage, so that holes in the model do not count. In the units of L0 (the paper's "replace L_spot by a constant",
    read literally: the lamp's light spread evenly). ``scene``: a loaded run's model (with a spotlight); ``config``:
    its TrainConfig (the rasterizer backend and threads)."""
    g, light = scene.gaussians, scene.appearance.light
    if light is None:
        raise ValueError("the model has no spotlight (3DGS): there is no lamp to match")
    irradiance, coverage = 0.0, 0.0
    for k in evenly_spaced(indices, count):
        camera = cameras[k]
        center = camera.c2w[:3, 3]
        normals = shading_normals(scene.config, g, view_directions(g.means, center), center)
        spot, to_light = light.incident(g.means, camera.c2w)
        e = spot * lambert_cosine(normals, to_light)
        image = rasterize(g.means, g.quats, g.scales, g.opacities, torch.cat([e, torch.ones_like(e), e], dim=1),
                          camera.viewmat, camera.K, camera.width, camera.height, backend=config.raster_backend,
                          num_threads=config.num_threads).image
        irradiance += float(image[..., 0].sum())
        coverage += float(image[..., 1].sum())
    return irradiance / coverage if coverage > 0 else 0.0


def _check_output(out: Path, run_dir: Path, data_dir: Path) -> None:
    """Refuse an output folder that a render may not replace: the dataset or inside it, the run folder or a folder
    holding it, the run's checkpoints folder, or a non-empty folder that is not an earlier render (a render replaces
    the whole folder). An existing non-empty folder is replaced only when it holds a manifest of ``spotless relight``
    or ``spotless render`` (kind ``relit``/``render``) or is the run's own ``RUN/relit`` or ``RUN/render`` (older runs
    wrote them without a manifest), and then only when it holds images (and EXR files) alone.

    Raises:
        OutputOverlapError / InputError: naming the folder and what to choose instead.
    """
    refuse_overlap(out, {"--data": data_dir}, "--out")
    refuse_working_directory(out, "--out")
    real_out, real_run = Path(os.path.realpath(out)), Path(os.path.realpath(run_dir))
    if real_run.is_relative_to(real_out):
        raise OutputOverlapError(f"{out}: --out is or holds the run folder {run_dir}; a render replaces its whole "
                                 "output folder: choose a new folder (default RUN/relit or RUN/render)")
    refuse_overlap(out, {"RUN/checkpoints": run_dir / "checkpoints"}, "--out")
    if out.is_symlink() and not out.exists():
        return  # a dangling link: replaced by the new folder, nothing behind it is touched
    if out.exists() and not out.is_dir():
        raise InputError(f"{out}: --out is a file, not a folder; choose a folder")
    if not out.is_dir() or out.is_symlink():
        return  # new, or a link that is replaced without touching the folder it points to
    entries = [p for p in out.iterdir() if p.name != MANIFEST_NAME]
    if not entries:
        return
    if not _earlier_render(out, run_dir):
        shown = ", ".join(sorted(p.name for p in entries)[:3]) + (
            f" (and {len(entries) - 3} more)" if len(entries) > 3 else "")
        raise InputError(f"{out}: holds files that are not images of an earlier render ({shown}; no {MANIFEST_NAME} "
                         "of `spotless relight`/`render`); a render replaces the whole folder: choose an empty or "
                         "new --out")
    foreign = sorted(p.name for p in entries if not p.name.startswith(".")
                     and (p.is_dir() or not (is_image_name(p.name) or p.suffix.lower() == ".exr")))
    if foreign:
        shown = ", ".join(foreign[:3]) + (f" (and {len(foreign) - 3} more)" if len(foreign) > 3 else "")
        raise InputError(f"{out}: holds files that are not images of an earlier render ({shown}); a render "
                         "replaces the whole folder: choose an empty or new --out")


def _earlier_render(out: Path, run_dir: Path) -> bool:
    """Whether the existing folder ``out`` was written by a render: it has a manifest of kind ``relit`` or
    ``render``, or it is the run's own ``RUN/relit`` or ``RUN/render`` (written by versions without manifests)."""
    try:
        manifest = read_manifest(out)
    except InputError:  # a damaged manifest vouches for nothing
        manifest = None
    if manifest is not None and manifest.get("kind") in ("relit", "render"):
        return True
    real_out = os.path.realpath(out)
    return any(os.path.realpath(run_dir / name) == real_out for name in ("relit", "render"))


def _remove_partial_siblings(out: Path) -> None:
    """Clean up what an interrupted render into ``out`` left beside it (the run lock is held): temporary folders are
    deleted, except that when ``out`` itself is missing (a crash between :func:`~spotlessgs.io.atomic.swap_in_folder`'s two renames) the
    previous folder, kept as an ``old-`` sibling, is renamed back to ``out`` first."""
    if not out.parent.is_dir():
        return
    siblings = [e for e in out.parent.iterdir() if is_partial_name(e.name, out.name)]
    if not os.path.lexists(out):
        old = [e for e in siblings if e.name.startswith(f".{out.name}{PARTIAL_MARK}old-")
               and e.is_dir() and not e.is_symlink()]
        if old:
            newest = max(old, key=lambda e: e.stat().st_mtime)
            os.rename(newest, out)
            log.warning("%s: restored the previous folder from %s (an earlier render was interrupted while "
                        "swapping folders)", out, newest.name)
            siblings.remove(newest)
    for entry in siblings:
        if entry.is_dir() and not entry.is_symlink():
            shutil.rmtree(entry, ignore_errors=True)
        else:
            with contextlib.suppress(FileNotFoundError):
                entry.unlink()


@torch.no_grad()
def render_run(
    run_dir: str | Path,
    mode: str = "relit",
    which: str = "all",
    out_dir: str | Path | None = None,
    l0: Sequence[float] | str = "auto",
    exr: bool = False,
    progress: bool = True,
    device: str = "auto",
    low_frequency: bool = True,
    data_dir: str | Path | None = None,
    align_poses: bool = True,
) -> dict[str, Any]:
    """Render views of a run at the dataset's native resolution.

    Args:
        run_dir: the training run.
        mode: ``relit`` (constant L0 + the learned low-frequency light) or ``spot`` (the learned spotlight).
        which: ``test``, ``train`` or ``all``.
        out_dir: output folder; default ``RUN/relit`` or ``RUN/render``. It is replaced as a whole (see the module
            docstring), so it must be new, empty, or an earlier render's folder (its manifest says so, or it is the
            run's own ``RUN/relit`` / ``RUN/render``) holding images only; never the dataset or the run's files.
        l0: linear RGB relighting radiance (relit mode), or ``"auto"``: white, scaled so that about 1% of relit
            pixels reach 1 (see AUTO_L0_*), or ``"lamp"``: white at the lamp's own mean irradiance on what the
            training views see (:func:`lamp_irradiance`; the learned room light keeps the share of the view it had
            beside the lamp), the relit view then scaled as a whole so that about 1% of its pixels reach 1 (recorded
            as ``lamp_irradiance`` and ``low_frequency_gain``); the value used is reported.
        exr: also write linear float EXR files (``<name>.exr`` with channels R, G, B).
        low_frequency: relit mode: False leaves the learned low-frequency light out (image = R·L0 alone), to see what
            the reflectance alone gives; the automatic L0 is then chosen for that image.
        data_dir: the run's dataset when it has moved (``--data``); default: run.json's paths
            (:func:`spotlessgs.training.checkpoint.resolve_data_dir`).
        align_poses: a run that refined its poses (``refine_poses``) renders its training views at their learned
            poses and first aligns every other view it renders (the test views) to its spotlit input, model frozen
            (:mod:`spotlessgs.training.pose_alignment`); False renders those at the dataset's poses instead (to
            measure what the alignment buys). Recorded as ``pose_alignment`` in the summary and the manifest.
    Returns:
        a summary (views, L0, seconds per view, frames per second, clipped fraction, checkpoint step, manifest), also
        written as ``RUN/<relit|render>.json`` (outside the image folder, which holds images and its manifest only).

    Raises:
        FolderLockedError: another process writes the run (training, a render into the run), or another render
            writes ``out_dir``.
        InputError / OutputOverlapError: the dataset is not found, or the output folder may not be replaced.
    """
    if mode not in ("relit", "spot"):
        raise ValueError(f"mode must be relit or spot, got {mode!r}")
    if mode != "relit" and not low_frequency:
        raise ValueError("low_frequency=False only applies to relit mode")
    if isinstance(l0, str) and l0 not in L0_RULES:
        raise ValueError(f"l0 must be 'auto', 'lamp' or three numbers, got {l0!r}")
    if not isinstance(l0, str):
        l0 = [float(v) for v in l0]
        if len(l0) != 3 or any(not np.isfinite(v) or v < 0 for v in l0):
            raise ValueError(f"l0 must be three finite non-negative numbers, got {l0!r}")
    run_dir = Path(run_dir)
    data = resolve_data_dir(run_dir, read_run_info(run_dir), data_dir)  # a clear error before locking or loading
    default_out = run_dir / ("relit" if mode == "relit" else "render")
    out = Path(out_dir) if out_dir is not None else default_out
    _check_output(out, run_dir, data)
    with source_and_output_locks(run_dir, out, "spotless relight" if mode == "relit" else "spotless render"):
        _remove_partial_siblings(out)
        out.parent.mkdir(parents=True, exist_ok=True)
        tmp = partial_sibling(out)
        tmp.mkdir()
        try:
            summary = _render_into(run_dir, data, mode, which, out, tmp, l0, exr, progress, device, low_frequency,
                                   align_poses)
            swap_in_folder(tmp, out)
        except BaseException:
            shutil.rmtree(tmp, ignore_errors=True)
            raise
        if os.path.realpath(out) == os.path.realpath(default_out):  # the run's own folder: its summary beside it;
            write_json(default_out.with_suffix(".json"),              # another --out never replaces that summary
                       {"schema_version": RUN_SCHEMA_VERSION, **summary})
    return summary


def _refined_cameras(run_dir: Path, scene, views, config, cameras, indices: Sequence[int]):
    """``cameras`` (all views) at the poses of a run that refined them: the training views' learned corrections, and
    each of ``indices`` that training did not fit aligned to its spotlit input with the model frozen
    (:mod:`spotlessgs.training.pose_alignment`; without the photometric camera, which the default texture loss does
    not see); the others at the dataset's poses. Returns the cameras and the summary's ``pose_alignment`` record."""
    deltas = load_pose_correction(run_dir, len(views.names), cameras.device).delta.detach().clone()
    unrefined = set(unrefined_views(views))
    start = time.perf_counter()
    aligned = align_views(scene, views, [k for k in indices if k in unrefined], config)
    for k, a in aligned.items():
        deltas[k] = a.delta.to(deltas.device)
    record = {
        "poses": "refined", "aligned_views": [views.names[k] for k in aligned], "loss": config.pose_align_loss,
        "steps": config.pose_align_steps, "seconds": time.perf_counter() - start,
        "corrections": {views.names[k]: {"translation_m": a.translation_m, "rotation_deg": a.rotation_deg,
                                         "loss_before": a.loss_before, "loss_after": a.loss_after}
                        for k, a in aligned.items()},
    }
    return corrected_cameras(cameras, deltas), record


def _output_size(cameras: Iterable[Intrinsics]) -> dict[str, Any]:
    """The outputs' ``width`` and ``height`` (the input cameras' shared size), or their ``sizes`` ([w, h] each) when
    the input cameras differ in size."""
    sizes = sorted({(c.width, c.height) for c in cameras})
    return {"width": sizes[0][0], "height": sizes[0][1]} if len(sizes) == 1 else {"sizes": [list(s) for s in sizes]}


def _render_into(run_dir: Path, data_dir: Path, mode: str, which: str, out: Path, tmp: Path,
                 l0: Sequence[float] | str, exr: bool, progress: bool, device: str,
                 low_frequency: bool, align_poses: bool = True) -> dict[str, Any]:
    """:func:`render_run`'s work with the run locked: render into ``tmp`` (to become ``out``) with its manifest."""
    from tqdm import tqdm

    checkpoint = checkpoint_identity(run_dir)  # the file the model is loaded from (the lock keeps it unchanged)
    scene, views, config, _info = load_run(run_dir, device=device, data_dir=data_dir)
    dev = scene.gaussians.means.device
    natives = views.dataset.cameras  # each view's input camera: its output has that camera's size and lens
    working = {native: working_camera(native) for native in dict.fromkeys(natives)}
    cameras = views.cameras.with_intrinsics(tuple(working[c] for c in natives)).to(dev)  # rendered in pinhole cameras
    to_input = {native: distort_maps(native, pinhole)[:2] for native, pinhole in working.items() if not native.is_pinhole}

    def in_input_camera(img: np.ndarray, k: int) -> np.ndarray:
        """View ``k``'s working-camera image (Hw, Ww, 3) resampled into its input camera's geometry (H, W, 3)."""
        maps = to_input.get(natives[k])
        return img if maps is None else remap(img, *maps)

    indices = select_views(views, which)
    alignment = None
    if config.refine_poses:  # the training views' learned poses; the others aligned to their inputs first
        cameras, alignment = _refined_cameras(run_dir, scene, views, config, cameras, indices if align_poses else [])
    g = scene.gaussians
    start = time.perf_counter()
    parts = None
    if mode == "relit" and scene.config.light_model != "none":  # 3dgs "relit" = its ordinary render
        parts = RelitColours(scene, cameras.c2w[indices[0]])

    def raster(k: int) -> np.ndarray:
        return parts.render(cameras[k], config).float().cpu().numpy()

    def relit_image(k: int, light: list[float] | None) -> np.ndarray:
        if parts is None:  # 3dgs: its ordinary render
            res = scene.render(cameras[k], relight_l0=[1.0, 1.0, 1.0], backend=config.raster_backend,
                               num_threads=config.num_threads)
            return res.image.float().cpu().numpy()
        both = raster(k)
        return both[..., :3] * np.asarray(light, dtype=np.float32) + np.float32(low_gain) * low_part(both)

    def low_part(both: np.ndarray) -> np.ndarray:
        """The R·L_lf channels of a six-channel render, zero when the low-frequency light is left out."""
        return both[..., 3:] if low_frequency else np.zeros_like(both[..., 3:])

    relight: list[float] | None = None
    low_gain, lamp = 1.0, None  # the low-frequency light's scale in the relit view ("lamp": the exposure gain)
    if mode == "relit" and parts is not None:
        if isinstance(l0, str):
            both = [raster(k) for k in evenly_spaced(indices, AUTO_L0_VIEWS)]
            if l0 == "lamp":
                lamp = lamp_irradiance(scene, cameras, select_views(views, "train"), config)
                low_gain = exposure_gain([lamp * b[..., :3] + low_part(b) for b in both])
                relight = [low_gain * lamp] * 3
            else:
                relight = auto_l0([b[..., :3] for b in both], [low_part(b) for b in both])
        else:
            relight = [float(v) for v in l0]
    clipped, total = 0, 0
    written: list[str] = []
    for k in tqdm(indices, desc=f"{mode} {run_dir.name}", disable=not progress, unit="view"):
        if mode == "relit":
            img = relit_image(k, relight)
        else:
            res = scene.render(cameras[k], backend=config.raster_backend, num_threads=config.num_threads)
            img = res.image.float().cpu().numpy()
        img = in_input_camera(img, k)
        clipped += int((img.max(axis=2) > 1.0).sum())
        total += img.shape[0] * img.shape[1]
        write_png(tmp / views.names[k], linear_to_srgb(img))
        written.append(views.names[k])
        if exr:
            written.append(Path(views.names[k]).stem + ".exr")
            write_exr(tmp / written[-1], {c: img[..., i] for i, c in enumerate("RGB")})
    seconds = time.perf_counter() - start
    fraction = clipped / max(total, 1)
    if mode == "relit" and fraction > CLIP_WARN_FRACTION:
        log.warning("%.2f%% of relit pixels exceed 1 and are clipped in the PNGs; lower --l0 (now %s) or use --exr",
                    100 * fraction, relight)
    summary = {"mode": mode, "views": which, "count": len(indices), "l0": relight, "low_frequency": low_frequency,
               "l0_mode": l0 if isinstance(l0, str) else "given",
               **({"lamp_irradiance": lamp, "low_frequency_gain": low_gain} if lamp is not None else {}),
               **_output_size(working),
               "seconds_per_view": seconds / max(len(indices), 1), "fps": len(indices) / max(seconds, 1e-9),
               "clipped_fraction": fraction, "num_gaussians": len(g), "device": str(dev), "out_dir": str(out),
               "pose_alignment": alignment}
    options = {k: summary[k] for k in ("mode", "views", "l0", "l0_mode", "low_frequency_gain", "low_frequency", "width",
                                       "height") if k in summary}
    if alignment is not None:  # what the evaluation reports: which views were aligned, and how
        options["pose_alignment"] = {k: alignment[k] for k in ("poses", "aligned_views", "loss", "steps")}
    write_manifest(tmp, "relit" if mode == "relit" else "render", run_dir=run_dir, checkpoint=checkpoint,
                   options={**options, "exr": exr}, dataset=dataset_record(data_dir, run_dir, len(views.names)),
                   frames=hash_frames(tmp, written))
    summary.update(checkpoint_step=None if checkpoint is None else checkpoint["step"],
                   manifest=str(manifest_path(out)))
    return summary
