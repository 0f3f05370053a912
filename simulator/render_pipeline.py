"""Render a paired dataset of one room: poses, both renders per pose, and the dataset files (bpy-free orchestration).

Output folder (the dataset contract, see ``docs/dataset.md``)::

    OUT/plan.json            settings fingerprint + poses (written first; a rerun with other settings is refused)
    OUT/images/frame_00042.png  spotlight-only (uneven) input, 8-bit sRGB
    OUT/gt/frame_00042.png      lamps-on ground truth, 8-bit sRGB
    OUT/exr/frame_00042.exr     linear uneven.RGB, gt.RGB, depth.Z (planar, m), normal.XYZ (world)
    OUT/points3d.ply            initial coloured point cloud back-projected from depth
    OUT/sparse/0/*.txt          COLMAP text model (true poses)
    OUT/transforms.json         nerfstudio-compatible + our "spotless" block (written last: the dataset is complete)

Every file is written atomically; a frame counts as done when its three files exist, so rerunning the same command
resumes where it stopped. ``shard=(i, n)`` renders frames ``k`` with ``k % n == i`` so n jobs can share a scene; the
job that finds every frame done writes the dataset-level files.
"""

from __future__ import annotations

import dataclasses
import logging
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from simulator.front3d import LoadOptions, load_house
from simulator.lighting import SPOTLIGHT_PRESETS, GroundTruthLighting, SpotlightConfig, with_ground_truth_lighting
from simulator.pointcloud import backproject_depth, merge_point_clouds
from simulator.trajectory import TrajectoryConfig, sample_trajectory
from spotlessgs.io.atomic import to_jsonable, write_json
from spotlessgs.io.cameras import Intrinsics
from spotlessgs.io.colmap_text import model_from_poses, write_colmap_text
from spotlessgs.io.colorspace import linear_to_srgb
from spotlessgs.io.exr import FrameEXR, read_frame_exr, write_frame_exr
from spotlessgs.io.images import read_image, write_png
from spotlessgs.io.ply import write_point_cloud
from spotlessgs.io.provenance import package_version, provenance
from spotlessgs.io.seeding import numpy_rng, stage_seed
from spotlessgs.io.transforms import DatasetMeta, FrameRecord, LightTruth, write_transforms

log = logging.getLogger(__name__)

SCHEMA_PLAN = 1


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
        lambertian: render every surface as an ideal Lambertian reflector (the Principled BSDF's specular layer off,
            metallic 0; colours and textures kept): a room with only diffuse materials. Blender's default dielectric
            keeps a 4 % Fresnel specular layer even at roughness 0.9, which is not Lambertian.
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
    lambertian: bool = False
    seed: int = 0
    preset: str = "uneven"
    spotlight: SpotlightConfig = field(default_factory=SpotlightConfig)
    ground_truth: GroundTruthLighting = field(default_factory=GroundTruthLighting)
    trajectory: TrajectoryConfig = field(default_factory=TrajectoryConfig)
    room: str | None = None
    max_points: int = 60_000

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
        threads: CPU threads for Cycles.
        device: ``auto``, ``cpu`` or ``gpu``.
        progress: show a progress bar.
    """

    shard: tuple[int, int] = (0, 1)
    threads: int = 2
    device: str = "auto"
    progress: bool = True


class DatasetFolderError(RuntimeError):
    """The output folder holds a dataset made with other settings."""


def frame_name(index: int) -> str:
    """File stem of frame ``index``: ``frame_00042``."""
    return f"frame_{index:05d}"


def frame_paths(out_dir: Path, index: int) -> dict[str, Path]:
    """The three per-frame files of frame ``index``."""
    stem = frame_name(index)
    return {
        "image": out_dir / "images" / f"{stem}.png",
        "gt": out_dir / "gt" / f"{stem}.png",
        "exr": out_dir / "exr" / f"{stem}.exr",
    }


def frame_done(out_dir: Path, index: int) -> bool:
    """True when all files of frame ``index`` exist (each is written atomically)."""
    return all(p.is_file() for p in frame_paths(out_dir, index).values())


def _fingerprint(scene_path: Path, config: RenderConfig) -> dict[str, Any]:
    """The settings that determine the output (JSON-able)."""
    cfg = dataclasses.asdict(config)
    if not cfg["lambertian"]:
        del cfg["lambertian"]  # recorded only when set: datasets rendered before the option existed still resume
    return {"scene": str(scene_path.resolve()), "config": to_jsonable(cfg)}


def _prepare_plan(out_dir: Path, scene_path: Path, config: RenderConfig, poses: np.ndarray) -> None:
    """Write ``plan.json`` or check that an existing one was made with the same settings and poses."""
    plan_path = out_dir / "plan.json"
    fingerprint = _fingerprint(scene_path, config)
    if plan_path.is_file():
        import json

        old = json.loads(plan_path.read_text())
        if old.get("fingerprint") != fingerprint:
            diff = sorted(
                k for k in set(old.get("fingerprint", {}).get("config", {})) | set(fingerprint["config"])
                if old.get("fingerprint", {}).get("config", {}).get(k) != fingerprint["config"].get(k)
            )
            raise DatasetFolderError(
                f"{out_dir} holds a dataset rendered with other settings (differs in: {', '.join(diff) or 'scene'}); "
                "use another --out or delete the folder"
            )
        if not np.allclose(np.asarray(old["poses"]), poses, atol=1e-9):
            raise DatasetFolderError(f"{plan_path}: stored poses differ from the ones this command computes")
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
    poses = sample_trajectory(
        room.floor_polygon,
        room.floor_z,
        room.ceiling_z,
        scene.furniture_boxes(room),
        traj_cfg,
        numpy_rng(config.seed, "trajectory"),
        label=f"{scene_path} room {room.instance_id}",
    )
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


def render_dataset(
    scene_path: str | Path,
    out_dir: str | Path,
    config: RenderConfig = RenderConfig(),
    load: LoadOptions = LoadOptions(),
    execution: ExecutionOptions = ExecutionOptions(),
) -> dict[str, Any]:
    """Render (or resume rendering) the paired dataset of one room.

    Returns:
        a summary: frames rendered now, frames skipped, seconds per frame, whether the dataset is complete.
    """
    scene_path, out_dir = Path(scene_path), Path(out_dir)
    shard_index, shard_count = execution.shard
    if not (shard_count >= 1 and 0 <= shard_index < shard_count):
        raise ValueError(f"shard {shard_index}/{shard_count} is invalid: need 0 <= I < N")
    scene, room, objects, poses = plan_poses(scene_path, config, load)
    out_dir.mkdir(parents=True, exist_ok=True)
    _prepare_plan(out_dir, scene_path, config, poses)

    mine = [k for k in range(len(poses)) if k % shard_count == shard_index]
    todo = [k for k in mine if not frame_done(out_dir, k)]
    summary: dict[str, Any] = {"rendered": 0, "skipped": len(mine) - len(todo), "seconds_per_frame": None}
    device = "n/a"
    blender = None
    if todo:
        from simulator.blender import renderer, scene_builder  # bpy is imported only when there is work

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
        )
        device = renderer.configure(settings)
        blender = renderer.blender_version()
        room_scene = dataclasses.replace(scene, objects=objects)
        built = scene_builder.build_scene(room_scene, config.spotlight, config.ground_truth.ceiling_glow,
                                          config.intrinsics(), lambertian=config.lambertian)
        from tqdm import tqdm

        bar = tqdm(todo, desc=f"render {scene_path.parent.name}", unit="frame", disable=not execution.progress)
        start = time.perf_counter()
        for k in bar:
            pair = renderer.render_pair(built, poses[k], settings, stage_seed(config.seed, f"cycles/{k}"))
            paths = frame_paths(out_dir, k)
            write_frame_exr(paths["exr"], FrameEXR(uneven=pair.uneven, gt=pair.gt, depth=pair.depth,
                                                   normal=pair.normal))
            write_png(paths["gt"], linear_to_srgb(pair.gt))
            write_png(paths["image"], linear_to_srgb(pair.uneven))
            summary["rendered"] += 1
        summary["seconds_per_frame"] = (time.perf_counter() - start) / len(todo)
    complete = all(frame_done(out_dir, k) for k in range(len(poses)))
    summary["complete"] = complete
    if complete and (summary["rendered"] > 0 or not (out_dir / "transforms.json").is_file()):
        finalize_dataset(out_dir, scene, room, poses, config, device=device, blender=blender)
    return summary


def finalize_dataset(
    out_dir: Path, scene, room, poses: np.ndarray, config: RenderConfig, device: str, blender: str | None
) -> None:
    """Write the point cloud, the COLMAP text model and ``transforms.json`` once every frame exists."""
    intr = config.intrinsics()
    rng = numpy_rng(config.seed, "pointcloud")
    per_frame_budget = max(config.max_points // max(len(poses), 1) * 4, 256)
    clouds = []
    for k in range(len(poses)):
        paths = frame_paths(out_dir, k)
        exr = read_frame_exr(paths["exr"])
        rgb = np.round(read_image(paths["image"]) * 255.0).astype(np.uint8)
        clouds.append(backproject_depth(exr.depth, rgb, exr.normal, intr, poses[k], max_points=per_frame_budget,
                                        rng=rng))
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
            "lambertian": config.lambertian,
            "ground_truth_lighting": to_jsonable(dataclasses.asdict(config.ground_truth)),
            "trajectory": to_jsonable(dataclasses.asdict(config.trajectory)),
            "h_fov_deg": config.h_fov_deg,
        },
        provenance=provenance(seed=config.seed, extra_packages=("bpy",), blender_version=blender or package_version("bpy"),
                              scene_file=str(scene.source)),
    )
    write_transforms(out_dir / "transforms.json", intr, frames, meta, ply_file_path="points3d.ply")
