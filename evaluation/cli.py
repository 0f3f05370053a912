"""`spotless eval` and `spotless sfm-rings`: thin click commands over the evaluation library (`spotless eval` builds an
:class:`EvalConfig` and calls one runner function)."""

from __future__ import annotations

from pathlib import Path

import click

from spotlessgs.clitools import THREAD_COUNT


@click.command("eval", context_settings={"help_option_names": ["-h", "--help"]})
@click.argument("run", required=False, type=click.Path(exists=True, file_okay=False, path_type=Path))
@click.option("--pred", type=click.Path(exists=True, file_okay=False, path_type=Path),
              help="Folder of predicted images (folder mode; needs --gt).")
@click.option("--gt", type=click.Path(exists=True, file_okay=False, path_type=Path),
              help="Folder of reference images, matched to --pred by file name.")
@click.option("--match", type=click.Choice(["both", "pred"]), default="both", show_default=True,
              help="Folder mode: 'both' scores the names both folders hold (they must hold the same); 'pred' scores "
                   "every image of --pred against its namesake in --gt, which may hold more (e.g. a dataset's gt/ "
                   "beside `relight --views test`).")
@click.option("--data", "data_dir", type=click.Path(exists=True, file_okay=False, path_type=Path),
              help="RUN mode: the run's dataset, when it has moved (default: the path recorded in RUN/run.json).")
@click.option("--sfm/--no-sfm", default=False, show_default=True, help="Also run downstream SfM (pycolmap, CPU).")
@click.option("--matcher", type=click.Choice(["sequential", "exhaustive"]), default="sequential", show_default=True,
              help="SfM image pairing.")
@click.option("--out", "out_dir", type=click.Path(file_okay=False, path_type=Path),
              help="Output folder for results.json, results.md and figures/ (run mode default: RUN/eval).")
@click.option("--json", "json_path", type=click.Path(dir_okay=False, path_type=Path),
              help="Also write the results JSON to this file.")
@click.option("--ground-truth", default="lamps", show_default=True, type=click.Choice(["lamps", "uniform"]),
              help="RUN mode: score against the dataset's lamps-on ground truth or its uniform one (even, shadow-free "
                   "light; a dataset rendered with `spotless-sim render --gt uniform`).")
@click.option("--no-lpips", is_flag=True, help="Skip LPIPS.")
@click.option("--threads", type=THREAD_COUNT, default=None, help="CPU threads for metrics and SfM.")
@click.option("--quiet", is_flag=True, help="No progress bars.")
def eval_command(run, pred, gt, match, data_dir, sfm, matcher, out_dir, json_path, ground_truth, no_lpips, threads,
                 quiet) -> None:
    """Score relit images: `spotless eval RUN` evaluates a training run; `spotless eval --pred DIR --gt DIR` scores
    any two folders of images matched by file name."""
    from evaluation.runner import EvalConfig, evaluate_folders, evaluate_run
    from evaluation.sfm import SfmConfig

    if run is not None and (pred is not None or gt is not None):
        raise click.UsageError("give either RUN or --pred/--gt, not both")
    if run is None and (pred is None or gt is None):
        raise click.UsageError("give a RUN folder, or both --pred DIR and --gt DIR")
    if data_dir is not None and run is None:
        raise click.UsageError("--data only applies to RUN mode")
    if match != "both" and run is not None:
        raise click.UsageError("--match only applies to folder mode (RUN mode scores the run's test views)")
    if ground_truth != "lamps" and run is None:
        raise click.UsageError("--ground-truth only applies to RUN mode (folder mode scores against --gt)")
    sfm_config = SfmConfig(matcher=matcher, **({"num_threads": threads} if threads else {}))
    config = EvalConfig(lpips=not no_lpips, sfm=sfm, sfm_config=sfm_config, num_threads=threads, progress=not quiet,
                        ground_truth=ground_truth)
    if run is not None:
        results = evaluate_run(run, config, out_dir=out_dir, json_path=json_path, data_dir=data_dir)
        where = out_dir or run / "eval"
    else:
        results = evaluate_folders(pred, gt, config, json_path=json_path, out_dir=out_dir, match=match)
        where = out_dir or json_path
    from evaluation.report import markdown_report

    click.echo(markdown_report(results))
    if where is not None:
        click.echo(f"results written to {where}")


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


@click.command("sfm-rings", context_settings={"help_option_names": ["-h", "--help"]})
@click.argument("runs", nargs=-1, required=True, callback=_labelled)
@click.option("--bins", default=4, show_default=True, type=click.IntRange(1, 20), help="Rings of image radius.")
def sfm_rings_command(runs: dict[str, Path], bins: int) -> None:
    """Reprojection error by image radius of finished SfM runs (LABEL=SPARSE_DIR, the folder of COLMAP sub-models).

    One Markdown row per run: its mean reprojection error (COLMAP's, over 3D points) and, per ring of image radius
    (fraction of the half-diagonal), the share of the observations and their mean reprojection error. Under a
    camera-mounted spotlight the features of the original images crowd in the bright centre, which changes the mean
    error for reasons other than image quality; the rings compare like with like."""
    from evaluation.sfm import ring_table  # deferred: the evaluation library, kept out of `spotless --help`
    try:
        click.echo(ring_table(runs, bins))
    except FileNotFoundError as err:
        raise click.ClickException(str(err)) from err


@click.command("ceiling", context_settings={"help_option_names": ["-h", "--help"]})
@click.argument("data", type=click.Path(exists=True, file_okay=False, path_type=Path))
@click.option("--out", "out_dir", required=True, type=click.Path(file_okay=False, path_type=Path),
              help="Folder for the oracles' images (albedo/, albedo-sh/, gt/) and their scores (eval-*/).")
@click.option("--ground-truth", default="lamps", show_default=True, type=click.Choice(["lamps", "uniform"]),
              help="Fit and score against the lamps-on ground truth or the uniform one (`spotless-sim render --gt "
                   "uniform`).")
@click.option("--no-lpips", is_flag=True, help="Skip LPIPS.")
@click.option("--threads", type=THREAD_COUNT, default=None, help="CPU threads for the metrics.")
@click.option("--quiet", is_flag=True, help="No progress bars.")
def ceiling_command(data: Path, out_dir: Path, ground_truth: str, no_lpips: bool, threads: int | None,
                    quiet: bool) -> None:
    """The relighting ceiling of a rendered dataset: its test views' true albedo (the renderer's diffuse colour
    pass) × one best gain, and × the best light per surface normal (SH 3 fitted to the ground truth), each scored
    against the ground truth like a method."""
    from evaluation.ceiling import ORACLES, ceiling  # deferred: the evaluation library, kept out of `spotless --help`
    from evaluation.report import markdown_report
    from evaluation.runner import EvalConfig

    config = EvalConfig(lpips=not no_lpips, num_threads=threads, progress=not quiet, ground_truth=ground_truth)
    for name, results in ceiling(data, out_dir, config).items():
        click.echo(f"## {name}: {ORACLES[name]}\n\n{markdown_report(results)}")
    click.echo(f"results written to {out_dir}/eval-*")
