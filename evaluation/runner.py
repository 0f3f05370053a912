"""Evaluation entry points: score two folders of images, or a training run against its dataset.

Both return the results dict that is also written as JSON (keys ``psnr ssim lpips psnr_aligned ssim_aligned
lpips_aligned tmp_psnr tmp_ssim sfm`` at the top level where they apply) and, with an output folder, a Markdown table
and PNG figures.

Provenance (see :mod:`spotlessgs.manifest`): ``evaluate_run`` scores a run's relit images only when their folder's
manifest says that they were made from the run's current checkpoint (same sha256: training was not resumed after
relighting), that the folder holds exactly the frames it lists and that none was changed since (same sha256); a run
with a checkpoint whose relit folder has no manifest is refused too. Each refusal is one
:class:`~spotlessgs.io.errors.InputError` line naming the folder, the problem and what to do. ``evaluate_folders``
checks the frames of a folder that has a manifest the same way (a checkpoint that has moved on since is only
recorded and warned about: folder mode scores images as they are). The results record the manifest they scored
(``relit_manifest`` / ``pred_manifest``: path, sha256, checkpoint step and sha256), and an output folder gets a
manifest of its own (kind ``eval``) listing the files written with their hashes. ``evaluate_run`` holds the run
folder's write lock while it works.
"""

from __future__ import annotations

import contextlib
import logging
import os
import re
import tempfile
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Iterator, Sequence

import numpy as np
import torch

from evaluation.alignment import GainAccumulator, apply_gain
from evaluation.dataset import DatasetFrame, DatasetViews, read_dataset, read_depth_exr
from evaluation.folders import ImagePair, image_names, match_folders
from evaluation.lpips import lpips
from evaluation.plots import save_image_grid, save_trajectory_plot
from evaluation.report import write_markdown, write_results_json
from evaluation.sfm import SfmConfig, SfmResult, run_sfm
from evaluation.temporal import (
    PAIR_PSNR_CAP_DB, PosedFrame, excess_flicker, exposure_leak, sequence_flicker, temporal_scores,
    warped_temporal_scores,
)
from spotlessgs.io.cameras import Intrinsics, opengl_to_opencv_c2w
from spotlessgs.io.dataset import GROUND_TRUTHS
from spotlessgs.io.errors import InputError
from spotlessgs.io.exr import read_emitters
from spotlessgs.io.folder_lock import folder_lock, source_and_output_locks
from spotlessgs.io.images import list_image_files, read_image
from spotlessgs.io.paths import refuse_overlap, refuse_run_file
from spotlessgs.io.provenance import provenance, sha256_file
from spotlessgs.manifest import (
    MANIFEST_NAME, checkpoint_step, current_checkpoint, dataset_record, hash_frames, manifest_path, manifest_sha256,
    read_manifest, verify_frames, write_manifest,
)
from spotlessgs.metrics import masked_psnr, masked_ssim, psnr, ssim
from spotlessgs.training.checkpoint import read_run_info, resolve_data_dir

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class EvalConfig:
    """What to compute and how."""

    lpips: bool = True  # compute LPIPS (AlexNet v0.1) besides PSNR and SSIM
    aligned: bool = True  # also score after the sequence-wide least-squares exposure gain (the *_aligned keys)
    temporal: bool = True  # temporal PSNR/SSIM between consecutive frames (and the warped variant when possible)
    sfm: bool = False  # run downstream SfM (pycolmap, CPU)
    sfm_config: SfmConfig = field(default_factory=SfmConfig)  # SfM settings (matcher, features, threads, seed)
    grid_frames: int = 4  # frames shown in the side-by-side figure
    num_threads: int | None = None  # torch CPU threads while evaluating (None: leave torch's setting)
    progress: bool = True  # show progress bars on stderr
    # evaluate_run only: also score the run's original (uneven) inputs (the ``input`` block: image metrics, temporal
    # metrics, SfM). False skips them when a caller scores the inputs once for many runs of one dataset.
    inputs: bool = True
    # which of the dataset's ground truths to score against (spotlessgs.io.dataset.GROUND_TRUTHS): "lamps" (the
    # lamps-on render) or "uniform" (even, shadow-free environment light; `spotless-sim render --gt uniform`)
    ground_truth: str = "lamps"

    def __post_init__(self) -> None:
        if self.ground_truth not in GROUND_TRUTHS:
            raise ValueError(f"ground_truth must be one of {list(GROUND_TRUTHS)}, got {self.ground_truth!r}")
        if self.grid_frames < 1:
            raise ValueError(f"grid_frames must be at least 1, got {self.grid_frames}")
        if self.num_threads is not None and self.num_threads < 1:
            raise ValueError(f"num_threads must be at least 1, got {self.num_threads}")


def _load(path: str | os.PathLike) -> np.ndarray:
    """An image for scoring: (H, W, 3) float32 sRGB in [0, 1], alpha composited over black (every method alike)."""
    return read_image(path, alpha="over_black")


def _bar(iterable, config: EvalConfig, desc: str, total: int | None = None):
    """A tqdm progress bar on stderr (disabled by ``config.progress``)."""
    from tqdm.auto import tqdm

    return tqdm(iterable, desc=desc, total=total, disable=not config.progress, leave=False, dynamic_ncols=True)


@contextlib.contextmanager
def _torch_threads(n: int | None) -> Iterator[None]:
    """Temporarily set torch's intra-op thread count."""
    if n is None:
        yield
        return
    old = torch.get_num_threads()
    torch.set_num_threads(n)
    try:
        yield
    finally:
        torch.set_num_threads(old)


def _chw(img: np.ndarray) -> torch.Tensor:
    """(H, W, 3) float array → (3, H, W) float32 tensor."""
    return torch.from_numpy(np.ascontiguousarray(img)).permute(2, 0, 1).float()


def _load_pair(pair: ImagePair) -> tuple[torch.Tensor, torch.Tensor]:
    """Load both images of a pair as (3, H, W); ValueError naming both files when their sizes differ."""
    pred, gt = _load(pair.pred), _load(pair.gt)
    if pred.shape != gt.shape:
        raise ValueError(
            f"{pair.name}: size mismatch: prediction {pair.pred} is {pred.shape[1]}x{pred.shape[0]}, "
            f"reference {pair.gt} is {gt.shape[1]}x{gt.shape[0]}"
        )
    return _chw(pred), _chw(gt)


def score_pairs(pairs: Sequence[ImagePair], config: EvalConfig = EvalConfig(), label: str = "metrics") -> dict:
    """Per-image and mean PSNR, SSIM, LPIPS and their exposure-aligned variants.

    Images are streamed (two passes when ``config.aligned``: the gain needs the whole sequence first), so memory
    does not grow with the number of images beyond the lamp masks (one bool per pixel, for pairs with an EXR), which
    are read once and kept for the second pass.

    Returns:
        dict with the mean metrics (``psnr``, ``ssim``, ``lpips``, ``*_aligned``), ``exposure_gain``,
        ``num_images`` and ``per_image`` (a list of per-image dicts with ``name`` and the same metric keys). When
        every pair's EXR has an emission pass, also ``*_masked`` and ``*_aligned_masked``: the same metrics over the
        pixels that show no lamp of the ground truth (:meth:`spotlessgs.io.exr.FrameEXR.emitters`), the aligned ones
        after a gain fitted on those pixels only (``exposure_gain_masked``); LPIPS averages its distance maps over
        them (:func:`evaluation.lpips.lpips` ``mask``).

    Raises:
        ValueError: no pairs, or a pair whose images differ in size.
    """
    if not pairs:
        raise ValueError("no image pairs to score")
    per_image: list[dict] = [{"name": p.name} for p in pairs]
    acc, acc_masked = GainAccumulator(), GainAccumulator()

    def score(pred: torch.Tensor, gt: torch.Tensor, row: dict, suffix: str) -> None:
        row["psnr" + suffix] = float(psnr(pred, gt)[0])
        row["ssim" + suffix] = float(ssim(pred, gt)[0])
        if config.lpips:
            row["lpips" + suffix] = float(lpips(pred, gt)[0])

    def score_masked(pred: torch.Tensor, gt: torch.Tensor, keep: torch.Tensor, row: dict, suffix: str) -> None:
        row["psnr" + suffix + "_masked"] = masked_psnr(pred, gt, keep)
        row["ssim" + suffix + "_masked"] = masked_ssim(pred, gt, keep)
        if config.lpips:
            row["lpips" + suffix + "_masked"] = float(lpips(pred, gt, mask=keep)[0])

    keeps: list[torch.Tensor | None] = []  # each pair's lamp-free pixels, read from its EXR once
    with _torch_threads(config.num_threads), torch.no_grad():
        for pair, row in _bar(list(zip(pairs, per_image)), config, f"{label}", total=len(pairs)):
            pred, gt = _load_pair(pair)
            try:
                score(pred, gt, row, "")
                keep = _non_emitters(pair, gt)
                if keep is not None:
                    score_masked(pred, gt, keep, row, "")
            except ValueError as exc:  # images too small for SSIM's window, lamps leaving no lamp-free window
                raise InputError(f"{pair.pred} against {pair.gt}: {exc}") from None
            acc.add(pred, gt)
            keeps.append(keep)
            if keep is not None:
                acc_masked.add(pred[:, keep], gt[:, keep])
        gain = gain_masked = None
        if config.aligned:
            if acc.sum_pp <= 0.0:
                folders = sorted({str(pair.pred.parent) for pair in pairs})
                raise InputError(f"{', '.join(folders)}: every pixel of the {len(pairs)} predicted image(s) is black, "
                                 "so the exposure gain of the aligned metrics is undefined (an empty render?)")
            gain = acc.gain()
            gain_masked = acc_masked.gain() if acc_masked.count else None
            for pair, row, keep in _bar(list(zip(pairs, per_image, keeps)), config, f"{label} (aligned)",
                                        total=len(pairs)):
                pred, gt = _load_pair(pair)
                score(apply_gain(pred, gain), gt, row, "_aligned")
                if keep is not None and gain_masked is not None:
                    score_masked(apply_gain(pred, gain_masked), gt, keep, row, "_aligned")
    keys = [k for k in per_image[0] if k != "name" and all(k in row for row in per_image)]
    out: dict = {k: float(np.mean([row[k] for row in per_image])) for k in keys}
    out["exposure_gain"] = gain
    if gain_masked is not None:
        out["exposure_gain_masked"] = gain_masked
    out["num_images"] = len(pairs)
    out["per_image"] = per_image
    return out


def _non_emitters(pair: ImagePair, gt: torch.Tensor) -> torch.Tensor | None:
    """(H, W) bool: the pixels of ``pair`` that show no lamp of the ground truth (its EXR's emission pass), or None
    when the pair has no EXR, the EXR no emission pass (or it is a depth-only file), or every pixel is a lamp."""
    if pair.exr is None:
        return None
    emitters = read_emitters(pair.exr)
    if emitters is None:
        return None
    if emitters.shape != tuple(gt.shape[-2:]):
        raise ValueError(f"{pair.exr}: EXR is {emitters.shape[1]}x{emitters.shape[0]}, the images of {pair.name} "
                         f"{gt.shape[-1]}x{gt.shape[-2]}")
    keep = torch.from_numpy(~emitters)
    return keep if bool(keep.any()) else None



def score_test_views(data_dir: str | os.PathLike, pred_dir: str | os.PathLike,
                     num_threads: int | None = None, ground_truth: str = "lamps") -> dict:
    """Mean PSNR/SSIM (raw and after one exposure gain) of ``pred_dir``'s images of the dataset's test views against
    their ground truth: the quick score of the reproduction's curve points and the benchmarks' rows (no LPIPS, no
    temporal metrics); ``pose_alignment``: the views whose poses were aligned before rendering (a run that refined
    its poses, :func:`relit_pose_alignment`), else None; ``ground_truth``: which of the dataset's ground truths."""
    data = read_dataset(data_dir, ground_truth)
    pairs = [ImagePair(f.name, Path(pred_dir) / f.name, f.gt_path) for f in data.test_frames if f.gt_path is not None]
    scores = score_pairs(pairs, EvalConfig(lpips=False, temporal=False, num_threads=num_threads, progress=False))
    return {**{k: scores[k] for k in ("psnr", "ssim", "psnr_aligned", "ssim_aligned")},
            "pose_alignment": relit_pose_alignment(Path(pred_dir))}


def relit_pose_alignment(folder: Path) -> dict | None:
    """What a relit folder's manifest says about its poses: for a run that refined its poses, ``{"poses": "refined",
    "aligned_views": [...], "loss": ..., "steps": ...}`` (the views that training did not fit, aligned to their spotlit
    inputs with the model frozen before rendering); None for the dataset's poses or a folder without a manifest."""
    try:
        manifest = read_manifest(folder)
    except InputError:
        return None
    options = (manifest or {}).get("options") or {}
    record = options.get("pose_alignment")
    return record if isinstance(record, dict) else None


def temporal_block(
    paths: Sequence[Path], config: EvalConfig, label: str, posed: DatasetViews | None = None
) -> dict:
    """Temporal metrics of one ordered sequence of image files: ``tmp_psnr``, ``tmp_ssim`` and, when ``posed`` gives
    depth and poses for every frame (same order as ``paths``), ``tmp_psnr_warped`` and ``tmp_ssim_warped``."""
    if len(paths) < 2:
        return {}
    if posed is not None and len(posed.frames) != len(paths):
        raise ValueError(f"temporal {label}: {len(paths)} images but {len(posed.frames)} posed frames")
    with _torch_threads(config.num_threads), torch.no_grad():
        frames = (_chw(_load(p)) for p in _bar(paths, config, f"temporal {label}", total=len(paths)))
        try:
            plain = temporal_scores(frames)
        except ValueError as exc:  # frames of different sizes: name the files (the scores name pair indices)
            pair = re.match(r"frames (\d+) and (\d+) differ", str(exc))
            where = f"{paths[int(pair[1])]} and {paths[int(pair[2])].name}" if pair else str(Path(paths[0]).parent)
            raise InputError(f"{where}: temporal {label}: {exc}") from None
        out = {"tmp_psnr": plain.mean_psnr, "tmp_ssim": plain.mean_ssim, "tmp_flicker": plain.flicker}
        if plain.identical_pairs:
            log.info("temporal %s: %d of %d consecutive pairs are identical, each counted as %g dB", label,
                     plain.identical_pairs, len(plain.psnr), PAIR_PSNR_CAP_DB)
        # one camera (the frames of several cameras are not warped); a lens warps through OpenCV's camera model
        if (posed is not None and posed.intrinsics is not None
                and all(f.depth_path is not None for f in posed.frames)):
            K = torch.from_numpy(posed.intrinsics.K()) if posed.intrinsics.is_pinhole else posed.intrinsics

            def gen():
                for p, f in zip(paths, posed.frames):
                    yield PosedFrame(
                        image=_chw(_load(p)),
                        depth=torch.from_numpy(read_depth_exr(f.depth_path)),
                        c2w=torch.from_numpy(opengl_to_opencv_c2w(f.c2w_opengl)),
                    )

            warped = warped_temporal_scores(_bar(gen(), config, f"warped temporal {label}", total=len(paths)), K)
            out.update(tmp_psnr_warped=warped.mean_psnr, tmp_ssim_warped=warped.mean_ssim,
                       tmp_warped_pairs=len(warped.psnr))
    return out


def _sfm_block(
    image_dir: Path, names: Sequence[str], work: Path, config: EvalConfig, label: str,
    intrinsics: Intrinsics | None = None, true_c2w: dict[str, np.ndarray] | None = None,
) -> tuple[dict, SfmResult]:
    """Run SfM on one sequence with a progress bar over its steps; returns (JSON summary, result)."""
    with _bar(None, config, f"SfM {label}", total=3) as bar:  # three steps: features, matching, mapping
        started: list[str] = []

        def on_step(name: str) -> None:
            if started:
                bar.update(1)  # the previous step has finished
            started.append(name)
            bar.set_postfix_str(name)

        result = run_sfm(image_dir, names, work, config.sfm_config, intrinsics, progress=on_step)
        bar.update(1)
    return result.summary(true_c2w, names), result


def _trajectory_panel(result: SfmResult, names: Sequence[str], true_c2w: dict | None) -> dict:
    """Plot data for one SfM result: centres in time order, points, true centres. With true poses every sub-model is
    aligned to them on its own (its sub-models' frames are unrelated); without, the largest sub-model is shown."""
    if true_c2w is None:
        model = result.models[0] if result.models else None
        order = [n for n in names if model is not None and n in model.poses_c2w]
        return {"centres": np.array([model.poses_c2w[n][:3, 3] for n in order]).reshape(-1, 3),
                "points": model.points_xyz if model is not None else np.zeros((0, 3))}
    aligned = {}
    points = [np.zeros((0, 3))]
    for model, common, errs in result.model_alignments(true_c2w, names):
        sim = errs.alignment
        aligned.update({n: sim.apply(model.poses_c2w[n][None, :3, 3])[0] for n in common})
        if len(model.points_xyz):
            points.append(sim.apply(model.points_xyz))
    order = [n for n in names if n in aligned]
    return {
        "centres": np.array([aligned[n] for n in order]).reshape(-1, 3),
        "points": np.concatenate(points),
        "true_centres": np.array([true_c2w[n][:3, 3] for n in names]),
    }


def _grid_indices(n: int, k: int) -> list[int]:
    """``k`` evenly spread indices in range(n) (all of them when n ≤ k)."""
    if n <= k:
        return list(range(n))
    return sorted(set(int(round(i)) for i in np.linspace(0, n - 1, k)))


def _write_outputs(out_dir: Path | None, json_path: Path | None, results: dict, title: str) -> None:
    """Write results.json and results.md into ``out_dir`` and/or the JSON to ``json_path``."""
    if out_dir is not None:
        write_results_json(out_dir / "results.json", results)
        write_markdown(out_dir / "results.md", results, title)
    if json_path is not None:
        write_results_json(json_path, results)


#: The files an evaluation writes into its output folder (the SfM work folder ``sfm/`` is scratch, not listed).
_EVAL_OUTPUTS = ("results.json", "results.md", "figures/grid.png", "figures/sfm_trajectories.png")


def _refuse_foreign_out(out: Path) -> None:
    """InputError unless ``out`` may take an evaluation's outputs: absent or empty, an earlier evaluation (its
    manifest's kind is ``eval`` or ``eval-folders``), or a folder holding nothing but what an evaluation writes (one
    interrupted before its manifest, or written by a version without manifests). Anything else (a render, the run's
    checkpoints, a user's folder) would get its results files replaced and its ``sfm/`` work folders deleted."""
    if out.exists() and not out.is_dir():
        raise InputError(f"{out}: --out is a file, not a folder")
    if not out.is_dir():
        return
    try:
        manifest = read_manifest(out)
    except InputError:  # a damaged manifest vouches for nothing: judged by the folder's entries below
        manifest = None
    if manifest is not None and manifest.get("kind") in ("eval", "eval-folders"):
        return
    own = {"results.json", "results.md", "figures", "sfm"}
    foreign = sorted(p.name for p in out.iterdir() if not p.name.startswith(".") and p.name not in own)
    if manifest is not None or foreign:
        shown = ", ".join(foreign[:4] or [f"a {manifest.get('kind')!r} manifest"])
        raise InputError(f"{out}: holds files that are not an earlier evaluation's ({shown}); an evaluation "
                         "replaces its results and SfM work folders there: choose an empty or new --out")


def _write_eval_manifest(out: Path, kind: str, run: Path | None, checkpoint: dict | None, config: EvalConfig,
                         dataset: dict | None, scored: dict | None, written: Sequence[str]) -> None:
    """The output folder's manifest (kind ``eval`` or ``eval-folders``): the files this evaluation wrote, with
    their hashes; an output of an earlier evaluation that this one did not write again is removed (no mixed
    folder)."""
    for name in _EVAL_OUTPUTS:
        if name not in written:
            (out / name).unlink(missing_ok=True)
    write_manifest(out, kind, run_dir=run, checkpoint=checkpoint, options=asdict(config), dataset=dataset,
                   frames=hash_frames(out, written), scored=scored)


def _manifest_record(folder: Path, manifest: dict, checkpoint_sha256: str | None) -> dict:
    """What results record about the manifest of a scored folder."""
    recorded = manifest.get("checkpoint") or {}
    return {"path": str(manifest_path(folder)), "sha256": manifest_sha256(folder), "kind": manifest["kind"],
            "checkpoint_step": recorded.get("step"), "checkpoint_sha256": checkpoint_sha256 or recorded.get("sha256")}


def check_relit_folder(run: Path, relit_dir: Path) -> dict | None:
    """Check that ``relit_dir`` holds the relit images of ``run``'s current checkpoint, exactly as written.

    Returns:
        the results' ``relit_manifest`` record (see :func:`_manifest_record`), or None for a run folder without a
        checkpoint whose relit folder has no manifest (images placed there by another tool: nothing to check).

    Raises:
        InputError: no manifest (the run has a checkpoint), a manifest of another kind, images of another checkpoint
            (training was resumed after relighting), or frames not listed, missing or changed (named), each with
            what to do.
    """
    remedy = f"run `spotless relight {run}` again"
    manifest = read_manifest(relit_dir)
    ckpt = current_checkpoint(run)
    if manifest is None:
        if ckpt is None:
            return None
        raise InputError(f"{relit_dir}: no manifest ({MANIFEST_NAME}), so which checkpoint made these images is "
                         f"unknown (relit by an older version or copied in); {remedy}")
    if manifest["kind"] != "relit":
        raise InputError(f"{relit_dir}: holds the output of `spotless {manifest['kind']}`, not relit images; {remedy}")
    recorded = manifest.get("checkpoint") or {}
    if ckpt is None:
        raise InputError(f"{relit_dir}: relit from the checkpoint at step {recorded.get('step')}, but the run has no "
                         "checkpoint to check them against; keep the run's checkpoints/ folder with it, or "
                         f"train and relight again")
    digest = sha256_file(ckpt)
    if digest != recorded.get("sha256"):
        now = checkpoint_step(run)
        if now is None:  # not training that went on: the file cannot be read
            raise InputError(f"{ckpt}: the run's checkpoint cannot be read (damaged or cut short), and it is not the "
                             f"one the relit images in {relit_dir} were made from (step {recorded.get('step')}); "
                             "restore it or train again")
        raise InputError(f"{relit_dir}: stale relit images: made from the checkpoint at step {recorded.get('step')}, "
                         f"but the run's checkpoint has changed since (now step {now}: training went on after "
                         f"relighting); {remedy}")
    verify_frames(relit_dir, manifest, remedy)
    return _manifest_record(relit_dir, manifest, digest)


def check_folder_manifest(folder: Path, label: str) -> dict | None:
    """Folder mode: when ``folder`` has a manifest, check that it holds exactly the frames listed, unchanged.

    A manifest's checkpoint that has changed since (its run still in place) is recorded (``checkpoint_current``)
    and warned about, not refused: folder mode scores the images as they are.

    Returns:
        the results' record of the manifest (see :func:`_manifest_record`), or None when the folder has none.

    Raises:
        InputError: frames not listed, missing or changed (named).
    """
    manifest = read_manifest(folder)
    if manifest is None:
        return None
    verify_frames(folder, manifest, f"write {label} {folder} again")
    record = _manifest_record(folder, manifest, None)
    run_dir = manifest.get("run_dir")
    if record["checkpoint_sha256"] and run_dir and Path(run_dir).is_dir():
        ckpt = current_checkpoint(run_dir)
        if ckpt is not None:
            record["checkpoint_current"] = sha256_file(ckpt) == record["checkpoint_sha256"]
            if not record["checkpoint_current"]:
                log.warning("%s: made from the checkpoint at step %s of %s, which has changed since (training went on)",
                            folder, record["checkpoint_step"], run_dir)
    return record


def evaluate_folders(
    pred_dir: str | os.PathLike,
    gt_dir: str | os.PathLike,
    config: EvalConfig = EvalConfig(),
    json_path: str | os.PathLike | None = None,
    out_dir: str | os.PathLike | None = None,
    match: str = "both",
) -> dict:
    """Score the images of ``pred_dir`` against those of ``gt_dir``, matched by file name: with ``match="both"``
    the folders must hold the same names; with ``"pred"`` every image of ``pred_dir`` is scored against its namesake
    in ``gt_dir``, which may hold more (a dataset's ``gt/`` beside the output of ``relight --views test``). A
    prediction folder whose manifest says that it holds training views (``relight --views all|train``) is scored as
    it is, with a warning: the test views alone are what `spotless eval RUN` scores.

    Temporal metrics (and SfM, when ``config.sfm``; COLMAP estimates the intrinsics) run on the prediction folder in
    file-name order. Writes the JSON to ``json_path`` and, with ``out_dir``, also results.json, results.md and
    figures/grid.png (and figures/sfm_trajectories.png) there.

    Raises:
        OutputOverlapError: ``out_dir`` or ``json_path`` is, holds or lies inside ``pred_dir`` or ``gt_dir``.
        ValueError / FileNotFoundError: see :func:`evaluation.folders.match_folders` and :func:`score_pairs`.
    """
    if match not in ("both", "pred"):
        raise ValueError(f"match must be 'both' or 'pred', got {match!r}")
    inputs = {"--pred": pred_dir, "--gt": gt_dir}
    if out_dir is not None:
        refuse_overlap(out_dir, inputs, "--out")
        _refuse_foreign_out(Path(out_dir))
    if json_path is not None:
        refuse_overlap(json_path, inputs, "--json")
    if out_dir is None:
        return _evaluate_folders(Path(pred_dir), Path(gt_dir), config, json_path, None, match)
    real_out = Path(os.path.realpath(out_dir))  # one writer per output folder, as in RUN mode
    with folder_lock(real_out.parent, "spotless eval", name=f".{real_out.name}.lock"):
        return _evaluate_folders(Path(pred_dir), Path(gt_dir), config, json_path, Path(out_dir), match)


def _evaluate_folders(pred_dir: Path, gt_dir: Path, config: EvalConfig, json_path: str | os.PathLike | None,
                      out_dir: Path | None, match: str) -> dict:
    """:func:`evaluate_folders` after its checks (with the output folder's lock held)."""
    pred_manifest = check_folder_manifest(Path(pred_dir), "--pred")
    gt_manifest = check_folder_manifest(Path(gt_dir), "--gt")
    # a folder whose manifest vouches for every file may hold more than images (relight --exr's EXR files)
    non_images = ("error" if pred_manifest is None else "skip", "error" if gt_manifest is None else "skip")
    names = image_names(pred_dir, non_images[0]) if match == "pred" else None
    pairs = match_folders(pred_dir, gt_dir, names, non_images=non_images)
    views = (read_manifest(Path(pred_dir)) or {}).get("options", {}).get("views") if pred_manifest else None
    if views in ("all", "train"):
        log.warning("%s: relit with --views %s: the scores include training views (`spotless eval RUN`, or `relight "
                    "--views test` and --match pred, score the test views alone)", pred_dir, views)
    results: dict = {"mode": "folders", "pred_dir": str(pred_dir), "gt_dir": str(gt_dir), "match": match,
                     "pred_manifest": pred_manifest, "gt_manifest": gt_manifest}
    scores = score_pairs(pairs, config, "image metrics")
    results.update(scores)
    if config.temporal:
        results.update(temporal_block([p.pred for p in pairs], config, "pred"))
    out = Path(out_dir) if out_dir is not None else None
    sfm_result = None
    if config.sfm:
        with _work_dir(out) as work:
            results["sfm"], sfm_result = _sfm_block(Path(pred_dir), [p.name for p in pairs], work / "pred",
                                                    config, "pred")
    results["config"] = asdict(config)
    results["provenance"] = provenance(extra_packages=("pycolmap", "kornia"))
    if out is not None:
        idx = _grid_indices(len(pairs), config.grid_frames)
        save_image_grid(out / "figures" / "grid.png",
                        [[_load(pairs[i].pred), _load(pairs[i].gt)] for i in idx],
                        ["prediction", "reference"], [pairs[i].name for i in idx])
        if sfm_result is not None:
            save_trajectory_plot(out / "figures" / "sfm_trajectories.png",
                                 {"prediction": _trajectory_panel(sfm_result, [p.name for p in pairs], None)})
    _write_outputs(out, Path(json_path) if json_path is not None else None, results, "Evaluation (folders)")
    if out is not None:
        written = list(_EVAL_OUTPUTS[:3]) + (["figures/sfm_trajectories.png"] if sfm_result is not None else [])
        checkpoint = None if pred_manifest is None or pred_manifest["checkpoint_sha256"] is None else {
            "step": pred_manifest["checkpoint_step"], "sha256": pred_manifest["checkpoint_sha256"]}
        scored = {"folder": str(Path(pred_dir).resolve()), "kind": None if pred_manifest is None else
                  pred_manifest["kind"], "manifest_sha256": None if pred_manifest is None else pred_manifest["sha256"]}
        _write_eval_manifest(out, "eval-folders", None, checkpoint, config, None, scored, written)
    return results


@contextlib.contextmanager
def _work_dir(out: Path | None) -> Iterator[Path]:
    """SfM scratch folder: ``out/sfm`` when there is an output folder (kept for inspection), else a temporary one."""
    if out is not None:
        (out / "sfm").mkdir(parents=True, exist_ok=True)
        yield out / "sfm"
    else:
        with tempfile.TemporaryDirectory(prefix="spotless-sfm-") as tmp:
            yield Path(tmp)


def _common_folder(data: DatasetViews) -> Path:
    """The single folder holding every input image of ``data`` (SfM reads images from one folder)."""
    folders = sorted({str(f.input_path.parent) for f in data.frames})
    if len(folders) != 1:
        raise ValueError(f"{data.root}: input images are spread over {len(folders)} folders ({folders}); SfM needs "
                         "them in one")
    return Path(folders[0])


def require_ground_truth(data_dir: str | os.PathLike, option: str) -> None:
    """InputError naming ``data_dir`` and the option that gave it when none of its test views has a ground-truth
    image: for a command that trains and then scores relit test views, before it trains."""
    if not any(f.gt_path is not None for f in read_dataset(data_dir).test_frames):
        raise InputError(f"{data_dir}: {option}: no test view has a ground-truth image (gt_file_path), and the relit "
                         "test views are scored against it; give a dataset with ground truth")


def scored_test_frames(data: DatasetViews) -> list[DatasetFrame]:
    """The dataset's test frames with ground truth, after checking that their input and ground-truth files exist.

    Raises:
        ValueError: no test view has a ground-truth image; FileNotFoundError: a listed image is missing (named).
    """
    test = [f for f in data.test_frames if f.gt_path is not None]
    if not test:
        raise ValueError(f"{data.root}: no test view has a ground-truth image (gt_file_path)")
    for f in test:
        for p in (f.gt_path, f.input_path):
            if not p.is_file():
                raise FileNotFoundError(f"{p}: image listed in transforms.json does not exist")
    return test


def score_inputs(data: DatasetViews, config: EvalConfig, sfm_dir: Path) -> tuple[dict, SfmResult | None]:
    """The original (uneven) inputs of a dataset, scored like a relit sequence: image metrics of the test views'
    inputs against the ground truth, temporal metrics of the whole input sequence (``config.temporal``), and SfM of
    the input folder with the dataset's intrinsics and true poses (``config.sfm``; work folder ``sfm_dir``).

    With SfM, when every frame has a ground-truth image in one folder (the simulator's datasets), SfM also runs on
    the evenly lit ground truth (``sfm_gt``, work folder ``<sfm_dir>_gt``): the reference for what perfect relighting
    would give the same pipeline.

    Returns:
        (the scores, with ``sfm`` and ``sfm_gt`` summaries when run; the inputs' SfmResult or None).
    """
    test = scored_test_frames(data)
    folder = _common_folder(data) if config.sfm else None  # before any work: a clear error, early
    scores = score_pairs([ImagePair(f.name, f.input_path, f.gt_path, f.depth_path) for f in test], config,
                         "input vs gt")
    if config.temporal:
        scores.update(temporal_block([f.input_path for f in data.frames], config, "input", data))
        flicker = ground_truth_flicker(data, config)  # what an evenly lit sequence has
        if flicker is not None:
            scores["gt_tmp_flicker"] = flicker
        leak = _exposure_leak([f.input_path for f in data.frames], data, config)
        if leak is not None:
            scores["tmp_exposure_leak"] = leak
    result = None
    if config.sfm:
        names = [f.name for f in data.frames]
        true = {f.name: opengl_to_opencv_c2w(f.c2w_opengl) for f in data.frames}
        scores["sfm"], result = _sfm_block(folder, names, sfm_dir, config, "input",
                                           data.intrinsics, true)
        gt_folder = _ground_truth_folder(data)
        if gt_folder is not None:
            scores["sfm_gt"], _ = _sfm_block(gt_folder, names, sfm_dir.with_name(sfm_dir.name + "_gt"), config,
                                             "ground truth", data.intrinsics, true)
    return scores, result


def _exposure_leak(paths: Sequence[Path], data: DatasetViews, config: EvalConfig) -> float | None:
    """:func:`evaluation.temporal.exposure_leak` of the sequence ``paths`` (one image per frame of ``data``, in
    order) against the ground truth, with the dataset's true exposure gains; None when the dataset has no gains (not
    a simulated robot camera's copy) or a frame has no ground truth."""
    if data.exposure_gains is None or not all(f.gt_path is not None for f in data.frames):
        return None
    with _torch_threads(config.num_threads), torch.no_grad():
        return exposure_leak((_chw(_load(p)) for p in paths), (_chw(_load(f.gt_path)) for f in data.frames),
                             data.exposure_gains)


def _excess_flicker(paths: Sequence[Path], data: DatasetViews, config: EvalConfig) -> float | None:
    """:func:`evaluation.temporal.excess_flicker` of the sequence ``paths`` (one image per frame of ``data``, in
    order) against the ground truth; None when a frame has no ground truth or there are fewer than two frames."""
    if len(paths) < 2 or not all(f.gt_path is not None and f.gt_path.is_file() for f in data.frames):
        return None
    with _torch_threads(config.num_threads), torch.no_grad():
        return excess_flicker((_chw(_load(p)) for p in paths), (_chw(_load(f.gt_path)) for f in data.frames))


def ground_truth_flicker(data: DatasetViews, config: EvalConfig = EvalConfig()) -> float | None:
    """The flicker (:func:`evaluation.temporal.sequence_flicker`) of the dataset's ground-truth sequence, every
    frame in order (the frames' ``gt_path``: the kind the dataset was read with); None when a frame has none."""
    if len(data.frames) < 2 or not all(f.gt_path is not None and f.gt_path.is_file() for f in data.frames):
        return None
    with _torch_threads(config.num_threads), torch.no_grad():
        return sequence_flicker(_chw(_load(f.gt_path)) for f in data.frames)


def _ground_truth_folder(data: DatasetViews) -> Path | None:
    """The single folder holding a ground-truth image of every frame of ``data`` with the input's file name (None
    when some frame has none, or they are spread over several folders or named otherwise)."""
    paths = [f.gt_path for f in data.frames]
    if any(p is None or not p.is_file() for p in paths):
        return None
    folders = {p.parent for p in paths}
    if len(folders) != 1 or any(p.name != f.name for p, f in zip(paths, data.frames)):
        return None
    return folders.pop()


def evaluate_run(
    run_dir: str | os.PathLike,
    config: EvalConfig = EvalConfig(),
    out_dir: str | os.PathLike | None = None,
    json_path: str | os.PathLike | None = None,
    data_dir: str | os.PathLike | None = None,
) -> dict:
    """Evaluate a training run: its relit test views against ground truth, temporal metrics on the whole relit and
    input sequences, and (``config.sfm``) SfM on inputs vs relit with the dataset's intrinsics and true poses. With
    ``config.inputs`` False the inputs are not scored (no ``input`` block, no ``sfm/input`` folder).

    The relit folder is checked first (:func:`check_relit_folder`: the run's current checkpoint, exactly the frames
    its manifest lists, unchanged), and the run folder's write lock is held throughout.

    Args:
        run_dir: the run folder (``run.json`` with the dataset's path, and ``relit/``).
        config: what to compute.
        out_dir: where results.json, results.md, figures/ and the output manifest go (default ``RUN/eval``).
        json_path: optional extra path for the JSON.
        data_dir: the run's dataset when it has moved (``--data``); default: run.json's paths
            (:func:`spotlessgs.training.checkpoint.resolve_data_dir`).

    Returns:
        the results dict: top-level keys for the relit sequence, ``input`` with the same keys for the original
        (uneven) inputs (absent when ``config.inputs`` is False), ``test_views``, ``relit_manifest`` (the manifest
        scored: path, sha256, checkpoint step and sha256; None for a run folder without checkpoint and manifest),
        ``config`` and ``provenance``.

    Raises:
        FileNotFoundError: run.json, relit images, inputs or ground truth missing (named).
        InputError: stale, unlisted, changed or unrecorded relit images; the dataset not found (see ``--data``).
        OutputOverlapError: ``out_dir`` overlaps the relit folder or the dataset, or ``json_path`` overlaps those,
            the run's checkpoints, run.json or config.json.
        ValueError: malformed run or dataset files, or no test view with ground truth.
        FolderLockedError: another process writes the run.
    """
    run = Path(run_dir)
    data_root = resolve_data_dir(run, read_run_info(run), data_dir)  # clear messages first
    relit_dir = run / "relit"
    if not relit_dir.is_dir():
        raise FileNotFoundError(f"{relit_dir}: the run has no relit images; run `spotless relight {run}` first")
    out = Path(out_dir) if out_dir is not None else run / "eval"
    refuse_overlap(out, {"RUN/relit": relit_dir, "--data": data_root}, "--out")
    _refuse_foreign_out(out)
    if json_path is not None:
        refuse_overlap(json_path, {"RUN/relit": relit_dir, "--data": data_root, "RUN/checkpoints": run / "checkpoints",
                                   "RUN/run.json": run / "run.json", "RUN/config.json": run / "config.json"}, "--json")
        refuse_run_file(json_path, run, "--json", may_replace=out)
    with source_and_output_locks(run, out, "spotless eval"):
        return _evaluate_run_locked(run, data_root, relit_dir, out, config, json_path)


def _evaluate_run_locked(run: Path, data_root: Path, relit_dir: Path, out: Path, config: EvalConfig,
                         json_path: str | os.PathLike | None) -> dict:
    """:func:`evaluate_run` with the run folder locked."""
    data = read_dataset(data_root, config.ground_truth)
    relit_manifest = check_relit_folder(run, relit_dir)
    # a verified manifest vouches for every file (EXR files of `relight --exr` included); else images only
    relit_names = set(image_names(relit_dir)) if relit_manifest is None else {
        p.name for p in list_image_files(relit_dir, non_images="skip")}
    missing = [f.name for f in data.frames if f.name not in relit_names]
    if missing:
        hint = "" if relit_manifest is None else f"; run `spotless relight {run}` (every view: --views all)"
        raise FileNotFoundError(f"{relit_dir}: missing relit images for {len(missing)} view(s), e.g. {missing[:3]}"
                                + hint)
    test = scored_test_frames(data)
    relit_pairs = [ImagePair(f.name, relit_dir / f.name, f.gt_path, f.depth_path) for f in test]

    results: dict = {"mode": "run", "run_dir": str(run), "data_dir": str(data.root),
                     "test_views": [f.name for f in test], "relit_manifest": relit_manifest,
                     "pose_alignment": relit_pose_alignment(relit_dir)}
    results.update(score_pairs(relit_pairs, config, "relit vs gt"))
    if config.temporal:
        results.update(temporal_block([relit_dir / f.name for f in data.frames], config, "relit", data))
        leak = _exposure_leak([relit_dir / f.name for f in data.frames], data, config)
        if leak is not None:
            results["tmp_exposure_leak"] = leak
    # against the ground truth read (config.ground_truth), so also where the temporal metrics are not asked for
    excess = _excess_flicker([relit_dir / f.name for f in data.frames], data, config)
    if excess is not None:
        results["tmp_flicker_excess"] = excess
    panels = {}
    names = [f.name for f in data.frames]
    true = {f.name: opengl_to_opencv_c2w(f.c2w_opengl) for f in data.frames}
    if config.inputs:
        results["input"], input_sfm = score_inputs(data, config, out / "sfm" / "input")
        if input_sfm is not None:
            panels[f"input ({input_sfm.registered_images}/{input_sfm.total_images} registered)"] = \
                _trajectory_panel(input_sfm, names, true)
    if config.sfm:
        results["sfm"], res = _sfm_block(relit_dir, names, out / "sfm" / "relit", config, "relit", data.intrinsics,
                                         true)
        panels[f"relit ({res.registered_images}/{res.total_images} registered)"] = _trajectory_panel(res, names, true)
    results["config"] = asdict(config)
    results["provenance"] = provenance(extra_packages=("pycolmap", "kornia"))

    idx = _grid_indices(len(test), config.grid_frames)
    save_image_grid(
        out / "figures" / "grid.png",
        [[_load(test[i].input_path), _load(relit_dir / test[i].name), _load(test[i].gt_path)]
         for i in idx],
        ["input", "relit", "ground truth"], [test[i].name for i in idx],
    )
    if panels:
        save_trajectory_plot(out / "figures" / "sfm_trajectories.png", panels)
    _write_outputs(out, Path(json_path) if json_path is not None else None, results, f"Evaluation of {run.name}")
    written = list(_EVAL_OUTPUTS[:3]) + (["figures/sfm_trajectories.png"] if panels else [])
    checkpoint = None if relit_manifest is None else {  # the checkpoint checked above (the lock keeps it)
        "file": Path(os.path.relpath(current_checkpoint(run), run)).as_posix(),
        "step": relit_manifest["checkpoint_step"], "sha256": relit_manifest["checkpoint_sha256"]}
    scored = {"folder": str(relit_dir.resolve()), "kind": "relit",
              "manifest_sha256": None if relit_manifest is None else relit_manifest["sha256"]}
    _write_eval_manifest(out, "eval", run, checkpoint, config, dataset_record(data.root, run, len(data.frames)),
                         scored, written)
    return results
