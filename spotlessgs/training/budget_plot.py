"""The Gaussian budget's trade-off as a figure: Gaussians vs relit PSNR vs relit render speed.

One point per run (e.g. the default strategy and the budget on each room): left panel relit PSNR against the number
of Gaussians, right panel relit frames per second against the number of Gaussians; runs of one room share a colour,
the marker says the strategy; a point that is the mean of repeated runs shows their PSNR range as an error bar.
Written atomically (PNG or PDF by the file name).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

from spotlessgs.io.atomic import atomic_path


@dataclass(frozen=True)
class BudgetPoint:
    """One run in the figure."""

    # Room / dataset name (one colour per room).
    room: str
    # Strategy label, e.g. "default" or "budget" (one marker per strategy).
    strategy: str
    # Final number of Gaussians.
    gaussians: int
    # Relit PSNR against the ground truth (dB), exposure-aligned (one least-squares gain per sequence, docs/method.md §10).
    relit_psnr: float
    # Relit rendering speed (frames per second).
    relit_fps: float
    # (low, high) relit PSNR over repeated runs when the point is their mean: drawn as an error bar (None = one run).
    psnr_range: tuple[float, float] | None = None

    def __post_init__(self) -> None:
        if self.gaussians < 1:
            raise ValueError(f"BudgetPoint {self.room}/{self.strategy}: gaussians must be >= 1, got {self.gaussians}")
        for name in ("relit_psnr", "relit_fps"):
            if not math.isfinite(getattr(self, name)):
                raise ValueError(f"BudgetPoint {self.room}/{self.strategy}: {name} is not finite")
        if self.psnr_range is not None:
            low, high = self.psnr_range
            if not (math.isfinite(low) and math.isfinite(high) and low <= self.relit_psnr <= high):
                raise ValueError(f"BudgetPoint {self.room}/{self.strategy}: psnr_range {self.psnr_range} must be "
                                 f"finite and contain relit_psnr {self.relit_psnr}")


def plot_budget(points: list[BudgetPoint], out_path: str | Path, title: str = "Gaussian budget") -> Path:
    """Draw the two panels for ``points`` (at least one) into ``out_path``; returns the path."""
    if not points:
        raise ValueError("plot_budget: no points to plot")
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    rooms = sorted({p.room for p in points})
    strategies = sorted({p.strategy for p in points})
    colours = {r: plt.get_cmap("tab10")(i % 10) for i, r in enumerate(rooms)}
    markers = {s: "os^Dv"[i % 5] for i, s in enumerate(strategies)}
    fig, axes = plt.subplots(1, 2, figsize=(9, 3.6))
    for ax, field, label in ((axes[0], "relit_psnr", "relit PSNR vs GT, exposure-aligned (dB)"),
                             (axes[1], "relit_fps", "relit render speed (FPS)")):
        for room in rooms:
            mine = sorted((p for p in points if p.room == room), key=lambda p: p.gaussians)
            ax.plot([p.gaussians for p in mine], [getattr(p, field) for p in mine], "-", color=colours[room],
                    alpha=0.5)
            for p in mine:
                if field == "relit_psnr" and p.psnr_range is not None:
                    ax.errorbar(p.gaussians, p.relit_psnr, yerr=[[p.relit_psnr - p.psnr_range[0]],
                                                                  [p.psnr_range[1] - p.relit_psnr]],
                                color=colours[room], capsize=3, alpha=0.7)
                ax.scatter(p.gaussians, getattr(p, field), color=colours[room], marker=markers[p.strategy],
                           label=f"{room} / {p.strategy}")
        ax.set_xlabel("Gaussians")
        ax.set_ylabel(label)
        ax.grid(alpha=0.3)
    axes[0].legend(fontsize=7)
    fig.suptitle(title)
    fig.tight_layout()
    out_path = Path(out_path)
    with atomic_path(out_path) as tmp:
        fig.savefig(tmp, format=out_path.suffix.lstrip(".") or "png", dpi=120)
    plt.close(fig)
    return out_path
