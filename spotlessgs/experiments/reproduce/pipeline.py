"""The reproduction pipeline: which stages exist for a config, where they write, and the one entry point.

Output folder layout::

    OUT/reproduce.json                    the resolved config (a rerun with another config is refused; the same
                                          rooms from another --scenes-dir are not: renders check their content)
    OUT/datasets/<room>-<variant>/        rendered test datasets (simulator)
    OUT/datasets/<room>-uneven-noisy/     the uneven dataset with camera sensor noise (config.sensor_noise)
    OUT/datasets/<room>-robot/            the uneven dataset through a robot camera, sparse start (config.robot_*)
    OUT/datasets/gan-<room>/              other rooms' renders for the Cycle-GAN
    OUT/inputs/<room>-<variant>/          the uneven inputs' evaluation, once per dataset (results.json, sfm/)
    OUT/ceiling/<room>-<variant>/         the relighting ceiling's oracles and their scores (evaluation.ceiling;
                                          uniform/: the same against the uniform ground truth)
    OUT/runs/<room>-<variant>/seed-<s>/<method>/  the same with each of ``extra_seeds``
    OUT/runs/<room>-<variant>/<method>/   training runs (+ relit/, eval/ without the inputs, eval-uniform/ against
                                          the uniform ground truth (image metrics), curve/; auto:
                                          model_selection.json, selection/ and gaussian_budget.json)
    OUT/cyclegan/                         the Cycle-GAN checkpoint
    OUT/baselines2d/<room>-<variant>/<method>/  enhanced images and their evaluation
    OUT/.stages/...                       done-markers with each stage's summary
    OUT/REPORT.md, OUT/results.json, OUT/figures/
"""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

from spotlessgs.io.atomic import write_json
from spotlessgs.io.folder_lock import folder_lock
from spotlessgs.io.json_files import read_json
from spotlessgs.io.paths import refuse_foreign_folder, refuse_overlap
from spotlessgs.experiments.reproduce.config import (
    CEILING_STAGE, INPUTS_STAGE, NEUTRAL_NEW_FIELDS, NOISY_VARIANT, RESIDUAL_VARIANT, RGBD_VARIANT, ROBOT_VARIANT,
    ReproduceConfig, dataset_id, train_stage,
)
from simulator.render_many import RENDER_MEMORY_MB
from simulator.render_pipeline import rendered_scene_sha256
from spotlessgs.io.provenance import sha256_file
from spotlessgs.jobs import ExecutorSpec, RunReport, Stage, StageGraph, StageResources, execute
from spotlessgs.jobs.graph import marker_path
from spotlessgs.training.config import PRESETS as TRAIN_PRESETS
from spotlessgs.run import AUTO

CONFIG_FILE = "reproduce.json"
# Memory that each stage declares to a cluster scheduler (MiB; Ray places a task only on a node with that much
# unclaimed; the local executor ignores it). Measured on the 2-core machine (2026-11-25, tiny and quick presets):
# every stage's process peaks at 0.4-0.6 GiB, most of it the Python, torch and Ray baseline, and a Blender render
# below 1 GiB; declared with about 2x margin. Training grows with its Gaussian budget (about 5 KiB per Gaussian at
# the quick preset's 20k), so it declares 1 GiB plus 8 KiB per Gaussian the preset allows (9 GiB for the paper's 1M).
STAGE_MEMORY_MB = 1024
TASKS = "spotlessgs.experiments.reproduce.tasks"


def train_memory_mb(config: ReproduceConfig) -> int:
    """The memory a training stage of ``config`` declares (see STAGE_MEMORY_MB)."""
    return STAGE_MEMORY_MB + TRAIN_PRESETS[config.train_preset].max_gaussians * 8 // 1024


def dataset_stage(variant: str, ds: str) -> str:
    """The stage that writes dataset ``ds``: ``noise/<ds>`` for a sensor-noise copy, ``robot/<ds>`` for a
    robot-camera copy, ``render/<ds>`` otherwise."""
    return {NOISY_VARIANT: f"noise/{ds}", ROBOT_VARIANT: f"robot/{ds}", RGBD_VARIANT: f"robot/{ds}"}.get(
        variant, f"render/{ds}")


def build_graph(config: ReproduceConfig, out: Path) -> StageGraph:
    """Every stage of the pipeline for ``config`` writing under ``out``.

    The list order is the scheduling priority among ready stages: renders first (everything waits for them), then
    the Cycle-GAN (long, independent of the 3D runs), then the 3D runs, the inputs' evaluation of each dataset
    (``eval-inputs/<dataset>``: the same for every method, so scored once), the 2D baselines and the report.
    """
    out = Path(out)
    stages: list[Stage] = []
    render_resources = StageResources(memory_mb=RENDER_MEMORY_MB)
    train_resources = StageResources(memory_mb=train_memory_mb(config), gpu=True)
    other = StageResources(memory_mb=STAGE_MEMORY_MB)
    common = {"sfm": config.sfm, "sfm_matcher": config.sfm_matcher, "lpips": config.lpips, "seed": config.seed}
    for room, variant in config.datasets():
        ds = dataset_id(room, variant)
        stages.append(Stage(
            f"render/{ds}", f"{TASKS}:render_room", output=out / "datasets" / ds, clean_on_retry=False,
            resources=render_resources,
            kwargs={"scene_file": str(config.scene_file(room)), "out_dir": str(out / "datasets" / ds),
                    "variant": variant, "frames": config.frames, "width": config.width, "height": config.height,
                    "samples": config.samples, "seed": config.seed, "uniform_gt": config.uniform_gt,
                    "residual_light": config.residual_light if variant == RESIDUAL_VARIANT else 0.0}))
    if "cyclegan" in config.baselines:
        for room in config.gan_rooms:
            stages.append(Stage(
                f"render/gan-{room}", f"{TASKS}:render_room", output=out / "datasets" / f"gan-{room}",
                clean_on_retry=False, resources=render_resources,
                kwargs={"scene_file": str(config.scene_file(room)), "out_dir": str(out / "datasets" / f"gan-{room}"),
                        "variant": "uneven", "frames": config.gan_frames, "width": config.gan_width,
                        "height": config.gan_height, "samples": config.gan_samples, "seed": config.seed}))
        source, target = config.gan_domains()
        stages.append(Stage(
            "cyclegan/train", f"{TASKS}:train_cyclegan_stage", output=out / "cyclegan", resources=other,
            clean_on_retry=False,  # the training resumes from its checkpoint (other settings or images are refused)
            deps=tuple(f"render/gan-{room}" for room in config.gan_rooms),
            kwargs={"uneven_dirs": [str(out / "datasets" / f"gan-{r}" / "images") for r in source],
                    "even_dirs": [str(out / "datasets" / f"gan-{r}" / "gt") for r in target],
                    "out_dir": str(out / "cyclegan"), "cyclegan_preset": config.cyclegan_preset,
                    "steps": config.cyclegan_steps, "seed": config.seed}))

    def copy_of_uneven(task: str, room: str, variant: str, settings: dict) -> Stage:
        """The stage (:func:`dataset_stage`) that writes a copy of the room's uneven dataset with ``task``."""
        ds, source = dataset_id(room, variant), dataset_id(room, "uneven")
        return Stage(dataset_stage(variant, ds), f"{TASKS}:{task}", deps=(f"render/{source}",),
                     output=out / "datasets" / ds, clean_on_retry=False, resources=other,
                     kwargs={"data_dir": str(out / "datasets" / source), "out_dir": str(out / "datasets" / ds),
                             **settings})

    for room, variant in config.noisy_datasets():
        shot, read = config.sensor_noise
        stages.append(copy_of_uneven("add_noise_copy", room, variant,
                                     {"shot": float(shot), "read": float(read), "seed": config.seed}))
    for room, variant in config.robot_datasets() + config.rgbd_datasets():
        shot, read = config.robot_noise
        depth = {"depth_noise": float(config.robot_depth_noise)} if variant == RGBD_VARIANT else {}
        stages.append(copy_of_uneven("robot_camera_copy", room, variant, {
            "shot": float(shot), "read": float(read), "sensitivity": float(config.robot_sensitivity),
            "lens": config.robot_lens, "distortion": [float(v) for v in config.robot_distortion],
            "matcher": config.sfm_matcher, "seed": config.seed, **depth}))
    rendered = set(config.datasets())
    for room, variant in config.all_datasets():
        ds = dataset_id(room, variant)
        for seed in config.seeds() if (room, variant) in rendered else (config.seed,):
            for method in config.methods_for(variant):
                name = train_stage(ds, method, seed, config)
                run_dir = out / "runs" / name.removeprefix("train/")
                selection = ({"selection_min_proxy_iterations": config.selection_min_proxy_iterations}
                             if method == AUTO else {})
                stages.append(Stage(
                    name, f"{TASKS}:train_method", deps=(dataset_stage(variant, ds),), output=run_dir,
                    clean_on_retry=False, resources=train_resources,  # resumes from its checkpoint
                    kwargs={"data_dir": str(out / "datasets" / ds), "run_dir": str(run_dir), "variant": method,
                            "train_preset": config.train_preset, "iterations": config.train_iterations,
                            "image_width": config.train_width, "curve_fractions": tuple(config.curve_fractions),
                            **selection, **common, "seed": seed}))
    # once per dataset, after its dataset only: the inputs' evaluation, then the relighting ceiling
    for prefix, task, folder in ((INPUTS_STAGE, "evaluate_inputs", "inputs"),
                                 (CEILING_STAGE, "evaluate_ceiling", "ceiling")):
        for room, variant in config.all_datasets():
            ds = dataset_id(room, variant)
            stages.append(Stage(
                f"{prefix}/{ds}", f"{TASKS}:{task}", deps=(dataset_stage(variant, ds),), output=out / folder / ds,
                resources=other,
                kwargs={"data_dir": str(out / "datasets" / ds), "out_dir": str(out / folder / ds), **common}))
    for room, variant in config.datasets():
        if variant not in config.baseline_variants:
            continue
        ds = dataset_id(room, variant)
        for method in config.baselines:
            deps = (f"render/{ds}",) + (("cyclegan/train",) if method == "cyclegan" else ())
            target_dir = out / "baselines2d" / ds / method
            stages.append(Stage(
                f"baseline2d/{ds}/{method}", f"{TASKS}:run_baseline2d", deps=deps, output=target_dir,
                resources=other,
                kwargs={"method": method, "data_dir": str(out / "datasets" / ds), "out_dir": str(target_dir),
                        "checkpoint": str(out / "cyclegan") if method == "cyclegan" else None,
                        **common}))
    stages.append(Stage("report", f"{TASKS}:write_report_stage", deps=tuple(s.name for s in stages),
                        resources=other, kwargs={"out_dir": str(out)}))
    return StageGraph(stages)


#: What the report stage writes into OUT besides figures/: a rerun writes the report again when one is missing.
REPORT_FILES = ("REPORT.md", "results.json")


def check_or_record_config(config: ReproduceConfig, out: Path) -> None:
    """Write ``OUT/reproduce.json``, or refuse (ValueError naming the differing fields) a folder made with another
    config, and (InputError) a folder with files but no ``reproduce.json``: another tool's, or a reproduction whose
    finished stages were made under unknown settings. ``scenes_dir`` is where the rooms are read from, not a setting:
    another path (a moved or second checkout) is recorded once its rooms are checked to be the ones the folder's
    datasets were rendered from (their plan.json's sha256 of each house file), and each render stage checks that its
    room's content is the one it rendered (simulator render plans identify the scene by its sha256)."""
    path = Path(out) / CONFIG_FILE
    wanted = json.loads(json.dumps(config.to_dict()))
    if path.is_file():
        old = read_json(path, "the reproduction's settings")
        defaults = json.loads(json.dumps(ReproduceConfig().to_dict()))
        old.update({k: wanted[k] for k in NEUTRAL_NEW_FIELDS if k not in old and wanted[k] == defaults[k]})
        fields = sorted(k for k in set(old) | set(wanted) if k != "scenes_dir" and old.get(k) != wanted.get(k))
        if fields:
            fields.sort(key=lambda k: k != "preset")  # a preset changes many fields: named first
            shown = "; ".join(f"{k}: {repr(old[k]) if k in old else 'not recorded'} then, {wanted.get(k)!r} now"
                              for k in fields[:4])
            more = f"; and {len(fields) - 4} more: {fields[4:]}" if len(fields) > 4 else ""
            raise ValueError(f"{path}: this folder was made with other settings ({shown}{more}); "
                             "use a new --out or the same settings")
        if old.get("scenes_dir") != wanted["scenes_dir"]:
            _check_same_rooms(config, Path(out))  # finished renders are skipped: their rooms must be these
            write_json(path, wanted)
        return
    # another tool's folder, or a reproduction whose settings file is gone: its stages' settings are unknown
    refuse_foreign_folder(out, [CONFIG_FILE], "--out", "a reproduction of known settings", count_hidden=[".stages"])
    write_json(path, wanted)


def _check_same_rooms(config: ReproduceConfig, out: Path) -> None:
    """ValueError naming the room and the dataset when a house file under the (new) ``config.scenes_dir`` differs
    from the one a dataset of ``out`` was rendered from (its plan.json's sha256): the finished render stages would be
    skipped and the folder's results credited to rooms that were never rendered."""
    rooms = [(room, dataset_id(room, variant)) for room, variant in config.datasets()]
    rooms += [(room, f"gan-{room}") for room in config.gan_rooms if "cyclegan" in config.baselines]
    for room, ds in rooms:
        recorded = rendered_scene_sha256(out / "datasets" / ds)
        scene = Path(config.scenes_dir) / room / "house.json"  # not scene_file: a missing room is build_graph's to name
        if recorded is not None and scene.is_file() and sha256_file(scene) != recorded:
            raise ValueError(f"{scene}: differs from the room {out / 'datasets' / ds} was rendered from; use the "
                             "scenes this folder was made with (--scenes-dir) or a new --out")


def reproduce(config: ReproduceConfig, out: str | Path, jobs: int = 1,
              executor: ExecutorSpec | None = None) -> RunReport:
    """Run (or resume) every stage for ``config`` in ``out`` with up to ``jobs`` stages at once on this machine, or
    with ``executor`` (e.g. on a Ray cluster: ``ExecutorSpec("ray", ray_address="auto")``).

    Raises:
        ValueError: ``out`` was made with other settings; FileNotFoundError: a shipped room is missing;
        spotlessgs.io.errors.FolderLockedError: another process is running a reproduction into ``out``;
        spotlessgs.jobs.StageFailedError: a stage raised (the others keep their results).
    """
    out = Path(out)
    executor = executor if executor is not None else ExecutorSpec(jobs=jobs)
    if executor.kind == "ray":  # a Ray worker resolves a relative path in its node's working directory, not this one
        out = out.resolve()
        config = dataclasses.replace(config, scenes_dir=Path(config.scenes_dir).resolve())
    refuse_overlap(out, {"--scenes-dir": config.scenes_dir}, "--out")
    executor.check()  # a cluster that is not there is said before anything is written
    graph = build_graph(config, out)  # checks the rooms exist before anything is written
    with folder_lock(out, "spotless reproduce"):  # a second reproduce into OUT would delete the stages this one runs
        check_or_record_config(config, out)
        if not all((out / name).is_file() for name in REPORT_FILES):  # deleted or never written: written again
            marker_path(out, "report").unlink(missing_ok=True)
        return execute(graph, out, executor)
