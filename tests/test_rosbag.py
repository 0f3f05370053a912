"""``spotless prepare --bag``: ROS 1 and ROS 2 bags that the tests write themselves with ``rosbags``."""

from __future__ import annotations

import json

import cv2
import numpy as np
import pytest
from click.testing import CliRunner
from rosbags.typesys import Stores, get_typestore
from scipy.spatial.transform import Rotation

from evaluation.synthetic import render_room_sequence
from evaluation.trajectory import trajectory_errors
from spotlessgs.cli import main
from spotlessgs.io.cameras import Intrinsics, opengl_to_opencv_c2w
from spotlessgs.io.dataset import read_dataset
from spotlessgs.io.errors import InputError
from spotlessgs.io.images import read_image
from spotlessgs.io.rosbag import camera_info_intrinsics, decode_image, read_bag
from spotlessgs.prepare import prepare_bag

FRAMES, WIDTH, HEIGHT = 6, 64, 48


@pytest.fixture(scope="module")
def sequence():
    return render_room_sequence(num_frames=FRAMES, width=WIDTH, height=HEIGHT, seed=1)


def _write_bag(path, sequence, ros: int, compressed: bool = False, encoding: str = "rgb8", depth: str | None = None,
               depth_offset_ns: int = 5_000_000, info_size: tuple[int, int] | None = None, zero_k: bool = False,
               zero_first_orientation: bool = False, damaged_frame: int | None = None,
               cropped_frame: int | None = None, skip_odometry: tuple[int, ...] = (), frame_stamps=None,
               odometry_child: str = "cam_optical"):
    """A bag with the sequence's frames (raw or JPEG), its CameraInfo and the camera's odometry; with ``depth``
    (``16UC1`` or ``32FC1``) also its registered depth images on ``/cam/depth``, ``depth_offset_ns`` after each
    frame. Damage for the error tests: ``info_size`` (width, height) in the CameraInfo instead of the frames',
    ``zero_k`` an uncalibrated CameraInfo (K all zeros), ``zero_first_orientation`` a zero quaternion in the first
    odometry message, ``damaged_frame`` that frame's message cut short, ``cropped_frame`` that raw frame one column
    narrower, ``skip_odometry`` those odometry messages left out (a dropout), ``frame_stamps`` each frame's header
    stamp in ns (e.g. 0: a driver that leaves it unfilled; the bag's time stays 0.5 i s)."""
    if ros == 1:
        from rosbags.rosbag1 import Writer
        store = get_typestore(Stores.ROS1_NOETIC)
        serialize = store.serialize_ros1
    else:
        from rosbags.rosbag2 import Writer
        store = get_typestore(Stores.ROS2_HUMBLE)
        serialize = store.serialize_cdr
    t = store.types
    intr = sequence.intrinsics
    frames, (height, width) = len(sequence.spot), sequence.spot.shape[1:3]
    c2w = opengl_to_opencv_c2w(sequence.c2w_opengl)
    writer = Writer(path) if ros == 1 else Writer(path, version=9)
    with writer:
        image_type = "sensor_msgs/msg/CompressedImage" if compressed else "sensor_msgs/msg/Image"
        images = writer.add_connection("/cam/image", image_type, typestore=store)
        info = writer.add_connection("/cam/info", "sensor_msgs/msg/CameraInfo", typestore=store)
        odom = writer.add_connection("/cam/odom", "nav_msgs/msg/Odometry", typestore=store)
        depths = writer.add_connection("/cam/depth", "sensor_msgs/msg/Image", typestore=store) if depth else None

        def header(ns):
            stamp = t["builtin_interfaces/msg/Time"](sec=ns // 10**9, nanosec=ns % 10**9)
            kwargs = {"seq": 0} if ros == 1 else {}
            return t["std_msgs/msg/Header"](stamp=stamp, frame_id="cam_optical", **kwargs)

        k = [0.0] * 9 if zero_k else [intr.fx, 0, intr.cx - 0.5, 0, intr.fy, intr.cy - 0.5, 0, 0, 1]
        roi = t["sensor_msgs/msg/RegionOfInterest"](x_offset=0, y_offset=0, height=0, width=0, do_rectify=False)
        matrices = {"d": np.zeros(5), "k": np.array(k, float), "r": np.eye(3).ravel(), "p": np.zeros(12)}
        if ros == 1:  # ROS 1 names them D, K, R, P
            matrices = {name.upper(): value for name, value in matrices.items()}
        info_width, info_height = info_size or (width, height)
        msg = t["sensor_msgs/msg/CameraInfo"](header=header(0), height=info_height, width=info_width,
                                              distortion_model="plumb_bob", binning_x=0, binning_y=0, roi=roi,
                                              **matrices)
        writer.write(info, 0, serialize(msg, "sensor_msgs/msg/CameraInfo"))
        for i in range(frames + 1):  # odometry every 0.5 s; frame i at 0.5 i s
            if i in skip_odometry:
                continue
            ns = i * 500_000_000
            j = min(i, frames - 1)
            q = np.zeros(4) if zero_first_orientation and i == 0 else Rotation.from_matrix(c2w[j, :3, :3]).as_quat()
            pose = t["geometry_msgs/msg/Pose"](position=t["geometry_msgs/msg/Point"](x=c2w[j, 0, 3], y=c2w[j, 1, 3],
                                                                                      z=c2w[j, 2, 3]),
                                               orientation=t["geometry_msgs/msg/Quaternion"](x=q[0], y=q[1], z=q[2],
                                                                                            w=q[3]))
            cov = np.zeros(36)
            twist = t["geometry_msgs/msg/Twist"](linear=t["geometry_msgs/msg/Vector3"](x=0, y=0, z=0),
                                                 angular=t["geometry_msgs/msg/Vector3"](x=0, y=0, z=0))
            msg = t["nav_msgs/msg/Odometry"](header=header(ns), child_frame_id=odometry_child,
                                             pose=t["geometry_msgs/msg/PoseWithCovariance"](pose=pose, covariance=cov),
                                             twist=t["geometry_msgs/msg/TwistWithCovariance"](twist=twist,
                                                                                              covariance=cov))
            writer.write(odom, ns, serialize(msg, "nav_msgs/msg/Odometry"))
        for i in range(frames):
            ns = 500_000_000 * i
            stamp_ns = ns if frame_stamps is None else frame_stamps[i]
            rgb = np.round(sequence.spot[i] * 255).astype(np.uint8)
            if compressed:
                ok, data = cv2.imencode(".jpg", cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR), [cv2.IMWRITE_JPEG_QUALITY, 95])
                msg = t["sensor_msgs/msg/CompressedImage"](header=header(stamp_ns), format="jpeg", data=data.ravel())
            else:
                data = cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR) if encoding == "bgr8" else rgb
                data = np.ascontiguousarray(data[:, :-1]) if i == cropped_frame else data
                msg = t["sensor_msgs/msg/Image"](header=header(stamp_ns), height=height, width=data.shape[1],
                                                 encoding=encoding, is_bigendian=0, step=3 * data.shape[1],
                                                 data=data.ravel())
            raw = serialize(msg, image_type)
            writer.write(images, ns, raw[:30] if i == damaged_frame else raw)
            if depth is not None:
                z = sequence.depth[i]
                data, step = ((np.round(z * 1000).astype("<u2"), 2 * width) if depth == "16UC1"
                              else (z.astype("<f4"), 4 * width))
                msg = t["sensor_msgs/msg/Image"](header=header(ns + depth_offset_ns), height=height, width=width,
                                                 encoding=depth, is_bigendian=0, step=step,
                                                 data=data.view(np.uint8).ravel())
                writer.write(depths, ns + depth_offset_ns, serialize(msg, "sensor_msgs/msg/Image"))
    return c2w


@pytest.mark.parametrize("ros, compressed, encoding", [(2, False, "rgb8"), (1, False, "bgr8"), (2, True, "rgb8")])
def test_a_bag_with_odometry_becomes_a_posed_dataset(sequence, tmp_path, ros, compressed, encoding):
    bag = tmp_path / ("cam.bag" if ros == 1 else "cam")
    c2w = _write_bag(bag, sequence, ros, compressed, encoding)
    result = CliRunner().invoke(main, ["prepare", "--bag", str(bag), "--image-topic", "/cam/image",
                                       "--camera-info-topic", "/cam/info", "--odometry-topic", "/cam/odom",
                                       "--out", str(tmp_path / "data"), "-q"])
    assert result.exit_code == 0, result.output + repr(result.exception)
    data = read_dataset(tmp_path / "data")
    assert data.n_frames == FRAMES and data.intrinsics == sequence.intrinsics  # the CameraInfo, +0.5 px back
    np.testing.assert_allclose(data.c2w_opencv, c2w, atol=1e-6)  # frames fall on odometry stamps
    for k, path in enumerate(data.image_paths):
        error = np.abs(read_image(path) - np.round(sequence.spot[k] * 255) / 255)
        assert (error.mean() < 0.01) if compressed else (error.max() < 1e-6)  # JPEG at quality 95, or exact
    summary = json.loads((tmp_path / "data" / "prepare.json").read_text())
    assert summary["source"]["frames_kept"] == FRAMES and summary["poses"] == "from the pose topic"


def test_poses_are_interpolated_and_frames_subsampled(sequence, tmp_path):
    bag = tmp_path / "cam"
    c2w = _write_bag(bag, sequence, 2)
    frames = read_bag(bag, "/cam/image", "/cam/info", "/cam/odom", min_interval_s=0.9)
    assert len(frames.images) == 3 and frames.skipped == 3  # 0, 1 and 2 s of 0, 0.5, ..., 2.5 s
    np.testing.assert_allclose(frames.c2w, c2w[[0, 2, 4]], atol=1e-6)
    far = read_bag(bag, "/cam/image", None, "/cam/odom", min_motion_m=10.0)
    assert len(far.images) == 1 and far.intrinsics is None


def test_bag_errors_name_the_bag_and_the_problem(sequence, tmp_path):
    bag = tmp_path / "cam"
    _write_bag(bag, sequence, 2)
    with pytest.raises(InputError, match=r"cam: no topic '/camera/rgb'; the bag has: /cam/image \(sensor_msgs"):
        read_bag(bag, "/camera/rgb")
    with pytest.raises(InputError, match=r"topic '/cam/odom' is nav_msgs/msg/Odometry, expected sensor_msgs"):
        read_bag(bag, "/cam/odom")
    (tmp_path / "broken.bag").write_bytes(b"#ROSBAG V2.0\ngarbage")
    with pytest.raises(InputError, match=r"broken\.bag: not a readable ROS 1 or ROS 2 bag"):
        read_bag(tmp_path / "broken.bag", "/cam/image")
    result = CliRunner().invoke(main, ["prepare", "--bag", str(bag), "--image-topic", "/cam/image", "--odometry-topic",
                                       "/cam/odom", "--out", str(tmp_path / "data")])
    assert result.exit_code == 2 and "need the camera too" in result.output


def test_damaged_or_inconsistent_bags_name_the_bag_topic_and_stamp(sequence, tmp_path):
    """A cut-short message, a frame of another size, a CameraInfo of another size or uncalibrated: one line naming
    the bag, the topic and (for a frame) its time stamp, before anything is written."""
    cases = [
        ({"damaged_frame": 2}, r"cam: /cam/image at 1000000000 ns: damaged sensor_msgs/msg/Image message"),
        ({"cropped_frame": 3}, rf"cam: /cam/image: the frame at 1500000000 ns is {WIDTH - 1}x{HEIGHT}, the first "
                               rf"{WIDTH}x{HEIGHT}"),
        ({"info_size": (640, 480)}, rf"cam: /cam/image: the frames are {WIDTH}x{HEIGHT} but /cam/info says 640x480"),
        ({"zero_k": True}, r"cam: /cam/info: the CameraInfo cannot be used \(.*focal lengths must be positive.*\); is "
                           r"the camera calibrated\?"),
    ]
    for k, (damage, message) in enumerate(cases):
        bag = tmp_path / f"{k}" / "cam"
        _write_bag(bag, sequence, 2, **damage)
        with pytest.raises(InputError, match=message):
            read_bag(bag, "/cam/image", "/cam/info", "/cam/odom")
        out = tmp_path / f"{k}" / "data"
        result = CliRunner().invoke(main, ["prepare", "--bag", str(bag), "--image-topic", "/cam/image",
                                           "--camera-info-topic", "/cam/info", "--odometry-topic", "/cam/odom",
                                           "--out", str(out), "-q"])
        assert result.exit_code == 2 and len(result.output.strip().splitlines()) == 1, result.output
        assert not out.exists() or not any(out.iterdir())  # refused before anything was written


def test_odometry_before_it_is_initialised_is_skipped(sequence, tmp_path):
    """A zero quaternion (odometry that has not initialised yet) drops that pose with a warning; the frames between
    the remaining poses keep theirs."""
    bag = tmp_path / "cam"
    c2w = _write_bag(bag, sequence, 2, zero_first_orientation=True)
    frames = read_bag(bag, "/cam/image", "/cam/info", "/cam/odom")
    assert len(frames.images) == FRAMES - 1 and frames.skipped == 1  # the frame at 0 s had only the zero pose
    np.testing.assert_allclose(frames.c2w, c2w[1:], atol=1e-6)


def test_image_encodings_and_camera_models():
    from types import SimpleNamespace

    rgb = np.arange(2 * 3 * 3, dtype=np.uint8).reshape(2, 3, 3)
    raw = SimpleNamespace(encoding="bgr8", height=2, width=3, step=10, is_bigendian=0,
                          data=np.pad(rgb[..., ::-1].reshape(2, 9), ((0, 0), (0, 1))).ravel())  # padded rows
    np.testing.assert_allclose(decode_image(raw, "sensor_msgs/msg/Image", "x"), rgb / 255.0, atol=1e-7)
    mono16 = SimpleNamespace(encoding="mono16", height=1, width=2, step=4, is_bigendian=1,
                             data=np.array([0x12, 0x34, 0xFF, 0xFF], np.uint8))
    np.testing.assert_allclose(decode_image(mono16, "sensor_msgs/msg/Image", "x")[0, :, 0], [0x1234 / 65535, 1.0])
    with pytest.raises(InputError, match="image encoding '32FC1' is not supported"):
        decode_image(SimpleNamespace(encoding="32FC1", data=b""), "sensor_msgs/msg/Image", "x")
    info = SimpleNamespace(k=[500, 0, 319.5, 0, 510, 239.5, 0, 0, 1], width=640, height=480,
                           distortion_model="equidistant", d=[0.1, 0.01, 0.0, 0.0])
    assert camera_info_intrinsics(info, "x") == Intrinsics(500, 510, 320, 240, 640, 480, "fisheye",
                                                           (0.1, 0.01, 0.0, 0.0))
    info.distortion_model, info.d = "plumb_bob", [-0.2, 0.05, 0.001, 0.0, 0.0]
    assert camera_info_intrinsics(info, "x").distortion == (-0.2, 0.05, 0.001, 0.0)
    info.distortion_model = "fov"
    with pytest.raises(InputError, match="distortion model 'fov' is not supported"):
        camera_info_intrinsics(info, "x")
    # K describes the full sensor; binned 2 x 2, the images are 320 x 240 with every pixel figure halved (was
    # refused: "the frames are 320x240 but the CameraInfo says 640x480"); a region of interest moves the centre
    def pixels(c):
        return (c.fx, c.fy, c.cx, c.cy, c.width, c.height)

    info.distortion_model, info.binning_x, info.binning_y = "plumb_bob", 2, 2
    assert pixels(camera_info_intrinsics(info, "x")) == (250, 255, 160, 120, 320, 240)
    info.roi = SimpleNamespace(x_offset=100, y_offset=40, width=400, height=300)
    assert pixels(camera_info_intrinsics(info, "x")) == (250, 255, 110, 100, 200, 150)
    info.binning_x = info.binning_y = 0  # 0: no binning, as 1
    assert pixels(camera_info_intrinsics(info, "x")) == (500, 510, 220, 200, 400, 300)


def test_a_bag_without_odometry_goes_through_structure_from_motion(tmp_path):
    room = render_room_sequence(num_frames=16, width=240, height=180, seed=0)
    bag = tmp_path / "cam"
    c2w = _write_bag(bag, room, 2)
    summary = prepare_bag(bag, tmp_path / "data", "/cam/image", "/cam/info", matcher="exhaustive")
    assert summary["registered"] == 16 and summary["camera_model"] == "given"  # the CameraInfo camera, kept
    assert summary["source"]["frames_kept"] == 16 and summary["source"]["pose_topic"] is None
    assert summary["images"] == f"{bag}: /cam/image"  # not the temporary folder the frames went through, now gone
    errors = trajectory_errors(read_dataset(tmp_path / "data").c2w_opencv, c2w)
    assert errors.ate_rmse < 0.02  # SfM's poses against the odometry the bag also holds, after similarity alignment


@pytest.mark.parametrize("ros, encoding", [(2, "16UC1"), (1, "32FC1")])
def test_a_bags_registered_depth_gives_depth_images_and_a_dense_start(sequence, tmp_path, ros, encoding):
    from spotlessgs.io.depth_images import read_depth_image
    from spotlessgs.io.ply import read_point_cloud
    from spotlessgs.prepare import DEPTH_POINTS_FILE

    bag = tmp_path / ("cam.bag" if ros == 1 else "cam")
    _write_bag(bag, sequence, ros, depth=encoding)
    result = CliRunner().invoke(main, ["prepare", "--bag", str(bag), "--image-topic", "/cam/image",
                                       "--camera-info-topic", "/cam/info", "--odometry-topic", "/cam/odom",
                                       "--depth-topic", "/cam/depth", "--out", str(tmp_path / "data"), "-q"])
    assert result.exit_code == 0, result.output + repr(result.exception)
    data = read_dataset(tmp_path / "data")
    assert data.depth_scale == 0.001
    for k, path in enumerate(data.depth_paths):  # each frame's own depth image (5 ms later), in millimetres
        # the bag's millimetres (rounded in float32), or its metres rounded to millimetres here
        z = sequence.depth[k] if encoding == "16UC1" else sequence.depth[k].astype(np.float64)
        np.testing.assert_allclose(read_depth_image(path), np.round(z * 1000) / 1000, atol=1e-9)
    assert data.ply_path == tmp_path / "data" / DEPTH_POINTS_FILE
    summary = json.loads((tmp_path / "data" / "prepare.json").read_text())
    assert summary["points"]["source"] == "depth images" and summary["source"]["depth_topic"] == "/cam/depth"
    cloud = read_point_cloud(data.ply_path)
    assert len(cloud.xyz) > 1000 and cloud.normals is not None


def test_depth_that_is_not_in_step_with_the_frames_or_has_no_poses_is_refused(sequence, tmp_path):
    bag = tmp_path / "cam"
    _write_bag(bag, sequence, 2, depth="16UC1", depth_offset_ns=100_000_000)
    with pytest.raises(InputError, match=r"cam: /cam/depth: no depth image within 40 ms of the frame at 0 ns "
                                         r"\(nearest \+100.0 ms\)"):
        read_bag(bag, "/cam/image", "/cam/info", "/cam/odom", depth_topic="/cam/depth")
    with pytest.raises(InputError, match="depth images from '/cam/depth' need the camera's poses"):
        prepare_bag(bag, tmp_path / "data", "/cam/image", "/cam/info", depth_topic="/cam/depth")
    with pytest.raises(InputError, match=r"topic '/cam/info' is sensor_msgs/msg/CameraInfo, expected sensor_msgs/msg/Image"):
        read_bag(bag, "/cam/image", "/cam/info", "/cam/odom", depth_topic="/cam/info")
    result = CliRunner().invoke(main, ["prepare", "--images", str(tmp_path), "--depth-topic", "/cam/depth",
                                       "--out", str(tmp_path / "o")])
    assert result.exit_code != 0 and "--depth-topic goes with --bag" in result.output


def test_frames_left_out_are_counted_by_reason_and_said(sequence, tmp_path, caplog):
    """Frames in an odometry dropout got a pose made up across it; frames out of order or outside the poses were
    dropped without a word ("N of N registered"); zero header stamps (an unfilled header) kept one frame of all."""
    import logging

    bag = tmp_path / "gap"
    _write_bag(bag, sequence, 2, skip_odometry=(3, 4, 5))  # poses at 1.0 and 3.0 s only around frames 3-5
    with caplog.at_level(logging.WARNING, logger="spotlessgs.io.rosbag"):
        frames = read_bag(bag, "/cam/image", "/cam/info", "/cam/odom")
    assert frames.skipped_by == {"pose_gap": 3} and len(frames.images) == FRAMES - 3
    assert any("3 of %d frames left out: 3 in a gap of the pose topic" % FRAMES in r.getMessage()
               for r in caplog.records)
    bag = tmp_path / "zero"
    _write_bag(bag, sequence, 2, frame_stamps=[0] * FRAMES)  # the bag's own times are used instead
    frames = read_bag(bag, "/cam/image", "/cam/info", "/cam/odom")
    assert len(frames.images) == FRAMES and frames.skipped_by == {}
    assert frames.stamps_ns.tolist() == [500_000_000 * i for i in range(FRAMES)]
    bag = tmp_path / "order"
    stamps = [500_000_000 * i for i in range(FRAMES)]
    stamps[2], stamps[3] = stamps[3], stamps[2]
    _write_bag(bag, sequence, 2, frame_stamps=stamps)
    frames = read_bag(bag, "/cam/image", "/cam/info", "/cam/odom")
    assert frames.skipped_by == {"stamp_not_increasing": 1} and len(frames.images) == FRAMES - 1


def test_odometry_of_another_frame_than_the_images_is_warned_about(sequence, tmp_path, caplog):
    """Most robots' /odom places base_link, whose axes are not the optical frame's: it was taken as the camera's
    pose without a word (the camera looked straight up)."""
    import logging

    said = {}
    for child in ("base_link", "/cam_optical"):  # a leading slash (ROS 1 style) names the same frame
        bag = tmp_path / child.strip("/")
        _write_bag(bag, sequence, 2, odometry_child=child)
        caplog.clear()
        with caplog.at_level(logging.WARNING, logger="spotlessgs.io.rosbag"):
            read_bag(bag, "/cam/image", "/cam/info", "/cam/odom")
        said[child] = [r.getMessage() for r in caplog.records if "places the frame" in r.getMessage()]
    assert said["/cam_optical"] == [] and len(said["base_link"]) == 1
    assert "/cam/odom places the frame 'base_link', the images are in 'cam_optical'" in said["base_link"][0]
