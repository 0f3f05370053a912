"""``spotless benchmark``: the experiments' benchmarks as commands, thin over their library modules.

    spotless benchmark models --data data/bedroom --out bench/train --iterations 1500
    spotless benchmark selection --data data/bedroom --data data/storage_room --out bench/selection --seed 0 --seed 1
    spotless benchmark robot --ideal out/quick/datasets/bedroom-uneven --robot out/quick/datasets/bedroom-robot \
        --out bench/robot --threads 2
    spotless benchmark poses --data data/bedroom --out bench/poses --translation-cm 3 --rotation-deg 0.3

``models`` is :mod:`spotlessgs.experiments.benchmark` (what each model component costs and buys), ``selection`` is
:mod:`spotlessgs.experiments.selection_benchmark` (model selection and the Gaussian budget against SpotlessGS),
``robot`` is :mod:`spotlessgs.experiments.robot_benchmark` (what each robot-camera component costs and buys),
``poses`` is :mod:`spotlessgs.experiments.pose_benchmark` (what camera pose refinement costs and buys).
"""

from __future__ import annotations

import logging
from pathlib import Path
from typing import Any

import click

from spotlessgs.clitools import THREAD_COUNT, FiniteFloatRange
from spotlessgs.experiments.benchmark import VARIANTS


def trainer_settings(_ctx: Any, _param: Any, texts: tuple[str, ...]) -> tuple[tuple[str, Any], ...]:
    """click callback of a repeatable ``--set KEY=VALUE`` option: the (TrainConfig field, typed value) pairs
    (spotlessgs.training.config.parse_setting); click.BadParameter naming a bad one. `spotless train`,
    `spotless benchmark models` and `spotless benchmark robot` use it."""
    from spotlessgs.training.config import parse_setting  # deferred: commands load without the library

    try:
        pairs = tuple(parse_setting(text) for text in texts)
    except ValueError as exc:
        raise click.BadParameter(str(exc)) from exc
    names = [name for name, _ in pairs]
    repeated = sorted({n for n in names if names.count(n) > 1})
    if repeated:  # the last one won, silently
        raise click.BadParameter(f"{', '.join(repeated)} set more than once; give each setting once")
    if "preset" in names:  # the field only records the preset; its schedule comes from --preset
        raise click.BadParameter("preset is chosen with --preset, not --set")
    return pairs


def refuse_dedicated_settings(settings: tuple[tuple[str, Any], ...], **options: str) -> None:
    """UsageError when ``--set`` names a setting that has its own option here (``options``: setting -> option,
    e.g. ``iterations="--iterations"``): the report prints the option's value, not the one trained with."""
    clash = [f"--set {name} (use {options[name]})" for name, _ in settings if name in options]
    if clash:
        raise click.UsageError(f"{', '.join(clash)}: this setting has its own option, which the report prints")


def _name_list(value: str, allowed: tuple[str, ...]) -> tuple[tuple[str, ...], list[str], list[str]]:
    """A comma-separated option value: (its names, those not in ``allowed``, those given more than once)."""
    names = tuple(v.strip() for v in value.split(",") if v.strip())
    return names, [n for n in names if n not in allowed], sorted({n for n in names if names.count(n) > 1})


def row_names(rows: str | None, allowed: tuple[str, ...]) -> tuple[str, ...]:
    """The rows a ``--rows`` value names (comma-separated; None: every row of ``allowed``, in order);
    click.BadParameter naming the unknown ones."""
    if rows is None:
        return allowed
    names, unknown, repeated = _name_list(rows, allowed)
    if unknown:
        raise click.BadParameter(f"unknown rows {unknown}; choose from {list(allowed)}", param_hint="--rows")
    if repeated or not names:  # a row twice printed it twice; no row replaced a finished table with an empty one
        problem = f"rows {repeated} given twice" if repeated else "no row named"
        raise click.BadParameter(f"{problem}; choose from {list(allowed)}", param_hint="--rows")
    return names


@click.group()
def benchmark() -> None:
    """Benchmarks: per-model cost and quality (models); model selection and the Gaussian budget (selection); the
    robot-camera components (robot); camera pose refinement (poses)."""


def _variant_names(_ctx, _param, value: str) -> tuple[str, ...]:
    """``--variants`` as a tuple of model names (BadParameter naming unknown, repeated or no names, before anything
    trains: an unknown name used to fail only when its turn came, after the others had trained)."""
    names, unknown, repeated = _name_list(value, VARIANTS)
    if not names or unknown or repeated:
        problem = (f"unknown {unknown}" if unknown else f"repeated {repeated}" if repeated else "no names")
        raise click.BadParameter(f"{value!r}: {problem}; choose from {', '.join(VARIANTS)}")
    return names


@benchmark.command("models")
@click.option("--data", required=True, type=click.Path(exists=True, file_okay=False, path_type=Path))
@click.option("--out", required=True, type=click.Path(file_okay=False, path_type=Path))
@click.option("--variants", default=",".join(VARIANTS), show_default=True, callback=_variant_names,
              help="Comma-separated model variants to measure.")
@click.option("--preset", default="quick", show_default=True, type=click.Choice(["tiny", "quick", "paper"]))
@click.option("--iterations", default=1500, show_default=True, type=click.IntRange(1))
@click.option("--threads", default=1, show_default=True, type=THREAD_COUNT)
@click.option("--seed", default=0, show_default=True, type=int)
@click.option("--low-frequency-shading", type=click.Choice(["spot_cosine", "irradiance"]), default=None,
              help="Train every variant with this low-frequency shading (see `spotless train`).")
@click.option("--set", "settings", multiple=True, metavar="KEY=VALUE", callback=trainer_settings,
              help="Train every variant with this trainer setting (a TrainConfig field; repeat the option), e.g. "
                   "--set loss_space=srgb --set falloff_tau=0.01 --set learn_falloff=false.")
@click.option("--child", is_flag=True, hidden=True, help="Train one variant in this process (used by the benchmark).")
def models(data, out, variants, preset, iterations, threads, seed, low_frequency_shading, settings, child):
    """Training ms/step, relit FPS, peak memory and relit PSNR of each model variant after a fixed step budget."""
    # deferred (as in every command): the torch-based library, kept out of `spotless --help`
    from spotlessgs.experiments.benchmark import child as train_one, markdown_table, run_benchmark

    refuse_dedicated_settings(settings, iterations="--iterations", num_threads="--threads",
                              low_frequency_shading="--low-frequency-shading")
    names = variants
    parsed = settings + ((("low_frequency_shading", low_frequency_shading),) if low_frequency_shading else ())
    if child:
        train_one(str(data), str(out), names[0], preset, iterations, threads, seed, parsed)
        return
    rows = run_benchmark(data, out, names, preset, iterations, threads, seed, parsed)
    click.echo(markdown_table(rows, iterations, threads, parsed))


@benchmark.command("selection")
@click.option("--data", "data_dirs", required=True, multiple=True,
              type=click.Path(exists=True, file_okay=False, path_type=Path),
              help="Dataset folder with ground truth (repeat for several rooms; room = folder name).")
@click.option("--out", required=True, type=click.Path(file_okay=False, path_type=Path))
@click.option("--preset", default="quick", show_default=True, type=click.Choice(["tiny", "quick", "paper"]))
@click.option("--iterations", type=click.IntRange(1), default=None, help="Override the preset's iteration count.")
@click.option("--width", "image_width", type=click.IntRange(8), default=None,
              help="Override the training image width (pixels).")
@click.option("--threads", default=1, show_default=True, type=THREAD_COUNT)
@click.option("--seed", "seeds", default=(0,), show_default=True, type=int, multiple=True,
              help="Seed of training, selection holdout and view order; repeat to measure several seeds and "
                   "summarise them (OUT/seed-<s>/ each).")
@click.option("--min-proxy-iterations", type=click.IntRange(1), default=None,
              help="Shortest selection proxy run (default: the selection's; small only for tests).")
def selection(data_dirs, out, preset, iterations, image_width, threads, seeds, min_proxy_iterations):
    """Measure automatic model selection and the Gaussian budget against SpotlessGS."""
    from spotlessgs.experiments.selection_benchmark import RESULTS_MD, BenchmarkSettings, run_seeds

    logging.basicConfig(level=logging.INFO, format="%(levelname)s %(name)s: %(message)s")
    settings = BenchmarkSettings(preset, iterations, image_width, threads, seeds[0], min_proxy_iterations)
    run_seeds(list(data_dirs), out, settings, list(seeds))
    click.echo((out / RESULTS_MD).read_text())


@benchmark.command("robot")
@click.option("--ideal", required=True, type=click.Path(exists=True, file_okay=False, path_type=Path),
              help="The room's ideal input (e.g. out/quick/datasets/bedroom-uneven).")
@click.option("--robot", required=True, type=click.Path(exists=True, file_okay=False, path_type=Path),
              help="The same room through a robot camera with a sparse start (e.g. out/quick/datasets/bedroom-robot).")
@click.option("--out", required=True, type=click.Path(file_okay=False, path_type=Path))
@click.option("--rows", default=None, help="Comma-separated rows (default: all of them, in order).")
@click.option("--model", default="spotless", show_default=True)
@click.option("--preset", default="quick", show_default=True, type=click.Choice(["tiny", "quick", "paper"]))
@click.option("--iterations", type=click.IntRange(1), default=None, help="Override the preset's iteration count.")
@click.option("--threads", default=1, show_default=True, type=THREAD_COUNT)
@click.option("--seed", default=0, show_default=True, type=int)
@click.option("--set", "settings", multiple=True, metavar="KEY=VALUE", callback=trainer_settings,
              help="Train every row with this trainer setting (a TrainConfig field; repeat the option; a row's own "
                   "switch wins), e.g. --set depth_spread=off.")
def robot(ideal, robot, out, rows, model, preset, iterations, threads, seed, settings):
    """What each robot-camera component costs per training step and buys in relit PSNR (one row per component)."""
    from spotlessgs.experiments.robot_benchmark import ROWS, markdown_table, run_robot_benchmark

    logging.basicConfig(level=logging.INFO, format="%(levelname)s %(name)s: %(message)s")
    names = row_names(rows, tuple(ROWS))
    results = run_robot_benchmark(ideal, robot, out, names, model, preset, threads, seed, iterations, settings)
    click.echo(markdown_table(results))


@benchmark.command("poses")
@click.option("--data", required=True, type=click.Path(exists=True, file_okay=False, path_type=Path),
              help="A dataset with true poses (and ground truth), e.g. a `spotless-sim render` of a room.")
@click.option("--out", required=True, type=click.Path(file_okay=False, path_type=Path))
@click.option("--translation-cm", default=3.0, show_default=True, type=FiniteFloatRange(0, 10000),
              help="Every frame's pose error in the perturbed copy: its centre moved this far in a random direction.")
@click.option("--rotation-deg", default=0.3, show_default=True, type=FiniteFloatRange(0, 180),
              help="... and turned by this angle about a random axis.")
@click.option("--error-model", default="independent", show_default=True, type=click.Choice(["independent", "drift"]),
              help="independent: every frame off by exactly the amounts above; drift: a random walk along the frames "
                   "(as VIO drifts), whose RMS over frames is the amounts above.")
@click.option("--points", default="kept", show_default=True, type=click.Choice(["kept", "triangulated"]),
              help="kept: the dataset's point cloud (true geometry); triangulated: points triangulated with each "
                   "dataset's own poses (the perturbed start shares the poses' errors, as an SfM or VIO cloud does).")
@click.option("--rows", default=None, help="Comma-separated rows (default: all of them, in order).")
@click.option("--model", default="spotless", show_default=True)
@click.option("--preset", default="quick", show_default=True, type=click.Choice(["tiny", "quick", "paper"]))
@click.option("--iterations", type=click.IntRange(1), default=None, help="Override the preset's iteration count.")
@click.option("--threads", default=1, show_default=True, type=THREAD_COUNT)
@click.option("--seed", default=0, show_default=True, type=int, help="Seed of training and of the perturbation.")
def poses(data, out, translation_cm, rotation_deg, error_model, points, rows, model, preset, iterations, threads,
          seed):
    """What camera pose refinement costs per step and buys: pose errors and relit PSNR on the dataset and on a copy
    whose poses are perturbed by a known amount, with and without --refine-poses."""
    from spotlessgs.experiments.pose_benchmark import ROWS, markdown_table, run_pose_benchmark

    logging.basicConfig(level=logging.INFO, format="%(levelname)s %(name)s: %(message)s")
    names = row_names(rows, tuple(ROWS))
    results = run_pose_benchmark(data, out, translation_cm / 100.0, rotation_deg, names, model, preset, threads, seed,
                                 iterations, error_model=error_model, points=points)
    click.echo(markdown_table(results))
