"""The relighting ceiling: what the best relighting of the form albedo × light can score against the ground truth.

SpotlessGS relights as albedo × BRDF × (L0 + L_lf); the lamps-on ground truth also holds what no such relighting
produces (glowing lamp surfaces, lamp fall-off and shadows, a warm tint). The first oracle takes the renderer's own
albedo (the diffuse colour pass in each frame's EXR, :class:`spotlessgs.io.exr.FrameEXR`) and one best gain for the
whole sequence: the aligned metrics of :func:`evaluation.runner.score_pairs` apply exactly that gain, so the oracle
is scored like every method, on the same test views.

    spotless ceiling DATA --out CEILING     # writes CEILING/pred (albedo) and CEILING/gt, then scores them
"""

from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np

from evaluation.dataset import read_dataset
from evaluation.runner import EvalConfig, evaluate_folders, scored_test_frames
from spotlessgs.io.atomic import atomic_path
from spotlessgs.io.colorspace import linear_to_srgb
from spotlessgs.io.errors import InputError
from spotlessgs.io.exr import read_frame_exr
from spotlessgs.io.images import write_png
from spotlessgs.io.paths import refuse_overlap


def write_albedo_oracle(data_dir: str | Path, out: str | Path) -> tuple[Path, Path]:
    """``out/pred``: the albedo of every scored test view of the dataset (sRGB PNGs named as the inputs), and
    ``out/gt``: their ground truths (copies), so that ``spotless eval --pred out/pred --gt out/gt`` scores the oracle.

    Raises:
        InputError: a test view has no EXR, or its EXR has no albedo pass (rendered before 2026-11-24: render the
            dataset again), naming the file.
    """
    data_dir, out = Path(data_dir), Path(out)
    refuse_overlap(out, {"DATA": data_dir}, "--out")
    data = read_dataset(data_dir)
    pred_dir, gt_dir = out / "pred", out / "gt"
    for frame in scored_test_frames(data):
        if frame.depth_path is None:
            raise InputError(f"{data_dir}: test view {frame.name} has no EXR (exr_file_path); the ceiling needs the "
                             "renderer's albedo pass")
        albedo = read_frame_exr(frame.depth_path).albedo
        if albedo is None:
            raise InputError(f"{frame.depth_path}: no albedo pass (albedo.R/G/B); render the dataset again with "
                             "spotless-sim render (datasets from 2026-11-24 on have it)")
        write_png(pred_dir / frame.name, linear_to_srgb(np.clip(albedo, 0.0, 1.0)))
        with atomic_path(gt_dir / frame.name) as tmp:
            shutil.copy2(frame.gt_path, tmp)
    return pred_dir, gt_dir


def albedo_ceiling(data_dir: str | Path, out: str | Path, config: EvalConfig = EvalConfig()) -> dict:
    """Write the albedo oracle of ``data_dir`` into ``out`` and score it (results in ``out/eval``): its aligned
    metrics are albedo × one best gain against the ground truth, on the test views."""
    pred_dir, gt_dir = write_albedo_oracle(data_dir, out)
    return evaluate_folders(pred_dir, gt_dir, config, out_dir=Path(out) / "eval")
