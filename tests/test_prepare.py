"""``spotless prepare --images``: spotlit frames -> a COLMAP dataset the trainer reads, with a summary."""

from __future__ import annotations

import json
import os
import shutil

import cv2
import numpy as np
import pytest
from click.testing import CliRunner

from evaluation.synthetic import render_room_sequence, write_dataset_folder
from spotlessgs.cli import main
from spotlessgs.io.dataset import read_dataset
from spotlessgs.io.errors import InputError
from spotlessgs.io.images import read_image, write_png
from spotlessgs.prepare import SUMMARY_FILE, prepare_images


@pytest.fixture(scope="module")
def room(tmp_path_factory):
    """16 spotlit frames of the ray-cast room (240 x 180) with their true poses."""
    root = tmp_path_factory.mktemp("prepare") / "room"
    write_dataset_folder(render_room_sequence(num_frames=16, width=240, height=180, seed=0), root, with_depth=False)
    return root


def test_frames_become_a_dataset_with_poses_close_to_the_truth(room, tmp_path):
    out = tmp_path / "data"
    result = CliRunner().invoke(main, ["prepare", "--images", str(room / "images"), "--out", str(out), "--camera-model",
                                       "PINHOLE", "--matcher", "exhaustive", "--truth", str(room), "-q"])
    assert result.exit_code == 0, result.output + repr(result.exception)
    assert "16 of 16 frames registered" in result.output
    summary = json.loads((out / SUMMARY_FILE).read_text())
    assert summary["registered"] == 16 and summary["not_registered"] == []
    truth = read_dataset(room).intrinsics
    assert summary["camera"]["fx"] == pytest.approx(truth.fx, rel=0.05)  # estimated by bundle adjustment
    assert summary["pose_error"]["poses"] == 16 and summary["pose_error"]["ate_rmse_m"] < 0.02
    assert summary["brightening"]["blur_sigma_px"] == 0.0  # clean renders: no blur against noise
    data = read_dataset(out)  # the trainer's reader: images/ + sparse/0
    assert data.n_frames == 16 and data.intrinsics.is_pinhole
    for path in data.image_paths[:3]:  # the originals, not the brightened copies SfM saw
        np.testing.assert_array_equal(read_image(path), read_image(room / "images" / path.name))
        assert not np.array_equal(read_image(path), read_image(out / "sfm" / "input" / path.name))


def test_noise_level_measures_the_added_noise_and_decides_the_blur():
    """Immerkær's estimate of Gaussian noise (std 0.02) on a smooth image is 0.02 within 5 %, and it reads a smooth
    image as nearly noise-free; frames blur before brightening only from NOISY_FRAMES on."""
    from spotlessgs.io.frame_quality import noise_level
    from spotlessgs.prepare.images import DENOISE_SIGMA_PX, NOISY_FRAMES, brighten, brightening_blur

    y, x = np.mgrid[0:120, 0:160] / 160.0
    smooth = np.repeat((0.2 + 0.5 * x * y + 0.1 * np.sin(4 * x))[..., None], 3, axis=2).astype(np.float32)
    noise = np.random.default_rng(0).normal(0.0, 0.02, smooth.shape[:2])[..., None].astype(np.float32)
    noisy = np.clip(smooth + noise, 0, 1)
    assert noise_level(smooth) < 0.001
    assert noise_level(noisy) == pytest.approx(0.02, rel=0.05)
    assert brightening_blur([smooth] * 3) == (pytest.approx(noise_level(smooth)), 0.0)
    level, blur = brightening_blur([noisy, noisy, smooth])  # the median frame decides
    assert level >= NOISY_FRAMES and blur == DENOISE_SIGMA_PX
    # the blur takes the noise down before CLAHE lifts it
    assert noise_level(brighten(noisy, blur)) < 0.6 * noise_level(brighten(noisy))


def test_a_frame_that_does_not_register_is_named(room, tmp_path):
    frames = tmp_path / "frames"
    shutil.copytree(room / "images", frames)
    rng = np.random.default_rng(0)
    write_png(frames / "frame_00016.png", rng.uniform(0, 1, (180, 240, 3)))  # noise: matches nothing
    summary = prepare_images(frames, tmp_path / "data", camera_model="PINHOLE", matcher="exhaustive",
                             intrinsics=read_dataset(room).intrinsics)
    assert summary["not_registered"] == ["frame_00016.png"] and summary["registered"] == 16
    assert "frame_00016.png" not in {p.name for p in read_dataset(tmp_path / "data").image_paths}


def test_prepare_writes_only_into_its_own_folder_and_replaces_its_earlier_posed_dataset(room, tmp_path):
    """A folder of another tool's files is refused before anything is written (its transforms.json and images
    would be overwritten); an earlier prepare's posed dataset (a bag with odometry) is replaced by the new SfM model
    (its transforms.json was read instead, with the old camera); a second prepare into the folder is locked out."""
    from spotlessgs.io.errors import FolderLockedError

    theirs = tmp_path / "theirs"
    (theirs / "images").mkdir(parents=True)
    (theirs / "transforms.json").write_text('{"frames": []}')
    with pytest.raises(InputError, match=r"theirs: holds files but no prepare\.json or \.spotless_prepare\.json "
                                         r"\(images, transforms\.json\): not a dataset that `spotless prepare` began"):
        prepare_images(room / "images", theirs)
    assert sorted(p.name for p in theirs.iterdir()) == ["images", "transforms.json"]

    out = tmp_path / "data"
    out.mkdir()
    (out / "prepare.json").write_text("{}")  # an earlier prepare of a bag with odometry: a posed dataset
    shutil.copy(room / "transforms.json", out / "transforms.json")
    import subprocess
    import sys

    holder = subprocess.Popen([sys.executable, "-c", "import time; from spotlessgs.io.folder_lock import folder_lock\n"
                               f"with folder_lock({str(out)!r}, 'another prepare'):\n"
                               "    print('held', flush=True); time.sleep(60)"], stdout=subprocess.PIPE, text=True)
    try:
        assert holder.stdout.readline().strip() == "held"
        with pytest.raises(FolderLockedError, match="another prepare"):
            prepare_images(room / "images", out)
    finally:
        holder.kill()
        holder.wait()
    prepare_images(room / "images", out, camera_model="PINHOLE", intrinsics=read_dataset(room).intrinsics)
    assert not (out / "transforms.json").exists() and (out / "sparse" / "0").is_dir()
    assert read_dataset(out).image_paths[0].parent == out / "images"


def test_bad_frames_are_refused_naming_the_file(room, tmp_path):
    frames = tmp_path / "frames"
    frames.mkdir()
    for name in ("frame_00000.png", "frame_00001.png"):
        shutil.copy(room / "images" / name, frames / name)
    (frames / "frame_00002.png").write_bytes(b"not a png")
    with pytest.raises(InputError, match=r"frame_00002\.png: cannot be decoded"):
        prepare_images(frames, tmp_path / "a")
    write_png(frames / "frame_00002.png", np.zeros((90, 120, 3)))
    with pytest.raises(InputError, match=r"frame_00002\.png: image is 120x90, the first frame frame_00000\.png is "
                                         r"240x180"):
        prepare_images(frames, tmp_path / "b")
    with pytest.raises(InputError, match="--out"):
        prepare_images(frames, frames / "inside")
    shutil.copy(room / "images" / "frame_00001.png", frames / "frame_00002.png")
    write_png(frames / "frame_00001.jpg", np.zeros((180, 240, 3)))  # its PNG copy would be frame_00001.png
    with pytest.raises(InputError, match=r"frames: frame_00001\.jpg and frame_00001\.png would both become "
                                         r"frame_00001\.png in the dataset \(up to letter case\); rename one of them"):
        prepare_images(frames, tmp_path / "a")
    (frames / "frame_00001.jpg").rename(frames / "FRAME_00001.jpg")  # one file on macOS and Windows
    with pytest.raises(InputError, match=r"FRAME_00001\.jpg and frame_00001\.png would both become frame_00001\.png "
                                         r"in the dataset \(up to letter case\)"):
        prepare_images(frames, tmp_path / "a")
    assert not (tmp_path / "a").exists() and not (tmp_path / "b").exists()  # nothing written before the checks


def test_the_darkgs_layout_trains_on_its_linear_raw_frames(room, tmp_path):
    """DarkGS keeps COLMAP's brightened frames in input/ (or images/) and the linear frames it trains on in raw/."""
    from spotlessgs.io.colmap_text import model_from_poses, write_colmap_text
    from spotlessgs.io.colorspace import srgb_to_linear
    from spotlessgs.training.data import load_training_views

    source = read_dataset(room)
    folder = tmp_path / "darkgs"
    names = [p.name for p in source.image_paths]
    write_colmap_text(folder / "sparse" / "0", model_from_poses(source.intrinsics, names, source.c2w_opengl))
    linear = []
    for path in source.image_paths:
        image = srgb_to_linear(read_image(path))
        linear.append(np.round(image * 65535) / 65535)
        (folder / "raw").mkdir(parents=True, exist_ok=True)  # 16-bit linear RGB, as a RAW converter writes it
        cv2.imwrite(str(folder / "raw" / path.name), np.round(image * 65535).astype(np.uint16)[..., ::-1])
        write_png(folder / "input" / path.name, np.clip(4 * image, 0, 1))  # what COLMAP saw
    data = read_dataset(folder)
    assert data.meta["source_format"] == "darkgs" and data.image_paths[0] == folder / "raw" / names[0]
    views = load_training_views(folder)  # linear already: not linearised a second time
    np.testing.assert_allclose(views.images[3].numpy(), linear[3], atol=1e-6)
    (folder / "raw" / names[5]).unlink()
    with pytest.raises(InputError, match=rf"raw: no linear frame\(s\) for the registered image {names[5]}"):
        read_dataset(folder)


@pytest.mark.parametrize("model, hint", [("SIMPLE_RADIAL", "PINHOLE"), ("OPENCV", "SIMPLE_RADIAL")])
def test_a_lens_that_cannot_be_used_names_a_simpler_model(room, tmp_path, monkeypatch, model, hint):
    """When the estimated lens folds the image, the error names a camera model with fewer lens parameters than the
    one asked for (never the same one), and the summary keeps the error."""
    import spotlessgs.prepare.images as prepare_module

    def folded(_out):
        raise InputError("cameras.bin: COLMAP camera 1: the opencv distortion [-0.3, 0, 0, 0] cannot be inverted")

    monkeypatch.setattr(prepare_module, "read_dataset", folded)
    with pytest.raises(InputError, match=f"estimated a {model} camera that cannot be used .* such as {hint}$"):
        prepare_images(room / "images", tmp_path / "data", camera_model=model)
    assert "cannot be inverted" in json.loads((tmp_path / "data" / SUMMARY_FILE).read_text())["error"]


def test_brightened_copies_are_reused_only_for_the_same_frame_and_blur(tmp_path):
    """Resuming reuses a copy made from the same file with the same blur; a frame replaced under the same name (or
    another blur) is brightened again, and a damaged record only costs a rebrightening."""
    from spotlessgs.prepare.images import COPIES_RECORD, brighten, write_brightened_copies

    frames, copies = tmp_path / "frames", tmp_path / "copies"
    frames.mkdir()
    rng = np.random.default_rng(0)
    for name in ("a.png", "b.png"):
        write_png(frames / name, rng.uniform(0, 0.3, (24, 32, 3)))
    sources = [(name, frames / name) for name in ("a.png", "b.png")]
    reads = []

    def read(path):
        reads.append(path.name)
        return read_image(path)

    write_brightened_copies(copies, sources, read, 0.0)
    assert reads == ["a.png", "b.png"]
    np.testing.assert_allclose(read_image(copies / "a.png"), brighten(read_image(frames / "a.png")), atol=1 / 255)
    write_brightened_copies(copies, sources, read, 0.0)  # a rerun: nothing to do
    assert reads == ["a.png", "b.png"]
    write_png(frames / "b.png", rng.uniform(0, 0.3, (24, 32, 3)))  # the same name, another frame
    os.utime(frames / "b.png", ns=(1, 1))  # a modification time of its own even on a coarse clock
    write_brightened_copies(copies, sources, read, 0.0)
    assert reads == ["a.png", "b.png", "b.png"]
    np.testing.assert_allclose(read_image(copies / "b.png"), brighten(read_image(frames / "b.png")), atol=1 / 255)
    write_brightened_copies(copies, sources, read, 1.0)  # another blur: every copy again
    assert reads[3:] == ["a.png", "b.png"]
    (copies / COPIES_RECORD).write_text("{damaged")
    write_brightened_copies(copies, sources, read, 1.0)
    assert reads[5:] == ["a.png", "b.png"]
