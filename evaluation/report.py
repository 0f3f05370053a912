"""Results to files: a JSON document (non-finite numbers become null) and a Markdown summary table."""

from __future__ import annotations

import math
import os
from typing import Any


from spotlessgs.io.atomic import to_jsonable, write_json, write_text

#: Image-metric keys in display order, with their column titles and number formats.
IMAGE_COLUMNS: tuple[tuple[str, str, str], ...] = (
    ("psnr", "PSNR ↑", "{:.2f}"),
    ("ssim", "SSIM ↑", "{:.4f}"),
    ("lpips", "LPIPS ↓", "{:.4f}"),
    ("psnr_aligned", "PSNR al. ↑", "{:.2f}"),
    ("ssim_aligned", "SSIM al. ↑", "{:.4f}"),
    ("lpips_aligned", "LPIPS al. ↓", "{:.4f}"),
    # the same with the ground truth's lamps left out (datasets with an emission pass; evaluation.runner.score_pairs)
    ("psnr_aligned_masked", "PSNR al. no lamps ↑", "{:.2f}"),
    ("ssim_aligned_masked", "SSIM al. no lamps ↑", "{:.4f}"),
    ("lpips_aligned_masked", "LPIPS al. no lamps ↓", "{:.4f}"),
    ("tmp_psnr", "tPSNR ↑", "{:.2f}"),
    ("tmp_ssim", "tSSIM ↑", "{:.4f}"),
    ("tmp_psnr_warped", "tPSNR warp ↑", "{:.2f}"),
    ("tmp_ssim_warped", "tSSIM warp ↑", "{:.4f}"),
)
#: SfM keys in display order, with their column titles and formats.
SFM_COLUMNS: tuple[tuple[str, str, str], ...] = (
    ("reprojection_error_px", "Reproj. err. (px) ↓", "{:.3f}"),
    ("observations_per_image", "Obs./image ↑", "{:.1f}"),
    ("registered_images", "Registered", "{}"),
    ("points3d", "3D points", "{}"),
    ("models", "Sub-models", "{}"),
)


def write_results_json(path: str | os.PathLike, results: dict) -> None:
    """Write ``results`` atomically as JSON (see :func:`to_jsonable`)."""
    write_json(path, to_jsonable(results))


def _fmt(value: Any, fmt: str) -> str:
    """One table cell: '—' for missing or non-finite values (an identical image pair has PSNR = ∞: shown as '∞')."""
    if value is None:
        return "—"
    if isinstance(value, float) and math.isinf(value):
        return "∞" if value > 0 else "−∞"
    if isinstance(value, float) and math.isnan(value):
        return "—"
    return fmt.format(value)


def markdown_report(results: dict, title: str = "Evaluation") -> str:
    """A Markdown summary: one image/temporal-metric row per sequence, then an SfM table when SfM was run.

    Args:
        results: the dict returned by :func:`evaluation.runner.evaluate_folders` or ``evaluate_run``: top-level metric
            keys for the evaluated sequence, and optionally an ``input`` dict with the same keys for the original
            inputs.
        title: the heading.
    """
    rows = [({"run": "relit", "folders": "prediction"}.get(results.get("mode"), "evaluated"), results)]
    if isinstance(results.get("input"), dict):
        rows.append(("input (uneven)", results["input"]))
    cols = [c for c in IMAGE_COLUMNS if any(r.get(c[0]) is not None for _, r in rows)]
    lines = [f"# {title}", ""]
    if "num_images" in results:
        lines.append(f"{results['num_images']} scored image(s)"
                     + (f"; exposure gain {results['exposure_gain']:.4f}" if results.get("exposure_gain") else "")
                     + ".")
        lines.append("")
    alignment = results.get("pose_alignment")
    if isinstance(alignment, dict):
        views = alignment.get("aligned_views") or []
        if views:
            lines.append(f"Camera poses refined in training; {len(views)} view(s) that training did not fit "
                         f"({', '.join(views[:6])}{', ...' if len(views) > 6 else ''}) were aligned to their "
                         f"spotlit inputs ({alignment.get('loss')} loss, {alignment.get('steps')} steps, model "
                         "frozen, never the ground truth) before relighting.")
        else:
            lines.append("Camera poses refined in training; the views that training did not fit were relit at the "
                         "dataset's poses (not aligned).")
        lines.append("")
    if cols:
        lines.append("| sequence | " + " | ".join(t for _, t, _ in cols) + " |")
        lines.append("|---|" + "---|" * len(cols))
        for label, r in rows:
            lines.append(f"| {label} | " + " | ".join(_fmt(r.get(k), f) for k, _, f in cols) + " |")
        lines.append("")
    sfm_rows = [(label, r["sfm"]) for label, r in rows if isinstance(r.get("sfm"), dict)]
    if isinstance(results.get("input"), dict) and isinstance(results["input"].get("sfm_gt"), dict):
        sfm_rows.append(("ground truth (evenly lit, reference)", results["input"]["sfm_gt"]))
    if sfm_rows:
        has_traj = any(isinstance(s.get("trajectory"), dict) for _, s in sfm_rows)
        head = [t for _, t, _ in SFM_COLUMNS] + (["ATE RMSE ↓", "RRE (deg) ↓"] if has_traj else [])
        lines += ["## Structure from motion", "", "| sequence | " + " | ".join(head) + " |", "|---|" + "---|" * len(head)]
        for label, s in sfm_rows:
            cells = [_fmt(s.get(k), f) for k, _, f in SFM_COLUMNS]
            cells[2] = f"{s.get('registered_images', 0)}/{s.get('total_images', 0)}"
            if has_traj:
                t = s.get("trajectory") or {}
                cells += [_fmt(t.get("ate_rmse"), "{:.4f}"), _fmt(t.get("rre_mean_deg"), "{:.3f}")]
            lines.append(f"| {label} | " + " | ".join(cells) + " |")
        lines.append("")
    return "\n".join(lines)


def write_markdown(path: str | os.PathLike, results: dict, title: str = "Evaluation") -> None:
    """Write :func:`markdown_report` atomically."""
    write_text(path, markdown_report(results, title))
