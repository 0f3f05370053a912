"""Where in the image the SfM observations lie, and how well they re-project there, for finished SfM runs.

    python -m evaluation.sfm_rings original=OUT/inputs/bedroom-uneven/sfm/sparse \\
        relit=OUT/runs/bedroom-uneven/spotless/eval/sfm/relit/sparse --bins 4

prints one Markdown row per run: its mean reprojection error (COLMAP's, over 3D points) and, per ring of image radius
(fraction of the half-diagonal), the share of the observations and their mean reprojection error. Under a
camera-mounted spotlight the features of the original images crowd in the bright centre, which changes the mean error
for reasons other than image quality; the rings compare like with like.
"""

from __future__ import annotations

from pathlib import Path

import click


def ring_table(runs: dict[str, Path], bins: int) -> str:
    """Markdown table of :meth:`evaluation.sfm.SfmResult.errors_by_radius` for every labelled sparse folder."""
    from evaluation.sfm import load_sfm_result, ring_cell

    rows = []
    for label, sparse in runs.items():
        result = load_sfm_result(sparse)
        rings = result.errors_by_radius(bins)
        total = sum(r["observations"] for r in rings)
        cells = [ring_cell(r, total) for r in rings]
        mean = "n/a" if result.reprojection_error_px is None else f"{result.reprojection_error_px:.3f}"
        rows.append(f"| {label} | {total} | {mean} | " + " | ".join(cells) + " |")
    edges = [f"r {k / bins:.2f}–{(k + 1) / bins:.2f}" for k in range(bins)]
    header = "| run | observations | reprojection error (px) | " + " | ".join(edges) + " |"
    return "\n".join([header, "|" + "---|" * (3 + bins)] + rows)


def _labelled(_ctx, _param, values: tuple[str, ...]) -> dict[str, Path]:
    runs: dict[str, Path] = {}
    for value in values:
        label, sep, path = value.partition("=")
        if not sep or not label or not path:
            raise click.BadParameter(f"{value!r}: expected LABEL=SPARSE_DIR")
        if label in runs:
            raise click.BadParameter(f"label {label!r} given twice")
        runs[label] = Path(path)
    return runs


@click.command(context_settings={"help_option_names": ["-h", "--help"]})
@click.argument("runs", nargs=-1, required=True, callback=_labelled)
@click.option("--bins", default=4, show_default=True, type=click.IntRange(1, 20), help="Rings of image radius.")
def main(runs: dict[str, Path], bins: int) -> None:
    """Reprojection error by image radius of finished SfM runs (LABEL=SPARSE_DIR, the folder of COLMAP sub-models)."""
    try:
        click.echo(ring_table(runs, bins))
    except FileNotFoundError as err:
        raise click.ClickException(str(err)) from err


if __name__ == "__main__":
    main()
