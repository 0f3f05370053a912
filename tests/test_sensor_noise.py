"""Camera sensor noise (simulator.sensor_noise): the noise statistics of the model, and the noisy copy of a dataset
(only the spotlight-only images change; reruns resume and reproduce the same bytes; bad input is refused)."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
from click.testing import CliRunner

from simulator.sensor_noise import NOISE_RECORD, SensorNoise, add_sensor_noise, add_sensor_noise_to_dataset
from spotlessgs.io.cameras import Intrinsics
from spotlessgs.io.colorspace import linear_to_srgb, srgb_to_linear
from spotlessgs.io.exr import FrameEXR, write_frame_exr
from spotlessgs.io.images import read_image, write_png
from spotlessgs.io.transforms import FrameRecord, write_transforms


def test_noise_has_the_model_mean_and_standard_deviation():
    noise = SensorNoise(shot=0.01, read=0.012)
    x = np.full((300, 300, 3), 0.25)
    y = add_sensor_noise(x, noise, np.random.default_rng(0))
    assert y.dtype == np.float32 and y.shape == x.shape
    expected_std = math.sqrt(0.01 * 0.25 + 0.012**2)  # 0.0514: far from the clipping bounds at 0.25
    assert y.mean() == pytest.approx(0.25, abs=5e-4)
    assert y.std() == pytest.approx(expected_std, rel=0.02)
    # the variance grows linearly with the signal (shot noise): at 0.64 it is 0.01 * 0.64 + read^2
    y = add_sensor_noise(np.full((300, 300, 3), 0.64), noise, np.random.default_rng(1))
    assert y.std() == pytest.approx(math.sqrt(0.0064 + 0.012**2), rel=0.02)


def test_noise_is_clipped_like_a_sensor_and_reproducible():
    noise = SensorNoise(shot=0.0, read=0.05)
    black = add_sensor_noise(np.zeros((200, 200, 3)), noise, np.random.default_rng(2))
    assert black.min() == 0.0 and black.max() <= 1.0
    assert black.mean() == pytest.approx(0.05 / math.sqrt(2 * math.pi), rel=0.03)  # E[max(0, N(0, s))]
    white = add_sensor_noise(np.full((10, 10, 3), 3.0), noise, np.random.default_rng(2))
    assert (white == 1.0).all()  # a saturated pixel stays clipped
    x = np.random.default_rng(3).uniform(0, 1, (8, 8, 3))
    np.testing.assert_array_equal(add_sensor_noise(x, noise, np.random.default_rng(9)),
                                  add_sensor_noise(x, noise, np.random.default_rng(9)))
    np.testing.assert_array_equal(add_sensor_noise(x, SensorNoise(0.0, 0.0), np.random.default_rng(9)),
                                  x.astype(np.float32))


@pytest.mark.parametrize("call, match", [
    (lambda: SensorNoise(shot=-0.1), r"shot must be in \[0, 1\], got -0.1"),
    (lambda: SensorNoise(read=math.nan), r"read must be in \[0, 1\], got nan"),
    (lambda: SensorNoise(read=1e300), r"read must be in \[0, 1\], got 1e\+300"),  # overflowed, blocking the folder
    (lambda: add_sensor_noise(np.zeros((4, 4)), SensorNoise(), np.random.default_rng(0)), r"\(H, W, 3\)"),
    (lambda: add_sensor_noise(np.full((2, 2, 3), np.inf), SensorNoise(), np.random.default_rng(0)), "non-finite"),
])
def test_bad_noise_input_is_refused(call, match):
    with pytest.raises(ValueError, match=match):
        call()


def _dataset(root, frames=3, height=24, width=32):
    """A finished dataset with frame EXRs (linear uneven + gt), PNGs and transforms.json; returns the uneven linears."""
    rng = np.random.default_rng(11)
    records, linears = [], []
    for k in range(frames):
        uneven = rng.uniform(0.0, 0.8, (height, width, 3)).astype(np.float32)
        gt = rng.uniform(0.2, 0.6, (height, width, 3)).astype(np.float32)
        name = f"frame_{k:05d}"
        write_frame_exr(root / "exr" / f"{name}.exr", FrameEXR(uneven=uneven, gt=gt,
                                                                 depth=np.ones((height, width), np.float32),
                                                                 normal=np.zeros((height, width, 3), np.float32)))
        write_png(root / "images" / f"{name}.png", linear_to_srgb(uneven))
        write_png(root / "gt" / f"{name}.png", linear_to_srgb(gt))
        c2w = np.eye(4)
        c2w[0, 3] = 0.1 * k
        records.append(FrameRecord(f"images/{name}.png", c2w, gt_file_path=f"gt/{name}.png",
                                   exr_file_path=f"exr/{name}.exr"))
        linears.append(uneven)
    write_transforms(root / "transforms.json", Intrinsics.from_fov(75.0, width, height), records, None)
    return linears


def test_noisy_copy_changes_only_the_spotlight_images_and_resumes(tmp_path):
    src, out = tmp_path / "clean", tmp_path / "noisy"
    linears = _dataset(src)
    noise = SensorNoise(shot=0.01, read=0.012)
    assert add_sensor_noise_to_dataset(src, out, noise, seed=4) == 3
    for k, linear in enumerate(linears):
        name = f"frame_{k:05d}.png"
        assert (out / "gt" / name).read_bytes() == (src / "gt" / name).read_bytes()
        noisy = srgb_to_linear(read_image(out / "images" / name))
        clean = srgb_to_linear(read_image(src / "images" / name))
        residual = noisy - linear
        # the residual is the model's noise (plus 8-bit quantisation, ~0.004 at most in linear here)
        assert np.abs(noisy - clean).mean() > 0.02
        assert residual.std() == pytest.approx(float(np.sqrt(noise.shot * linear + noise.read**2).mean()), rel=0.2)
    assert (out / "transforms.json").read_bytes() == (src / "transforms.json").read_bytes()
    record = json.loads((out / NOISE_RECORD).read_text())
    assert record["shot"] == 0.01 and record["read"] == 0.012 and record["seed"] == 4
    # a rerun writes nothing; an interrupted run (a frame missing) writes that frame again, with the same bytes
    before = (out / "images" / "frame_00001.png").read_bytes()
    assert add_sensor_noise_to_dataset(src, out, noise, seed=4) == 0
    (out / "images" / "frame_00001.png").unlink()
    assert add_sensor_noise_to_dataset(src, out, noise, seed=4) == 1
    assert (out / "images" / "frame_00001.png").read_bytes() == before
    # other noise frames differ
    other = tmp_path / "other-seed"
    add_sensor_noise_to_dataset(src, other, noise, seed=5)
    assert (other / "images" / "frame_00001.png").read_bytes() != before


def test_noisy_copy_refuses_bad_folders(tmp_path):
    src = tmp_path / "clean"
    _dataset(src, frames=2)
    with pytest.raises(ValueError, match="is the same path as the input --data"):
        add_sensor_noise_to_dataset(src, src, SensorNoise())
    with pytest.raises(ValueError, match=r"not a finished dataset \(no transforms.json\)"):
        add_sensor_noise_to_dataset(tmp_path / "missing", tmp_path / "o", SensorNoise())
    add_sensor_noise_to_dataset(src, tmp_path / "o2", SensorNoise(0.01, 0.01))
    with pytest.raises(ValueError, match=r"made with other settings or of another dataset \(shot: 0\.01 then, 0\.02 "
                                         r"now\)"):
        add_sensor_noise_to_dataset(src, tmp_path / "o2", SensorNoise(0.02, 0.01))
    # the source and its copy moved together (a reproduction folder moved to another disk): the same settings
    import shutil

    shutil.copytree(src, tmp_path / "moved" / "clean")
    shutil.copytree(tmp_path / "o2", tmp_path / "moved" / "o2")
    assert add_sensor_noise_to_dataset(tmp_path / "moved" / "clean", tmp_path / "moved" / "o2",
                                       SensorNoise(0.01, 0.01)) == 0
    other = tmp_path / "other"  # another dataset into the same copy: refused by its content
    _dataset(other, frames=3)
    with pytest.raises(ValueError, match=r"source_fingerprint"):
        add_sensor_noise_to_dataset(other, tmp_path / "o2", SensorNoise(0.01, 0.01))
    meta = json.loads((src / "transforms.json").read_text())
    meta["frames"][1].pop("exr_file_path", None)
    (src / "transforms.json").write_text(json.dumps(meta))
    with pytest.raises(ValueError, match="has no linear render"):
        add_sensor_noise_to_dataset(src, tmp_path / "o3", SensorNoise())


def test_command_line(tmp_path):
    from simulator.cli import main

    src = tmp_path / "clean"
    _dataset(src, frames=2)
    result = CliRunner().invoke(main, ["add-noise", "--data", str(src), "--out", str(tmp_path / "noisy"),
                                       "--shot", "0.005", "--read", "0.01", "--seed", "3"])
    assert result.exit_code == 0, result.output + repr(result.exception)
    assert "wrote 2 image(s)" in result.output
    assert json.loads((tmp_path / "noisy" / NOISE_RECORD).read_text())["shot"] == 0.005
    result = CliRunner().invoke(main, ["add-noise", "--data", str(src), "--out", str(tmp_path / "robot"),
                                       "--robot-camera", "--vignetting", "0.2", "--max-gain", "3", "--lens", "opencv",
                                       "--distortion=-0.1,0.01,0,0"])
    assert result.exit_code == 0, result.output + repr(result.exception)
    record = json.loads((tmp_path / "robot" / "camera_effects.json").read_text())
    assert record["vignetting"] == 0.2 and record["max_gain"] == 3.0 and len(record["gains"]) == 2
    transforms = json.loads((tmp_path / "robot" / "transforms.json").read_text())
    assert transforms["camera_model"] == "OPENCV" and transforms["k1"] == -0.1 and record["camera"]["lens"] == "opencv"
    result = CliRunner().invoke(main, ["add-noise", "--data", str(src), "--out", str(tmp_path / "bad"),
                                       "--robot-camera", "--lens", "opencv", "--distortion", "x,y"])
    assert result.exit_code == 2 and "--distortion" in result.output


def _tree(root) -> dict:
    return {str(p.relative_to(root)): p.read_bytes() if p.is_file() else None for p in sorted(root.rglob("*"))}


def test_an_output_that_overlaps_the_data_is_refused_before_anything_is_written(tmp_path):
    """OUT equal to DATA, inside it, or containing it would mix the noisy copy with its source (or read what it
    writes): refused with one line, exit 2, nothing written."""
    from simulator.cli import main
    from spotlessgs.io.errors import OutputOverlapError

    src = tmp_path / "data" / "clean"
    _dataset(src, frames=2)
    before = _tree(tmp_path)
    for out, words in ((src, "same path as the input --data"), (src / "noisy", "inside the input --data"),
                       (tmp_path / "data", "contains the input --data")):
        with pytest.raises(OutputOverlapError, match=words):
            add_sensor_noise_to_dataset(src, out, SensorNoise())
        result = CliRunner().invoke(main, ["add-noise", "--data", str(src), "--out", str(out)])
        assert result.exit_code == 2, result.output
        assert words in result.output and len(result.output.strip().splitlines()) == 1, result.output
        assert _tree(tmp_path) == before


def test_temporary_files_of_a_killed_run_are_removed_when_the_next_starts(tmp_path):
    """A run killed with SIGKILL in the middle of a write leaves ``.<name>.partial-*`` files; the next run removes
    them (and completes the copy)."""
    src, out = tmp_path / "clean", tmp_path / "noisy"
    _dataset(src)
    noise = SensorNoise()
    add_sensor_noise_to_dataset(src, out, noise, seed=1)
    expected = _tree(out)
    (out / "images" / "frame_00002.png").unlink()
    (out / "images" / ".frame_00002.png.partial-k1ll3d.png").write_bytes(b"half a png")
    (out / ".sensor_noise.json.partial-k1ll3d.json").write_text("{")
    assert add_sensor_noise_to_dataset(src, out, noise, seed=1) == 1
    assert _tree(out) == expected


def test_the_uniform_ground_truth_travels_with_the_copy_and_through_a_lens(tmp_path):
    """A dataset rendered with ``--gt uniform``: a plain noisy copy keeps gt_uniform/ byte for byte; a copy through a
    lens resamples it like the lamps-on ground truth (the same maps: the PNG is the resampled EXR channel)."""
    from simulator.sensor_noise import CameraEffects
    from spotlessgs.io.exr import read_frame_exr
    from spotlessgs.io.lens import distort_maps, remap

    src = tmp_path / "clean"
    _dataset(src, frames=2, height=48, width=64)
    rng = np.random.default_rng(5)
    for k in range(2):
        name = f"frame_{k:05d}"
        frame = read_frame_exr(src / "exr" / f"{name}.exr")
        uniform = rng.uniform(0.1, 0.9, frame.gt.shape).astype(np.float32)
        write_frame_exr(src / "exr" / f"{name}.exr", FrameEXR(uneven=frame.uneven, gt=frame.gt, depth=frame.depth,
                                                               normal=frame.normal, gt_uniform=uniform))
        write_png(src / "gt_uniform" / f"{name}.png", linear_to_srgb(uniform))
    plain = tmp_path / "plain"
    add_sensor_noise_to_dataset(src, plain, SensorNoise(shot=0.01, read=0.01), seed=0)
    for k in range(2):
        name = f"frame_{k:05d}.png"
        assert (plain / "gt_uniform" / name).read_bytes() == (src / "gt_uniform" / name).read_bytes()
    lensed = tmp_path / "lens"
    effects = CameraEffects(lens="opencv", distortion=(-0.2, 0.03, 0.0, 0.0))
    add_sensor_noise_to_dataset(src, lensed, None, seed=0, effects=effects)
    # made again with the same settings (an interrupted copy resumed): the record read back has the distortion as a
    # JSON list, not the tuple the settings give, and is still the same; nothing is left to write
    assert add_sensor_noise_to_dataset(src, lensed, None, seed=0, effects=effects) == 0
    camera = effects.camera(Intrinsics.from_fov(75.0, 64, 48))
    map_x, map_y, _valid = distort_maps(camera, Intrinsics.from_fov(75.0, 64, 48))
    for k in range(2):
        name = f"frame_{k:05d}"
        source = read_frame_exr(src / "exr" / f"{name}.exr").gt_uniform
        copied = read_frame_exr(lensed / "exr" / f"{name}.exr").gt_uniform
        np.testing.assert_allclose(copied, remap(source, map_x, map_y), atol=1e-6)
        assert not np.allclose(copied, source, atol=0.05)  # really resampled
        png = read_image(lensed / "gt_uniform" / f"{name}.png")
        np.testing.assert_allclose(png, linear_to_srgb(np.clip(copied, 0, 1)), atol=1 / 255 + 1e-6)


def test_a_noisy_copy_never_takes_over_another_folder_and_is_finished_only_with_its_last_frame(tmp_path):
    """``--out`` holding another dataset is refused, its files untouched; a copy that fails on a frame has no
    transforms.json (which marks a finished dataset), and the run after the repair completes it."""
    from spotlessgs.io.errors import InputError

    _dataset(tmp_path / "data")
    _dataset(tmp_path / "other")
    before = {p: p.read_bytes() for p in (tmp_path / "other").rglob("*") if p.is_file()}
    with pytest.raises(ValueError, match=r"other: holds files but no sensor_noise\.json \(.*\): not a noisy copy this "
                                         r"command began; choose an empty or new --out"):
        add_sensor_noise_to_dataset(tmp_path / "data", tmp_path / "other", SensorNoise(), seed=1)
    assert {p: p.read_bytes() for p in (tmp_path / "other").rglob("*") if p.is_file()} == before

    exr = tmp_path / "data" / "exr" / "frame_00002.exr"
    exr.rename(exr.with_suffix(".moved"))
    with pytest.raises((OSError, ValueError), match="frame_00002.exr"):
        add_sensor_noise_to_dataset(tmp_path / "data", tmp_path / "copy", SensorNoise(), seed=1)
    assert (tmp_path / "copy" / "images" / "frame_00001.png").is_file()
    assert not (tmp_path / "copy" / "transforms.json").exists()
    exr.with_suffix(".moved").rename(exr)
    assert add_sensor_noise_to_dataset(tmp_path / "data", tmp_path / "copy", SensorNoise(), seed=1) == 1
    assert (tmp_path / "copy" / "transforms.json").read_bytes() == (tmp_path / "data" / "transforms.json").read_bytes()

    (tmp_path / "copy" / NOISE_RECORD).write_text("{damaged")
    with pytest.raises(InputError, match=r"copy/sensor_noise.json: .*JSON"):
        add_sensor_noise_to_dataset(tmp_path / "data", tmp_path / "copy", SensorNoise(), seed=1)


@pytest.mark.parametrize("args, message", [
    (["--lens", "fisheye", "--distortion", "0.1,0,0,0"], "--lens, --distortion only apply with --robot-camera"),
    (["--vignetting", "0.5"], "--vignetting only applies with --robot-camera"),
    (["--depth-range", "3"], "--depth-range only applies with --depth-camera"),
])
def test_camera_options_without_their_camera_are_a_usage_error(tmp_path, args, message):
    """Before, they were ignored without a word: the copy had a pinhole camera or no depth."""
    from simulator.cli import main as sim_main

    _dataset(tmp_path / "data")
    result = CliRunner().invoke(sim_main, ["add-noise", "--data", str(tmp_path / "data"), "--out",
                                           str(tmp_path / "copy"), *args])
    assert result.exit_code == 2 and message in result.output, result.output
    assert not (tmp_path / "copy").exists()
