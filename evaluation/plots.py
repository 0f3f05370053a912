"""Figures (matplotlib, Agg backend, written atomically): a side-by-side image grid and SfM trajectory plots."""

from __future__ import annotations

import os
from typing import Mapping, Sequence

import numpy as np

from spotlessgs.io.figures import pyplot, save_figure


def save_image_grid(
    path: str | os.PathLike,
    rows: Sequence[Sequence[np.ndarray]],
    column_titles: Sequence[str],
    row_titles: Sequence[str],
) -> None:
    """Write a grid of images (one row per frame, one column per source, e.g. input / relit / ground truth).

    Args:
        path: output PNG.
        rows: rows × columns of (H, W, 3) float images in [0, 1].
        column_titles: one title per column.
        row_titles: one label per row (e.g. the frame name).
    """
    if not rows or any(len(r) != len(column_titles) for r in rows) or len(row_titles) != len(rows):
        raise ValueError("image grid: every row needs one image per column title, and one title per row")
    plt = pyplot()
    h, w = rows[0][0].shape[:2]
    ncol, nrow = len(column_titles), len(rows)
    scale = 3.2 / max(w, h) * max(w, 1)
    fig, axes = plt.subplots(nrow, ncol, figsize=(scale * ncol, scale * h / w * nrow + 0.4), squeeze=False)
    for r, images in enumerate(rows):
        for c, img in enumerate(images):
            ax = axes[r][c]
            ax.imshow(np.clip(img, 0, 1), interpolation="nearest")
            ax.set_xticks([])
            ax.set_yticks([])
            if r == 0:
                ax.set_title(column_titles[c], fontsize=10)
            if c == 0:
                ax.set_ylabel(row_titles[r], fontsize=8)
    save_figure(fig, path, dpi=110)


def save_trajectory_plot(
    path: str | os.PathLike,
    panels: Mapping[str, dict],
) -> None:
    """Top-down plot of SfM camera trajectories (coloured by time) over their sparse points, one panel per sequence.

    Args:
        path: output PNG.
        panels: title → dict with ``centres`` (N, 3) estimated camera centres in time order, ``points`` (P, 3) sparse
            points (same frame), and optionally ``true_centres`` (N, 3) for the same frames; when true centres are given
            the estimate must already be aligned to them (world z up: the plot shows x–y), otherwise the plot shows the
            two principal axes of the estimate.
    """
    if not panels:
        raise ValueError("trajectory plot: no panels")
    plt = pyplot()
    fig, axes = plt.subplots(1, len(panels), figsize=(5.2 * len(panels), 4.8), squeeze=False)
    for ax, (title, panel) in zip(axes[0], panels.items()):
        centres = np.asarray(panel.get("centres", np.zeros((0, 3))), dtype=np.float64).reshape(-1, 3)
        points = np.asarray(panel.get("points", np.zeros((0, 3))), dtype=np.float64).reshape(-1, 3)
        true = panel.get("true_centres")
        if true is not None:
            basis, origin = np.eye(3)[:, :2], np.zeros(3)
            xlabel, ylabel = "x (m)", "y (m)"
        else:
            basis, origin = _principal_plane(centres if len(centres) >= 3 else points)
            xlabel, ylabel = "principal axis 1", "principal axis 2"
        if len(points):
            pp = (points - origin) @ basis
            if len(centres):  # keep far outliers from squashing the plot
                lo, hi = np.percentile(pp, 1, axis=0), np.percentile(pp, 99, axis=0)
                pp = pp[np.all((pp >= lo) & (pp <= hi), axis=1)]
            ax.scatter(pp[:, 0], pp[:, 1], s=1, c="0.7", label="sparse points", rasterized=True)
        if true is not None:
            tt = (np.asarray(true, dtype=np.float64).reshape(-1, 3) - origin) @ basis
            ax.plot(tt[:, 0], tt[:, 1], "--", color="0.2", lw=1, label="true")
        if len(centres):
            cc = (centres - origin) @ basis
            ax.plot(cc[:, 0], cc[:, 1], "-", color="0.4", lw=0.8)
            sc = ax.scatter(cc[:, 0], cc[:, 1], c=np.arange(len(cc)), cmap="viridis", s=14, zorder=3,
                            label="estimated")
            fig.colorbar(sc, ax=ax, label="frame")
        ax.set_title(title)
        ax.set_xlabel(xlabel)
        ax.set_ylabel(ylabel)
        ax.set_aspect("equal", adjustable="datalim")
        if len(centres) or len(points):
            ax.legend(loc="best", fontsize=7)
    save_figure(fig, path, dpi=110)


def _principal_plane(x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(3, 2) basis of the two largest principal axes of (N, 3) points and their (3,) mean (identity for < 2 points)."""
    if len(x) < 2:
        return np.eye(3)[:, :2], np.zeros(3)
    mean = x.mean(0)
    _, _, vt = np.linalg.svd(x - mean, full_matrices=False)
    basis = np.zeros((3, 2))
    basis[:, : min(2, len(vt))] = vt[:2].T
    return basis, mean
