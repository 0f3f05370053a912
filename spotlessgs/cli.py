"""`spotless`: train, relight, render and evaluate. Commands stay thin: they build a config and call one library
function."""

from __future__ import annotations

import json
import logging
from pathlib import Path

import click

from spotlessgs.clitools import THREAD_COUNT, FiniteFloatRange, SafeGroup

from evaluation.cli import ceiling_command, eval_command, sfm_rings_command
from spotlessgs.baselines2d.cli import baseline2d
from spotlessgs.experiments.cli import benchmark, trainer_settings
from spotlessgs.experiments.reproduce.cli import reproduce

#: The largest --l0 channel accepted: a light a million times the default's already turns every pixel white; far
#: larger values overflow float32 (inf in the EXR files).
MAX_L0 = 1e6
MODELS = ["3dgs", "darkgs", "darkgs-calibrated", "darkgs+sh", "darkgs+brdf", "spotless"]


@click.group(cls=SafeGroup, context_settings={"help_option_names": ["-h", "--help"]})
@click.version_option(package_name="spotlessgs")
@click.option("-v", "--verbose", is_flag=True, help="Log debug messages.")
def main(verbose: bool) -> None:
    """SpotlessGS: relightable Gaussian Splatting for images lit by an onboard spotlight."""
    logging.basicConfig(level=logging.DEBUG if verbose else logging.INFO, format="%(levelname)s %(name)s: %(message)s")


@main.command()
@click.option("--data", "data_dir", required=True, type=click.Path(exists=True, file_okay=False, path_type=Path),
              help="Dataset folder: ours (transforms.json + spotless block), nerfstudio, or COLMAP (images/ + sparse/0).")
@click.option("--out", "run_dir", required=True, type=click.Path(file_okay=False, path_type=Path), help="Run folder.")
@click.option("--model", default="spotless", show_default=True, type=click.Choice([*MODELS, "auto"]),
              help="Model variant, or 'auto': choose the light/reflectance model from held-out training views "
                   "(spotlessgs.training.selection), then train it.")
@click.option("--preset", default="quick", show_default=True, type=click.Choice(["tiny", "quick", "paper"]))
@click.option("--iterations", type=click.IntRange(1), default=None, help="Override the preset's iteration count.")
@click.option("--width", "image_width", type=click.IntRange(8), default=None,
              help="Override the training image width (pixels).")
@click.option("--seed", default=0, show_default=True, type=int)
@click.option("--resume", is_flag=True, help="Continue from the run's last checkpoint.")
@click.option("--light-prior", nargs=3, type=FiniteFloatRange(), default=None, metavar="X Y Z",
              help="Prior light position in the camera frame (m, OpenCV axes): adds weight * |t - prior|.")
@click.option("--light-prior-weight", type=FiniteFloatRange(0), default=None)
@click.option("--linear", "linear_input", is_flag=True, help="The images are linear (RAW), not sRGB.")
@click.option("--max-gaussians", type=click.IntRange(1), default=None, help="Hard cap on the number of Gaussians.")
@click.option("--tolerance-db", type=FiniteFloatRange(0), default=None,
              help="--model auto: held-out PSNR the choice may give up against the best candidate (default 0.25; "
                   "the coordinate search's two decisions, BRDF then SH degree, get half each).")
@click.option("--selection-search", type=click.Choice(["coordinate", "grid"]), default=None,
              help="--model auto: candidate search (default coordinate).")
@click.option("--trusted-start-reflectance", type=click.Choice(["compare", "learned"]), default=None,
              help="--model auto on a start the trainer trusts (a dense one with normals): keep the learned BRDF, "
                   "the start's normals held (default), or compare the BRDFs on held-out pixels.")
@click.option("--gaussian-budget", is_flag=True,
              help="Stop densifying when held-out error stops improving and prune Gaussians that do not change the "
                   "renders (spotlessgs.training.budget).")
@click.option("--photometric", type=click.Choice(["auto", "on", "off"]), default=None,
              help="Learn each frame's exposure and the lens's vignetting (spotlessgs.models.photometric); default "
                   "auto: on for real cameras' datasets, off for our simulator's fixed-exposure renders.")
@click.option("--low-frequency-shading", type=click.Choice(["spot_cosine", "irradiance"]), default=None,
              help="How the SH / ambient light shades the spotlit images: spot_cosine (the paper's equation, default) "
                   "or irradiance (by the directional albedo, as relighting shades it); SpotlessGS on a dense start "
                   "with normals uses irradiance (trust_start_geometry; --set trust_start_geometry=off keeps this "
                   "choice).")
@click.option("--refine-poses", is_flag=True,
              help="Learn a small correction of every training view's camera pose beside the scene (poses from VIO "
                   "or SfM a few cm off); test views are then aligned to their spotlit inputs (model frozen) before "
                   "they are relit and scored. The refined poses: RUN/poses.json.")
@click.option("--set", "settings", multiple=True, metavar="KEY=VALUE", callback=trainer_settings,
              help="Any other trainer setting (a TrainConfig field of spotlessgs/training/config.py; repeat the "
                   "option), e.g. --set loss_space=srgb (the photometric loss on sRGB-encoded values) or "
                   "--set falloff_tau=0.01 --set learn_falloff=false (the spotlight's fall-off).")
@click.option("--threads", type=THREAD_COUNT, default=None, help="CPU threads.")
@click.option("--device", default=None, type=click.Choice(["auto", "cpu", "cuda"]), help="[default: auto]")
@click.option("-q", "--quiet", is_flag=True, help="No progress bar.")
def train(data_dir, run_dir, model, preset, iterations, image_width, seed, resume, light_prior, light_prior_weight,
          linear_input, max_gaussians, tolerance_db, selection_search, trusted_start_reflectance, gaussian_budget,
          photometric, low_frequency_shading, refine_poses, settings, threads, device, quiet):
    """Train a relightable model (or a baseline) on the uneven images of a dataset."""
    # deferred (here and in the other commands): the torch-based library, kept out of `spotless --help`
    from spotlessgs.run import RunSpec, train as train_run
    from spotlessgs.training.selection import format_selection_table, selection_config

    if model != "auto" and any(v is not None for v in (tolerance_db, selection_search, trusted_start_reflectance)):
        raise click.UsageError("--tolerance-db, --selection-search and --trusted-start-reflectance only apply to "
                               "--model auto")
    if light_prior_weight is not None and light_prior is None:
        raise click.UsageError("--light-prior-weight weighs --light-prior; give --light-prior X Y Z too")
    if light_prior is not None and model == "3dgs":
        raise click.UsageError("--light-prior has no effect with --model 3dgs (it has no spotlight to place)")
    overrides = dict(settings)
    flags = (("device", "--device", device), ("linear_input", "--linear", True if linear_input else None),
             ("refine_poses", "--refine-poses", True if refine_poses else None),
             ("iterations", "--iterations", iterations), ("image_width", "--width", image_width),
             ("num_threads", "--threads", threads), ("light_prior_weight", "--light-prior-weight", light_prior_weight),
             ("max_gaussians", "--max-gaussians", max_gaussians), ("photometric", "--photometric", photometric),
             ("low_frequency_shading", "--low-frequency-shading", low_frequency_shading))
    for key, flag, value in flags:  # a flag and --set of one setting: the user must choose
        if value is not None:
            if key in overrides:
                raise click.UsageError(f"{flag} and --set {key}=... both set {key}; give one of them")
            overrides[key] = value
    spec = RunSpec(data=data_dir, model=model, preset=preset, strategy="budget" if gaussian_budget else "default",
                   seed=seed, overrides=tuple(overrides.items()), light_prior=light_prior or None,
                   selection=selection_config(tolerance_db, selection_search, trusted_start_reflectance)
                   if model == "auto" else None)
    run = train_run(spec, run_dir, resume=resume, progress=not quiet)
    if run.decision is not None:
        click.echo(format_selection_table(run.decision))
    summary = run.summary or {}
    psnr = summary.get("test_psnr_reconstruction")
    psnr = "n/a" if psnr is None else f"{psnr:.2f} dB"
    click.echo(f"{run_dir}: {summary.get('steps')} steps, {summary.get('num_gaussians')} Gaussians, "
               f"{summary.get('ms_per_step', float('nan')):.0f} ms/step, test reconstruction PSNR {psnr}")


@main.command()
@click.argument("run_dir", type=click.Path(exists=True, file_okay=False, path_type=Path))
@click.option("--l0", nargs=3, type=FiniteFloatRange(0, MAX_L0), default=None, metavar="R G B",
              help="Constant linear RGB radiance that replaces the spotlight. Default: automatic (white, scaled so "
                   "that about 1% of relit pixels reach 1; the value used is reported).")
@click.option("--lamp-l0", is_flag=True,
              help="L0 = the learned lamp's own mean irradiance on what the training views see: the lamp's light "
                   "spread evenly, beside the room light as learned (for rooms with light of their own); the relit "
                   "view is then scaled as a whole so that about 1% of its pixels reach 1.")
@click.option("--views", "which", default="all", show_default=True, type=click.Choice(["test", "train", "all"]))
@click.option("--out", "out_dir", type=click.Path(file_okay=False, path_type=Path), default=None,
              help="Output folder (default RUN/relit).")
@click.option("--exr", is_flag=True, help="Also write linear float EXR images (no clipping).")
@click.option("--data", "data_dir", type=click.Path(exists=True, file_okay=False, path_type=Path), default=None,
              help="The run's dataset, when it has moved (default: the path recorded in RUN/run.json).")
@click.option("--device", default="auto", show_default=True, type=click.Choice(["auto", "cpu", "cuda"]))
@click.option("--no-low-frequency", is_flag=True,
              help="Leave the learned low-frequency (SH / ambient) light out: the image is reflectance x L0 alone.")
@click.option("-q", "--quiet", is_flag=True)
def relight(run_dir, l0, lamp_l0, which, out_dir, exr, data_dir, device, no_low_frequency, quiet):
    """Relight a trained run under even light (paper eq. 8) and write PNGs named like the dataset's images.

    The output folder is replaced as a whole and gets a manifest (.manifest.json) that `spotless eval` checks."""
    from spotlessgs.rendering import render_run

    if lamp_l0 and l0:
        raise click.UsageError("give --l0 or --lamp-l0, not both")
    rule = "lamp" if lamp_l0 else "auto"
    click.echo(json.dumps(render_run(run_dir, "relit", which, out_dir, l0=l0 or rule, exr=exr, progress=not quiet,
                                     device=device, low_frequency=not no_low_frequency, data_dir=data_dir),
                          indent=2))


@main.command()
@click.argument("run_dir", type=click.Path(exists=True, file_okay=False, path_type=Path))
@click.option("--views", "which", default="all", show_default=True, type=click.Choice(["test", "train", "all"]))
@click.option("--out", "out_dir", type=click.Path(file_okay=False, path_type=Path), default=None,
              help="Output folder (default RUN/render).")
@click.option("--exr", is_flag=True, help="Also write linear float EXR images.")
@click.option("--data", "data_dir", type=click.Path(exists=True, file_okay=False, path_type=Path), default=None,
              help="The run's dataset, when it has moved (default: the path recorded in RUN/run.json).")
@click.option("--device", default="auto", show_default=True, type=click.Choice(["auto", "cpu", "cuda"]))
@click.option("-q", "--quiet", is_flag=True)
def render(run_dir, which, out_dir, exr, data_dir, device, quiet):
    """Render a trained run under its learned spotlight (to compare with the inputs)."""
    from spotlessgs.rendering import render_run

    click.echo(json.dumps(render_run(run_dir, "spot", which, out_dir, exr=exr, progress=not quiet, device=device,
                                     data_dir=data_dir), indent=2))


@main.command()
@click.option("--images", "images_dir", default=None, type=click.Path(exists=True, file_okay=False, path_type=Path),
              help="The spotlit frames (PNG/JPEG), in time order by file name.")
@click.option("--bag", "bag", default=None, type=click.Path(exists=True, path_type=Path),
              help="Or a ROS 1 (.bag) or ROS 2 (folder or .db3/.mcap) bag; needs --image-topic.")
@click.option("--image-topic", default=None, help="--bag: the camera's Image or CompressedImage topic.")
@click.option("--camera-info-topic", default=None, help="--bag: its CameraInfo topic (the camera, kept fixed).")
@click.option("--odometry-topic", default=None,
              help="--bag: Odometry or PoseStamped of the camera's optical frame: poses without SfM.")
@click.option("--depth-topic", default=None,
              help="--bag with --odometry-topic: an RGB-D camera's depth Image registered to the colour camera "
                   "(16UC1 mm or 32FC1 m, e.g. aligned_depth_to_color): a dense start from it instead of SfM points.")
@click.option("--every", "min_interval_s", default=0.0, show_default=True, type=FiniteFloatRange(0),
              help="--bag: keep frames at least this many seconds apart.")
@click.option("--min-motion", "min_motion_m", default=0.0, show_default=True, type=FiniteFloatRange(0),
              help="--bag with --odometry-topic: keep frames at least this many metres apart.")
@click.option("--points", "posed_dir", default=None,
              type=click.Path(exists=True, file_okay=False, path_type=Path),
              help="Or a posed dataset (transforms.json) without a point cloud: a dense cloud from its depth images "
                   "(DATA/depth_points.ply) or sparse points triangulated with its poses on brightened training "
                   "frames (DATA/sfm_points.ply); no --out.")
@click.option("--points-from", default="auto", show_default=True, type=click.Choice(["auto", "depth", "sfm"]),
              help="--points: back-project the frames' depth images (an RGB-D camera's depth_file_path), "
                   "triangulate, or auto: depth images where every training frame has one.")
@click.option("--out", "out_dir", default=None, type=click.Path(file_okay=False, path_type=Path),
              help="--images/--bag: the dataset folder to write: images/, sparse/0 (COLMAP), prepare.json.")
@click.option("--camera-model", default="SIMPLE_RADIAL", show_default=True,
              type=click.Choice(["SIMPLE_PINHOLE", "PINHOLE", "SIMPLE_RADIAL", "RADIAL", "OPENCV", "FULL_OPENCV",
                                 "OPENCV_FISHEYE"]),
              help="The COLMAP camera model that structure from motion estimates.")
@click.option("--matcher", default="sequential", show_default=True, type=click.Choice(["sequential", "exhaustive"]),
              help="Image pairs to match: each frame with its successors (video), or every pair.")
@click.option("--truth", "truth_dir", type=click.Path(exists=True, file_okay=False, path_type=Path), default=None,
              help="A dataset with the true poses of these frames (by file name): the summary gets the pose error.")
@click.option("--threads", type=THREAD_COUNT, default=1, show_default=True)
@click.option("--seed", default=0, show_default=True, type=int)
@click.option("-q", "--quiet", is_flag=True)
def prepare(images_dir, bag, image_topic, camera_info_topic, odometry_topic, depth_topic, min_interval_s, min_motion_m,
            posed_dir, points_from, out_dir, camera_model, matcher, truth_dir, threads, seed, quiet):
    """Turn a folder of spotlit frames, or a camera of a ROS bag, into a dataset: structure from motion on
    brightened copies (or the bag's odometry and points triangulated with it), the originals kept for training;
    frames that do not register are named. --points adds a start to a posed dataset: from its depth images, or
    triangulated."""
    from spotlessgs.io.dataset import read_dataset
    from spotlessgs.prepare import add_depth_points, add_sfm_points, has_depth_images, prepare_bag, prepare_images

    if sum(x is not None for x in (images_dir, bag, posed_dir)) != 1:
        raise click.UsageError("give one of --images, --bag and --points")
    if bag is not None and image_topic is None:
        raise click.UsageError("--bag needs --image-topic")
    if depth_topic is not None and bag is None:
        raise click.UsageError("--depth-topic goes with --bag")
    if points_from != "auto" and posed_dir is None:
        raise click.UsageError("--points-from goes with --points")
    if (out_dir is None) != (posed_dir is not None):
        raise click.UsageError("--points adds to its dataset and takes no --out" if posed_dir is not None
                               else "--images and --bag need --out")
    progress = None if quiet else (lambda name: click.echo(f"prepare: {name}", err=True))
    if posed_dir is not None and (points_from == "depth" or (
            points_from == "auto" and (posed_dir / "transforms.json").is_file()
            and has_depth_images(read_dataset(posed_dir)))):
        points = add_depth_points(posed_dir, seed=seed, progress=progress)
        click.echo(f"{posed_dir}: {points['points']} points from the depth images of {points['frames']} training "
                   f"frames ({100 * points['voxel_m']:.1f} cm voxels) in {points['file']}")
        return
    if posed_dir is not None:
        points = add_sfm_points(posed_dir, matcher, threads, seed, progress)
        click.echo(f"{posed_dir}: {points['points']} points triangulated from {points['frames']} training frames "
                   f"(reprojection error {points['reprojection_error_px']:.2f} px) in {points['file']}")
        return
    if bag is not None:
        summary = prepare_bag(bag, out_dir, image_topic, camera_info_topic, odometry_topic, min_interval_s,
                              min_motion_m, camera_model, matcher, truth_dir, threads, seed, progress,
                              depth_topic=depth_topic)
    else:
        summary = prepare_images(images_dir, out_dir, camera_model, matcher, truth=truth_dir, threads=threads,
                                 seed=seed, progress=progress)
    error = summary.get("pose_error")
    click.echo(f"{out_dir}: {summary['registered']} of {summary['frames']} frames registered"
               + (f", pose error {error['ate_rmse_m']:.3f} m RMSE after similarity alignment" if error else "")
               + (f"; not registered: {', '.join(summary['not_registered'])}" if summary["not_registered"] else ""))


@main.command()
@click.argument("run_dir", type=click.Path(exists=True, file_okay=False, path_type=Path))
@click.option("--out", "out_path", required=True, type=click.Path(dir_okay=False, path_type=Path))
@click.option("--l0", nargs=3, type=FiniteFloatRange(0, MAX_L0), default=(1.0, 1.0, 1.0), show_default=True,
              metavar="R G B")
@click.option("--data", "data_dir", type=click.Path(exists=True, file_okay=False, path_type=Path), default=None,
              help="The run's dataset, when it has moved (default: the path recorded in RUN/run.json).")
def export(run_dir, out_path, l0, data_dir):
    """Export the relit model as a standard 3DGS PLY (opens in common 3DGS viewers)."""
    from spotlessgs.export import export_ply

    click.echo(f"wrote {export_ply(run_dir, out_path, l0, data_dir=data_dir)}")


def _scales(_ctx, _param, values: tuple[str, ...]) -> dict[str, float]:
    """``PATTERN=FACTOR`` options as a dict (BadParameter naming a malformed one)."""
    scales = {}
    for value in values:
        pattern, _, factor = value.partition("=")
        try:
            scales[pattern] = float(factor)
        except ValueError:
            raise click.BadParameter(f"{value!r} is not PATTERN=FACTOR (e.g. 'render/*=64')") from None
        if not pattern or not 0 < scales[pattern] < float("inf"):  # NaN fails the comparison too
            raise click.BadParameter(f"{value!r}: need a stage name pattern and a finite factor > 0")
    return scales


@main.command("cluster-projection")
@click.argument("root", type=click.Path(exists=True, file_okay=False, path_type=Path))
@click.option("--nodes", default="1,4,16", show_default=True, help="Comma-separated node counts to project onto.")
@click.option("--cores-per-node", default=2, show_default=True, type=click.IntRange(1),
              help="CPU cores of one node; a node runs cores // threads stages at once.")
@click.option("--threads", type=THREAD_COUNT, default=None,
              help="Threads per stage (default: what the markers recorded).")
@click.option("--scale", "scales", multiple=True, callback=_scales, metavar="PATTERN=FACTOR",
              help="Multiply the measured time of the stages whose name matches PATTERN (fnmatch; the first match "
                   "counts), e.g. to carry measured rates to a larger preset: --scale 'render/*=64'.")
def cluster_projection(root, nodes, cores_per_node, threads, scales):
    """Project the wall time of a finished reproduction or render-many job (ROOT) onto N nodes, from the stage times
    its done-markers recorded: the replay of its stage graph, and the critical path no cluster can beat."""
    from spotlessgs.jobs.projection import projection_table, read_measured_stages

    try:
        counts = [int(n) for n in nodes.split(",") if n.strip()]
    except ValueError:
        raise click.BadParameter(f"{nodes!r} is not a comma-separated list of node counts", param_hint="--nodes")
    if not counts or min(counts) < 1:
        raise click.BadParameter("give at least one node count, each at least 1", param_hint="--nodes")
    click.echo(projection_table(read_measured_stages(root), counts, cores_per_node, threads, scales))


main.add_command(eval_command, name="eval")
main.add_command(sfm_rings_command)
main.add_command(ceiling_command)
main.add_command(baseline2d)
main.add_command(reproduce)
main.add_command(benchmark)

if __name__ == "__main__":
    main()
