"""The relighting ceiling: what the best relighting of the form albedo × light can score against the ground truth.

SpotlessGS relights as albedo × BRDF × (L0 + L_lf); the lamps-on ground truth also holds what no such relighting
produces (glowing lamp surfaces, lamp fall-off and shadows, a warm tint). Two oracles use the renderer's own
reflectance ``a`` of the visible surfaces: the diffuse plus the glossy colour pass in each frame's EXR
(:meth:`spotlessgs.io.exr.FrameEXR.reflectance`; the diffuse colour alone for datasets rendered before the glossy
pass, on which a metal reflects nothing), scored like every method on the same test views:

* ``albedo``: the reflectance and one best gain for the whole sequence: the aligned metrics of
  :func:`evaluation.runner.score_pairs` apply exactly that gain;
* ``albedo-sh``: the reflectance times the best light per surface normal, ``a · max(0, cᵀY(n))`` with real SH of degree
  3 (the form of the relighting's L0 + L_lf), ``c`` fitted per colour channel by least squares against the linear
  ground truth over every test pixel that is not an emitter (:meth:`FrameEXR.emitters`).

Against the uniform ground truth (``--ground-truth uniform``: even, shadow-free light; a dataset rendered with
``spotless-sim render --gt uniform``) the oracles are the same, fitted and scored against that ground truth instead.

    spotless ceiling DATA --out CEILING     # CEILING/albedo, CEILING/albedo-sh, CEILING/gt, CEILING/eval-*
"""

from __future__ import annotations

import dataclasses
import shutil
from pathlib import Path

import numpy as np
import torch

from evaluation.dataset import read_dataset
from evaluation.folders import ImagePair
from evaluation.report import write_markdown, write_results_json
from evaluation.runner import EvalConfig, score_pairs, scored_test_frames
from spotlessgs.io.atomic import atomic_path, write_json
from spotlessgs.io.colorspace import linear_to_srgb
from spotlessgs.io.errors import InputError
from spotlessgs.io.exr import read_frame_exr
from spotlessgs.io.images import write_png
from spotlessgs.io.json_files import read_json
from spotlessgs.io.paths import refuse_foreign_folder, refuse_overlap
from spotlessgs.io.provenance import provenance
from spotlessgs.models.sh import sh_basis

#: SH degree of the oracle's light per normal (the relighting's low-frequency light uses up to 3).
ORACLE_SH_DEGREE = 3
#: The oracles, in the order they are scored: folder name -> what it is.
#: The record a ceiling folder holds: which dataset and ground truth its images are of (and how they were made).
CEILING_RECORD = "ceiling.json"
ORACLES = {"albedo": "true reflectance x one gain", "albedo-sh": "true reflectance x best light per normal (SH 3)"}


def _test_frames(data_dir: Path, ground_truth: str = "lamps"):
    """(frame, FrameEXR with albedo) of every scored test view, the frames' ``gt_path`` the ``ground_truth`` kind;
    InputError naming the file where a pass is missing."""
    out = []
    for frame in scored_test_frames(read_dataset(data_dir, ground_truth)):
        if frame.depth_path is None:
            raise InputError(f"{data_dir}: test view {frame.name} has no EXR (exr_file_path); the ceiling needs the "
                             "renderer's albedo pass")
        exr = read_frame_exr(frame.depth_path)
        if exr.albedo is None:
            raise InputError(f"{frame.depth_path}: no albedo pass (albedo.R/G/B); render the dataset again with "
                             "spotless-sim render (datasets from 2026-11-24 on have it)")
        if ground_truth == "uniform" and exr.gt_uniform is None:
            raise InputError(f"{frame.depth_path}: no uniform ground truth (gt_uniform.R/G/B); render the dataset with "
                             "spotless-sim render --gt uniform")
        out.append((frame, exr))
    return out


def linear_ground_truth(exr, ground_truth: str = "lamps") -> np.ndarray:
    """(H, W, 3) the linear ground truth of kind ``ground_truth`` held by a FrameEXR."""
    return exr.gt_uniform if ground_truth == "uniform" else exr.gt


def normal_basis(exr, degree: int = ORACLE_SH_DEGREE) -> tuple[np.ndarray, np.ndarray]:
    """(H, W, (degree+1)²) real SH basis of a FrameEXR's unit normals, and the (H, W) bool pixels that show a surface
    (finite depth, a normal of unit length)."""
    length = np.linalg.norm(exr.normal, axis=-1, keepdims=True)
    normals = exr.normal / np.maximum(length, 1e-12)
    basis = sh_basis(torch.from_numpy(normals.astype(np.float64)), degree).numpy()
    return basis, np.isfinite(exr.depth) & (length[..., 0] > 0.5)


def fit_light_per_normal(frames, bases, ground_truth: str = "lamps") -> np.ndarray:
    """(3, B) SH coefficients ``c`` of the light per normal minimising Σ (a · cᵀY(n) − g)² per channel (a the
    reflectance) over the
    pixels of ``frames`` (FrameEXRs) that show a surface and no emitter, g the ``ground_truth`` kind; ``bases``: each
    frame's :func:`normal_basis`."""
    albedo, basis, gt = [], [], []
    for exr, (frame_basis, surface) in zip(frames, bases):
        lamps = exr.emitters()
        use = surface if lamps is None else surface & ~lamps
        albedo.append(exr.reflectance()[use])
        basis.append(frame_basis[use])
        gt.append(linear_ground_truth(exr, ground_truth)[use])
    albedo, gt = np.concatenate(albedo).astype(np.float64), np.concatenate(gt).astype(np.float64)
    basis = np.concatenate(basis)
    return np.stack([np.linalg.lstsq(albedo[:, ch, None] * basis, gt[:, ch], rcond=None)[0] for ch in range(3)])


def write_oracles(data_dir: str | Path, out: str | Path, ground_truth: str = "lamps") -> tuple[list[ImagePair], str]:
    """Each oracle's images of every scored test view (sRGB PNGs named as the inputs) in ``out/<oracle>`` and their
    ground truths (copies) in ``out/gt``; returns the image pairs of the first oracle (the others: the same names in
    their folders), each with its frame's EXR (for the lamp-masked metrics), and what the reflectance was made of
    (every EXR with the glossy pass or not); ``ground_truth``: the kind fitted and copied.

    Raises:
        InputError: a test view has no EXR, or its EXR has no albedo pass (rendered before 2026-11-24: render the
            dataset again), naming the file; ``out`` holds files but no :data:`CEILING_RECORD`, or the ceiling of
            another dataset or ground truth.
    """
    data_dir, out = Path(data_dir), Path(out)
    refuse_overlap(out, {"DATA": data_dir}, "--out")
    refuse_foreign_folder(out, [CEILING_RECORD], "--out", "a ceiling written by this command")
    wanted = {"data": str(data_dir.resolve()), "ground_truth": ground_truth}
    if (out / CEILING_RECORD).is_file():
        old = read_json(out / CEILING_RECORD, "a ceiling's record")
        if {k: old.get(k) for k in wanted} != wanted:
            raise InputError(f"{out}: holds the ceiling of {old.get('data')} ({old.get('ground_truth')} ground truth), "
                             "not of this dataset and ground truth; choose an empty or new --out")
    frames = _test_frames(data_dir, ground_truth)
    write_json(out / CEILING_RECORD, {**wanted, **provenance()})
    bases = [normal_basis(exr) for _, exr in frames]
    coefficients = fit_light_per_normal([exr for _, exr in frames], bases, ground_truth)
    pairs = []
    for (frame, exr), (basis, _surface) in zip(frames, bases):
        light = np.maximum(basis @ coefficients.T, 0.0)  # (H, W, 3)
        reflectance = exr.reflectance()
        write_png(out / "albedo" / frame.name, linear_to_srgb(np.clip(reflectance, 0.0, 1.0)))
        write_png(out / "albedo-sh" / frame.name, linear_to_srgb(np.clip(reflectance * light, 0.0, 1.0)))
        with atomic_path(out / "gt" / frame.name) as tmp:
            shutil.copy2(frame.gt_path, tmp)
        pairs.append(ImagePair(frame.name, out / "albedo" / frame.name, out / "gt" / frame.name, frame.depth_path))
    glossy = all(exr.glossy is not None for _, exr in frames)
    return pairs, "diffuse + glossy colour" if glossy else "diffuse colour (no glossy pass)"


def ceiling(data_dir: str | Path, out: str | Path, config: EvalConfig = EvalConfig()) -> dict[str, dict]:
    """Write the oracles of ``data_dir`` into ``out`` and score each against the ground truth like a method's test
    views (image metrics, aligned, and without the lamps where the EXRs have an emission pass; results in
    ``out/eval-<oracle>/results.json`` and ``.md``; ``config.ground_truth``: which of the dataset's ground truths);
    returns the results by oracle name."""
    out = Path(out)
    pairs, reflectance = write_oracles(data_dir, out, config.ground_truth)
    results = {}
    for name in ORACLES:
        oracle = [dataclasses.replace(p, pred=out / name / p.name) for p in pairs]
        results[name] = {"mode": "ceiling", "oracle": name, "what": ORACLES[name], "data": str(data_dir),
                         "ground_truth": config.ground_truth,
                         "reflectance": reflectance,
                         **score_pairs(oracle, config, name)}
        write_results_json(out / f"eval-{name}" / "results.json", results[name])
        write_markdown(out / f"eval-{name}" / "results.md", results[name], f"Ceiling: {ORACLES[name]}")
    return results
