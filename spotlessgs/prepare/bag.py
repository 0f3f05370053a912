"""``spotless prepare --bag FILE --image-topic T [--odometry-topic T] --out DATA``: one camera of a ROS 1 or ROS 2
bag becomes a dataset: with odometry, a posed nerfstudio dataset whose sparse points are triangulated with the poses
(:mod:`spotlessgs.prepare.points`), or with an RGB-D camera's depth topic (``--depth-topic``) a dense cloud from its
depth images (:mod:`spotlessgs.prepare.depth_points`); without odometry, the frames go through structure from motion
(:mod:`spotlessgs.prepare.images`)."""

from __future__ import annotations

import dataclasses
import logging
import tempfile
from collections.abc import Callable
from pathlib import Path
from typing import Any

from spotlessgs.io.atomic import write_json
from spotlessgs.io.cameras import opencv_to_opengl_c2w
from spotlessgs.io.depth_images import DEFAULT_DEPTH_SCALE, write_depth_image
from spotlessgs.io.errors import InputError
from spotlessgs.io.images import write_png
from spotlessgs.io.paths import refuse_overlap
from spotlessgs.io.provenance import provenance
from spotlessgs.io.rosbag import read_bag
from spotlessgs.io.transforms import FrameRecord, write_transforms
from spotlessgs.prepare.depth_points import add_depth_points
from spotlessgs.prepare.images import (
    SUMMARY_FILE, checked_frames, pose_error, prepared_folder, write_image_dataset,
)
from spotlessgs.prepare.points import add_sfm_points

log = logging.getLogger(__name__)


def prepare_bag(
    bag: str | Path, out: str | Path, image_topic: str, camera_info_topic: str | None = None,
    pose_topic: str | None = None, min_interval_s: float = 0.0, min_motion_m: float = 0.0,
    camera_model: str = "SIMPLE_RADIAL", matcher: str = "sequential", truth: str | Path | None = None,
    threads: int = 1, seed: int = 0, progress: Callable[[str], None] | None = None, points: bool = True,
    depth_topic: str | None = None,
) -> dict[str, Any]:
    """Turn one camera of a ROS 1 or ROS 2 bag into a dataset in ``out``.

    With ``pose_topic`` (odometry of the camera's optical frame) the frames and their poses become a nerfstudio
    ``transforms.json`` (the camera from ``camera_info_topic``, which is then required) and, with ``points``, sparse
    points triangulated with those poses (:func:`~spotlessgs.prepare.points.add_sfm_points`; when none can be, a
    warning, and the trainer starts without); without it the frames go through :func:`prepare_images` (structure
    from motion; the CameraInfo camera, when given, is kept fixed). With ``depth_topic`` (and ``pose_topic``) each
    frame also gets its registered depth image (``depth/frame_*.png``, 16-bit millimetres, its ``depth_file_path``),
    and the points are those depth images back-projected (:func:`~spotlessgs.prepare.depth_points.add_depth_points`).

    Raises:
        InputError: as :func:`spotlessgs.io.rosbag.read_bag` and :func:`prepare_images`; poses without a camera;
            depth without poses.
    """
    bag, out = Path(bag), Path(out)
    refuse_overlap(out, {"--bag": bag}, "--out")
    if pose_topic is not None and camera_info_topic is None:
        raise InputError(f"{bag}: poses from {pose_topic!r} need the camera too: give its CameraInfo topic")
    if depth_topic is not None and pose_topic is None:
        raise InputError(f"{bag}: depth images from {depth_topic!r} need the camera's poses (metric, as the depth): "
                         "give its odometry topic")
    step = progress or (lambda _name: None)
    step(f"reading {image_topic}")
    frames = read_bag(bag, image_topic, camera_info_topic, pose_topic, min_interval_s, min_motion_m, depth_topic)
    with prepared_folder(out, {"bag": str(bag.resolve()), "image_topic": image_topic}):
        return _write_bag_dataset(frames, bag, out, image_topic, camera_info_topic, pose_topic, depth_topic,
                                  camera_model, matcher, truth, threads, seed, progress, points)


def _write_bag_dataset(frames, bag: Path, out: Path, image_topic: str, camera_info_topic: str | None,
                       pose_topic: str | None, depth_topic: str | None, camera_model: str, matcher: str,
                       truth: str | Path | None, threads: int, seed: int, progress: Callable[[str], None] | None,
                       points: bool) -> dict[str, Any]:
    """:func:`prepare_bag` of the frames read from the bag (:func:`~spotlessgs.io.rosbag.read_bag`) with ``out`` held
    (:func:`~spotlessgs.prepare.images.prepared_folder`)."""
    source = {"bag": str(bag.resolve()), "image_topic": image_topic, "camera_info_topic": camera_info_topic,
              "pose_topic": pose_topic, "depth_topic": depth_topic, "frames_kept": len(frames.images),
              "frames_skipped": frames.skipped, "frames_skipped_by": frames.skipped_by}
    if frames.c2w is None:
        with tempfile.TemporaryDirectory(prefix="spotless-bag-") as tmp:
            for k, image in enumerate(frames.images):
                write_png(Path(tmp) / f"frame_{k:05d}.png", image, bits=None)  # a 16-bit camera's levels kept
            summary = write_image_dataset(Path(tmp), checked_frames(Path(tmp)), out, camera_model, matcher,
                                          frames.intrinsics, truth, threads, seed, progress,
                                          source_name=f"{bag}: {image_topic}")
        summary["source"] = source
        write_json(out / SUMMARY_FILE, summary)
        return summary
    records = []
    for k, (image, c2w) in enumerate(zip(frames.images, frames.c2w)):
        name, depth_name = f"images/frame_{k:05d}.png", None
        write_png(out / name, image, bits=None)  # a 12- or 16-bit camera's levels kept
        if frames.depths is not None:
            depth_name = f"depth/frame_{k:05d}.png"
            write_depth_image(out / depth_name, frames.depths[k], DEFAULT_DEPTH_SCALE)
        records.append(FrameRecord(name, opencv_to_opengl_c2w(c2w), depth_file_path=depth_name))
    write_transforms(out / "transforms.json", frames.intrinsics, records, None,
                     depth_unit_scale_factor=None if frames.depths is None else DEFAULT_DEPTH_SCALE)
    summary = {"source": source, "frames": len(records), "registered": len(records), "not_registered": [],
               "poses": "from the pose topic", "camera": dataclasses.asdict(frames.intrinsics),
               "provenance": provenance(seed=seed)}
    if truth is not None:
        summary["pose_error"] = pose_error(out, Path(truth))
    write_json(out / SUMMARY_FILE, summary)
    if points:
        try:
            summary["points"] = (add_sfm_points(out, matcher, threads, seed, progress) if frames.depths is None
                                 else add_depth_points(out, seed=seed, progress=progress))
        except InputError as exc:
            log.warning("%s", exc)
    return summary
