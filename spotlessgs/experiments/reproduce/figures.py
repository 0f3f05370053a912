"""Figures of the report: the qualitative grid and the speed-against-error plot (PNG, written atomically)."""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import numpy as np

from evaluation.plots import save_image_grid
from spotlessgs.io.figures import pyplot, save_figure
from spotlessgs.io.dataset import UNIFORM_GT_DIR
from spotlessgs.io.images import read_image
from spotlessgs.experiments.reproduce.tables import LABELS, best_darkgs


def qualitative_grid(path: Path, data_dir: Path, runs_dir: Path, methods: dict[str, Any], test_views: list[str],
                     max_rows: int = 3, ceiling_dir: Path | None = None) -> list[str]:
    """Write input / 3DGS / DarkGS (the better run) / ours / ours auto / the ceiling / GT / the uniform GT for up to
    ``max_rows`` test views.

    Args:
        path: output PNG.
        data_dir: the dataset folder (``images/``, ``gt/``, and ``gt_uniform/`` when it has the uniform ground truth).
        runs_dir: folder holding one run folder per method (``<method>/relit/<name>``).
        methods: the dataset's method entries (to choose the DarkGS run).
        test_views: file names of the test views.
        ceiling_dir: the dataset's relighting ceiling (``albedo-sh/<name>``: the true albedo under the best light per
            normal), drawn when it holds every picked view.
    Returns:
        the column titles actually drawn (methods that were not trained are left out).
    Raises:
        ValueError: no test views.
    """
    if not test_views:
        raise ValueError(f"{data_dir}: no test views for the qualitative grid")
    darkgs, _ = best_darkgs(methods)
    columns: list[tuple[str, Path]] = [("Input", data_dir / "images")]
    for key, title in (("3dgs", "3DGS"), (darkgs, LABELS.get(darkgs or "", "DarkGS")), ("spotless", "Ours"),
                       ("auto", "Ours (auto)")):
        if key and key in methods:
            columns.append((title, runs_dir / key / "relit"))
    picks = [test_views[int(round(i))] for i in np.linspace(0, len(test_views) - 1, min(max_rows, len(test_views)))]
    for title, folder in (("Ceiling (true albedo)", None if ceiling_dir is None else ceiling_dir / "albedo-sh"),
                          ("Ground truth", data_dir / "gt"),
                          ("Uniform ground truth", data_dir / UNIFORM_GT_DIR)):
        if folder is not None and (title == "Ground truth" or all((folder / n).is_file() for n in picks)):
            columns.append((title, folder))
    rows = [[read_image(folder / name, alpha="over_black") for _title, folder in columns] for name in picks]
    save_image_grid(path, rows, [t for t, _ in columns], picks)
    return [t for t, _ in columns]


def speed_error_plot(path: Path, collected: dict[str, Any]) -> None:
    """Test PSNR (exposure-aligned) against training time: one curve per 3D method (a point per curve milestone),
    one subplot per dataset; 2D baselines as markers (Cycle-GAN at its training time) or horizontal lines (no
    training)."""
    plt = pyplot()
    datasets = list(collected["datasets"].items())
    fig, axes = plt.subplots(1, max(len(datasets), 1), figsize=(5.2 * max(len(datasets), 1), 4.0), squeeze=False)
    for ax, (ds_name, ds) in zip(axes[0], datasets):
        for name, entry in ds.get("methods", {}).items():
            curve = [p for p in entry.get("curve", []) if _finite(p.get("psnr_aligned"))]
            if curve:
                ax.plot([p["train_seconds"] for p in curve], [p["psnr_aligned"] for p in curve], marker="o",
                        label=LABELS.get(name, name))
        for name, entry in ds.get("baselines2d", {}).items():
            value = entry.get("metrics", {}).get("psnr_aligned")
            if not _finite(value):
                continue
            if name == "cyclegan" and _finite((collected.get("cyclegan") or {}).get("seconds")):
                ax.scatter([collected["cyclegan"]["seconds"]], [value], marker="s", label=LABELS[name], zorder=3)
            else:
                ax.axhline(value, linestyle="--", linewidth=1, label=f"{LABELS.get(name, name)} (no training)",
                           color="0.5" if name == "clahe" else "0.7")
        input_psnr = (ds.get("input") or {}).get("psnr_aligned")
        if _finite(input_psnr):
            ax.axhline(input_psnr, linestyle=":", color="k", linewidth=1, label="Input (spotlight-lit)")
        ax.set_title(ds_name)
        ax.set_xlabel("training time (s)")
        ax.set_ylabel("test PSNR, exposure-aligned (dB)")
        ax.grid(alpha=0.3)
        ax.legend(fontsize=7)
    save_figure(fig, path, dpi=110)


def _finite(x: Any) -> bool:
    return isinstance(x, (int, float)) and not isinstance(x, bool) and math.isfinite(x)
