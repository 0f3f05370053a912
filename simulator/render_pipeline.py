"""Render a paired dataset of one room: poses, both renders per pose, and the dataset files (bpy-free orchestration).

Output folder (the dataset contract, see ``docs/dataset.md``)::

    OUT/plan.json            settings fingerprint + poses (written first; a rerun with other settings is refused)
    OUT/images/frame_00042.png  spotlight-only (uneven) input, 8-bit sRGB
    OUT/gt/frame_00042.png      lamps-on ground truth, 8-bit sRGB
    OUT/gt_uniform/frame_00042.png  with ``uniform_gt``: the uniform ground truth (even, shadow-free light), 8-bit sRGB
    OUT/exr/frame_00042.exr     linear uneven.RGB, gt.RGB, depth.Z (planar, m), normal.XYZ (world), albedo.RGB,
                                glossy.RGB, emission.RGB (the ground truth's glowing surfaces), with ``uniform_gt``
                                gt_uniform.RGB
    OUT/points3d.ply            initial coloured point cloud back-projected from depth
    OUT/sparse/0/*.txt          COLMAP text model (true poses)
    OUT/transforms.json         nerfstudio-compatible + our "spotless" block (written last: the dataset is complete)

Every file is written atomically; a frame counts as done when all its files exist, so rerunning the same command
resumes where it stopped. ``shard=(i, n)`` renders frames ``k`` with ``k % n == i`` so n jobs can share a scene; the
job that finds every frame done writes the dataset-level files. ``frame_range=(a, b)`` renders frames ``a <= k < b``
and never writes the dataset-level files: ``spotless-sim render-many`` (:mod:`simulator.render_many`) splits datasets
into such ranges and finishes each dataset with a whole-dataset call once its ranges are done.

Blender runs in a child process (see :func:`render_dataset`): Cycles swallows Ctrl-C, so the parent, which stays
responsive, kills the child on SIGINT / SIGTERM, removes the temporary files, and stops within a second; the finished
frames stay valid. The renderer's scratch folder (``OUT/.render-scratch-<i>of<n>``) and the temporary files of atomic
writes (``.<name>.partial-*``) that a killed run leaves are removed at the start of the next run.
"""

from __future__ import annotations

import contextlib
import dataclasses
import json
import logging
import multiprocessing
import os
import re
import shutil
import signal
import time
import traceback
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Iterable

import numpy as np

from simulator.child_process import silenced_output
from simulator.front3d import LoadOptions, load_house
from simulator.lighting import SPOTLIGHT_PRESETS, GroundTruthLighting, SpotlightConfig, with_ground_truth_lighting
from simulator.pointcloud import backproject_depth, merge_point_clouds
from simulator.scene_model import content_sha256
from simulator.trajectory import TrajectoryConfig, sample_trajectory, shutter_poses
from spotlessgs.io.atomic import PARTIAL_MARK, remove_partial_files, to_jsonable, write_json
from spotlessgs.io.cameras import Intrinsics
from spotlessgs.io.colmap_text import model_from_poses, write_colmap_text
from spotlessgs.io.colorspace import linear_to_srgb
from spotlessgs.io.errors import FolderLockedError, InputError, OutputOverlapError, WriteError
from spotlessgs.io.exr import FrameEXR, read_frame_exr, write_frame_exr
from spotlessgs.io.folder_lock import folder_lock
from spotlessgs.io.images import read_image, write_png
from spotlessgs.io.json_files import read_json
from spotlessgs.io.paths import refuse_foreign_folder, refuse_overlap
from spotlessgs.io.processes import die_with_parent, drop_blender_script_paths
from spotlessgs.io.dataset import UNIFORM_GT_DIR
from spotlessgs.io.ply import write_point_cloud
from spotlessgs.io.provenance import package_version, provenance, sha256_file
from spotlessgs.io.seeding import numpy_rng, stage_seed
from spotlessgs.io.transforms import DatasetMeta, FrameRecord, LightTruth, write_transforms

log = logging.getLogger(__name__)

SCHEMA_PLAN = 1
#: The render plan (poses, settings and the room's fingerprint) a dataset folder gets before its first frame.
PLAN_FILE = "plan.json"


@dataclass(frozen=True)
class RenderConfig:
    """Everything that determines a rendered dataset (besides the scene file).

    Attributes:
        frames: number of poses along the loop.
        width, height: image size (pixels).
        h_fov_deg: horizontal field of view of the pinhole camera (principal point at the image centre).
        samples: Cycles samples per pixel.
        denoise: OpenImageDenoise on both renders.
        max_bounces: light bounces (0 = direct light only: no bounce light at all).
        ambient: world strength in the spotlight-only render (0 = a dark room).
        residual_light: the room's own lights left on in the spotlight-only render at this fraction of their
            ground-truth power (a dimmed ceiling light that stays on; 0 = off): light that the spotlight does not
            explain, for the low-frequency light to model.
        lambertian: render every surface as an ideal Lambertian reflector (the Principled BSDF's specular layer off,
            metallic 0; colours and textures kept): a room with only diffuse materials. Blender's default dielectric
            keeps a 4 % Fresnel specular layer even at roughness 0.9, which is not Lambertian.
        motion_blur: camera motion blur in the spotlight-only input: the shutter is open this fraction of the time
            between two frames, centred on the frame (0 = sharp; the ground truth is always sharp).
        uniform_gt: also render the uniform ground truth (``gt_uniform/``): the room under even, shadow-free
            environment light of radiance 1, lamps present but unlit (the relighting equation's constant L0).
        seed: the command seed; poses, render noise and point sampling each derive their own generator from it.
        preset: name of the spotlight preset (``uneven`` or ``saturated``), recorded in the dataset.
        spotlight: the camera-mounted spotlight.
        ground_truth: lamps and ceiling lights of the evenly lit render.
        trajectory: the camera loop.
        room: 3D-FRONT room ``instanceid`` to render; None = the room with the largest floor.
        max_points: cap on the initial point cloud size.
    """

    frames: int = 120
    width: int = 320
    height: int = 240
    h_fov_deg: float = 75.0
    samples: int = 32
    denoise: bool = True
    max_bounces: int = 4
    ambient: float = 0.0
    residual_light: float = 0.0
    lambertian: bool = False
    motion_blur: float = 0.0
    uniform_gt: bool = False
    seed: int = 0
    preset: str = "uneven"
    spotlight: SpotlightConfig = field(default_factory=SpotlightConfig)
    ground_truth: GroundTruthLighting = field(default_factory=GroundTruthLighting)
    trajectory: TrajectoryConfig = field(default_factory=TrajectoryConfig)
    room: str | None = None
    max_points: int = 60_000

    def __post_init__(self) -> None:
        if not 0.0 <= self.motion_blur <= 1.0:
            raise ValueError(f"RenderConfig.motion_blur must be in [0, 1] (a fraction of the time between two "
                             f"frames), got {self.motion_blur}")

    @staticmethod
    def from_preset(preset: str, **overrides: Any) -> "RenderConfig":
        """A config with the named spotlight preset (``uneven`` / ``saturated``) and field overrides."""
        if preset not in SPOTLIGHT_PRESETS:
            raise ValueError(f"unknown preset {preset!r}; choose one of {sorted(SPOTLIGHT_PRESETS)}")
        return RenderConfig(preset=preset, spotlight=SPOTLIGHT_PRESETS[preset], **overrides)

    def intrinsics(self) -> Intrinsics:
        """Pinhole intrinsics of the rendered images."""
        return Intrinsics.from_fov(self.h_fov_deg, self.width, self.height)


@dataclass(frozen=True)
class ExecutionOptions:
    """How to run (does not change the output).

    Attributes:
        shard: (index, count): render only frames k with k % count == index.
        frame_range: (start, stop): render only frames start <= k < stop, and leave the dataset-level files to a
            whole-dataset call (None: the shard's frames).
        threads: CPU threads for Cycles.
        device: ``auto``, ``cpu`` or ``gpu``.
        progress: show a progress bar.
        quiet: silence what Blender's C code prints while it probes the devices and builds the scene (Cycles' GPU
            probing warns about every missing GPU library); Python log messages are kept.
    """

    shard: tuple[int, int] = (0, 1)
    frame_range: tuple[int, int] | None = None
    threads: int = 2
    device: str = "auto"
    progress: bool = True
    quiet: bool = False

    @property
    def part(self) -> "FramePart":
        """The frames this job renders."""
        return FramePart(self.shard, self.frame_range)


@dataclass(frozen=True)
class FramePart:
    """Which frames of a dataset one render job renders: all of them (the job owns the folder), a shard
    (``k % count == index``) or a range (``start <= k < stop``). Shards and ranges share the folder with the jobs of
    the other parts, so each cleans up only after itself."""

    shard: tuple[int, int] = (0, 1)
    frame_range: tuple[int, int] | None = None

    def __post_init__(self) -> None:
        index, count = self.shard
        if not (count >= 1 and 0 <= index < count):
            raise ValueError(f"shard {index}/{count} is invalid: need 0 <= I < N")
        if self.frame_range is not None:
            if count != 1:
                raise ValueError("a frame range and a shard cannot be combined")
            start, stop = self.frame_range
            if not 0 <= start < stop:
                raise ValueError(f"frame range {start}-{stop} is invalid: need 0 <= start < stop")

    @property
    def owns_folder(self) -> bool:
        """True for the job that renders every frame (it alone may remove every leftover and finish the dataset)."""
        return self.shard == (0, 1) and self.frame_range is None

    @property
    def label(self) -> str:
        """A name for the part's scratch folder and lock: ``0of1``, ``2of4``, ``frames-10-20``."""
        if self.frame_range is not None:
            return f"frames-{self.frame_range[0]}-{self.frame_range[1]}"
        return f"{self.shard[0]}of{self.shard[1]}"

    def frames(self, count: int) -> list[int]:
        """The part's frames of a dataset of ``count`` frames (ValueError for a range beyond the last frame)."""
        if self.frame_range is not None:
            start, stop = self.frame_range
            if stop > count:
                raise ValueError(f"frame range {start}-{stop} is beyond the dataset's {count} frames")
            return list(range(start, stop))
        index, n = self.shard
        return [k for k in range(count) if k % n == index]


def _as_part(part: "FramePart | tuple[int, int]") -> FramePart:
    """A FramePart from itself or a shard tuple."""
    return part if isinstance(part, FramePart) else FramePart(shard=tuple(part))


class DatasetFolderError(RuntimeError):
    """The output folder holds a dataset made with other settings."""


def frame_name(index: int) -> str:
    """File stem of frame ``index``: ``frame_00042``."""
    return f"frame_{index:05d}"


def frame_paths(out_dir: Path, index: int, uniform_gt: bool = False) -> dict[str, Path]:
    """The per-frame files of frame ``index``: image, gt, exr and with ``uniform_gt`` the uniform ground truth."""
    stem = frame_name(index)
    return {
        "image": out_dir / "images" / f"{stem}.png",
        "gt": out_dir / "gt" / f"{stem}.png",
        **({"gt_uniform": out_dir / UNIFORM_GT_DIR / f"{stem}.png"} if uniform_gt else {}),
        "exr": out_dir / "exr" / f"{stem}.exr",
    }


def frame_done(out_dir: Path, index: int, uniform_gt: bool = False) -> bool:
    """True when all files of frame ``index`` exist (each is written atomically)."""
    return all(p.is_file() for p in frame_paths(out_dir, index, uniform_gt).values())


def _fingerprint(scene_path: Path, config: RenderConfig, room_sha256: str | None) -> dict[str, Any]:
    """The settings that determine the output (JSON-able): the scene (its path, and its content's sha256, which is
    what identifies it), the room as loaded (``room_sha256``: :func:`~simulator.scene_model.content_sha256`, the
    models and textures included; None: not known, left out) and the render settings."""
    cfg = dataclasses.asdict(config)
    for option in ("lambertian", "motion_blur", "uniform_gt", "residual_light"):
        if not cfg[option]:
            del cfg[option]  # recorded only when set: datasets rendered before the option existed still resume
    room = {} if room_sha256 is None else {"room_sha256": room_sha256}
    return {"scene": str(scene_path.resolve()), "scene_sha256": sha256_file(scene_path), **room,
            "config": to_jsonable(cfg)}


def _plan_differences(old: dict[str, Any], new: dict[str, Any]) -> list[str]:
    """What differs between a stored plan's fingerprint ``old`` (as read; any form) and ``new``
    (:func:`_fingerprint`): the scene first, then the names of the settings. The room as loaded is compared where
    both record it (a plan from before 2026-12-07 does not)."""
    old_cfg = old.get("config", {}) if isinstance(old.get("config"), dict) else {}
    diff = sorted(k for k in set(old_cfg) | set(new["config"]) if old_cfg.get(k) != new["config"].get(k))
    scene = _scene_difference(old, new)
    if scene is None and "room_sha256" in new and old.get("room_sha256", new["room_sha256"]) != new["room_sha256"]:
        scene = "the room's models or textures (their files, or --future-dir, --texture-dir, --allow-missing)"
    return diff if scene is None else [scene, *diff]


def _read_plan(plan_path: Path) -> tuple[dict[str, Any], dict[str, Any]]:
    """A dataset's plan.json and its fingerprint ({} where it has none); InputError naming a damaged file."""
    plan = read_json(plan_path, "a dataset's render plan")
    return plan, plan["fingerprint"] if isinstance(plan.get("fingerprint"), dict) else {}


def rendered_scene_sha256(out_dir: Path) -> str | None:
    """The sha256 of the house file the dataset in ``out_dir`` was rendered from (its plan.json), or None where it
    has no plan or its plan does not record one."""
    plan_path = Path(out_dir) / PLAN_FILE
    if not plan_path.is_file():
        return None
    found = _read_plan(plan_path)[1].get("scene_sha256")
    return found if isinstance(found, str) else None


def check_plan_settings(out_dir: Path, scene_path: Path, config: RenderConfig) -> None:
    """DatasetFolderError when ``out_dir`` holds a plan.json made from another scene file or with other settings,
    InputError when it holds files but no plan.json (another tool's folder); nothing when it is absent or empty (the
    room as loaded is compared when the dataset renders): for a job that checks its datasets before it runs any task
    (``spotless-sim render-many``, whose finished tasks a rerun skips)."""
    refuse_foreign_folder(out_dir, [PLAN_FILE], "--out", "a dataset this renderer began")
    plan_path = Path(out_dir) / PLAN_FILE
    if plan_path.is_file():
        diff = _plan_differences(_read_plan(plan_path)[1], _fingerprint(scene_path, config, None))
        if diff:
            raise DatasetFolderError(f"{out_dir} holds a dataset rendered with other settings (differs in: "
                                     f"{', '.join(diff)}); use another --out or delete the folder")


def _scene_difference(old: dict[str, Any], new: dict[str, Any]) -> str | None:
    """None when a stored fingerprint's scene is the new one (the same file content, wherever the file now lies: a
    moved checkout, a colleague's copy; a plan from before the content hash, by its path or that file's content),
    else how they differ."""
    if "scene_sha256" in old:
        old_sha = old["scene_sha256"]
    elif old.get("scene") == new["scene"]:
        return None
    else:
        old_path = Path(str(old.get("scene", "")))
        if not old_path.is_file():
            return (f"scene: {old.get('scene')} then, {new['scene']} now, and the first is gone, so their contents "
                    "cannot be compared")
        old_sha = sha256_file(old_path)
    return None if old_sha == new["scene_sha256"] else \
        f"scene: {old.get('scene')} then, {new['scene']} now, another file content"


def _prepare_plan(out_dir: Path, scene_path: Path, config: RenderConfig, poses: np.ndarray, room_sha256: str) -> None:
    """Write ``plan.json`` or check that an existing one was made with the same scene, room as loaded (models and
    textures: a plan from before 2026-12-07 has no record of them, and gets one), settings and poses."""
    plan_path = out_dir / PLAN_FILE
    fingerprint = _fingerprint(scene_path, config, room_sha256)
    if plan_path.is_file():
        old, old_fp = _read_plan(plan_path)
        diff = _plan_differences(old_fp, fingerprint)
        if diff:
            raise DatasetFolderError(
                f"{out_dir} holds a dataset rendered with other settings (differs in: {', '.join(diff)}); "
                "use another --out or delete the folder"
            )
        stored = old.get("poses")
        try:
            stored = np.asarray(stored, dtype=np.float64)
        except (TypeError, ValueError):
            stored = None
        if stored is None or stored.shape != poses.shape:
            raise DatasetFolderError(f"{plan_path}: damaged render plan: 'poses' is not a list of {len(poses)} 4x4 "
                                     "matrices; use another --out or delete the folder")
        if not np.allclose(stored, poses, atol=1e-9):
            raise DatasetFolderError(f"{plan_path}: stored poses differ from the ones this command computes")
        if old_fp != fingerprint:  # the same scene from another path, or a plan from before the content hash
            write_json(plan_path, {**old, "fingerprint": fingerprint})
        return
    write_json(plan_path, {"schema": SCHEMA_PLAN, "fingerprint": fingerprint, "poses": poses.tolist()})


def plan_poses(scene_path: Path, config: RenderConfig, load: LoadOptions):
    """Load the scene, pick the room and sample the camera loop.

    Returns:
        (scene with ground-truth lights, room, room objects, poses (N, 4, 4) camera-to-world in the OpenGL convention)
    """
    scene = load_house(scene_path, load)
    room = scene.room(config.room)
    objects = scene.objects_in(room)
    scene = with_ground_truth_lighting(scene, objects, config.ground_truth)
    objects = scene.objects_in(room)
    traj_cfg = dataclasses.replace(config.trajectory, n_frames=config.frames)
    label = f"{scene_path} room {room.instance_id}"
    try:
        poses = sample_trajectory(
            room.floor_polygon,
            room.floor_z,
            room.ceiling_z,
            scene.furniture_boxes(room),
            traj_cfg,
            numpy_rng(config.seed, "trajectory"),
            label=label,
        )
    except ValueError as exc:  # a room the camera path does not fit: name the scene and the room
        if str(exc).startswith(label):
            raise
        raise InputError(f"{label}: {exc}") from None
    return scene, room, objects, poses


def light_truth(spot: SpotlightConfig) -> LightTruth:
    """The spotlight as recorded in the dataset (pose in the OpenCV camera frame)."""
    return LightTruth(
        position_in_camera=np.asarray(spot.position_in_camera, dtype=np.float64),
        rotation_in_camera=spot.rotation_matrix(),
        cone_angle_deg=float(spot.cone_angle_deg),
        blend=float(spot.blend),
        power_w=float(spot.power_w),
        color=np.asarray(spot.color, dtype=np.float64),
        radius_m=float(spot.radius_m),
    )


# ---------------------------------------------------------------------------------------------------------------------
# What a killed render leaves behind

#: Name prefix of the renderer's scratch folders inside a dataset (``.render-scratch-<label>``, one per FramePart).
SCRATCH_PREFIX = ".render-scratch"
_FRAME_PARTIAL = re.compile(r"^\.frame_(\d+)\.")


def scratch_dir(out_dir: str | Path, part: FramePart | tuple[int, int] = (0, 1)) -> Path:
    """The renderer's scratch folder of ``part`` (a FramePart or a shard) inside the dataset (Blender writes the EXR
    of each render there)."""
    return Path(out_dir) / f"{SCRATCH_PREFIX}-{_as_part(part).label}"


def remove_leftovers(out_dir: str | Path, part: FramePart | tuple[int, int] = (0, 1),
                     frames: Iterable[int] = ()) -> list[Path]:
    """Remove what a killed render left in ``out_dir``: temporary files of atomic writes and scratch folders.

    A render of every frame (``part`` (0, 1)) owns the folder: every ``.partial-`` file and every scratch folder
    goes. A shard or frame range shares the folder with other parts that may be running, so it removes only the
    temporary files of its own ``frames`` and its own scratch folder (leftovers of the dataset-level files wait for a
    whole-dataset run).

    Returns:
        the removed files and folders.
    """
    out_dir = Path(out_dir)
    if not out_dir.is_dir():
        return []
    removed: list[Path] = []
    part = _as_part(part)
    if part.owns_folder:
        removed += remove_partial_files(out_dir)
        scratch = [p for p in out_dir.glob(f"{SCRATCH_PREFIX}*") if p.is_dir() and not p.is_symlink()]
    else:
        mine = set(frames)
        for sub in ("images", "gt", UNIFORM_GT_DIR, "exr"):
            folder = out_dir / sub
            for path in folder.glob(f".frame_*{PARTIAL_MARK}*") if folder.is_dir() else ():
                match = _FRAME_PARTIAL.match(path.name)
                if match and int(match.group(1)) in mine and path.is_file() and not path.is_symlink():
                    with contextlib.suppress(FileNotFoundError):
                        path.unlink()
                        removed.append(path)
        own = scratch_dir(out_dir, part)
        scratch = [own] if own.is_dir() and not own.is_symlink() else []
    for folder in scratch:
        shutil.rmtree(folder, ignore_errors=True)
        removed.append(folder)
    return removed


# ---------------------------------------------------------------------------------------------------------------------
# Degenerate rooms and black frames

#: A pixel counts as lit when one of its channels reaches 2/255 in the 8-bit sRGB image (linear 2/255/12.92).
LIT_LEVEL = 2.0 / 255.0 / 12.92
#: A frame is (almost) all black when fewer than this fraction of its pixels are lit; it sees no geometry when fewer
#: than this fraction of its pixels hit a surface.
DARK_FRACTION = 0.01
# (flag of frame_check, key of the summary's "dark_frames", what the warning says)
_FRAME_PROBLEMS = (
    ("gt_dark", "gt", "an (almost) all-black ground truth (evenly lit render)"),
    ("image_dark", "images", "an (almost) all-black spotlight-only image"),
    ("empty", "empty", "no geometry in view"),
)


def frame_check(uneven: np.ndarray, gt: np.ndarray, depth: np.ndarray) -> dict[str, bool]:
    """What is wrong with one frame's renders (linear RGB, planar depth).

    Returns:
        ``gt_dark`` / ``image_dark``: the ground truth / the spotlight-only image is (almost) all black: fewer than
        1 % of its pixels reach 2/255 in the 8-bit sRGB image; ``empty``: fewer than 1 % of the pixels hit a surface.
    """

    def dark(image: np.ndarray) -> bool:
        brightest = np.max(np.nan_to_num(np.asarray(image, dtype=np.float32), nan=0.0), axis=-1)
        return bool(np.mean(brightest >= LIT_LEVEL) < DARK_FRACTION)

    return {"gt_dark": dark(gt), "image_dark": dark(uneven),
            "empty": bool(np.mean(np.isfinite(np.asarray(depth))) < DARK_FRACTION)}


def dark_frames(checks: dict[int, dict[str, bool]]) -> dict[str, list[str]]:
    """The names of the frames with each problem of :func:`frame_check`: ``{"gt": [...], "images": [...],
    "empty": [...]}`` in frame order."""
    return {key: [frame_name(k) for k in sorted(checks) if checks[k][flag]] for flag, key, _ in _FRAME_PROBLEMS}


def warn_dark_frames(report: dict[str, list[str]], where: str | Path, total: int) -> None:
    """One ``logging.warning`` line per problem of :func:`dark_frames` that some frame has, naming the frames."""
    for _, key, text in _FRAME_PROBLEMS:
        names = report.get(key, [])
        if names:
            log.warning("%s: %d of %d frame(s) with %s: %s", where, len(names), total, text, ", ".join(names))


def check_scene(scene_path: Path, room, objects, lights, config: RenderConfig) -> None:
    """Refuse a room that cannot give a usable dataset, before anything is written or rendered.

    Args:
        scene_path: the house file (named in the error).
        room, objects: the room and its objects, lamps already emitting (:func:`plan_poses`).
        lights: the ground-truth light fixtures (``Scene.lights`` of :func:`plan_poses`).

    Raises:
        InputError: the room has no visible geometry (no mesh with a positive area), or no light at all for the
            ground-truth render: no lamp or light strip with power, no emitting surface and no ceiling for the
            ceiling glow (every evenly lit image would be black; a room of only a floor, for instance).
    """
    where = f"{scene_path}: room {room.instance_id!r}"
    if not any(len(o.faces) and o.area() > 0.0 for o in objects):
        raise InputError(f"{where} has no visible geometry (no mesh with a positive area): nothing to render")
    lamps = [light for light in lights if light.power_w > 0 and max(light.color) > 0]
    emitters = [o for o in objects if o.material.emission > 0 and max(o.material.emission_color) > 0]
    ceilings = [o for o in objects if o.category.lower() == "ceiling"] if config.ground_truth.ceiling_glow > 0 else []
    if not (lamps or emitters or ceilings):
        raise InputError(f"{where} has no light for the ground-truth render: no lamp or light strip (furniture whose "
                         "category names a lamp, LightBand meshes) and no ceiling for the ceiling glow, so every "
                         "evenly lit image would be black; add a light to the room")


def _refuse_unusable(report: dict[str, list[str]], total: int, scene_path: Path, room, out_dir: Path) -> None:
    """Raise when every frame of the dataset is unusable (before any dataset-level file is written)."""
    where = f"{scene_path}: room {room.instance_id!r}"
    kept = (f"the frames are kept in {out_dir}, which is not a finished dataset (no transforms.json); fix the scene "
            "and render into a new folder")
    if total and len(report["empty"]) == total:
        raise InputError(f"{where}: no frame sees any geometry; {kept}")
    if total and len(report["gt"]) == total:
        raise InputError(f"{where}: the ground truth (evenly lit render) of every frame is (almost) all black: the "
                         f"room's lights do not light what the camera sees; {kept}")


# ---------------------------------------------------------------------------------------------------------------------
# Rendering


def render_inputs(scene_path: Path, load: LoadOptions) -> dict[str, Path | None]:
    """What a render reads, by the option that names it: the house file and the model and texture folders."""
    house = scene_path.parent
    future = load.future_dir or (house / "models" if (house / "models").is_dir() else None)
    textures = load.texture_dir or (house / "textures" if (house / "textures").is_dir() else None)
    return {"--scene": scene_path, "--future-dir": future, "--texture-dir": textures}


def render_dataset(
    scene_path: str | Path,
    out_dir: str | Path,
    config: RenderConfig = RenderConfig(),
    load: LoadOptions = LoadOptions(),
    execution: ExecutionOptions = ExecutionOptions(),
) -> dict[str, Any]:
    """Render (or resume rendering) the paired dataset of one room.

    Blender runs in a child process ('spawn'): the parent loads the scene, checks it, writes ``plan.json`` and waits;
    the child builds the Blender scene, renders the frames and writes each frame's files atomically. On
    ``KeyboardInterrupt`` (Ctrl-C, and SIGTERM via :class:`spotlessgs.io.signals.Terminated`) the parent kills the
    child, removes the temporary files and the scratch folder and re-raises: finished frames stay valid, a rerun
    resumes. An error in the child is raised again here with its type and message (its traceback as the cause).
    Temporary files and scratch folders that a killed earlier run left are removed first (see
    :func:`remove_leftovers`).

    Degenerate rooms: a room without visible geometry, or without any light for the ground truth (no lamp, light strip,
    emitting surface or ceiling glow) is refused before anything is written. After rendering, frames whose ground
    truth or spotlight-only image is (almost) all black, or that see no geometry, are named in one warning per problem
    and in the summary. When the dataset is complete and *every* frame's ground truth is black (or no frame sees any
    geometry), the dataset is unusable: :class:`InputError` naming the scene file, the frames are kept but the
    dataset-level files (``transforms.json`` last) are not written, so the folder never looks finished. Black
    spotlight-only images in some or all frames only warn (a very dark input is what the method is for).

    Raises:
        OutputOverlapError: ``out_dir`` is the house file's folder, contains the house file, or overlaps the model or
            texture folder (checked before anything is written).
        InputError: a degenerate room (see above).
        DatasetFolderError: ``out_dir`` holds a dataset rendered with other settings.

    Returns:
        a summary: frames rendered now, frames skipped, seconds per frame, whether the dataset is complete, and
        ``dark_frames`` (:func:`dark_frames` of the frames rendered now, or of every frame when the dataset was
        finished now).
    """
    scene_path, out_dir = Path(scene_path), Path(out_dir)
    part = execution.part  # checks the shard and the frame range
    refuse_overlap(out_dir, render_inputs(scene_path, load), "--out")
    # another tool's dataset (or any folder of files) would get some of its frames replaced and others kept
    refuse_foreign_folder(out_dir, [PLAN_FILE], "--out", "a dataset this renderer began")
    scene, room, objects, poses = plan_poses(scene_path, config, load)
    part.frames(len(poses))  # a range beyond the last frame is refused before anything is written
    check_scene(scene_path, room, objects, scene.lights, config)
    with _render_lock(out_dir, part):
        return _render_planned(scene_path, out_dir, config, execution, scene, room, objects, poses)


@contextlib.contextmanager
def _render_lock(out_dir: Path, part: FramePart):
    """A render of every frame holds ``OUT/.lock`` alone; a shard or frame range holds it shared with the other
    parts, and its own ``OUT/.lock-shard-I-of-N`` or ``OUT/.lock-frames-A-B`` alone (the same part twice, or a whole
    render beside parts, is refused)."""
    index, count = part.shard
    if part.frame_range is not None:
        start, stop = part.frame_range
        command, own = f"spotless-sim render-many (frames {start}-{stop})", f".lock-{part.label}"
    else:
        command = "spotless-sim render" + (f" --shard {index}/{count}" if count > 1 else "")
        own = f".lock-shard-{index}-of-{count}"
    with contextlib.ExitStack() as stack:
        stack.enter_context(folder_lock(out_dir, command, shared=not part.owns_folder))
        if not part.owns_folder:
            stack.enter_context(folder_lock(out_dir, command, name=own))
        yield


def _render_planned(scene_path: Path, out_dir: Path, config: RenderConfig, execution: ExecutionOptions, scene, room,
                    objects, poses: np.ndarray) -> dict[str, Any]:
    """:func:`render_dataset` once the room is checked and ``out_dir`` is locked."""
    part = execution.part
    # first: a folder of another dataset is left untouched
    _prepare_plan(out_dir, scene_path, config, poses, content_sha256(objects, scene.lights))
    mine = part.frames(len(poses))
    remove_leftovers(out_dir, part, mine)

    todo = [k for k in mine if not frame_done(out_dir, k, config.uniform_gt)]
    summary: dict[str, Any] = {"rendered": 0, "skipped": len(mine) - len(todo), "seconds_per_frame": None}
    device, blender, checks = "n/a", None, {}
    if todo:
        room_scene = dataclasses.replace(scene, objects=objects)
        result = _render_in_child(out_dir, config, execution, room_scene, poses, todo,
                                  label=f"render {scene_path.parent.name}")
        device, blender, checks = result.device, result.blender, result.checks
        summary["rendered"] = len(checks)
        summary["seconds_per_frame"] = result.seconds_per_frame
        if not part.owns_folder:  # the job that finishes the dataset may render nothing itself: it reads these
            write_json(out_dir / PARTS_DIR / f"{part.label}.json", {"device": device, "blender": blender})
    complete = all(frame_done(out_dir, k, config.uniform_gt) for k in range(len(poses)))
    summary["complete"] = complete
    report, total = dark_frames(checks), len(checks)
    finishes = part.frame_range is None  # a range leaves the dataset-level files to a whole-dataset call
    if finishes and complete and (summary["rendered"] > 0 or not (out_dir / "transforms.json").is_file()):
        if summary["rendered"] == 0:
            device, blender = parts_device(out_dir)
        report = finalize_dataset(out_dir, scene, room, poses, config, device=device, blender=blender)
        total = len(poses)
    warn_dark_frames(report, out_dir, total)
    summary["dark_frames"] = report
    return summary


#: Where the jobs that render a shard or a frame range record their render device and Blender version.
PARTS_DIR = ".render-parts"


def parts_device(out_dir: Path) -> tuple[str, str | None]:
    """The render device and Blender version that the shards' or frame ranges' jobs recorded (devices that differ
    between parts joined with ``+``); ``("n/a", None)`` when none recorded one."""
    records = []
    for path in sorted((out_dir / PARTS_DIR).glob("*.json")):
        with contextlib.suppress(OSError, ValueError):
            records.append(json.loads(path.read_text(encoding="utf-8")))
    devices = sorted({str(r.get("device")) for r in records if r.get("device")})
    blenders = sorted({str(r.get("blender")) for r in records if r.get("blender")})
    return ("+".join(devices) or "n/a"), ("+".join(blenders) or None)


class RenderProcessError(RuntimeError):
    """The Blender child process ended without reporting (killed from outside, out of memory, crashed)."""


class _ChildTraceback(Exception):
    """The traceback of an exception raised in the render process, attached as the cause of the re-raised one."""

    def __init__(self, text: str) -> None:
        super().__init__(text)
        self.text = text

    def __str__(self) -> str:
        return f"\n\"\"\"\n{self.text.rstrip()}\n\"\"\""


@dataclass
class _ChildResult:
    device: str = "n/a"
    blender: str | None = None
    checks: dict[int, dict[str, bool]] = field(default_factory=dict)
    seconds_per_frame: float | None = None


class _PipeLogHandler(logging.Handler):
    """Sends the child's log records to the parent, which hands them to its own handlers."""

    def __init__(self, conn) -> None:
        super().__init__()
        self.conn = conn

    def emit(self, record: logging.LogRecord) -> None:
        try:
            message = record.getMessage()
            if record.exc_info:
                message += "\n" + logging.Formatter().formatException(record.exc_info)
            attrs = {**record.__dict__, "msg": message, "args": None, "exc_info": None, "exc_text": None}
            self.conn.send(("log", logging.makeLogRecord(attrs)))
        except Exception:  # noqa: BLE001 - logging must not raise
            self.handleError(record)


#: Exceptions the render process may report, rebuilt by name in the parent from plain data (the child's exception
#: object is never pickled); any other type comes back as a RuntimeError that names it.
_REPORTED_ERRORS = {cls.__name__: cls for cls in (
    InputError, OutputOverlapError, WriteError, FolderLockedError, FileNotFoundError, FileExistsError,
    NotADirectoryError, IsADirectoryError, PermissionError, OSError, ValueError, RuntimeError, MemoryError, KeyError,
    TypeError)}


def _portable(exc: BaseException) -> tuple[list | None, str, str, str]:
    """An exception as plain data, rebuilt by :func:`_rebuilt`: ([errno, strerror, filename] of an OSError or None,
    type name, message, traceback text)."""
    text = "".join(traceback.format_exception(type(exc), exc, exc.__traceback__))
    os_fields = None
    if isinstance(exc, OSError) and exc.errno is not None:
        os_fields = [exc.errno, exc.strerror, None if exc.filename is None else str(exc.filename)]
    return os_fields, type(exc).__name__, str(exc), text


def _rebuilt(os_fields: list | None, type_name: str, message: str) -> BaseException:
    """The parent's copy of a reported exception: the same type where it is a known one, with the same message (and
    errno, strerror and filename for an OSError)."""
    cls = _REPORTED_ERRORS.get(type_name)
    if cls is None:
        return RuntimeError(f"{type_name}: {message}")
    if os_fields is not None and issubclass(cls, OSError):
        return cls(*os_fields)
    return cls(message)


def _child_main(conn, parent_pid: int, out_dir: str, config: RenderConfig, execution: ExecutionOptions,
                log_level: int) -> None:
    """Entry of the render process: receive the scene, render the frames, report each one, then ``done``/``error``."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # Ctrl-C reaches the whole process group: the parent handles it
    die_with_parent(signal.SIGKILL, parent_pid)
    drop_blender_script_paths()
    root = logging.getLogger()
    root.handlers[:] = [_PipeLogHandler(conn)]
    root.setLevel(log_level)
    try:
        room_scene, poses, todo = conn.recv()
        _render_frames(conn, Path(out_dir), config, execution, room_scene, poses, todo)
        message: tuple = ("done",)
    except BaseException as exc:  # noqa: BLE001 - every error goes back to the parent
        message = ("error", *_portable(exc))
    with contextlib.suppress(OSError):
        conn.send(message)
    conn.close()


def _render_frames(conn, out_dir: Path, config: RenderConfig, execution: ExecutionOptions, room_scene,
                   poses: np.ndarray, todo: list[int]) -> None:
    """In the render process: build the Blender scene, then render and write every frame of ``todo``."""
    with silenced_output(execution.quiet):  # Cycles' device probing prints to the C-level stdout
        from simulator.blender import renderer, scene_builder  # deferred: bpy is imported only in the render process

        scene_builder.reset_blender()
        settings = renderer.CyclesSettings(
            width=config.width,
            height=config.height,
            samples=config.samples,
            denoise=config.denoise,
            max_bounces=config.max_bounces,
            threads=execution.threads,
            device=execution.device,
            ambient=config.ambient,
            residual_light=config.residual_light,
            motion_blur=config.motion_blur > 0,
            uniform_gt=config.uniform_gt,
        )
        device = renderer.configure(settings)
        built = scene_builder.build_scene(room_scene, config.spotlight, config.ground_truth.ceiling_glow,
                                          config.intrinsics(), lambertian=config.lambertian)
    conn.send(("ready", device, renderer.blender_version()))
    scratch = scratch_dir(out_dir, execution.part)
    scratch.mkdir(parents=True, exist_ok=True)
    try:
        for k in todo:
            shutter = shutter_poses(poses, k, config.motion_blur) if config.motion_blur > 0 else None
            pair = renderer.render_pair(built, poses[k], settings, stage_seed(config.seed, f"cycles/{k}"),
                                        workdir=scratch, shutter=shutter)
            paths = frame_paths(out_dir, k, config.uniform_gt)
            write_frame_exr(paths["exr"], FrameEXR(uneven=pair.uneven, gt=pair.gt, depth=pair.depth,
                                                   normal=pair.normal, albedo=pair.albedo, emission=pair.emission,
                                                   gt_uniform=pair.gt_uniform, glossy=pair.glossy))
            write_png(paths["gt"], linear_to_srgb(pair.gt))
            if pair.gt_uniform is not None:
                write_png(paths["gt_uniform"], linear_to_srgb(pair.gt_uniform))
            write_png(paths["image"], linear_to_srgb(pair.uneven))
            conn.send(("frame", k, frame_check(pair.uneven, pair.gt, pair.depth)))
    finally:
        shutil.rmtree(scratch, ignore_errors=True)


@contextlib.contextmanager
def _sigint_ignored():
    """Ignore SIGINT while the child starts, so that it is born ignoring it (an ignored signal stays ignored across
    exec, and Python then installs no KeyboardInterrupt handler). Off the main thread, or under a handler installed by
    C code, nothing changes: the child ignores SIGINT from its first line on."""
    previous = signal.getsignal(signal.SIGINT)
    changed = False
    if previous is not None:
        try:
            signal.signal(signal.SIGINT, signal.SIG_IGN)
            changed = True
        except ValueError:  # not the main thread
            pass
    try:
        yield
    finally:
        if changed:
            signal.signal(signal.SIGINT, previous)


def _stop(process) -> None:
    """Kill the render process (it ignores SIGINT) and reap it."""
    if process.pid is None:
        return
    with contextlib.suppress(OSError, ValueError):
        process.kill()
    process.join(timeout=30)


def _describe_exit(code: int | None) -> str:
    if code is None:
        return "still running"
    if code < 0:
        try:
            name = signal.Signals(-code).name
        except ValueError:
            name = f"signal {-code}"
        return f"killed by {name}" + (" — out of memory?" if -code == signal.SIGKILL else "")
    return f"exit status {code}"


def _render_in_child(out_dir: Path, config: RenderConfig, execution: ExecutionOptions, room_scene,
                     poses: np.ndarray, todo: list[int], label: str) -> _ChildResult:
    """Run :func:`_render_frames` in a spawned child; wait for it, show progress, forward its log records.

    On any exception here (``KeyboardInterrupt`` and ``Terminated`` included) the child is killed, the temporary files
    of its frames and its scratch folder are removed, and the exception propagates.
    """
    from tqdm import tqdm

    context = multiprocessing.get_context("spawn")
    conn, child_conn = context.Pipe(duplex=True)
    process = context.Process(
        target=_child_main, name="spotless-render",
        args=(child_conn, os.getpid(), str(out_dir), config, execution, logging.getLogger().getEffectiveLevel()),
    )
    result = _ChildResult()
    failure: tuple | None = None
    finished = False
    bar = tqdm(total=len(todo), desc=label, unit="frame", disable=not execution.progress)
    try:
        with _sigint_ignored():
            process.start()
        child_conn.close()
        with contextlib.suppress(BrokenPipeError, ConnectionResetError):  # a child dead before reading: its exit
            conn.send((room_scene, poses, todo))                           # status is reported below
        started = last = time.perf_counter()
        while True:
            if not conn.poll(0.2):
                continue
            try:
                message = conn.recv()
            except EOFError:
                break
            kind = message[0]
            if kind == "log":
                logging.getLogger(message[1].name).handle(message[1])
            elif kind == "ready":
                result.device, result.blender = message[1], message[2]
                started = time.perf_counter()
            elif kind == "frame":
                result.checks[message[1]] = message[2]
                last = time.perf_counter()
                bar.update(1)
            elif kind == "error":
                failure = message[1:]
                break
            elif kind == "done":
                finished = True
                break
        while process.is_alive():
            process.join(timeout=0.2)
    except BaseException:
        _stop(process)
        remove_leftovers(out_dir, execution.part, todo)
        raise
    finally:
        bar.close()
        conn.close()
    if result.checks:
        result.seconds_per_frame = (last - started) / len(result.checks)
    if failure is not None:
        payload, type_name, message_text, text = failure
        remove_leftovers(out_dir, execution.part, todo)
        raise _rebuilt(payload, type_name, message_text) from _ChildTraceback(text)
    if not finished:
        remove_leftovers(out_dir, execution.part, todo)
        raise RenderProcessError(
            f"{out_dir}: the Blender render process stopped unexpectedly ({_describe_exit(process.exitcode)}) after "
            f"{len(result.checks)} of {len(todo)} frame(s); the finished frames are kept: rerun the same command "
            "to resume")
    return result


def finalize_dataset(
    out_dir: Path, scene, room, poses: np.ndarray, config: RenderConfig, device: str, blender: str | None
) -> dict[str, list[str]]:
    """Write the point cloud, the COLMAP text model and ``transforms.json`` once every frame exists.

    Every frame is checked first (:func:`frame_check`); when every ground truth is black, or no frame sees any
    geometry, :class:`InputError` is raised before any of these files is written.

    Returns:
        :func:`dark_frames` of every frame.
    """
    intr = config.intrinsics()
    rng = numpy_rng(config.seed, "pointcloud")
    per_frame_budget = max(config.max_points // max(len(poses), 1) * 4, 256)
    clouds = []
    checks = {}
    for k in range(len(poses)):
        paths = frame_paths(out_dir, k)
        exr = read_frame_exr(paths["exr"])
        checks[k] = frame_check(exr.uneven, exr.gt, exr.depth)
        rgb = np.round(read_image(paths["image"]) * 255.0).astype(np.uint8)
        clouds.append(backproject_depth(exr.depth, rgb, exr.normal, intr, poses[k], max_points=per_frame_budget,
                                        rng=rng))
    report = dark_frames(checks)
    _refuse_unusable(report, len(poses), Path(scene.source), room, out_dir)
    voxel = max(0.01, float(np.sqrt(room.floor_area())) / 200.0)
    cloud = merge_point_clouds(clouds, voxel_size=voxel, max_points=config.max_points, rng=rng)
    write_point_cloud(out_dir / "points3d.ply", cloud.xyz, cloud.rgb, cloud.normals)

    names = [f"images/{frame_name(k)}.png" for k in range(len(poses))]
    model = model_from_poses(intr, [Path(n).name for n in names], poses, cloud.xyz, cloud.rgb)
    write_colmap_text(out_dir / "sparse" / "0", model)

    frames = [
        FrameRecord(
            file_path=names[k],
            c2w_opengl=poses[k],
            gt_file_path=f"gt/{frame_name(k)}.png",
            exr_file_path=f"exr/{frame_name(k)}.exr",
        )
        for k in range(len(poses))
    ]
    meta = DatasetMeta(
        scene_id=scene.scene_id,
        room=room.instance_id,
        seed=config.seed,
        preset=config.preset,
        light=light_truth(config.spotlight),
        renderer={
            "engine": "CYCLES",
            "device": device,
            "samples": config.samples,
            "denoise": "OPENIMAGEDENOISE" if config.denoise else None,
            "max_bounces": config.max_bounces,
            "view_transform": "Standard",
            "ambient": config.ambient,
            **({"residual_light": config.residual_light} if config.residual_light > 0 else {}),
            "lambertian": config.lambertian,
            **({"motion_blur": config.motion_blur} if config.motion_blur > 0 else {}),
            **({"ground_truths": {"lamps": "gt", "uniform": UNIFORM_GT_DIR}} if config.uniform_gt else {}),
            "ground_truth_lighting": to_jsonable(dataclasses.asdict(config.ground_truth)),
            "trajectory": to_jsonable(dataclasses.asdict(config.trajectory)),
            "h_fov_deg": config.h_fov_deg,
        },
        provenance=provenance(seed=config.seed, extra_packages=("bpy",), blender_version=blender or package_version("bpy"),
                              scene_file=str(scene.source)),
    )
    write_transforms(out_dir / "transforms.json", intr, frames, meta, ply_file_path="points3d.ply")
    return report
