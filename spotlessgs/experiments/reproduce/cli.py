"""``spotless reproduce``: a thin click command over :func:`spotlessgs.experiments.reproduce.pipeline.reproduce`."""

from __future__ import annotations

import time
from pathlib import Path

import click

from spotlessgs.clitools import THREAD_COUNT
from spotlessgs.experiments.reproduce.config import SHIPPED_ROOMS, ReproduceConfig, preset


def config_from_options(preset_name: str, scenes: tuple[str, ...], seed: int, scenes_dir: Path | None,
                        no_sfm: bool, no_sensor_noise: bool = False) -> ReproduceConfig:
    """The config for the command's options. With ``scenes``, the Cycle-GAN's rooms are the preset's minus the test
    rooms, topped up from the other shipped rooms to two. The sensor-noise copies serve Table III: ``no_sfm`` drops
    them too."""
    base = preset(preset_name)
    overrides: dict = {"seed": seed}
    if scenes:
        overrides["scenes"] = tuple(scenes)
        others = [r for r in base.gan_rooms if r not in scenes]
        others += [r for r in SHIPPED_ROOMS if r not in scenes and r not in others]
        overrides["gan_rooms"] = tuple(others[: max(2, len([r for r in base.gan_rooms if r not in scenes]))])
    if scenes_dir is not None:
        overrides["scenes_dir"] = scenes_dir
    if no_sfm:
        overrides["sfm"] = False
    if no_sfm or no_sensor_noise:
        overrides["sensor_noise"] = None
    return base.replace(**overrides)


@click.command()
@click.option("--preset", "preset_name", default="quick", show_default=True,
              type=click.Choice(["tiny", "quick", "paper", "components"]),
              help="tiny: minutes (tests); quick: ~30 min on a 2-core CPU; paper: the paper's scale (GPU); "
                   "components: the DarkGS ablation with three seeds on the rooms where the SH light, the BRDF and "
                   "interreflection matter (storage room, white room, bedroom with residual light).")
@click.option("--scenes", multiple=True, type=click.Choice(list(SHIPPED_ROOMS)),
              help="Test room(s) (repeat the option); default: the preset's.")
@click.option("--out", "out_dir", required=True, type=click.Path(file_okay=False, path_type=Path),
              help="Output folder (rerun with the same settings to resume).")
@click.option("--jobs", default=1, show_default=True, type=click.IntRange(1),
              help="local executor: stages run in parallel (each gets max(1, cores // jobs) threads).")
@click.option("--executor", default="local", show_default=True, type=click.Choice(["local", "ray"]),
              help="local: worker processes on this machine; ray: one Ray task per stage on a cluster whose nodes "
                   "all see --out at the same path (pip install 'spotlessgs[cluster]'; docs/cluster.md).")
@click.option("--ray-address", default="auto", show_default=True,
              help="--executor ray: the cluster to join (auto: this machine's cluster or $RAY_ADDRESS; HOST:PORT: "
                   "its head node; local: a private Ray instance on this machine).")
@click.option("--threads", type=THREAD_COUNT, default=None,
              help="CPU threads per stage (default: cores // jobs locally, 1 on Ray, where each stage asks for as "
                   "many CPUs). Results depend on it: compare runs made with the same value.")
@click.option("--seed", default=0, show_default=True, type=int)
@click.option("--scenes-dir", type=click.Path(exists=True, file_okay=False, path_type=Path), default=None,
              help="Folder with <room>/house.json (default: the repository's scenes/).")
@click.option("--no-sfm", is_flag=True, help="Skip the SfM evaluation (Table III) and the sensor-noise copies.")
@click.option("--no-sensor-noise", is_flag=True,
              help="Skip the copy of each uneven dataset with camera sensor noise (Table III's robot-camera rows).")
def reproduce(preset_name, scenes, out_dir, jobs, executor, ray_address, threads, seed, scenes_dir, no_sfm,
              no_sensor_noise):
    """Render, train, evaluate and write REPORT.md with the paper's Tables I-IV, runtime and figures."""
    from spotlessgs.experiments.reproduce.pipeline import reproduce as run_pipeline
    from spotlessgs.jobs import ExecutorSpec

    try:
        config = config_from_options(preset_name, scenes, seed, scenes_dir, no_sfm, no_sensor_noise)
    except ValueError as exc:
        raise click.BadParameter(str(exc)) from exc
    start = time.perf_counter()
    spec = ExecutorSpec(kind=executor, jobs=jobs, threads=threads,
                        ray_address=None if ray_address == "local" else ray_address)
    report = run_pipeline(config, out_dir, executor=spec)  # errors: one line and the exit code (spotlessgs.clitools)
    click.echo(f"{out_dir}: ran {len(report.ran)} stage(s), skipped {len(report.skipped)} finished one(s) in "
               f"{time.perf_counter() - start:.1f} s; report: {out_dir / 'REPORT.md'}")
