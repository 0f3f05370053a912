"""`baseline2d`: the single-view 2D baselines (CLAHE, MSRCR, Cycle-GAN) as click commands (thin wrappers)."""

from __future__ import annotations

from pathlib import Path

import click

from spotlessgs.clitools import THREAD_COUNT


@click.group("baseline2d", context_settings={"help_option_names": ["-h", "--help"]})
def baseline2d() -> None:
    """Single-image baselines that relight each uneven image independently."""


@baseline2d.command("enhance")
@click.argument("method", type=click.Choice(["clahe", "msrcr", "cyclegan"]))
@click.argument("in_dir", type=click.Path(exists=True, file_okay=False, path_type=Path))
@click.argument("out_dir", type=click.Path(file_okay=False, path_type=Path))
@click.option("--checkpoint", type=click.Path(exists=True, path_type=Path),
              help="cyclegan: the folder train-cyclegan wrote (or its checkpoint file).")  # fmt: skip
@click.option("--clip-limit", type=float, help="clahe: histogram clip limit (multiple of the mean bin height).")
@click.option("--tiles", type=int, help="clahe: tiles along each image axis.")
@click.option("--low-percent", type=float, help="msrcr: percentile clipped to black.")
@click.option("--high-percent", type=float, help="msrcr: percentile clipped to white.")
@click.option("--threads", type=THREAD_COUNT, help="cyclegan: torch threads.")
def enhance_command(method, in_dir, out_dir, checkpoint, clip_limit, tiles, low_percent, high_percent, threads):
    """Enhance every image of IN_DIR with METHOD; write OUT_DIR/<name>.png."""
    from spotlessgs.baselines2d.enhance import enhance_folder

    given = {
        "checkpoint": checkpoint, "clip_limit": clip_limit, "low_percent": low_percent,
        "high_percent": high_percent, "num_threads": threads,
    }  # fmt: skip
    if tiles is not None:
        given.update(tiles_y=tiles, tiles_x=tiles)
    allowed = {
        "clahe": {"clip_limit", "tiles_y", "tiles_x"},
        "msrcr": {"low_percent", "high_percent"},
        "cyclegan": {"checkpoint", "num_threads"},
    }[method]
    misplaced = sorted(k for k, v in given.items() if v is not None and k not in allowed)
    if misplaced:
        raise click.UsageError(f"options {misplaced} do not apply to method {method!r}")
    written = enhance_folder(method, in_dir, out_dir, **{k: v for k, v in given.items() if v is not None})
    click.echo(f"wrote {len(written)} images to {out_dir}")


@baseline2d.command("train-cyclegan")
@click.option("--uneven", "uneven_dirs", multiple=True, required=True,
              type=click.Path(exists=True, file_okay=False, path_type=Path), help="Folder of uneven images (repeat).")
@click.option("--even", "even_dirs", multiple=True, required=True,
              type=click.Path(exists=True, file_okay=False, path_type=Path),
              help="Folder of evenly lit images of other scenes (repeat).")
@click.option("--out", "out_dir", required=True, type=click.Path(file_okay=False, path_type=Path),
              help="Run folder (resumes when it holds a checkpoint).")
@click.option("--preset", "preset_name", default="quick", show_default=True,
              type=click.Choice(["tiny", "quick", "paper"]))
@click.option("--steps", type=int, help="Override the preset's number of steps.")
@click.option("--threads", type=THREAD_COUNT, help="Override the preset's torch thread count.")
@click.option("--seed", type=int, default=0, show_default=True)
@click.option("--no-progress", is_flag=True, help="Hide the progress bar.")
def train_command(uneven_dirs, even_dirs, out_dir, preset_name, steps, threads, seed, no_progress):
    """Train the unpaired uneven -> even Cycle-GAN; print the checkpoint path."""
    from spotlessgs.baselines2d.cyclegan import preset, train_cyclegan

    overrides = {k: v for k, v in {"steps": steps, "num_threads": threads}.items() if v is not None}
    config = preset(preset_name, **overrides)
    checkpoint = train_cyclegan(uneven_dirs, even_dirs, out_dir, config, seed=seed, progress=not no_progress)
    click.echo(str(checkpoint))


if __name__ == "__main__":
    baseline2d()
