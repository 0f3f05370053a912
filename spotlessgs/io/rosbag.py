"""Frames, camera and poses from a ROS 1 or ROS 2 bag, without a ROS install (the ``rosbags`` package).

* images: ``sensor_msgs/Image`` (rgb8, bgr8, rgba8, bgra8, mono8, mono16, rgb16, bgr16, and Bayer patterns, which
  OpenCV demosaics) or ``sensor_msgs/CompressedImage`` (JPEG, PNG: OpenCV decodes);
* camera: ``sensor_msgs/CameraInfo`` (K, and the distortion models ``plumb_bob`` / ``rational_polynomial`` as our
  ``opencv`` lens, ``equidistant`` as ``fisheye``; ROS's K puts pixel centres at integers, ours at +0.5);
* poses: ``nav_msgs/Odometry`` or ``geometry_msgs/PoseStamped`` of the camera's optical frame (x right, y down, z
  forward: OpenCV's axes), interpolated to each frame's time stamp (linear position, spherical rotation);
* depth: an RGB-D camera's ``sensor_msgs/Image`` registered to the colour camera (RealSense's
  ``aligned_depth_to_color``): ``16UC1`` in millimetres or ``32FC1`` in metres (REP 118; 0 or NaN: no measurement),
  the one nearest in time to each kept frame, within :data:`DEPTH_SYNC_NS`.

Frames are kept at least ``min_interval_s`` apart in time and, with poses, ``min_motion_m`` apart in space.
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass, field
from pathlib import Path

import cv2
import numpy as np
from rosbags.highlevel import AnyReader
from rosbags.typesys import Stores, get_typestore
from scipy.spatial.transform import Rotation

from spotlessgs.io.cameras import Intrinsics, interpolate_pose
from spotlessgs.io.errors import InputError

log = logging.getLogger(__name__)

IMAGE_TYPES = ("sensor_msgs/msg/Image", "sensor_msgs/msg/CompressedImage")
POSE_TYPES = ("nav_msgs/msg/Odometry", "geometry_msgs/msg/PoseStamped")
#: Depth encodings (REP 118) and the metres per unit of each.
DEPTH_ENCODINGS = {"16uc1": (np.uint16, 0.001), "mono16": (np.uint16, 0.001), "32fc1": (np.float32, 1.0)}
#: The most a depth image's stamp may be from its colour frame's (a camera's colour and depth streams at 15 fps or
#: faster are within half a frame).
DEPTH_SYNC_NS = 40_000_000
_CHANNELS = {"rgb8": (3, np.uint8, None), "bgr8": (3, np.uint8, cv2.COLOR_BGR2RGB), "rgba8": (4, np.uint8, None),
             "bgra8": (4, np.uint8, cv2.COLOR_BGRA2RGBA), "mono8": (1, np.uint8, None), "mono16": (1, np.uint16, None),
             "rgb16": (3, np.uint16, None), "bgr16": (3, np.uint16, cv2.COLOR_BGR2RGB)}
_BAYER = {"bayer_rggb8": cv2.COLOR_BayerRG2RGB, "bayer_bggr8": cv2.COLOR_BayerBG2RGB,
          "bayer_gbrg8": cv2.COLOR_BayerGB2RGB, "bayer_grbg8": cv2.COLOR_BayerGR2RGB}


@dataclass(frozen=True)
class BagFrames:
    """What a bag holds for one camera.

    Attributes:
        stamps_ns: (N,) the kept frames' header time stamps (ns).
        images: N (H, W, 3) float32 sRGB images in [0, 1].
        intrinsics: from the CameraInfo topic, or None.
        c2w: (N, 4, 4) camera-to-world (OpenCV axes) at the frames' stamps from the pose topic, or None.
        skipped: frames read but not kept (the sum of ``skipped_by``).
        depths: N (H, W) float64 depth images in metres (NaN: no measurement) from the depth topic, or None.
        skipped_by: how many frames each reason left out (:data:`SKIP_REASONS`; reasons that left none out absent).
    """

    stamps_ns: np.ndarray
    images: list[np.ndarray]
    intrinsics: Intrinsics | None
    c2w: np.ndarray | None
    skipped: int
    depths: list[np.ndarray] | None = None
    skipped_by: dict[str, int] = field(default_factory=dict)


#: Why a frame of the image topic is left out: keys of BagFrames.skipped_by, with what the warning says of them.
SKIP_REASONS = {
    "subsampled": "closer in time than --every to the last kept frame",
    "stamp_not_increasing": "a header stamp not after the last kept frame's (the topic out of order)",
    "outside_poses": "outside the pose topic's time span",
    "pose_gap": "in a gap of the pose topic (its poses there lie further apart than MAX_POSE_GAP_NS)",
    "not_moved": "moved less than --min-motion since the last kept frame",
}
#: A frame whose two bracketing poses lie further apart in time than this (ns) gets no interpolated pose (a dropout or
#: a reset of the odometry: a pose made up across it would be wrong) and is left out.
MAX_POSE_GAP_NS = 500_000_000


def decode_image(msg, msgtype: str, where: str) -> np.ndarray:
    """(H, W, 3) float32 sRGB in [0, 1] of an Image or CompressedImage message; InputError naming ``where``."""
    if msgtype.endswith("CompressedImage"):
        data = cv2.imdecode(np.frombuffer(bytes(msg.data), np.uint8), cv2.IMREAD_UNCHANGED)
        if data is None:
            raise InputError(f"{where}: the compressed image ({msg.format}) cannot be decoded")
        if data.ndim == 3:
            data = cv2.cvtColor(data, cv2.COLOR_BGRA2RGBA if data.shape[2] == 4 else cv2.COLOR_BGR2RGB)
    else:
        encoding = msg.encoding.lower()
        raw = np.frombuffer(bytes(msg.data), np.uint8)
        if encoding in _BAYER:
            data = cv2.cvtColor(_rows(raw, msg, 1, np.uint8, where)[..., 0], _BAYER[encoding])
        elif encoding in _CHANNELS:
            channels, dtype, conversion = _CHANNELS[encoding]
            data = _rows(raw, msg, channels, dtype, where)
            if conversion is not None:
                data = cv2.cvtColor(data, conversion)
        else:
            raise InputError(f"{where}: image encoding {msg.encoding!r} is not supported (supported: "
                             f"{', '.join([*_CHANNELS, *_BAYER])})")
    scale = 65535.0 if data.dtype == np.uint16 else 255.0
    image = data.astype(np.float32) / scale
    if image.ndim == 2:
        image = image[..., None]
    if image.shape[2] == 1:
        image = np.repeat(image, 3, axis=2)
    return np.ascontiguousarray(image[..., :3])


def decode_depth(msg, where: str) -> np.ndarray:
    """(H, W) float64 depth in metres (NaN where 0, NaN or negative: no measurement) of a depth Image message
    (:data:`DEPTH_ENCODINGS`); InputError naming ``where``."""
    encoding = msg.encoding.lower()
    if encoding not in DEPTH_ENCODINGS:
        raise InputError(f"{where}: depth encoding {msg.encoding!r} is not supported (16UC1 in mm, 32FC1 in m)")
    dtype, scale = DEPTH_ENCODINGS[encoding]
    data = _rows(np.frombuffer(bytes(msg.data), np.uint8), msg, 1, dtype, where)[..., 0].astype(np.float64) * scale
    return np.where(np.isfinite(data) & (data > 0), data, np.nan)


def _rows(raw: np.ndarray, msg, channels: int, dtype, where: str) -> np.ndarray:
    """The (H, W, C) pixels of a raw Image message (row stride ``step``, byte order ``is_bigendian``)."""
    itemsize = np.dtype(dtype).itemsize
    if msg.step < msg.width * channels * itemsize or raw.size < msg.step * msg.height:
        raise InputError(f"{where}: {raw.size} bytes do not hold a {msg.width}x{msg.height} {msg.encoding} image "
                         f"with row stride {msg.step}")
    rows = raw[: msg.step * msg.height].reshape(msg.height, msg.step)[:, : msg.width * channels * itemsize]
    order = ">" if msg.is_bigendian else "<"
    return np.ascontiguousarray(rows).view(np.dtype(dtype).newbyteorder(order)).reshape(
        msg.height, msg.width, channels).astype(dtype)


def camera_info_intrinsics(msg, where: str) -> Intrinsics:
    """Our Intrinsics of a CameraInfo message (pixel centres move from integers to +0.5; ROS 1 names the fields K and
    D, ROS 2 k and d). K, width and height describe the full-resolution calibration; the images are that camera's
    region of interest (``roi``, when set), binned by ``binning_x`` x ``binning_y`` (0 or 1: none), as the ROS
    ``image_geometry`` package reads them: the principal point moves by the region's offset, then every pixel
    figure is divided by the binning (distortion acts on normalised coordinates and is unchanged)."""
    k = np.asarray(msg.k if hasattr(msg, "k") else msg.K, dtype=np.float64)
    model = (msg.distortion_model or "").lower()
    d = tuple(float(v) for v in (msg.d if hasattr(msg, "d") else msg.D))
    if model in ("plumb_bob", "rational_polynomial", ""):
        lens = "opencv" if any(d) else "pinhole"
        if not any(d):
            d = ()
        else:  # OpenCV's order: k1, k2, p1, p2, k3[, k4, k5, k6]
            d = d[:8] if len(d) >= 8 else (d + (0.0,) * 5)[:5]
    elif model == "equidistant":
        lens, d = "fisheye", (d + (0.0,) * 4)[:4]
    else:
        raise InputError(f"{where}: distortion model {msg.distortion_model!r} is not supported (plumb_bob, "
                         "rational_polynomial, equidistant)")
    width, height, cx, cy = int(msg.width), int(msg.height), k[2] + 0.5, k[5] + 0.5
    roi = getattr(msg, "roi", None)
    if roi is not None and int(roi.width) > 0 and int(roi.height) > 0:
        width, height = int(roi.width), int(roi.height)
        cx, cy = cx - int(roi.x_offset), cy - int(roi.y_offset)
    bin_x, bin_y = (max(1, int(getattr(msg, name, 0) or 0)) for name in ("binning_x", "binning_y"))
    try:
        return Intrinsics(k[0] / bin_x, k[4] / bin_y, cx / bin_x, cy / bin_y, width // bin_x, height // bin_y, lens, d)
    except ValueError as exc:  # an uncalibrated camera publishes zeros
        raise InputError(f"{where}: the CameraInfo cannot be used ({exc}); is the camera calibrated?") from None


def _pose(msg, msgtype: str) -> tuple[np.ndarray, np.ndarray]:
    pose = msg.pose.pose if msgtype.endswith("Odometry") else msg.pose
    p, q = pose.position, pose.orientation
    return np.array([p.x, p.y, p.z]), np.array([q.x, q.y, q.z, q.w])


def _deserialize(reader, raw: bytes, conn, t: int, where: str):
    """The message ``raw`` of connection ``conn``; InputError naming ``where`` (the bag and topic) and the bag's time
    ``t`` (ns) where it cannot be decoded (a truncated or damaged message)."""
    try:
        return reader.deserialize(raw, conn.msgtype)
    except Exception as exc:  # rosbags raises its own error types, and struct or index errors from the raw bytes
        raise InputError(f"{where} at {t} ns: damaged {conn.msgtype} message ({exc})") from None


def _stamp_ns(msg, fallback: int) -> int:
    """The message's header stamp (ns), or ``fallback`` (the bag's receive time) where it has none or a zero one
    (drivers that leave the header unfilled)."""
    stamp = getattr(getattr(msg, "header", None), "stamp", None)
    value = None if stamp is None else int(stamp.sec) * 1_000_000_000 + int(stamp.nanosec)
    return fallback if not value else value


def read_bag(bag: str | Path, image_topic: str, camera_info_topic: str | None = None, pose_topic: str | None = None,
             min_interval_s: float = 0.0, min_motion_m: float = 0.0, depth_topic: str | None = None) -> BagFrames:
    """Read one camera's frames (and optionally its CameraInfo, poses and registered depth images) from a ROS 1 or
    ROS 2 bag.

    Raises:
        InputError: the bag cannot be read, a topic is missing or of the wrong type (the bag's topics are listed), a
            frame cannot be decoded, no frame is kept, or a kept frame has no depth image within DEPTH_SYNC_NS or one
            of another size.
    """
    bag = Path(bag)
    try:
        reader = AnyReader([bag], default_typestore=get_typestore(Stores.ROS2_HUMBLE))
        reader.open()
    except Exception as exc:  # rosbags raises its own error types for every kind of damage
        raise InputError(f"{bag}: not a readable ROS 1 or ROS 2 bag ({exc})") from None
    try:
        topics = {c.topic: c.msgtype for c in reader.connections}

        def connections(topic: str, types: tuple[str, ...]):
            if topic not in topics:
                raise InputError(f"{bag}: no topic {topic!r}; the bag has: "
                                 + ", ".join(f"{t} ({m})" for t, m in sorted(topics.items())))
            if topics[topic] not in types:
                raise InputError(f"{bag}: topic {topic!r} is {topics[topic]}, expected {' or '.join(types)}")
            return [c for c in reader.connections if c.topic == topic]

        image_conns = connections(image_topic, IMAGE_TYPES)
        intrinsics = None
        if camera_info_topic is not None:
            conns = connections(camera_info_topic, ("sensor_msgs/msg/CameraInfo",))
            for conn, t, raw in reader.messages(connections=conns):
                where = f"{bag}: {camera_info_topic}"
                intrinsics = camera_info_intrinsics(_deserialize(reader, raw, conn, t, where), where)
                break
        poses, posed_frame = None, None
        if pose_topic is not None:
            conns = connections(pose_topic, POSE_TYPES)
            messages = [(_deserialize(reader, raw, c, t, f"{bag}: {pose_topic}"), c, t)
                        for c, t, raw in reader.messages(connections=conns)]
            records = [(_stamp_ns(m, t), *_pose(m, c.msgtype)) for m, c, t in messages]
            # the frame an odometry message places (PoseStamped does not say)
            posed_frame = next((str(m.child_frame_id) for m, c, _t in messages
                                if c.msgtype.endswith("Odometry") and getattr(m, "child_frame_id", "")), None)
            records.sort(key=lambda r: r[0])
            valid = [r for r in records if _valid_pose(r[1], r[2])]
            if len(valid) < len(records):  # odometry that is not yet initialised often publishes a zero quaternion
                log.warning("%s: %s: %d of %d poses skipped (a zero or non-finite orientation, or a non-finite "
                            "position)", bag, pose_topic, len(records) - len(valid), len(records))
            records = valid
            if len(records) < 2:
                raise InputError(f"{bag}: topic {pose_topic!r} has {len(records)} usable pose(s); at least 2 are "
                                 "needed")
            poses = records
        stamps, images, c2w = [], [], []
        image_frame = None  # the frame the images' headers name
        skipped: dict[str, int] = {}
        last_stamp, last_centre = None, None
        for conn, t, raw in reader.messages(connections=image_conns):
            msg = _deserialize(reader, raw, conn, t, f"{bag}: {image_topic}")
            stamp = _stamp_ns(msg, t)
            image_frame = image_frame or str(getattr(getattr(msg, "header", None), "frame_id", "") or "") or None
            reason = None
            if last_stamp is not None and stamp <= last_stamp:
                reason = "stamp_not_increasing"
            elif last_stamp is not None and (stamp - last_stamp) < min_interval_s * 1e9:
                reason = "subsampled"
            pose = None
            if reason is None and poses is not None:
                pose, reason = _interpolate(poses, stamp)
                if pose is not None and last_centre is not None and \
                        np.linalg.norm(pose[:3, 3] - last_centre) < min_motion_m:
                    reason = "not_moved"
            if reason is not None:
                skipped[reason] = skipped.get(reason, 0) + 1
                continue
            images.append(decode_image(msg, conn.msgtype, f"{bag}: {image_topic} at {stamp} ns"))
            stamps.append(stamp)
            last_stamp = stamp
            if pose is not None:
                c2w.append(pose)
                last_centre = pose[:3, 3]
        if poses is not None and posed_frame and image_frame and posed_frame.lstrip("/") != image_frame.lstrip("/"):
            # most robots' /odom places base_link: its axes are not the optical frame's (z forward, y down)
            log.warning("%s: %s places the frame %r, the images are in %r: the poses are used as the camera's "
                        "(OpenCV axes) as they are, with no transform between the two; give the odometry of the "
                        "camera's optical frame", bag, pose_topic, posed_frame, image_frame)
        if not images:
            span = "" if poses is None else f"; the poses span {poses[0][0]} to {poses[-1][0]} ns"
            raise InputError(f"{bag}: no frame of {image_topic!r} was kept ({_skip_text(skipped)}{span})")
        unexpected = {r: n for r, n in skipped.items() if r not in ("subsampled", "not_moved")}
        if unexpected:  # not what the user asked for: said, with the reason
            log.warning("%s: %s: %d of %d frames left out: %s", bag, image_topic, sum(unexpected.values()),
                        len(images) + sum(skipped.values()), _skip_text(unexpected))
        _check_frame_sizes(images, stamps, intrinsics, f"{bag}: {image_topic}", camera_info_topic)
        depths = None
        if depth_topic is not None:
            depths = _matched_depths(reader, connections(depth_topic, ("sensor_msgs/msg/Image",)), stamps,
                                     f"{bag}: {depth_topic}")
            for k, (image, depth) in enumerate(zip(images, depths)):
                if depth.shape != image.shape[:2]:
                    raise InputError(f"{bag}: {depth_topic}: the depth image at {stamps[k]} ns is "
                                     f"{depth.shape[1]}x{depth.shape[0]}, the frame {image.shape[1]}x{image.shape[0]} "
                                     "(the depth must be registered to the colour camera: aligned_depth_to_color)")
    finally:
        reader.close()
    return BagFrames(np.array(stamps, dtype=np.int64), images, intrinsics, np.stack(c2w) if poses else None,
                     sum(skipped.values()), depths, skipped)


def _skip_text(counts: dict[str, int]) -> str:
    """How many frames each reason left out, in words (:data:`SKIP_REASONS`)."""
    return "; ".join(f"{n} {SKIP_REASONS[r]}" for r, n in counts.items())


def _matched_depths(reader, conns, stamps: list[int], where: str) -> list[np.ndarray]:
    """The depth image (:func:`decode_depth`) nearest in time to each of ``stamps`` (ns), of the messages of
    ``conns``, in one pass over them: each frame keeps the nearest message within DEPTH_SYNC_NS seen so far, and only
    the kept messages are decoded. InputError naming ``where`` and the frame's stamp where none lies within
    DEPTH_SYNC_NS."""
    frame_stamps = np.asarray(stamps, dtype=np.int64)
    order = np.argsort(frame_stamps, kind="stable")
    sorted_stamps = frame_stamps[order]
    nearest: dict[int, tuple[int, int, object]] = {}  # frame -> (|Δt|, the message's stamp, the message)
    depth_stamps = []
    for conn, t, raw in reader.messages(connections=conns):
        msg = _deserialize(reader, raw, conn, t, where)
        stamp = _stamp_ns(msg, t)
        depth_stamps.append(stamp)
        lo = int(np.searchsorted(sorted_stamps, stamp - DEPTH_SYNC_NS, side="left"))
        hi = int(np.searchsorted(sorted_stamps, stamp + DEPTH_SYNC_NS, side="right"))
        for k in order[lo:hi].tolist():
            gap = abs(stamp - stamps[k])
            if k not in nearest or gap < nearest[k][0]:
                nearest[k] = (gap, stamp, msg)
    if not depth_stamps:
        raise InputError(f"{where}: the topic has no message")
    for k, stamp in enumerate(stamps):
        if k not in nearest:
            closest = min(depth_stamps, key=lambda s: abs(s - stamp))
            raise InputError(f"{where}: no depth image within {DEPTH_SYNC_NS / 1e6:.0f} ms of the frame at {stamp} ns "
                             f"(nearest {(closest - stamp) / 1e6:+.1f} ms)")
    decoded: dict[int, np.ndarray] = {}  # by the message's stamp: frames that share a message decode it once
    for _gap, stamp, msg in nearest.values():
        if stamp not in decoded:
            decoded[stamp] = decode_depth(msg, f"{where} at {stamp} ns")
    return [decoded[nearest[k][1]] for k in range(len(stamps))]


def _check_frame_sizes(images: list[np.ndarray], stamps: list[int], intrinsics: Intrinsics | None, where: str,
                       camera_info_topic: str | None) -> None:
    """InputError naming ``where`` (the bag and image topic) and the frame's stamp where a kept frame differs in size
    from the first, or the frames from the CameraInfo's width and height."""
    height, width = images[0].shape[:2]
    for image, stamp in zip(images, stamps):
        if image.shape[:2] != (height, width):
            raise InputError(f"{where}: the frame at {stamp} ns is {image.shape[1]}x{image.shape[0]}, the first "
                             f"{width}x{height}; one camera's frames must share a size")
    if intrinsics is not None and (intrinsics.width, intrinsics.height) != (width, height):
        raise InputError(f"{where}: the frames are {width}x{height} but {camera_info_topic} says "
                         f"{intrinsics.width}x{intrinsics.height} (a CameraInfo of another camera or resolution)")


def _valid_pose(position: np.ndarray, quaternion: np.ndarray) -> bool:
    """Whether a pose message can place a camera: a finite position and a finite, non-zero orientation."""
    norm = float(np.linalg.norm(quaternion))
    return bool(np.isfinite(position).all()) and math.isfinite(norm) and norm > 1e-6


def _interpolate(records, stamp: int) -> tuple[np.ndarray | None, str | None]:
    """(camera-to-world at ``stamp`` from time-sorted (stamp, position, quaternion xyzw) records, None) or (None, why
    there is none: ``outside_poses``, ``pose_gap`` (bracketing poses more than MAX_POSE_GAP_NS apart))."""
    times = np.array([r[0] for r in records], dtype=np.int64)
    if stamp < times[0] or stamp > times[-1]:
        return None, "outside_poses"
    i = int(np.clip(np.searchsorted(times, stamp, side="right") - 1, 0, len(times) - 2))
    span = times[i + 1] - times[i]
    if span > MAX_POSE_GAP_NS and stamp not in (times[i], times[i + 1]):
        return None, "pose_gap"
    w = 0.0 if span == 0 else (stamp - times[i]) / span
    ends = []
    for _stamp, position, quaternion in (records[i], records[i + 1]):
        end = np.eye(4)
        end[:3, :3] = Rotation.from_quat(quaternion).as_matrix()
        end[:3, 3] = position
        ends.append(end)
    c2w = interpolate_pose(ends[0], ends[1], w)
    if not math.isfinite(float(c2w.sum())):
        return None, "outside_poses"
    return c2w, None
