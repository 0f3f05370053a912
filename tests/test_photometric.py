"""The photometric camera (per-frame exposure, vignetting), known exposures, and the simulator's robot-camera effects."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
import torch
from PIL import Image

from simulator.sensor_noise import EFFECTS_RECORD, CameraEffects, add_sensor_noise_to_dataset
from spotlessgs.io.colorspace import srgb_to_linear
from spotlessgs.io.errors import InputError
from spotlessgs.io.exposure import frame_exposures
from spotlessgs.io.images import read_image
from spotlessgs.models.photometric import MIN_FALLOFF, PhotometricCamera
from test_sensor_noise import _dataset as exr_dataset

pytestmark = pytest.mark.usefixtures("one_torch_thread")


def test_gains_are_relative_to_the_fitted_frames_and_vignetting_is_the_polynomial():
    radius = torch.tensor([[0.0, 0.5], [1.0, 0.25]])
    camera = PhotometricCamera(4, [0, 1, 2], radius)
    with torch.no_grad():
        camera.log_gain.copy_(torch.tensor([0.1, 0.4, 0.7, 2.0]))  # frame 3 is not fitted (a test view)
        camera.coefficients.copy_(torch.tensor([-0.3, 0.1, -0.05]))
    mean = 0.4
    # frame 3 is never fitted and has no known exposure: the reference (gain 1), whatever its parameter holds
    torch.testing.assert_close(camera.gains(), torch.exp(torch.tensor([0.1, 0.4, 0.7, mean]) - mean))
    r2 = radius ** 2
    falloff = 1 - 0.3 * r2 + 0.1 * r2 ** 2 - 0.05 * r2 ** 3
    torch.testing.assert_close(camera.falloff(), falloff)
    image = torch.rand(2, 2, 3)
    torch.testing.assert_close(camera(image, 2), image * falloff[..., None] * math.exp(0.7 - mean))
    with torch.no_grad():
        camera.coefficients.copy_(torch.tensor([-2.0, 0.0, 0.0]))
    assert float(camera.falloff().detach()[1, 0]) == pytest.approx(MIN_FALLOFF)  # clamped, never black
    report = camera.report(["a", "b", "c", "d"])
    assert report["exposure"]["gains"]["d"] == 1.0
    assert report["vignetting"]["falloff"]["1.0"] == pytest.approx(MIN_FALLOFF)


def test_switched_off_parts_leave_the_image_alone_and_priors_set_the_start():
    radius = torch.rand(3, 4)
    image = torch.rand(3, 4, 3)
    assert torch.equal(PhotometricCamera(2, [0, 1], radius, exposure=False, vignetting=False)(image, 1), image)
    prior = torch.log(torch.tensor([0.01, 0.04, 0.06]))
    camera = PhotometricCamera(3, [0, 1], radius, vignetting=False, log_gain_prior=prior)
    # 0.01 and 0.04 around their geometric mean 0.02; frame 2, never fitted, keeps its known ratio to that mean
    torch.testing.assert_close(camera.gains(), torch.tensor([0.5, 2.0, 3.0]))
    with pytest.raises(ValueError, match="log_gain_prior must be 2 finite values"):
        PhotometricCamera(2, [0], radius, log_gain_prior=prior)
    with pytest.raises(ValueError, match="no fitted frames"):
        PhotometricCamera(3, [], radius)


def test_known_exposures_come_from_sidecars_or_exif(tmp_path):
    paths = []
    for k, (seconds, iso) in enumerate([(0.01, 100), (0.02, 400)]):
        path = tmp_path / f"f{k}.jpg"
        exif = Image.Exif()
        exif.get_ifd(0x8769).update({0x829A: seconds, 0x8827: iso})
        Image.fromarray(np.zeros((4, 4, 3), np.uint8)).save(path, exif=exif)
        paths.append(path)
    assert frame_exposures(paths) == pytest.approx([0.01, 0.08])  # time × ISO / 100
    (tmp_path / "f1.json").write_text(json.dumps({"exposure_time": 0.005, "gain": 3.0}))  # a sidecar wins
    assert frame_exposures(paths) == pytest.approx([0.01, 0.015])
    png = tmp_path / "plain.png"
    Image.fromarray(np.zeros((4, 4, 3), np.uint8)).save(png)
    assert frame_exposures([*paths, png]) is None  # one frame without: no prior at all
    (tmp_path / "f0.json").write_text(json.dumps({"exposure_time": -1}))
    with pytest.raises(InputError, match=r"f0\.json: 'exposure_time' must be a positive number"):
        frame_exposures(paths)
    (tmp_path / "f0.json").write_text("{")
    with pytest.raises(InputError, match=r"f0\.json: not a readable JSON exposure record"):
        frame_exposures(paths)


def test_auto_exposure_converges_to_the_target_within_its_range():
    effects = CameraEffects(target_level=0.2, max_gain=4.0, adaptation=0.5)
    gains = effects.gains(np.array([0.1] * 6 + [0.01] * 8 + [0.5]))
    assert gains[0] == pytest.approx(2.0)  # the first frame: at once
    assert gains[13] == pytest.approx(4.0, rel=0.01)  # very dark frames: the largest gain, approached
    assert gains[14] == pytest.approx(math.exp(0.5 * math.log(gains[13])), rel=1e-9)  # halfway (log) to 1
    assert CameraEffects(auto_exposure=False).gains(np.array([0.01, 0.5])).tolist() == [1.0, 1.0]
    falloff = CameraEffects(vignetting=0.35).falloff(4, 6, 3.0, 2.0)
    corner = 1 - 0.35 * (math.hypot(2.5, 1.5) / math.hypot(3, 2)) ** 2  # the corner pixel's centre
    assert falloff[0, 0] == pytest.approx(corner) and falloff.max() < 1.0
    with pytest.raises(ValueError, match="vignetting out of range"):
        CameraEffects(vignetting=1.0)


def test_a_robot_camera_copy_records_its_effects(tmp_path):
    src, out = tmp_path / "clean", tmp_path / "robot"
    linears = exr_dataset(src)
    effects = CameraEffects(target_level=0.6, max_gain=3.0, vignetting=0.3)
    assert add_sensor_noise_to_dataset(src, out, None, seed=0, effects=effects) == 3
    record = json.loads((out / EFFECTS_RECORD).read_text())
    gains = effects.gains(np.array([float(np.mean(x)) for x in linears]))
    assert list(record["gains"].values()) == pytest.approx(gains.tolist())
    height, width = linears[0].shape[:2]
    falloff = effects.falloff(height, width, width / 2, height / 2)[..., None]
    for k, linear in enumerate(linears):
        recorded = srgb_to_linear(read_image(out / "images" / f"frame_{k:05d}.png"))
        np.testing.assert_allclose(recorded, np.clip(linear * gains[k] * falloff, 0, 1), atol=0.005)  # 8-bit


def test_the_trainer_turns_the_camera_on_for_real_cameras_resumes_and_reports_it(tmp_path_factory, tmp_path):
    from conftest import synthetic_box_dataset
    from spotlessgs.run import RunSpec, train

    box = synthetic_box_dataset(tmp_path_factory, "photometric", seed=2)  # our simulator's block: a fixed exposure
    small = (("iterations", 20), ("num_threads", 1), ("checkpoint_every", 10), ("image_width", 32))
    plain = train(RunSpec(data=box, model="darkgs", preset="tiny", overrides=small), tmp_path / "auto", progress=False)
    assert plain.summary["photometric"] is False and not (tmp_path / "auto" / "photometric.json").exists()
    on = (*small, ("photometric", "on"))
    straight = train(RunSpec(data=box, model="darkgs", preset="tiny", overrides=on), tmp_path / "on", progress=False)
    assert straight.summary["photometric"] is True
    spec = RunSpec(data=box, model="darkgs", preset="tiny", overrides=on)
    train(spec, tmp_path / "resumed", progress=False, stop_after=10)
    train(spec, tmp_path / "resumed", progress=False, resume=True)
    first, second = (json.loads((tmp_path / name / "photometric.json").read_text()) for name in ("on", "resumed"))
    assert first == second and first["exposure"]["gains"] and first["vignetting"]["coefficients"] != [0.0] * 3
    gains = np.array(list(first["exposure"]["gains"].values()))
    fitted = [i for i in range(len(gains)) if i not in (0, 11)]  # test views 0 and 11 are never fitted
    assert math.exp(np.log(gains[fitted]).mean()) == pytest.approx(1.0, abs=1e-6)  # the reference exposure


def test_a_robot_camera_copy_through_a_lens_resamples_the_renders_and_records_the_camera(tmp_path):
    """Independent check of one pixel: its ray through the lens (OpenCV's, checked against pycolmap in test_lens.py)
    lands at a render position whose value the horizontal ramp gives exactly (bilinear sampling is exact on it)."""
    from spotlessgs.io.cameras import Intrinsics
    from spotlessgs.io.dataset import read_dataset
    from spotlessgs.io.exr import FrameEXR, write_frame_exr
    from spotlessgs.io.lens import undistort
    from spotlessgs.io.colorspace import linear_to_srgb
    from spotlessgs.io.images import write_png
    from spotlessgs.io.transforms import DatasetMeta, FrameRecord, write_transforms

    width, height = 40, 30
    render = Intrinsics.from_fov(70.0, width, height)
    ramp = np.repeat(((np.arange(width) + 0.5) / width)[None, :, None], height, 0).repeat(3, 2).astype(np.float32)
    src, records = tmp_path / "clean", []
    for k in range(2):
        name = f"frame_{k:05d}"
        step = np.where(np.arange(width) < width // 2, 1.0, 3.0)[None, :].repeat(height, 0).astype(np.float32)
        write_frame_exr(src / "exr" / f"{name}.exr", FrameEXR(uneven=0.5 * ramp, gt=ramp, depth=step,
                        normal=np.zeros((height, width, 3), np.float32)))
        write_png(src / "images" / f"{name}.png", linear_to_srgb(0.5 * ramp))
        write_png(src / "gt" / f"{name}.png", linear_to_srgb(ramp))
        records.append(FrameRecord(f"images/{name}.png", np.eye(4), gt_file_path=f"gt/{name}.png",
                                   exr_file_path=f"exr/{name}.exr"))
    write_transforms(src / "transforms.json", render, records, DatasetMeta(scene_id="ramp"))
    effects = CameraEffects(auto_exposure=False, vignetting=0.0, lens="opencv", distortion=(-0.2, 0.05, 0.0, 0.0))
    add_sensor_noise_to_dataset(src, tmp_path / "robot", None, effects=effects)
    data = read_dataset(tmp_path / "robot", check_files=True)
    camera = data.intrinsics
    assert camera == effects.camera(render) and camera.lens == "opencv" and camera.fx > render.fx
    assert data.meta["camera_effects"]["lens"] == "opencv"
    # the EXRs are the renders through the lens: the ground truth as its PNG, the depth sampled, never blended
    from spotlessgs.io.exr import read_frame_exr

    assert data.exr_paths == tuple(tmp_path / "robot" / "exr" / f"frame_{k:05d}.exr" for k in range(2))
    through_lens = read_frame_exr(data.exr_paths[1])
    np.testing.assert_allclose(linear_to_srgb(np.clip(through_lens.gt, 0, 1)),
                               read_image(tmp_path / "robot" / "gt" / "frame_00001.png"), atol=1 / 255 + 1e-6)
    assert set(np.unique(through_lens.depth)) == {1.0, 3.0}
    assert (through_lens.depth[:, 0] == 1.0).all() and (through_lens.depth[:, -1] == 3.0).all()
    # every pixel's ray falls inside the render, the outermost just so (the image edge, finely sampled)
    t = np.linspace(0.0, 1.0, 401)
    edges = np.concatenate([np.c_[t * width, 0 * t], np.c_[t * width, 0 * t + height], np.c_[0 * t, t * height],
                            np.c_[0 * t + width, t * height]])
    rays = undistort(camera, edges)
    u, v = render.fx * rays[:, 0] + render.cx, render.fy * rays[:, 1] + render.cy
    margins = [u.min(), width - u.max(), v.min(), height - v.max()]
    assert min(margins) > -1e-3 and min(margins) < 0.05
    pixels = np.array([[5.5, 4.5], [20.5, 15.5], [37.5, 27.5]])
    expected_u = render.fx * undistort(camera, pixels)[:, 0] + render.cx
    for image, scale in ((read_image(tmp_path / "robot" / "images" / "frame_00001.png"), 0.5),
                         (read_image(tmp_path / "robot" / "gt" / "frame_00001.png"), 1.0)):
        linear = srgb_to_linear(image)
        values = [linear[int(v), int(x), 0] for x, v in pixels]
        np.testing.assert_allclose(values, scale * np.clip(expected_u, 0.5, width - 0.5) / width, atol=0.006)
