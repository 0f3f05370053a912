"""An RGB-D camera's start: depth images (spotlessgs.io.depth_images) in the dataset contract (``depth_file_path``,
``depth_unit_scale_factor``), the simulator's depth camera (``spotless-sim add-noise --depth-camera``), and
``spotless prepare --points`` back-projecting them into a dense cloud with normals (spotlessgs.prepare.depth_points)
that the trainer trusts."""

from __future__ import annotations

import json
import shutil

import numpy as np
import pytest
from click.testing import CliRunner

from evaluation.synthetic import ROOM_X, ROOM_Y, ROOM_Z, render_room_sequence, write_dataset_folder
from simulator.pointcloud import backproject_depth
from simulator.sensor_noise import DepthCamera, SensorNoise, add_sensor_noise_to_dataset
from spotlessgs.cli import main
from spotlessgs.io.cameras import Intrinsics
from spotlessgs.io.dataset import read_dataset
from spotlessgs.io.depth_images import depth_units, read_depth_image, write_depth_image
from spotlessgs.io.errors import InputError
from spotlessgs.io.exr import FrameEXR, read_frame_exr, write_frame_exr
from spotlessgs.io.images import write_png
from spotlessgs.io.lens import camera_points
from spotlessgs.io.ply import read_point_cloud
from spotlessgs.io.transforms import DatasetError, FrameRecord, read_transforms, write_transforms
from spotlessgs.prepare import DEPTH_POINTS_FILE, SUMMARY_FILE, add_depth_points
from spotlessgs.prepare.depth_points import depth_surface, neighbour_mean_normals
from spotlessgs.training.config import TrainConfig
from spotlessgs.training.trainer import start_is_trusted

LENS = ("opencv", (-0.2, 0.03, 0.0, 0.0))


# ---- depth images ---------------------------------------------------------------------------------------------------


def test_depth_images_round_trip_in_units_and_mark_no_measurement(tmp_path):
    depth = np.array([[0.5, 1.2344, np.inf], [np.nan, -1.0, 70.0], [0.0004, 0.0006, 65.535]])
    write_depth_image(tmp_path / "d.png", depth)
    units = depth_units(depth)
    assert units.dtype == np.uint16
    assert units.tolist() == [[500, 1234, 0], [0, 0, 0], [0, 1, 65535]]  # rounded mm; 0: none, beyond 16 bits
    back = read_depth_image(tmp_path / "d.png")
    np.testing.assert_array_equal(np.isnan(back), units == 0)
    np.testing.assert_allclose(back[units > 0], units[units > 0] * 0.001)
    # another unit: 0.1 mm
    write_depth_image(tmp_path / "fine.png", np.array([[1.23456]]), scale=1e-4)
    assert read_depth_image(tmp_path / "fine.png", scale=1e-4)[0, 0] == pytest.approx(1.2346)


def test_a_depth_image_that_is_not_16_bit_grey_is_refused_naming_it(tmp_path):
    write_png(tmp_path / "colour.png", np.zeros((4, 5, 3), np.uint8))
    with pytest.raises(InputError, match="colour.png: a depth image must be 16-bit single-channel, got uint8"):
        read_depth_image(tmp_path / "colour.png")
    (tmp_path / "broken.png").write_bytes(b"not a png")
    with pytest.raises(InputError, match="broken.png: not a readable image"):
        read_depth_image(tmp_path / "broken.png")
    with pytest.raises(InputError, match="missing.png: depth image not found"):
        read_depth_image(tmp_path / "missing.png")


# ---- the dataset contract -------------------------------------------------------------------------------------------


def _frames(n: int, depth: bool) -> list[FrameRecord]:
    return [FrameRecord(f"images/f{k}.png", np.eye(4), depth_file_path=f"depth/f{k}.png" if depth else None)
            for k in range(n)]


def test_depth_file_paths_and_their_unit_round_trip_through_transforms(tmp_path):
    camera = Intrinsics.from_fov(60.0, 8, 6)
    write_transforms(tmp_path / "transforms.json", camera, _frames(3, True), None, depth_unit_scale_factor=1e-4)
    raw = json.loads((tmp_path / "transforms.json").read_text())
    assert raw["depth_unit_scale_factor"] == 1e-4 and raw["frames"][1]["depth_file_path"] == "depth/f1.png"
    dataset = read_transforms(tmp_path)
    assert dataset.depth_paths == tuple(tmp_path / f"depth/f{k}.png" for k in range(3))
    assert dataset.depth_scale == 1e-4
    assert [f.depth_file_path for f in dataset.frames()] == [f"depth/f{k}.png" for k in range(3)]
    # without depth: none, and the nerfstudio default of millimetres
    write_transforms(tmp_path / "plain.json", camera, _frames(2, False), None)
    plain = read_transforms(tmp_path / "plain.json")
    assert plain.depth_paths is None and plain.depth_scale == 0.001
    for k in range(3):
        write_png(tmp_path / "images" / f"f{k}.png", np.zeros((6, 8, 3), np.uint8))
    with pytest.raises(FileNotFoundError, match=r"frames\[0\]: depth image file .*f0.png does not exist"):
        read_transforms(tmp_path, check_files=True)


@pytest.mark.parametrize("value", [0, -0.001, "mm", True, float("inf")])
def test_a_bad_depth_unit_is_refused_naming_the_key(tmp_path, value):
    camera = Intrinsics.from_fov(60.0, 8, 6)
    write_transforms(tmp_path / "transforms.json", camera, _frames(1, True), None)
    raw = json.loads((tmp_path / "transforms.json").read_text())
    raw["depth_unit_scale_factor"] = value
    (tmp_path / "transforms.json").write_text(json.dumps(raw))
    with pytest.raises(DatasetError, match="transforms.json: depth_unit_scale_factor: must be a positive number"):
        read_transforms(tmp_path)


# ---- normals of a depth image ---------------------------------------------------------------------------------------


def _plane_depth(camera: Intrinsics, normal: np.ndarray, offset: float) -> np.ndarray:
    """(H, W) planar depth of the plane n·p = offset (camera frame) through ``camera``'s lens."""
    rays = camera_points(camera, np.ones((camera.height, camera.width)))  # z = 1
    return offset / (rays @ normal)


@pytest.mark.parametrize("lens", ["pinhole", "opencv"])
def test_depth_normals_of_a_tilted_plane_face_the_camera(lens):
    camera = Intrinsics(60.0, 60.0, 40.0, 30.0, 80, 60, *(LENS if lens == "opencv" else ("pinhole", ())))
    normal = np.array([0.3, -0.2, -1.0]) / np.linalg.norm([0.3, -0.2, -1.0])  # towards the camera
    depth = _plane_depth(camera, normal, -2.0)
    surface = depth_surface(depth, camera)
    normals = surface.normals
    inner = normals[4:-4, 4:-4]
    assert np.isfinite(inner).all()
    assert np.degrees(np.arccos(np.clip(inner @ normal, -1, 1))).max() < 0.1  # the window bends a curved z(u, v)
    assert np.isnan(normals[0]).all() and np.isnan(normals[:, -1]).all()  # no central difference at the border
    np.testing.assert_array_equal(np.isnan(surface.depth), np.isnan(normals).any(-1))
    assert np.nanmax(np.abs(surface.depth - depth) / depth) < 1e-3  # the average of a gently curved z(u, v)


def test_depth_normals_leave_out_depth_edges_and_unmeasured_pixels():
    camera = Intrinsics(60.0, 60.0, 40.0, 30.0, 80, 60)
    depth = np.full((60, 80), 2.0)
    depth[:, 40:] = 3.0  # a step: an object's edge
    depth[10, 10] = np.nan
    normals = depth_surface(depth, camera).normals
    unknown = np.isnan(normals).any(-1)
    assert unknown[:, 36:44].all()  # the jump between columns 39 and 40, widened by the window (5 + 2)
    assert not unknown[3:-3, 34].any() and not unknown[3:-3, 45].any()  # the border: no full window
    assert unknown[7:14, 7:14].all() and not unknown[6, 6] and not unknown[14, 14]  # around the missing pixel
    np.testing.assert_allclose(normals[30, 20], [0.0, 0.0, -1.0], atol=1e-9)


def test_the_averaged_depth_has_a_fifth_of_the_noise_of_a_5_by_5_window():
    camera = Intrinsics(60.0, 60.0, 40.0, 30.0, 80, 60)
    rng = np.random.default_rng(3)
    noisy = 2.0 + 0.01 * rng.standard_normal((60, 60 + 20))
    surface = depth_surface(noisy, camera)
    residual = surface.depth[5:-5, 5:-5] - 2.0
    assert residual.std() == pytest.approx(0.01 / 5, rel=0.25)  # 25 independent samples per pixel


def test_neighbour_mean_normals_denoise_a_plane_and_do_not_cancel_across_its_faces():
    rng = np.random.default_rng(4)
    xyz = np.concatenate([rng.uniform(-1, 1, (2000, 2)), np.zeros((2000, 1))], 1)
    noisy = np.array([0.0, 0.0, 1.0]) + 0.2 * rng.standard_normal((2000, 3))
    noisy /= np.linalg.norm(noisy, axis=1, keepdims=True)
    noisy[::2] *= -1  # half of them on the other face
    smoothed = neighbour_mean_normals(xyz, noisy, 16)
    before, after = (np.degrees(np.arccos(np.abs(n[:, 2]))) for n in (noisy, smoothed))
    assert np.median(after) < np.median(before) / 3
    np.testing.assert_array_equal(np.sign(smoothed[:, 2]), np.sign(noisy[:, 2]))  # each keeps its side
    np.testing.assert_allclose(np.linalg.norm(smoothed, axis=1), 1.0)


# ---- the simulator's depth camera -----------------------------------------------------------------------------------


def _rendered(root, frames=2, height=24, width=32):
    for k in range(frames):
        name = f"frame_{k:05d}"
        depth = np.full((height, width), 1.5 + 0.5 * k, np.float32)
        depth[0, 0] = np.inf  # no surface
        write_frame_exr(root / "exr" / f"{name}.exr", FrameEXR(
            uneven=np.full((height, width, 3), 0.3, np.float32), gt=np.full((height, width, 3), 0.5, np.float32),
            depth=depth, normal=np.zeros((height, width, 3), np.float32)))
        write_png(root / "images" / f"{name}.png", np.full((height, width, 3), 0.5))
    write_transforms(root / "transforms.json", Intrinsics.from_fov(75.0, width, height),
                     [FrameRecord(f"images/frame_{k:05d}.png", np.eye(4), exr_file_path=f"exr/frame_{k:05d}.exr")
                      for k in range(frames)], None)


def test_the_depth_camera_records_the_rendered_depth_with_its_noise(tmp_path):
    src = tmp_path / "clean"
    _rendered(src)
    exact, noisy = tmp_path / "exact", tmp_path / "noisy"
    add_sensor_noise_to_dataset(src, exact, None, depth_camera=DepthCamera(noise=0.0))
    add_sensor_noise_to_dataset(src, noisy, None, seed=3, depth_camera=DepthCamera(noise=0.01))
    for k, z in enumerate((1.5, 2.0)):
        dataset = read_dataset(exact)
        assert dataset.depth_paths[k] == exact / "depth" / f"frame_{k:05d}.png"
        clean = read_depth_image(dataset.depth_paths[k], dataset.depth_scale)
        assert np.isnan(clean[0, 0]) and np.nanmax(np.abs(clean - z)) < 1e-9
        measured = read_depth_image(read_dataset(noisy).depth_paths[k])
        residual = (measured - z)[1:]
        assert residual.std() == pytest.approx(0.01 * z * z, rel=0.25)  # σ = noise · z²
    before = (noisy / "depth" / "frame_00001.png").read_bytes()
    (noisy / "images" / "frame_00001.png").unlink()  # an interrupted copy: the frame again, the same bytes
    assert add_sensor_noise_to_dataset(src, noisy, None, seed=3, depth_camera=DepthCamera(noise=0.01)) == 1
    assert (noisy / "depth" / "frame_00001.png").read_bytes() == before
    with pytest.raises(ValueError, match="other settings"):
        add_sensor_noise_to_dataset(src, noisy, None, seed=3, depth_camera=DepthCamera(noise=0.02))


def test_the_depth_camera_looks_through_the_robot_cameras_lens(tmp_path):
    from simulator.sensor_noise import CameraEffects

    src, out = tmp_path / "clean", tmp_path / "robot"
    _rendered(src, frames=1, height=48, width=64)
    ramp = np.tile(np.linspace(1.0, 3.0, 64, dtype=np.float32), (48, 1))
    frame = read_frame_exr(src / "exr" / "frame_00000.exr")
    write_frame_exr(src / "exr" / "frame_00000.exr", FrameEXR(uneven=frame.uneven, gt=frame.gt, depth=ramp,
                                                                normal=frame.normal))
    add_sensor_noise_to_dataset(src, out, SensorNoise(0.0, 0.0), effects=CameraEffects(lens=LENS[0],
                                distortion=LENS[1]), depth_camera=DepthCamera(noise=0.0))
    lensed = read_frame_exr(out / "exr" / "frame_00000.exr").depth  # the render through the lens
    recorded = read_depth_image(out / "depth" / "frame_00000.png")
    np.testing.assert_allclose(recorded, np.round(lensed * 1000) / 1000, atol=1e-9)
    assert not np.allclose(recorded, ramp, atol=0.01)


@pytest.mark.parametrize("kwargs", [{"noise": -1.0}, {"max_range": 0.0}, {"max_range": 70.0}])
def test_a_bad_depth_camera_is_refused(kwargs):
    with pytest.raises(ValueError, match="DepthCamera"):
        DepthCamera(**kwargs)


# ---- prepare --points from depth images -----------------------------------------------------------------------------


@pytest.fixture(scope="module")
def rgbd_room(tmp_path_factory):
    """The ray-cast box room through a distorted lens, posed, with a depth camera's noisy 16-bit depth images."""
    seq = render_room_sequence(num_frames=12, width=96, height=72, seed=0, lens=LENS[0], distortion=LENS[1])
    root = tmp_path_factory.mktemp("rgbd") / "room"
    write_dataset_folder(seq, root, with_depth=False)
    camera = DepthCamera(noise=0.0025)
    rng = np.random.default_rng(0)
    for k, depth in enumerate(seq.depth):
        write_depth_image(root / "depth" / f"frame_{k:05d}.png", camera.measure(depth, rng))
    raw = json.loads((root / "transforms.json").read_text())
    for k, frame in enumerate(raw["frames"]):
        frame["depth_file_path"] = f"depth/frame_{k:05d}.png"
    (root / "transforms.json").write_text(json.dumps(raw))
    return root


def _box_distance_and_normal(xyz: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Each point's distance to the nearest face of the box room and that face's inward normal."""
    faces = np.stack([xyz[:, 0] + ROOM_X, ROOM_X - xyz[:, 0], xyz[:, 1] + ROOM_Y, ROOM_Y - xyz[:, 1],
                      xyz[:, 2], ROOM_Z - xyz[:, 2]], 1)
    nearest = np.argmin(np.abs(faces), 1)
    normals = np.zeros_like(xyz)
    normals[np.arange(len(xyz)), nearest // 2] = np.where(nearest % 2 == 0, 1.0, -1.0)
    return np.abs(faces[np.arange(len(xyz)), nearest]), normals


def test_prepare_points_back_projects_the_depth_images_into_a_trusted_dense_start(rgbd_room, tmp_path):
    data = tmp_path / "data"
    shutil.copytree(rgbd_room, data)
    before = json.loads((data / "transforms.json").read_text())
    result = CliRunner().invoke(main, ["prepare", "--points", str(data), "-q"])
    assert result.exit_code == 0, result.output + repr(result.exception)
    assert "from the depth images of 10 training frames" in result.output
    summary = json.loads((data / SUMMARY_FILE).read_text())["points"]
    assert summary["frames"] == 10 and summary["file"] == DEPTH_POINTS_FILE
    cloud = read_point_cloud(data / DEPTH_POINTS_FILE)
    assert len(cloud.xyz) == summary["points"] > 5000
    distance, true_normals = _box_distance_and_normal(np.asarray(cloud.xyz, np.float64))
    assert np.median(distance) < 0.01  # on the walls, through the lens (a pinhole back-projection is off by cm)
    angle = np.degrees(np.arccos(np.clip(np.abs((cloud.normals * true_normals).sum(1)), 0, 1)))
    assert np.median(angle) < 3.0 and np.mean(angle < 10) > 0.9
    facing = (cloud.normals * true_normals).sum(1) > 0  # the inward normals: towards the cameras inside
    assert facing.mean() > 0.99
    after = json.loads((data / "transforms.json").read_text())
    assert after.pop("ply_file_path") == DEPTH_POINTS_FILE and after == before
    # the trainer trusts it: dense, with normals
    dataset = read_dataset(data)
    assert start_is_trusted(TrainConfig(), read_point_cloud(dataset.ply_path))


def test_pinhole_back_projection_of_a_distorted_depth_image_would_miss_the_walls(rgbd_room):
    """What the lens in backproject_depth is for: the same depth image taken as a pinhole's lands off the walls."""
    dataset = read_dataset(rgbd_room)
    depth = read_depth_image(dataset.depth_paths[3])
    camera = dataset.cameras[3]
    rgb = np.zeros(depth.shape + (3,), np.uint8)
    through_lens = backproject_depth(depth, rgb, None, camera, dataset.c2w_opengl[3])
    pinhole = Intrinsics(camera.fx, camera.fy, camera.cx, camera.cy, camera.width, camera.height)
    as_pinhole = backproject_depth(depth, rgb, None, pinhole, dataset.c2w_opengl[3])
    assert np.median(_box_distance_and_normal(through_lens.xyz)[0]) < 0.01
    assert np.median(_box_distance_and_normal(as_pinhole.xyz)[0]) > 2 * np.median(
        _box_distance_and_normal(through_lens.xyz)[0])


def test_points_from_depth_refuse_a_frame_without_depth_and_leave_the_dataset(rgbd_room, tmp_path):
    data = tmp_path / "data"
    shutil.copytree(rgbd_room, data)
    raw = json.loads((data / "transforms.json").read_text())
    del raw["frames"][2]["depth_file_path"]
    (data / "transforms.json").write_text(json.dumps(raw))
    before = (data / "transforms.json").read_bytes()
    result = CliRunner().invoke(main, ["prepare", "--points", str(data), "--points-from", "depth", "-q"])
    assert result.exit_code != 0
    assert "frames[2] (images/frame_00002.png) has no depth_file_path (1 of 10 training frames" in result.output
    assert (data / "transforms.json").read_bytes() == before and not (data / DEPTH_POINTS_FILE).exists()
    # a depth image of another size than its frame
    raw["frames"][2]["depth_file_path"] = "depth/frame_00002.png"
    (data / "transforms.json").write_text(json.dumps(raw))
    write_depth_image(data / "depth" / "frame_00002.png", np.ones((10, 10)))
    with pytest.raises(InputError, match=r"frame_00002.png: the depth image is 10x10, its frame .* 96x72"):
        add_depth_points(data)
    assert not (data / DEPTH_POINTS_FILE).exists()
    # a colour frame of another size than its camera
    write_depth_image(data / "depth" / "frame_00002.png", np.ones((72, 96)))
    write_png(data / "images" / "frame_00002.png", np.zeros((36, 48, 3)))
    with pytest.raises(InputError, match=r"images/frame_00002.png: the frame is 48x36, its camera 96x72"):
        add_depth_points(data)
    assert (data / "transforms.json").read_text() == json.dumps(raw) and not (data / DEPTH_POINTS_FILE).exists()


def test_points_refuse_a_one_frame_dataset_and_a_damaged_summary_before_writing(rgbd_room, tmp_path):
    """One frame is a test frame only: no training frame to take points from. A prepare.json that is not a JSON object
    is named, and nothing is written: the dataset stays as it was, and a rerun after mending it completes."""
    data = tmp_path / "data"
    shutil.copytree(rgbd_room, data)
    raw = json.loads((data / "transforms.json").read_text())
    one = tmp_path / "one"
    shutil.copytree(rgbd_room, one)
    plain = {key: value for key, value in raw.items() if key != "spotless"}  # as a bag's: the every-11th split
    (one / "transforms.json").write_text(json.dumps({**plain, "frames": raw["frames"][:1]}))
    result = CliRunner().invoke(main, ["prepare", "--points", str(one), "--points-from", "depth", "-q"])
    assert result.exit_code == 2 and len(result.output.strip().splitlines()) == 1, result.output
    assert "one/transforms.json: no training frame (1 frame(s), all in the test split)" in result.output
    before = (data / "transforms.json").read_bytes()
    (data / SUMMARY_FILE).write_text("[]")
    with pytest.raises(InputError, match=r"prepare.json: damaged the summary of spotless prepare: expected a JSON "
                                         "object, found an array"):
        add_depth_points(data)
    assert (data / "transforms.json").read_bytes() == before and not (data / DEPTH_POINTS_FILE).exists()
    (data / SUMMARY_FILE).write_text("{}")
    assert add_depth_points(data)["points"] > 0
    assert read_dataset(data).ply_path == data / DEPTH_POINTS_FILE
    assert json.loads((data / SUMMARY_FILE).read_text())["points"]["file"] == DEPTH_POINTS_FILE


def test_points_from_is_a_choice_that_goes_with_points(rgbd_room, tmp_path):
    result = CliRunner().invoke(main, ["prepare", "--images", str(rgbd_room / "images"), "--out",
                                       str(tmp_path / "o"), "--points-from", "depth"])
    assert result.exit_code != 0 and "--points-from goes with --points" in result.output
