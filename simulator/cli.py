"""`spotless-sim`: generate rooms and render paired datasets. Commands stay thin: they build a config and call one
library function."""

from __future__ import annotations

import json
import logging
from pathlib import Path

import click

from spotlessgs.clitools import THREAD_COUNT, FiniteFloatRange, SafeGroup


def _shard(_ctx, _param, value: str) -> tuple[int, int]:
    try:
        index, count = (int(v) for v in value.split("/"))
    except ValueError:
        raise click.BadParameter(f"expected I/N (e.g. 0/4), got {value!r}") from None
    if not (count >= 1 and 0 <= index < count):
        raise click.BadParameter(f"need 0 <= I < N, got {value!r}")
    return index, count


#: ``--gt`` of ``render`` and ``render-many``.
_ground_truth_option = click.option(
    "--gt", "ground_truths", multiple=True, default=("lamps",), show_default=True,
    type=click.Choice(["lamps", "uniform"]),
    help="Ground truths to render. The lamps-on one (gt/) is always rendered; `--gt uniform` adds the room under even, "
         "shadow-free environment light of radiance 1 with the lamps unlit (gt_uniform/): what the relighting "
         "equation's constant L0 would show.")


@click.group(cls=SafeGroup, context_settings={"help_option_names": ["-h", "--help"]})
@click.version_option(package_name="spotlessgs")
@click.option("-v", "--verbose", is_flag=True, help="Log debug messages.")
def main(verbose: bool) -> None:
    """SpotlessGS simulator: 3D-FRONT-format rooms -> paired uneven / evenly lit datasets."""
    logging.basicConfig(level=logging.DEBUG if verbose else logging.INFO, format="%(levelname)s %(name)s: %(message)s")


@main.command()
@click.option("--scene", "scene_path", required=True, type=click.Path(exists=True, dir_okay=False, path_type=Path),
              help="3D-FRONT house JSON file.")
@click.option("--out", "out_dir", required=True, type=click.Path(file_okay=False, path_type=Path),
              help="Dataset folder to write (rerun the same command to resume).")
@click.option("--future-dir", type=click.Path(exists=True, file_okay=False, path_type=Path), default=None,
              help="3D-FUTURE model root (<dir>/<jid>/raw_model.obj). Default: <scene dir>/models.")
@click.option("--texture-dir", type=click.Path(exists=True, file_okay=False, path_type=Path), default=None,
              help="Architecture texture root (<dir>/<material jid>/texture.png). Default: <scene dir>/textures.")
@click.option("--allow-missing", is_flag=True, help="Skip missing models/textures/refs (with a warning) instead of failing.")
@click.option("--room", default=None, help="Room instanceid to render (default: the largest room).")
@click.option("--frames", default=120, show_default=True, type=click.IntRange(2, 100_000), help="Poses on the loop.")
@click.option("--width", default=320, show_default=True, type=click.IntRange(8, 8192))
@click.option("--height", default=240, show_default=True, type=click.IntRange(8, 8192))
@click.option("--fov", "h_fov_deg", default=75.0, show_default=True, type=FiniteFloatRange(10, 150),
              help="Horizontal field of view (degrees).")
@click.option("--samples", default=32, show_default=True, type=click.IntRange(1, 100_000),
              help="Cycles samples per pixel (see the README's speed-against-error table).")
@click.option("--no-denoise", is_flag=True, help="Disable OpenImageDenoise.")
@click.option("--bounces", default=4, show_default=True, type=click.IntRange(0, 32),
              help="Light bounces (0 = direct light only).")
@click.option("--ambient", default=0.0, show_default=True, type=FiniteFloatRange(0, 1e6),
              help="World light strength in the spotlight-only render. It enters a room only through openings to "
                   "the outside (a 3D-FRONT house's windows and doors): the shipped and generated rooms are closed, "
                   "so there it lights nothing; --residual-light leaves a room's own lights on instead.")
@click.option("--residual-light", default=0.0, show_default=True, type=FiniteFloatRange(0, 1),
              help="Leave the room's own lights on in the spotlight-only render at this fraction of their power (a "
                   "dimmed ceiling light): light the spotlight does not explain.")
@click.option("--lambertian", is_flag=True,
              help="Render every surface as an ideal Lambertian reflector (specular layer off, metallic 0): a room "
                   "with only diffuse materials.")
@click.option("--motion-blur", default=0.0, show_default=True, type=FiniteFloatRange(0, 1),
              help="Camera motion blur in the spotlit input: the shutter's open time as a fraction of the time "
                   "between two frames (0: sharp; the ground truth stays sharp).")
@_ground_truth_option
@click.option("--path", "camera_path", default="paper", show_default=True, type=click.Choice(["paper", "robot"]),
              help="Camera loop: the paper's (perpendicular to the path, 90° turns at the corners, 10 cm / 0.1 rad "
                   "pose noise) or a robot's (looks at the room's centre and turns smoothly, 2 cm / 0.02 rad).")
@click.option("--seed", default=0, show_default=True, type=int)
@click.option("--preset", default="uneven", show_default=True, type=click.Choice(["uneven", "saturated"]),
              help="Spotlight strength: uneven, or saturated (clips highlights).")
@click.option("--shard", default="0/1", show_default=True, callback=_shard,
              help="Render only frames k with k %% N == I (N jobs can share a scene).")
@click.option("--threads", default=2, show_default=True, type=THREAD_COUNT, help="CPU render threads.")
@click.option("--device", default="auto", show_default=True, type=click.Choice(["auto", "cpu", "gpu"]))
@click.option("-q", "--quiet", is_flag=True, help="No progress bar, and no messages from Blender's device probing.")
def render(scene_path, out_dir, future_dir, texture_dir, allow_missing, room, frames, width, height, h_fov_deg, samples,
           no_denoise, bounces, ambient, residual_light, lambertian, motion_blur, ground_truths, camera_path, seed,
           preset, shard, threads, device, quiet):
    """Render the spotlight-only and the evenly lit image of every pose of a room's camera loop.

    Ctrl-C (or SIGTERM) stops within a second or two (exit 130 / 143) and keeps every finished frame: rerun the same
    command to resume. OUT must not be the scene's folder, contain the scene file, or overlap the model or texture
    folder.
    """
    from simulator.front3d import LoadOptions
    from simulator.render_pipeline import ExecutionOptions, RenderConfig, render_dataset
    from simulator.trajectory import PATHS

    config = RenderConfig.from_preset(
        preset, frames=frames, width=width, height=height, h_fov_deg=h_fov_deg, samples=samples,
        denoise=not no_denoise, max_bounces=bounces, ambient=ambient, residual_light=residual_light,
        lambertian=lambertian, seed=seed,
        room=room, trajectory=PATHS[camera_path], motion_blur=motion_blur, uniform_gt="uniform" in ground_truths,
    )
    summary = render_dataset(
        scene_path, out_dir, config,
        LoadOptions(future_dir=future_dir, texture_dir=texture_dir, allow_missing=allow_missing),
        ExecutionOptions(shard=shard, threads=threads, device=device, progress=not quiet, quiet=quiet),
    )
    state = "complete" if summary["complete"] else "incomplete (other shards still to render)"
    dark = summary["dark_frames"]
    problems = [f"{len(dark[key])} with {what}" for key, what in
                (("gt", "a black ground truth"), ("images", "a black spotlight image"), ("empty", "no geometry"))
                if dark[key]]
    click.echo(f"{out_dir}: rendered {summary['rendered']}, skipped {summary['skipped']} finished frame(s); "
               f"dataset {state}" + (f"; frames: {', '.join(problems)} (see the warnings)" if problems else ""))


@main.command()
@click.option("--kind", required=True,
              help="Room kind: bedroom, living_room, office, storage_room, corridor or white_room.")
@click.option("--out", "out_dir", required=True, type=click.Path(file_okay=False, path_type=Path),
              help="Folder for house.json, models/ and textures/.")
@click.option("--seed", default=0, show_default=True, type=int)
def generate(kind, out_dir, seed):
    """Generate a new room in the 3D-FRONT format (with 3D-FUTURE-style furniture models and textures)."""
    from simulator.generator import ROOM_KINDS, generate_room

    if kind not in ROOM_KINDS:
        raise click.BadParameter(f"unknown kind {kind!r}; choose one of {', '.join(ROOM_KINDS)}", param_hint="--kind")
    path = generate_room(kind, out_dir, seed)
    click.echo(f"wrote {path}")


@main.command("render-many")
@click.option("--scenes", "scene_patterns", required=True, multiple=True,
              help="House files: a glob ('scenes/*/house.json'), a path, a comma-separated list of either, or a .txt "
                   "file with one per line (repeat the option to add more).")
@click.option("--out", "out_dir", required=True, type=click.Path(file_okay=False, path_type=Path),
              help="Root folder: one dataset ROOT/<room>-<variant> per room and variant, and ROOT/render_many.json "
                   "(rerun the same command to resume).")
@click.option("--variants", default="uneven", show_default=True,
              help="Comma-separated spotlight presets to render each room with (uneven, saturated).")
@click.option("--frames", default=120, show_default=True, type=click.IntRange(2, 100_000), help="Poses on the loop.")
@click.option("--width", default=320, show_default=True, type=click.IntRange(8, 8192))
@click.option("--height", default=240, show_default=True, type=click.IntRange(8, 8192))
@click.option("--samples", default=32, show_default=True, type=click.IntRange(1, 100_000),
              help="Cycles samples per pixel.")
@click.option("--path", "camera_path", default="paper", show_default=True, type=click.Choice(["paper", "robot"]),
              help="Camera loop (as for `render`).")
@click.option("--seed", default=0, show_default=True, type=int)
@_ground_truth_option
@click.option("--frames-per-task", default=20, show_default=True, type=click.IntRange(1),
              help="Consecutive frames rendered by one task (one Blender process).")
@click.option("--executor", default="local", show_default=True, type=click.Choice(["local", "ray"]),
              help="local: worker processes on this machine; ray: tasks on a Ray cluster whose nodes all see --out at "
                   "the same path (pip install 'spotlessgs[cluster]'; docs/cluster.md).")
@click.option("--jobs", default=1, show_default=True, type=click.IntRange(1),
              help="local executor: tasks run in parallel.")
@click.option("--ray-address", default="auto", show_default=True,
              help="--executor ray: auto, HOST:PORT of the head node, or local (a private Ray instance here).")
@click.option("--threads", type=THREAD_COUNT, default=None,
              help="Render threads per task (default: cores // jobs locally, 1 on Ray, where a task asks for as many "
                   "CPUs).")
@click.option("-q", "--quiet", is_flag=True, help="No progress bar.")
def render_many(scene_patterns, out_dir, variants, frames, width, height, samples, camera_path, seed, ground_truths,
                frames_per_task, executor, jobs, ray_address, threads, quiet):
    """Render many rooms and spotlight variants as one resumable job, split into frame ranges, on this machine or a
    Ray cluster; a failed task is reported with its error and the others still finish."""
    from simulator.render_many import SUMMARY_FILE, find_scenes, render_many as run_many
    from simulator.lighting import SPOTLIGHT_PRESETS
    from spotlessgs.jobs import ExecutorSpec

    names = [v.strip() for v in variants.split(",") if v.strip()]
    unknown = [v for v in names if v not in SPOTLIGHT_PRESETS]
    if not names or unknown:
        raise click.BadParameter(f"unknown variant(s) {unknown or names}; choose from {sorted(SPOTLIGHT_PRESETS)}",
                                 param_hint="--variants")
    settings = {"frames": frames, "width": width, "height": height, "samples": samples, "seed": seed,
                "path": camera_path, **({"uniform_gt": True} if "uniform" in ground_truths else {})}
    spec = ExecutorSpec(kind=executor, jobs=jobs, threads=threads,
                        ray_address=None if ray_address == "local" else ray_address)
    summary = run_many(find_scenes(scene_patterns), names, out_dir, settings, frames_per_task, spec,
                       progress=not quiet)
    for dataset in summary["datasets"]:
        state = "complete" if dataset["complete"] else "INCOMPLETE"
        click.echo(f"{dataset['dataset']}: {dataset['done']}/{dataset['frames']} frames ({dataset['rendered_now']} "
                   f"rendered now, {dataset['done_before']} before), {state}")
        for name, error in dataset["failed"].items():
            click.echo(f"  failed {name}: {error}")
    if summary["failed"]:
        raise RuntimeError(f"{out_dir / SUMMARY_FILE}: {len(summary['failed'])} task(s) failed (listed above); rerun "
                           "the same command to retry them")


@main.command("add-noise")
@click.option("--data", "data_dir", required=True, type=click.Path(exists=True, file_okay=False, path_type=Path),
              help="A finished dataset with linear renders (exr/).")
@click.option("--out", "out_dir", required=True, type=click.Path(file_okay=False, path_type=Path),
              help="Folder for the noisy copy (resumed when it holds one made with the same settings).")
@click.option("--shot", default=0.01, show_default=True, type=FiniteFloatRange(0, 1),
              help="Shot-noise variance per unit of linear signal (1e-4 low gain ... 0.012 high gain).")
@click.option("--read", default=0.012, show_default=True, type=FiniteFloatRange(0, 1),
              help="Read-noise standard deviation in linear intensity.")
@click.option("--seed", default=0, show_default=True, type=int)
@click.option("--robot-camera", is_flag=True,
              help="Also a robot camera's auto-exposure and vignetting (the truth in OUT/camera_effects.json).")
@click.option("--sensitivity", default=0.25, show_default=True, type=FiniteFloatRange(0, min_open=True),
              help="--robot-camera: what the sensor records of the render at gain 1 (a dark scene: < 1).")
@click.option("--max-gain", default=4.0, show_default=True, type=FiniteFloatRange(1),
              help="--robot-camera: the largest auto-exposure gain.")
@click.option("--vignetting", default=0.35, show_default=True, type=FiniteFloatRange(0, 1, max_open=True),
              help="--robot-camera: darkening at the farthest image corner.")
@click.option("--lens", default="pinhole", show_default=True, type=click.Choice(["pinhole", "opencv", "fisheye"]),
              help="--robot-camera: resample the renders through this lens (the ground truth too).")
@click.option("--distortion", default="", metavar="K1,K2,...",
              help="--robot-camera --lens: OpenCV's coefficients (opencv: k1,k2,p1,p2[,k3]; fisheye: k1,k2,k3,k4).")
@click.option("--no-point-cloud", is_flag=True,
              help="Leave out the depth-derived point cloud (then: spotless prepare --points OUT).")
@click.option("--depth-camera", is_flag=True,
              help="Also an RGB-D camera's depth images, registered to the frames (OUT/depth/, 16-bit PNG, mm).")
@click.option("--depth-noise", default=0.0025, show_default=True, type=FiniteFloatRange(0),
              help="--depth-camera: the depth's standard deviation at 1 m, metres (it grows with depth squared).")
@click.option("--depth-range", default=6.0, show_default=True, type=FiniteFloatRange(0, 65.535, min_open=True),
              help="--depth-camera: the farthest depth measured, metres (farther pixels hold 0).")
def add_noise(data_dir, out_dir, shot, read, seed, robot_camera, sensitivity, max_gain, vignetting, lens, distortion,
              no_point_cloud, depth_camera, depth_noise, depth_range):
    """Copy a dataset with camera sensor noise (shot + read) added to its spotlight-only images, and with
    --robot-camera a robot camera's auto-exposure and vignetting.

    OUT must not be DATA, lie inside it, or contain it.
    """
    from simulator.sensor_noise import CameraEffects, DepthCamera, SensorNoise, add_sensor_noise_to_dataset

    context = click.get_current_context()
    for flag, needs, given in (("robot_camera", "--robot-camera", robot_camera),
                               ("depth_camera", "--depth-camera", depth_camera)):
        dependent = ("sensitivity", "max_gain", "vignetting", "lens", "distortion") if flag == "robot_camera" else \
            ("depth_noise", "depth_range")
        unused = [f"--{name.replace('_', '-')}" for name in dependent
                  if context.get_parameter_source(name) is click.core.ParameterSource.COMMANDLINE]
        if unused and not given:  # they would be ignored without a word
            raise click.UsageError(f"{', '.join(unused)} only {'apply' if len(unused) > 1 else 'applies'} with {needs}")
    try:
        coefficients = tuple(float(v) for v in distortion.split(",") if v.strip())
    except ValueError:
        raise click.BadParameter(f"not a comma-separated list of numbers: {distortion!r}", param_hint="--distortion")
    effects = CameraEffects(sensitivity=sensitivity, max_gain=max_gain, vignetting=vignetting, lens=lens,
                            distortion=coefficients) if robot_camera else None
    depth = DepthCamera(noise=depth_noise, max_range=depth_range) if depth_camera else None
    written = add_sensor_noise_to_dataset(data_dir, out_dir, SensorNoise(shot, read), seed, effects,
                                          point_cloud=not no_point_cloud, depth_camera=depth)
    click.echo(f"{out_dir}: wrote {written} image(s)")


@main.command()
@click.option("--scene", "scene_path", required=True, type=click.Path(exists=True, dir_okay=False, path_type=Path))
@click.option("--future-dir", type=click.Path(exists=True, file_okay=False, path_type=Path), default=None)
@click.option("--texture-dir", type=click.Path(exists=True, file_okay=False, path_type=Path), default=None)
@click.option("--allow-missing", is_flag=True)
def inspect(scene_path, future_dir, texture_dir, allow_missing):
    """Validate a 3D-FRONT house file and print its rooms, objects and lights as JSON."""
    from simulator.front3d import LoadOptions, load_house

    scene = load_house(scene_path, LoadOptions(future_dir, texture_dir, allow_missing))
    rooms = [
        {"instanceid": r.instance_id, "type": r.type, "floor_area_m2": round(r.floor_area(), 3),
         "height_m": round(r.ceiling_z - r.floor_z, 3), "objects": len(r.object_names),
         "lamps": sum(1 for o in scene.objects_in(r) if o.is_light)}
        for r in scene.rooms
    ]
    click.echo(json.dumps({"scene_id": scene.scene_id, "objects": len(scene.objects), "rooms": rooms}, indent=2))



@main.command()
@click.option("--scene", "scene_path", required=True, type=click.Path(exists=True, dir_okay=False, path_type=Path))
@click.option("--out", "out_dir", required=True, type=click.Path(file_okay=False, path_type=Path))
@click.option("--samples", default="4,8,16,32,64", show_default=True, help="Comma-separated sample counts.")
@click.option("--reference-samples", default=512, show_default=True, type=click.IntRange(1))
@click.option("--width", default=320, show_default=True, type=click.IntRange(8))
@click.option("--height", default=240, show_default=True, type=click.IntRange(8))
@click.option("--threads", default=2, show_default=True, type=THREAD_COUNT)
def benchmark(scene_path, out_dir, samples, reference_samples, width, height, threads):
    """Render speed against error: one view at several sample counts against a high-sample reference."""
    from simulator.benchmark import markdown_table, run_benchmark

    try:
        counts = [int(s) for s in samples.split(",") if s.strip()]
    except ValueError:
        raise click.BadParameter(f"{samples!r}: expected comma-separated integers", param_hint="--samples") from None
    if not counts or min(counts) < 1:
        raise click.BadParameter(f"{samples!r}: expected sample counts of at least 1", param_hint="--samples")
    rows = run_benchmark(scene_path, out_dir, counts, reference_samples, width, height, threads)
    click.echo(markdown_table(rows, width, height))


if __name__ == "__main__":
    main()
