"""Tests of the shared dataset I/O: cameras, sRGB, images, EXR, PLY, COLMAP models, transforms.json, point clouds."""

from __future__ import annotations

import dataclasses
import json
import math
import re
import struct
import zlib
from pathlib import Path

import numpy as np
import OpenEXR
import pycolmap
import pytest
import torch
from PIL import Image
from plyfile import PlyData, PlyElement
from scipy.spatial.transform import Rotation

from simulator.pointcloud import Points, backproject_depth, merge_point_clouds
from spotlessgs.io.camera_batch import Cameras
from spotlessgs.io.cameras import (
    Intrinsics,
    axis_angle_to_matrix,
    matrix_to_quaternion_wxyz,
    opencv_to_opengl_c2w,
    opengl_to_opencv_c2w,
    quaternion_wxyz_to_matrix,
    world_to_camera,
)
from spotlessgs.io.colmap_text import (
    ColmapCamera,
    model_from_poses,
    read_colmap_binary,
    read_colmap_model,
    read_colmap_text,
    write_colmap_text,
)
from spotlessgs.io.colorspace import linear_to_srgb, srgb_to_linear, to_uint8
from spotlessgs.io.dataset import load_initial_points, read_colmap_dataset, read_dataset
from spotlessgs.io.errors import InputError
from spotlessgs.io.exr import FrameEXR, blender_depth_to_planar, read_exr, read_frame_exr, write_exr, write_frame_exr
from spotlessgs.io.images import IMAGE_SUFFIXES, is_image_name, list_image_files, read_image, write_png
from spotlessgs.io.ply import read_point_cloud, write_point_cloud
from spotlessgs.io.transforms import (
    DatasetError,
    DatasetMeta,
    FrameRecord,
    LightTruth,
    read_transforms,
    split_indices,
    write_transforms,
)


def random_poses(n: int, seed: int = 0) -> np.ndarray:
    """(n, 4, 4) random rigid camera-to-world matrices."""
    rng = np.random.default_rng(seed)
    poses = np.tile(np.eye(4), (n, 1, 1))
    poses[:, :3, :3] = Rotation.random(n, random_state=seed).as_matrix()
    poses[:, :3, 3] = rng.normal(0, 2, (n, 3))
    return poses


# --------------------------------------------------------------------------------------------------- cameras


def test_intrinsics_from_fov_K_and_scaled():
    intr = Intrinsics.from_fov(90.0, 640, 480)
    assert intr.fx == pytest.approx(320.0) and intr.fy == pytest.approx(320.0)  # tan(45 deg) = 1
    assert (intr.cx, intr.cy) == (320.0, 240.0)
    assert intr.h_fov_deg == pytest.approx(90.0)
    np.testing.assert_allclose(intr.K(), [[320, 0, 320], [0, 320, 240], [0, 0, 1]])
    half = Intrinsics(500.0, 510.0, 319.5, 241.0, 640, 480).scaled(0.5)
    assert half == Intrinsics(250.0, 255.0, 159.75, 120.5, 320, 240)
    odd = Intrinsics(100.0, 100.0, 50.5, 40.5, 101, 81).scaled(0.5)  # 50.5 -> 51 (round half to even -> 50)
    assert (odd.width, odd.height) == (50, 40)
    assert odd.fx == pytest.approx(100 * 50 / 101) and odd.cy == pytest.approx(40.5 * 40 / 81)


@pytest.mark.parametrize(
    "kwargs, match",
    [
        (dict(fx=0.0, fy=1.0, cx=0.0, cy=0.0, width=2, height=2), "focal lengths must be positive"),
        (dict(fx=1.0, fy=1.0, cx=math.nan, cy=0.0, width=2, height=2), "cx must be finite"),
        (dict(fx=1.0, fy=1.0, cx=0.0, cy=0.0, width=2.5, height=2), "positive integers"),
        (dict(fx=1.0, fy=1.0, cx=0.0, cy=0.0, width=2, height=0), "positive integers"),
    ],
)
def test_intrinsics_validation(kwargs, match):
    with pytest.raises(ValueError, match=match):
        Intrinsics(**kwargs)


def test_intrinsics_fov_and_scale_errors():
    with pytest.raises(ValueError, match=r"field of view must be in \(0, 180\)"):
        Intrinsics.from_fov(180.0, 10, 10)
    with pytest.raises(ValueError, match="factor must be positive"):
        Intrinsics.from_fov(60.0, 10, 10).scaled(0.0)


def test_camera_convention_conversions_and_view_matrix():
    c2w = random_poses(5)
    cv = opengl_to_opencv_c2w(c2w)
    np.testing.assert_allclose(cv[:, :3, 0], c2w[:, :3, 0])  # x right in both
    np.testing.assert_allclose(cv[:, :3, 1], -c2w[:, :3, 1])  # y up -> y down
    np.testing.assert_allclose(cv[:, :3, 2], -c2w[:, :3, 2])  # looks along -z -> along +z
    np.testing.assert_array_equal(cv[:, :3, 3], c2w[:, :3, 3])
    np.testing.assert_array_equal(opencv_to_opengl_c2w(cv), c2w)
    np.testing.assert_allclose(world_to_camera(c2w), np.linalg.inv(c2w), atol=1e-12)
    np.testing.assert_allclose(world_to_camera(c2w[0]), np.linalg.inv(c2w[0]), atol=1e-12)
    with pytest.raises(ValueError, match=r"expected a \(4, 4\) or \(N, 4, 4\) array, got shape \(3, 4\)"):
        world_to_camera(np.eye(4)[:3])
    with pytest.raises(ValueError, match="opengl_to_opencv_c2w"):
        opengl_to_opencv_c2w(np.zeros((2, 3, 3)))


def test_rotation_helpers_against_scipy():
    rotvecs = np.concatenate([
        np.random.default_rng(3).normal(0, 1.5, (50, 3)),
        [[0, 0, 0], [1e-7, 0, 0], [math.pi, 0, 0], [0, math.pi, 0], [0, 0, math.pi], [2, -2, 1]],
    ])
    expected = Rotation.from_rotvec(rotvecs).as_matrix()
    np.testing.assert_allclose(axis_angle_to_matrix(rotvecs), expected, atol=1e-12)
    quats = matrix_to_quaternion_wxyz(expected)
    assert (quats[:, 0] >= 0).all()
    ref = Rotation.from_matrix(expected).as_quat()[:, [3, 0, 1, 2]]  # scipy is xyzw
    ref *= np.where(ref[:, :1] < 0, -1.0, 1.0)
    # 180-degree rotations have w = 0, where q and -q are both canonical: compare matrices for those.
    np.testing.assert_allclose(np.abs(quats), np.abs(ref), atol=1e-12)
    np.testing.assert_allclose(quaternion_wxyz_to_matrix(quats), expected, atol=1e-12)
    with pytest.raises(ValueError, match="non-zero"):
        quaternion_wxyz_to_matrix(np.zeros(4))
    with pytest.raises(ValueError, match=r"expected \(\.\.\., 3\)"):
        axis_angle_to_matrix(np.zeros(4))


# --------------------------------------------------------------------------------------------------- colour


def test_srgb_known_values():
    assert float(linear_to_srgb(0.5)) == pytest.approx(0.735357, abs=5e-7)
    assert float(srgb_to_linear(0.5)) == pytest.approx(0.214041, abs=5e-7)
    assert float(linear_to_srgb(0.0031308)) == pytest.approx(0.04044994, abs=1e-8)  # end of the linear segment
    assert float(linear_to_srgb(0.002)) == pytest.approx(0.02584, abs=1e-12)  # 12.92 * 0.002
    assert float(srgb_to_linear(0.04)) == pytest.approx(0.04 / 12.92, abs=1e-15)
    assert float(srgb_to_linear(0.8)) == pytest.approx(((0.8 + 0.055) / 1.055) ** 2.4, abs=1e-15)
    np.testing.assert_array_equal(linear_to_srgb(np.array([-0.5, 0.0, 1.0, 3.0])), [0.0, 0.0, 1.0, 1.0])  # clipped
    x = np.linspace(0, 1, 1001)
    np.testing.assert_allclose(srgb_to_linear(linear_to_srgb(x)), x, atol=1e-12)
    y = np.linspace(0, 1, 7, dtype=np.float32).reshape(1, 7, 1)
    assert linear_to_srgb(y).dtype == np.float32 and linear_to_srgb(y).shape == (1, 7, 1)
    assert srgb_to_linear(np.array([0, 255], dtype=np.uint8) / 255.0)[1] == 1.0


def test_srgb_on_torch_tensors_matches_numpy_and_has_finite_gradients():
    import torch

    x = np.linspace(-0.1, 1.1, 1201)
    for fn in (srgb_to_linear, linear_to_srgb):
        got = fn(torch.from_numpy(x))
        assert isinstance(got, torch.Tensor) and got.dtype == torch.float64
        np.testing.assert_allclose(got.numpy(), fn(x), rtol=0, atol=1e-15)  # one formula (pow may differ by 1 ulp)
        assert fn(torch.from_numpy(x).float()).dtype == torch.float32
    assert srgb_to_linear(torch.tensor([0, 255], dtype=torch.uint8))[1] == 1.0  # integers become float64, then clip
    assert float(srgb_to_linear(torch.tensor(0.5, dtype=torch.float64))) == pytest.approx(0.214041, abs=5e-7)
    y = torch.linspace(0, 1, 1001, dtype=torch.float64)
    assert torch.allclose(linear_to_srgb(srgb_to_linear(y)), y, atol=1e-12)
    for fn in (srgb_to_linear, linear_to_srgb):
        t = torch.tensor([0.0, 0.002, 0.04045, 0.5, 1.0], dtype=torch.float64, requires_grad=True)
        fn(t).sum().backward()
        assert torch.isfinite(t.grad).all() and (t.grad[:4] > 0).all()


def test_to_uint8_rounds_and_clips():
    np.testing.assert_array_equal(to_uint8(np.array([-0.2, 0.0, 0.5, 1 / 255, 0.9999, 1.3])), [0, 0, 128, 1, 255, 255])
    np.testing.assert_array_equal(to_uint8(np.array([0.4 / 255, 0.6 / 255])), [0, 1])
    with pytest.raises(ValueError, match="NaN"):
        to_uint8(np.array([np.nan]))


# --------------------------------------------------------------------------------------------------- images


def _png16(path: Path, data: np.ndarray, filters: list[int]) -> None:
    """Write a 16-bit PNG (grey/grey+alpha/RGB/RGBA) with the given per-row filter types, independently of Pillow."""
    h, w, c = data.shape
    bpp = 2 * c
    rows, prev = [], np.zeros(w * bpp, np.int32)
    for i in range(h):
        raw = np.frombuffer(data[i].astype(">u2").tobytes(), np.uint8).astype(np.int32)
        left = np.concatenate([np.zeros(bpp, np.int32), raw[:-bpp]])
        up_left = np.concatenate([np.zeros(bpp, np.int32), prev[:-bpp]])
        kind = filters[i % len(filters)]
        if kind == 0:
            enc = raw
        elif kind == 1:
            enc = raw - left
        elif kind == 2:
            enc = raw - prev
        elif kind == 3:
            enc = raw - ((left + prev) >> 1)
        else:
            p = left + prev - up_left
            pa, pb, pc = abs(p - left), abs(p - prev), abs(p - up_left)
            enc = raw - np.where((pa <= pb) & (pa <= pc), left, np.where(pb <= pc, prev, up_left))
        rows.append(bytes([kind]) + (enc & 255).astype(np.uint8).tobytes())
        prev = raw

    def chunk(kind: bytes, body: bytes) -> bytes:
        return struct.pack(">I", len(body)) + kind + body + struct.pack(">I", zlib.crc32(kind + body) & 0xFFFFFFFF)

    colour_type = {1: 0, 2: 4, 3: 2, 4: 6}[c]
    ihdr = struct.pack(">IIBBBBB", w, h, 16, colour_type, 0, 0, 0)
    body = chunk(b"IHDR", ihdr) + chunk(b"IDAT", zlib.compress(b"".join(rows))) + chunk(b"IEND", b"")
    path.write_bytes(b"\x89PNG\r\n\x1a\n" + body)


def test_png_round_trip_8bit(tmp_path):
    rng = np.random.default_rng(0)
    img = rng.integers(0, 256, (7, 9, 3), dtype=np.uint8)
    write_png(tmp_path / "a" / "x.png", img)
    np.testing.assert_array_equal(read_image(tmp_path / "a" / "x.png") * 255.0, img.astype(np.float32))
    assert read_image(tmp_path / "a" / "x.png").dtype == np.float32
    write_png(tmp_path / "f.png", img / 255.0)
    np.testing.assert_array_equal(np.asarray(Image.open(tmp_path / "f.png")), img)
    assert not list(tmp_path.glob("**/.*"))  # no temporary files left behind


@pytest.mark.parametrize("channels", [3, 4, 2])
def test_read_16bit_colour_png_exactly(tmp_path, channels):
    data = np.random.default_rng(channels).integers(0, 65536, (6, 5, channels)).astype(np.uint16)
    _png16(tmp_path / "x.png", data, filters=[0, 1, 2, 3, 4])
    img = read_image(tmp_path / "x.png")
    expected = data[:, :, :3] if channels >= 3 else np.repeat(data[:, :, :1], 3, axis=2)
    np.testing.assert_array_equal(img, expected.astype(np.float32) / 65535.0)


def test_read_grey_alpha_and_jpeg(tmp_path):
    grey16 = (np.arange(12).reshape(3, 4) * 5000).astype(np.uint16)
    Image.fromarray(grey16).save(tmp_path / "g16.png")
    np.testing.assert_array_equal(read_image(tmp_path / "g16.png")[:, :, 1], grey16 / np.float32(65535.0))
    grey8 = np.arange(12, dtype=np.uint8).reshape(3, 4) * 20
    Image.fromarray(grey8).save(tmp_path / "g8.png")
    img = read_image(tmp_path / "g8.png")
    assert img.shape == (3, 4, 3) and (img[:, :, 0] == img[:, :, 2]).all()
    rgba = np.random.default_rng(1).integers(0, 256, (3, 4, 4), dtype=np.uint8)
    Image.fromarray(rgba, mode="RGBA").save(tmp_path / "a.png")
    np.testing.assert_array_equal(read_image(tmp_path / "a.png"), rgba[:, :, :3] / np.float32(255.0))
    smooth = np.tile(np.linspace(0, 255, 16, dtype=np.uint8), (16, 1))
    Image.fromarray(np.stack([smooth] * 3, -1)).save(tmp_path / "j.jpg", quality=95)
    assert np.abs(read_image(tmp_path / "j.jpg") - smooth[:, :, None] / 255.0).max() < 0.03


@pytest.mark.parametrize("channels", [4, 2])
def test_alpha_over_black_on_16bit_png(tmp_path, channels):
    data = np.random.default_rng(10 + channels).integers(0, 65536, (4, 5, channels)).astype(np.uint16)
    _png16(tmp_path / "x.png", data, filters=[0, 4])
    img = read_image(tmp_path / "x.png", alpha="over_black")
    colour = data[:, :, :3] if channels == 4 else np.repeat(data[:, :, :1], 3, axis=2)
    expected = (colour.astype(np.float64) / 65535.0) * (data[:, :, -1:].astype(np.float64) / 65535.0)
    np.testing.assert_allclose(img, expected, atol=1e-7)


def test_alpha_over_black_on_8bit_rgba_grey_alpha_and_palette(tmp_path):
    rgba = np.zeros((2, 2, 4), np.uint8)
    rgba[..., :3] = 200
    rgba[..., 3] = [[255, 0], [51, 255]]  # alpha 1, 0, 0.2, 1
    Image.fromarray(rgba, "RGBA").save(tmp_path / "a.png")
    by_hand = np.array([[200 / 255, 0.0], [200 / 255 * 0.2, 200 / 255]])
    np.testing.assert_allclose(read_image(tmp_path / "a.png", alpha="over_black")[..., 0], by_hand, atol=1e-6)
    np.testing.assert_allclose(read_image(tmp_path / "a.png")[..., 0], 200 / 255, atol=1e-7)  # default: dropped
    Image.fromarray(rgba[..., [0, 3]], "LA").save(tmp_path / "la.png")
    got = read_image(tmp_path / "la.png", alpha="over_black")
    np.testing.assert_allclose(got, np.repeat(by_hand[..., None], 3, axis=2), atol=1e-6)
    pal = Image.fromarray(np.full((2, 2, 3), [10, 20, 30], np.uint8)).convert("P", palette=Image.ADAPTIVE)
    pal.save(tmp_path / "p.png")
    np.testing.assert_allclose(read_image(tmp_path / "p.png", alpha="over_black")[1, 1], np.array([10, 20, 30]) / 255)
    with pytest.raises(ValueError, match=r"alpha must be one of \('drop', 'over_black'\), got 'white'"):
        read_image(tmp_path / "a.png", alpha="white")


def test_32bit_integer_image_outside_16bit_range_is_refused(tmp_path):
    Image.fromarray(np.array([[0, 70000]], np.int32), "I").save(tmp_path / "i.tiff")
    with pytest.raises(ValueError, match=r"i.tiff: 32-bit integer image with values outside \[0, 65535\]"):
        read_image(tmp_path / "i.tiff")
    Image.fromarray(np.array([[0, 65535]], np.int32), "I").save(tmp_path / "ok.tiff")
    np.testing.assert_array_equal(read_image(tmp_path / "ok.tiff")[0, :, 0], [0.0, 1.0])
    Image.fromarray(np.zeros((2, 2), np.float32), "F").save(tmp_path / "f.tiff")
    with pytest.raises(ValueError, match="f.tiff: unsupported image mode 'F'"):
        read_image(tmp_path / "f.tiff")


def test_list_image_files_skips_or_refuses_other_files(tmp_path):
    folder = tmp_path / "imgs"
    for name in ("b.PNG", "a.jpg", "c.webp", ".hidden.png", "notes.txt"):
        (folder / name).parent.mkdir(exist_ok=True)
        (folder / name).write_bytes(b"")  # only names matter when listing
    (folder / "sub.png").mkdir()
    assert [p.name for p in list_image_files(folder)] == ["a.jpg", "b.PNG", "c.webp"]
    assert list_image_files(folder)[0] == folder / "a.jpg"
    assert is_image_name("X.JPEG") and not is_image_name("x.exr") and ".tiff" in IMAGE_SUFFIXES
    with pytest.raises(ValueError, match=r"imgs: non-image files found: notes.txt; expected only .png, .jpg"):
        list_image_files(folder, non_images="error")
    with pytest.raises(FileNotFoundError, match="nope: image folder not found"):
        list_image_files(tmp_path / "nope")
    (tmp_path / "empty").mkdir()
    (tmp_path / "empty" / "readme.md").write_text("x")
    with pytest.raises(ValueError, match=r"empty: no image files \(.png, .jpg, .jpeg, .tif"):
        list_image_files(tmp_path / "empty")
    with pytest.raises(ValueError, match="non_images must be 'skip' or 'error', got 'keep'"):
        list_image_files(folder, non_images="keep")


def test_image_errors(tmp_path):
    with pytest.raises(FileNotFoundError, match="missing.png: image file not found"):
        read_image(tmp_path / "missing.png")
    (tmp_path / "junk.png").write_bytes(b"this is not an image")
    with pytest.raises(ValueError, match="junk.png: cannot decode image"):
        read_image(tmp_path / "junk.png")

    def chunk(kind: bytes, body: bytes) -> bytes:
        return struct.pack(">I", len(body)) + kind + body + struct.pack(">I", zlib.crc32(kind + body))

    header = struct.pack(">IIBBBBB", 20000, 20000, 8, 2, 0, 0, 0)  # says 20000x20000 RGB: a decompression bomb
    (tmp_path / "huge.png").write_bytes(b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", header)
                                        + chunk(b"IDAT", zlib.compress(b"")) + chunk(b"IEND", b""))
    with pytest.raises(ValueError, match="huge.png: cannot decode image .*decompression bomb"):
        read_image(tmp_path / "huge.png")
    # the 16-bit colour PNGs that OpenCV decodes (bypassing Pillow's check) are refused from their header too
    header16 = struct.pack(">IIBBBBB", 20000, 20000, 16, 2, 0, 0, 0)
    (tmp_path / "huge16.png").write_bytes(b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", header16)
                                          + chunk(b"IDAT", zlib.compress(b"")) + chunk(b"IEND", b""))
    with pytest.raises(ValueError, match=r"huge16.png: cannot decode image \(20000x20000 = 400000000 pixels exceeds "
                                         r"the limit .*decompression bomb"):
        read_image(tmp_path / "huge16.png")
    with pytest.raises(ValueError, match=r"o.png: write_png expects an \(H, W, 3\) image, got shape \(4, 4\)"):
        write_png(tmp_path / "o.png", np.zeros((4, 4)))
    with pytest.raises(ValueError, match="o.png: write_png image contains NaN"):
        write_png(tmp_path / "o.png", np.full((2, 2, 3), np.nan))
    with pytest.raises(ValueError, match="uint8 or float data, got int32"):
        write_png(tmp_path / "o.png", np.zeros((2, 2, 3), np.int32))
    assert not (tmp_path / "o.png").exists()


# --------------------------------------------------------------------------------------------------- EXR


def test_exr_round_trip_with_inf_nan_and_half(tmp_path):
    rng = np.random.default_rng(0)
    depth = rng.uniform(0.1, 10, (5, 6)).astype(np.float32)
    depth[0, 0] = np.inf
    depth[1, 2] = np.nan
    chans = {
        "depth.Z": depth,
        "uneven.R": rng.normal(size=(5, 6)).astype(np.float32),
        "count": np.arange(30).reshape(5, 6),
    }
    write_exr(tmp_path / "f.exr", chans)
    back = read_exr(tmp_path / "f.exr")
    assert set(back) == set(chans)
    for name, arr in chans.items():
        np.testing.assert_array_equal(back[name], arr.astype(np.float32))
        assert back[name].dtype == np.float32
    write_exr(tmp_path / "h.exr", {"a": depth}, half=True, compression="piz")
    np.testing.assert_array_equal(read_exr(tmp_path / "h.exr")["a"], depth.astype(np.float16).astype(np.float32))


def test_exr_multipart_blender_layout(tmp_path):
    rng = np.random.default_rng(1)
    z = rng.uniform(1, 2, (4, 3)).astype(np.float32)
    r = rng.uniform(0, 1, (4, 3)).astype(np.float32)
    def header():  # a fresh dict per part: OpenEXR.Part stores the part name in it
        return {"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage}

    parts = [
        OpenEXR.Part(header(), {"ViewLayer.Depth.Z": z}, "ViewLayer.Depth"),  # Blender: full names inside the part
        OpenEXR.Part(header(), {"R": r, "G": r + 1, "B": r + 2}, "uneven"),  # short names: prefixed by the part name
    ]
    OpenEXR.File(parts).write(str(tmp_path / "mp.exr"))
    back = read_exr(tmp_path / "mp.exr")
    assert set(back) == {"ViewLayer.Depth.Z", "uneven.R", "uneven.G", "uneven.B"}
    np.testing.assert_array_equal(back["ViewLayer.Depth.Z"], z)
    np.testing.assert_array_equal(back["uneven.G"], r + 1)


def test_frame_exr_round_trip_and_errors(tmp_path):
    rng = np.random.default_rng(2)
    h, w = 4, 5
    normal = rng.normal(size=(h, w, 3)).astype(np.float32)
    normal /= np.linalg.norm(normal, axis=-1, keepdims=True)
    depth = rng.uniform(0.5, 4, (h, w)).astype(np.float32)
    depth[2, :] = np.inf
    frame = FrameEXR(
        uneven=rng.uniform(0, 3, (h, w, 3)).astype(np.float32),
        gt=rng.uniform(0, 1, (h, w, 3)).astype(np.float32),
        depth=depth,
        normal=normal,
    )
    write_frame_exr(tmp_path / "exr" / "frame_00000.exr", frame)
    back = read_frame_exr(tmp_path / "exr" / "frame_00000.exr")
    for name in ("uneven", "gt", "depth", "normal"):
        np.testing.assert_array_equal(getattr(back, name), getattr(frame, name))
    write_exr(tmp_path / "partial.exr", {"uneven.R": depth, "depth.Z": depth})
    with pytest.raises(ValueError, match=r"partial.exr: frame EXR lacks channels \['uneven.G', 'uneven.B', 'gt.R'"):
        read_frame_exr(tmp_path / "partial.exr")
    with pytest.raises(ValueError, match=r"FrameEXR: gt must have shape \(4, 5, 3\)"):
        FrameEXR(frame.uneven, frame.gt[:, :4], depth, normal)
    assert back.albedo is None and back.emission is None and back.emitters() is None  # a file from before the passes
    # the albedo and emission passes round-trip; emitters: pixels at least half emitted light
    gt = np.full((h, w, 3), 0.5, np.float32)
    emission = np.zeros((h, w, 3), np.float32)
    emission[0, 0] = 3.0  # a lamp brighter than the (denoised) ground truth
    emission[1, 1] = 0.25  # exactly half
    emission[3, 4] = 0.2  # bounce-lit surface with a faint glow
    passes = FrameEXR(frame.uneven, gt, depth, normal, albedo=np.full((h, w, 3), 0.3, np.float32), emission=emission)
    write_frame_exr(tmp_path / "passes.exr", passes)
    again = read_frame_exr(tmp_path / "passes.exr")
    np.testing.assert_array_equal(again.albedo, passes.albedo)
    np.testing.assert_array_equal(again.emission, emission)
    assert sorted(zip(*np.nonzero(again.emitters()))) == [(0, 0), (1, 1)]
    with pytest.raises(ValueError, match=r"FrameEXR: albedo must have shape \(4, 5, 3\)"):
        FrameEXR(frame.uneven, gt, depth, normal, albedo=np.zeros((h, w), np.float32))


def test_blender_depth_background_becomes_inf():
    depth = np.array([[3.0, 1e10], [2.5e9, 999.0]], np.float32)
    np.testing.assert_array_equal(blender_depth_to_planar(depth), [[3.0, np.inf], [np.inf, 999.0]])
    assert depth[0, 1] == 1e10  # input untouched


def test_exr_errors(tmp_path):
    with pytest.raises(ValueError, match="needs at least one channel"):
        write_exr(tmp_path / "a.exr", {})
    with pytest.raises(ValueError, match=r"channel 'b' has shape \(2, 3\), other channels have \(2, 2\)"):
        write_exr(tmp_path / "a.exr", {"a": np.zeros((2, 2)), "b": np.zeros((2, 3))})
    with pytest.raises(ValueError, match=r"channel 'a' must be a non-empty \(H, W\) array"):
        write_exr(tmp_path / "a.exr", {"a": np.zeros((2, 2, 3))})
    with pytest.raises(ValueError, match="unknown EXR compression 'lzw'"):
        write_exr(tmp_path / "a.exr", {"a": np.zeros((2, 2))}, compression="lzw")
    with pytest.raises(ValueError, match="unsupported dtype"):
        write_exr(tmp_path / "a.exr", {"a": np.array([["x"]])})
    with pytest.raises(FileNotFoundError, match="nope.exr: EXR file not found"):
        read_exr(tmp_path / "nope.exr")
    (tmp_path / "fake.exr").write_bytes(b"not an exr at all")
    with pytest.raises(ValueError, match="fake.exr: not an OpenEXR file"):
        read_exr(tmp_path / "fake.exr")
    z = np.zeros((2, 2), np.float32)
    parts = [OpenEXR.Part({}, {"a.b.Z": z}, "a"), OpenEXR.Part({}, {"Z": z}, "a.b")]  # both read as 'a.b.Z'
    OpenEXR.File(parts).write(str(tmp_path / "dup.exr"))
    with pytest.raises(ValueError, match="channel name 'a.b.Z' occurs twice"):
        read_exr(tmp_path / "dup.exr")


# --------------------------------------------------------------------------------------------------- PLY


def test_ply_round_trip_and_layout(tmp_path):
    rng = np.random.default_rng(0)
    xyz = rng.normal(size=(50, 3)).astype(np.float32)
    rgb = rng.integers(0, 256, (50, 3), dtype=np.uint8)
    normals = rng.normal(size=(50, 3)).astype(np.float32)
    write_point_cloud(tmp_path / "p.ply", xyz, rgb, normals)
    cloud = read_point_cloud(tmp_path / "p.ply")
    np.testing.assert_array_equal(cloud.xyz, xyz)
    np.testing.assert_array_equal(cloud.rgb, rgb)
    np.testing.assert_array_equal(cloud.normals, normals)
    ply = PlyData.read(str(tmp_path / "p.ply"))  # the 3DGS layout, checked with plyfile directly
    assert ply.header.splitlines()[1] == "format binary_little_endian 1.0"
    assert [p.name for p in ply["vertex"].properties] == ["x", "y", "z", "nx", "ny", "nz", "red", "green", "blue"]
    write_point_cloud(tmp_path / "q.ply", xyz.astype(np.float64), rgb, None)
    np.testing.assert_array_equal(read_point_cloud(tmp_path / "q.ply").normals, np.zeros((50, 3), np.float32))


def test_ply_errors(tmp_path):
    xyz, rgb = np.zeros((3, 3)), np.zeros((3, 3), np.uint8)
    with pytest.raises(ValueError, match=r"xyz must be \(N, 3\)"):
        write_point_cloud(tmp_path / "a.ply", np.zeros((3, 2)), rgb)
    with pytest.raises(ValueError, match=r"rgb must be \(3, 3\) like xyz"):
        write_point_cloud(tmp_path / "a.ply", xyz, rgb[:2])
    with pytest.raises(ValueError, match="rgb must be uint8, got float64"):
        write_point_cloud(tmp_path / "a.ply", xyz, rgb.astype(float))
    with pytest.raises(ValueError, match="xyz contains NaN"):
        write_point_cloud(tmp_path / "a.ply", np.full((3, 3), np.nan), rgb)
    with pytest.raises(ValueError, match="normals contain NaN"):
        write_point_cloud(tmp_path / "a.ply", xyz, rgb, np.full((3, 3), np.inf))
    with pytest.raises(FileNotFoundError, match="b.ply: PLY file not found"):
        read_point_cloud(tmp_path / "b.ply")
    verts = np.zeros(2, dtype=[("x", "f4"), ("y", "f4"), ("z", "f4")])
    PlyData([PlyElement.describe(verts, "vertex")]).write(str(tmp_path / "nocolour.ply"))
    with pytest.raises(ValueError, match=r"lacks properties \['red', 'green', 'blue'\]"):
        read_point_cloud(tmp_path / "nocolour.ply")
    verts = np.zeros(2, dtype=[("x", "f4"), ("y", "f4"), ("z", "f4"), ("red", "f4"), ("green", "u1"), ("blue", "u1")])
    PlyData([PlyElement.describe(verts, "vertex")]).write(str(tmp_path / "floatcolour.ply"))
    with pytest.raises(ValueError, match="'red' must be uchar"):
        read_point_cloud(tmp_path / "floatcolour.ply")
    (tmp_path / "junk.ply").write_bytes(b"ply\nformat nonsense\n")
    with pytest.raises(ValueError, match="junk.ply: cannot parse PLY file"):
        read_point_cloud(tmp_path / "junk.ply")


# --------------------------------------------------------------------------------------------------- COLMAP


def _model(n: int = 4):
    intr = Intrinsics(300.0, 310.0, 160.5, 119.25, 320, 240)
    c2w = random_poses(n, seed=5)
    rng = np.random.default_rng(5)
    xyz, rgb = rng.normal(size=(6, 3)), rng.integers(0, 256, (6, 3), dtype=np.uint8)
    names = [f"frame_{i:05d}.png" for i in range(n)]
    return intr, c2w, names, xyz, rgb, model_from_poses(intr, names, c2w, xyz, rgb)


def test_colmap_text_is_valid_for_pycolmap_and_round_trips(tmp_path):
    intr, c2w, names, xyz, rgb, model = _model()
    write_colmap_text(tmp_path / "sparse" / "0", model)
    rec = pycolmap.Reconstruction(str(tmp_path / "sparse" / "0"))
    assert rec.num_images() == 4 and rec.num_points3D() == 6
    cam = rec.camera(1)
    assert cam.model_name == "PINHOLE" and (cam.width, cam.height) == (320, 240)
    np.testing.assert_allclose(cam.params, [300.0, 310.0, 160.5, 119.25])
    for i in range(4):
        image = rec.image(i + 1)
        assert image.name == names[i]
        # Independent expectation: OpenCV world-to-camera = inverse of (OpenGL c2w with y, z axes flipped).
        expected = np.linalg.inv(c2w[i] @ np.diag([1.0, -1.0, -1.0, 1.0]))[:3]
        np.testing.assert_allclose(image.cam_from_world().matrix(), expected, atol=1e-12)
        xyzw = image.cam_from_world().rotation.quat  # pycolmap stores xyzw
        np.testing.assert_allclose(np.abs(xyzw[[3, 0, 1, 2]]), np.abs(model.images[i + 1].qvec), atol=1e-12)
    for pid, point in rec.points3D.items():
        np.testing.assert_array_equal(point.xyz, xyz[pid - 1])
        np.testing.assert_array_equal(point.color, rgb[pid - 1])
    back = read_colmap_text(tmp_path / "sparse" / "0")
    assert back.cameras == model.cameras
    for i, image in model.images.items():
        np.testing.assert_array_equal(back.images[i].qvec, image.qvec)
        np.testing.assert_array_equal(back.images[i].tvec, image.tvec)
        np.testing.assert_allclose(opencv_to_opengl_c2w(back.images[i].c2w_opencv()), c2w[i - 1], atol=1e-12)
    np.testing.assert_array_equal(back.points.xyz, xyz)
    np.testing.assert_array_equal(back.points.rgb, rgb)


def _pycolmap_reconstruction() -> pycolmap.Reconstruction:
    """A reconstruction built with pycolmap: 2 cameras, 3 images with keypoints, 2 points with tracks."""
    rec = pycolmap.Reconstruction()
    cam1 = pycolmap.Camera.create_from_model_name(1, "PINHOLE", 100.0, 64, 48)
    cam1.params = [100.0, 101.0, 32.0, 24.5]
    cam2 = pycolmap.Camera.create_from_model_name(2, "OPENCV", 90.0, 80, 60)
    cam2.params = [90.0, 91.0, 40.0, 30.0, 0.01, -0.02, 0.001, 0.002]
    rec.add_camera_with_trivial_rig(cam1)
    rec.add_camera_with_trivial_rig(cam2)
    for k in range(3):
        keypoints = np.array([[10.0 + k, 20.0], [30.0, 5.5 * k], [1.0, 2.0]])
        image = pycolmap.Image(name=f"img_{k}.jpg", keypoints=keypoints, camera_id=1 + k % 2, image_id=k + 1)
        pose = pycolmap.Rigid3d(pycolmap.Rotation3d(np.array([0.1 * k, 0.2, -0.3])), np.array([1.0, 2.0, 3.0 + k]))
        rec.add_image_with_trivial_frame(image, pose)
    for k, (xyz, obs) in enumerate([((0.5, 0.6, 4.0), [(1, 0), (2, 1)]), ((-1.0, 0.2, 5.0), [(2, 0), (3, 2)])]):
        track = pycolmap.Track()
        for image_id, idx in obs:
            track.add_element(image_id, idx)
        rec.add_point3D(np.array(xyz), track, np.array([10 * k, 20, 30], np.uint8))
    return rec


@pytest.mark.parametrize("fmt", ["binary", "text"])
def test_readers_match_pycolmap_written_models(tmp_path, fmt):
    rec = _pycolmap_reconstruction()
    if fmt == "binary":
        rec.write_binary(str(tmp_path))
        model = read_colmap_binary(tmp_path)
    else:
        rec.write_text(str(tmp_path))
        model = read_colmap_text(tmp_path)
    assert read_colmap_model(tmp_path).cameras == model.cameras
    assert set(model.cameras) == {1, 2}
    for cid, cam in rec.cameras.items():
        assert model.cameras[cid].model == cam.model_name
        np.testing.assert_array_equal(model.cameras[cid].params, cam.params)
        assert (model.cameras[cid].width, model.cameras[cid].height) == (cam.width, cam.height)
    assert set(model.images) == {1, 2, 3}
    for iid, image in rec.images.items():
        ours = model.images[iid]
        assert ours.name == image.name and ours.camera_id == image.camera_id
        np.testing.assert_allclose(ours.cam_from_world()[:3], image.cam_from_world().matrix(), atol=1e-12)
        np.testing.assert_array_equal(ours.xys, np.array([p.xy for p in image.points2D]))
        expected_ids = [p.point3D_id if p.has_point3D() else -1 for p in image.points2D]
        np.testing.assert_array_equal(ours.point3d_ids, expected_ids)
    for k, (pid, point) in enumerate(sorted(rec.points3D.items())):
        assert model.points.ids[k] == pid
        np.testing.assert_array_equal(model.points.xyz[k], point.xyz)
        np.testing.assert_array_equal(model.points.rgb[k], point.color)
        track = sorted((e.image_id, e.point2D_idx) for e in point.track.elements)
        assert sorted(map(tuple, model.points.tracks[k].tolist())) == track
    assert model.cameras[1].to_intrinsics() == Intrinsics(100.0, 101.0, 32.0, 24.5, 64, 48)
    assert model.cameras[2].to_intrinsics() == Intrinsics(90.0, 91.0, 40.0, 30.0, 80, 60, "opencv",
                                                          (0.01, -0.02, 0.001, 0.002))


def test_colmap_camera_models_to_intrinsics():
    assert ColmapCamera(1, "SIMPLE_PINHOLE", 10, 8, (5.0, 5.0, 4.0)).to_intrinsics() == Intrinsics(5, 5, 5, 4, 10, 8)
    assert ColmapCamera(1, "OPENCV", 10, 8, (5.0, 6.0, 5.0, 4.0, 0, 0, 0, 0)).to_intrinsics() == Intrinsics(
        5, 6, 5, 4, 10, 8)  # no distortion: a pinhole
    assert ColmapCamera(1, "SIMPLE_RADIAL", 10, 8, (5.0, 5.0, 4.0, 0.0)).to_intrinsics().is_pinhole
    # (the projections are checked against pycolmap's in test_lens.py)
    with pytest.raises(ValueError, match="model THIN_PRISM_FISHEYE is not supported"):
        ColmapCamera(3, "THIN_PRISM_FISHEYE", 10, 8, (5.0,) * 12).to_intrinsics()


def test_colmap_errors(tmp_path):
    intr, c2w, names, xyz, rgb, model = _model(2)
    with pytest.raises(ValueError, match=r"model_from_poses: expected \(2, 4, 4\) poses"):
        model_from_poses(intr, names, c2w[:1])
    with pytest.raises(FileNotFoundError, match="no COLMAP model"):
        read_colmap_model(tmp_path)
    write_colmap_text(tmp_path, model)
    good = (tmp_path / "cameras.txt").read_text()
    (tmp_path / "cameras.txt").write_text(good.replace("PINHOLE", "BANANA"))
    with pytest.raises(ValueError, match=r"cameras.txt:4: bad camera line \(unknown camera model 'BANANA'\)"):
        read_colmap_text(tmp_path)
    (tmp_path / "cameras.txt").write_text(good.replace(" 119.25", ""))
    with pytest.raises(ValueError, match="model PINHOLE needs 4 params, got 3"):
        read_colmap_text(tmp_path)
    (tmp_path / "cameras.txt").write_text(good.replace("\n1 PINHOLE", "\n7 PINHOLE"))
    with pytest.raises(ValueError, match="images.txt:5: image 1 refers to unknown camera 1"):
        read_colmap_text(tmp_path)
    (tmp_path / "cameras.txt").write_text(good)
    images = (tmp_path / "images.txt").read_text()
    (tmp_path / "images.txt").write_text(images.replace(" 1 frame_00000.png", " frame_00000.png"))
    with pytest.raises(ValueError, match="images.txt:5: bad image entry"):
        read_colmap_text(tmp_path)
    (tmp_path / "images.txt").write_text(images)
    (tmp_path / "points3D.txt").write_text("1 0.5 0.5\n")
    with pytest.raises(ValueError, match=r"points3D.txt:1: bad point line"):
        read_colmap_text(tmp_path)
    (tmp_path / "bin").mkdir()
    _pycolmap_reconstruction().write_binary(str(tmp_path / "bin"))
    data = (tmp_path / "bin" / "images.bin").read_bytes()
    (tmp_path / "bin" / "images.bin").write_bytes(data[:-7])
    with pytest.raises(ValueError, match="images.bin: truncated file"):
        read_colmap_binary(tmp_path / "bin")
    (tmp_path / "bin" / "images.bin").write_bytes(data + b"\x00")
    with pytest.raises(ValueError, match="images.bin: 1 unexpected trailing bytes"):
        read_colmap_binary(tmp_path / "bin")
    bad_name = model_from_poses(intr, ["has space.png", "b.png"], c2w)
    with pytest.raises(ValueError, match="name 'has space.png' is empty or contains whitespace"):
        write_colmap_text(tmp_path / "x", bad_name)
    # a pose that is not finite or has a zero quaternion, an id twice, a name that is not UTF-8: file and line
    lines = images.splitlines(keepends=True)
    entry = next(k for k, line in enumerate(lines) if line.startswith("1 "))
    fields = lines[entry].split(" ")
    for k, value, problem in ((7, "nan", "unusable pose"), (6, "inf", "unusable pose"), (1, "0", None)):
        damaged = fields.copy()
        damaged[k] = value
        if problem is None:  # the quaternion (w x y z) all zeros
            damaged[1:5] = ["0", "0", "0", "0"]
            problem = "unusable pose"
        (tmp_path / "images.txt").write_text("".join(lines[:entry] + [" ".join(damaged)] + lines[entry + 1:]))
        with pytest.raises(ValueError, match=rf"images.txt:{entry + 1}: image 1 has an {problem}"):
            read_colmap_text(tmp_path)
    twice = lines[entry + 2].split(" ")
    twice[0] = "1"
    (tmp_path / "images.txt").write_text("".join(lines[:entry + 2] + [" ".join(twice)] + lines[entry + 3:]))
    with pytest.raises(ValueError, match=rf"images.txt:{entry + 3}: image id 1 appears twice"):
        read_colmap_text(tmp_path)
    (tmp_path / "images.txt").write_bytes(images.replace("frame_00001.png", "fr\xe9me.png").encode("latin-1"))
    with pytest.raises(ValueError, match=rf"images.txt:{entry + 3}: not UTF-8 text"):
        read_colmap_text(tmp_path)
    (tmp_path / "images.txt").write_text(images)
    (tmp_path / "bin" / "images.bin").write_bytes(data.replace(b"img_0.jpg", b"img_\xe9.jpg", 1))
    with pytest.raises(ValueError, match="images.bin: image name at offset .* is not UTF-8"):
        read_colmap_binary(tmp_path / "bin")


# --------------------------------------------------------------------------------------------------- transforms.json


def _light() -> LightTruth:
    rot = Rotation.from_rotvec([0.05, -0.1, 0.02]).as_matrix()
    return LightTruth(np.array([0.1, -0.05, 0.02]), rot, cone_angle_deg=60.0, blend=0.3, power_w=40.0,
                      color=np.array([1.0, 0.95, 0.9]), radius_m=0.02)


def _write_dataset(root: Path, n: int = 23, meta: DatasetMeta | None = None, make_files: bool = True):
    intr = Intrinsics.from_fov(70.0, 64, 48)
    c2w = random_poses(n, seed=11)
    frames = [
        FrameRecord(f"images/frame_{i:05d}.png", c2w[i], f"gt/frame_{i:05d}.png", f"exr/frame_{i:05d}.exr")
        for i in range(n)
    ]
    if meta is None:
        meta = DatasetMeta(scene_id="house-1", room="LivingRoom-42", seed=np.int64(7), preset="tiny", light=_light(),
                           renderer={"engine": "CYCLES", "samples": 16}, provenance={"command": "spotless-sim render"})
    if make_files:
        img = np.zeros((48, 64, 3), np.uint8)
        for f in frames:
            write_png(root / f.file_path, img)
            write_png(root / f.gt_file_path, img)
            (root / f.exr_file_path).parent.mkdir(parents=True, exist_ok=True)
            (root / f.exr_file_path).write_bytes(b"")
        write_point_cloud(root / "points3D.ply", np.zeros((1, 3)), np.zeros((1, 3), np.uint8))
    write_transforms(root / "transforms.json", intr, frames, meta, ply_file_path="points3D.ply")
    return intr, c2w, frames, meta


def test_split_indices_paper_numbers():
    train, test = split_indices(316)
    assert (len(train), len(test)) == (287, 29)  # paper: 287 train / 29 test
    assert test[:3] == [0, 11, 22] and train[:3] == [1, 2, 3]
    assert split_indices(1) == ([], [0])
    with pytest.raises(ValueError, match="test_every >= 1"):
        split_indices(5, 0)


def test_transforms_round_trip_exact(tmp_path):
    intr, c2w, frames, meta = _write_dataset(tmp_path)
    desc = read_transforms(tmp_path, check_files=True)
    assert desc.intrinsics == intr
    np.testing.assert_array_equal(desc.c2w_opengl, c2w)
    np.testing.assert_array_equal(desc.c2w_opencv, c2w @ np.diag([1.0, -1.0, -1.0, 1.0]))
    np.testing.assert_allclose(desc.view_matrices(), np.linalg.inv(desc.c2w_opencv), atol=1e-12)
    assert desc.frames() == frames
    assert desc.image_paths[3] == tmp_path / "images" / "frame_00003.png"
    assert desc.gt_paths[3] == tmp_path / "gt" / "frame_00003.png"
    assert desc.exr_paths[0] == tmp_path / "exr" / "frame_00000.exr"
    assert desc.ply_path == tmp_path / "points3D.ply"
    assert desc.split.test == (0, 11, 22) and len(desc.split.train) == 20 and desc.split.rule == "every_11th"
    assert desc.light == meta.light
    np.testing.assert_array_equal(desc.light.rotation_in_camera, meta.light.rotation_in_camera)
    assert desc.meta["scene_id"] == "house-1" and desc.meta["renderer"] == {"engine": "CYCLES", "samples": 16}
    assert desc.meta["schema_version"] == 1 and desc.meta["seed"] == 7 and desc.meta["color_space"] == "srgb"
    raw = json.loads((tmp_path / "transforms.json").read_text())
    assert raw["camera_model"] == "OPENCV" and raw["k1"] == raw["k2"] == raw["p1"] == raw["p2"] == 0.0
    assert raw["frames"][0]["file_path"] == "images/frame_00000.png"
    # Rewriting what was read gives the same file, byte for byte.
    write_transforms(tmp_path / "again.json", desc.intrinsics, desc.frames(), meta, ply_file_path="points3D.ply")
    assert (tmp_path / "again.json").read_text() == (tmp_path / "transforms.json").read_text()
    no_light = DatasetMeta(scene_id="s", light=None)
    _write_dataset(tmp_path / "b", n=3, meta=no_light, make_files=False)
    assert read_transforms(tmp_path / "b" / "transforms.json").light is None


def test_light_truth_direction_and_validation():
    light = _light()
    np.testing.assert_allclose(light.direction_in_camera, light.rotation_in_camera @ [0, 0, 1])
    assert LightTruth.from_json(light.to_json()) == light
    base = light.to_json()
    for key, value, match in [
        ("cone_angle_deg", 0.0, r"cone_angle_deg: must be in \(0, 180\]"),
        ("blend", 1.5, r"blend: must be in \[0, 1\]"),
        ("power_w", -1.0, "power_w: must be positive"),
        ("radius_m", -0.1, "radius_m: must be non-negative"),
        ("color", [1, -1, 1], "color: must be non-negative"),
        ("rotation_in_camera", np.diag([1.0, 1.0, -1.0]).tolist(), "not a rotation matrix"),
        ("rotation_in_camera", [[1, 0], [0, 1]], r"expected shape \(3, 3\)"),
        ("position_in_camera", [0, 0, float("nan")], "contains NaN or inf"),
        ("power_w", "bright", "expected a finite number"),
    ]:
        with pytest.raises(DatasetError, match=match):
            LightTruth.from_json({**base, key: value}, "spotless.light")
    with pytest.raises(DatasetError, match=r"spotless.light: missing keys \['radius_m'\]"):
        LightTruth.from_json({k: v for k, v in base.items() if k != "radius_m"}, "spotless.light")


def _plain(tmp_path: Path, **overrides) -> Path:
    """A plain nerfstudio transforms.json without our block."""
    c2w = random_poses(3, seed=2)
    data = {"camera_model": "OPENCV", "fl_x": 50.0, "fl_y": 51.0, "cx": 32.0, "cy": 24.0, "w": 64, "h": 48,
            "k1": 0.0, "k2": 0.0, "p1": 0.0, "p2": 0.0,
            "frames": [{"file_path": f"images/{i}.jpg", "transform_matrix": c2w[i].tolist()} for i in range(3)]}
    data.update(overrides)
    path = tmp_path / "transforms.json"
    path.write_text(json.dumps(data))
    return path


def test_plain_nerfstudio_files(tmp_path):
    desc = read_transforms(_plain(tmp_path))
    assert desc.meta == {} and desc.light is None and desc.split.test == (0,) and desc.split.train == (1, 2)
    assert desc.intrinsics == Intrinsics(50.0, 51.0, 32.0, 24.0, 64, 48)
    assert desc.gt_paths == (None, None, None) and desc.ply_path is None
    # Per-frame intrinsics that agree are accepted.
    frames = json.loads(_plain(tmp_path).read_text())["frames"]
    for f in frames:
        f.update({"fl_x": 50.0, "fl_y": 51.0, "w": 64, "h": 48})
    desc = read_transforms(_plain(tmp_path, fl_x=None, fl_y=None, w=None, h=None, frames=frames))
    assert desc.intrinsics == Intrinsics(50.0, 51.0, 32.0, 24.0, 64, 48)
    # NeRF-synthetic style: camera_angle_x, no cx/cy, paths without suffix; w/h measured from the first image.
    frames = [{"file_path": f"./train/r_{i}", "transform_matrix": np.eye(4).tolist()} for i in range(2)]
    (tmp_path / "train").mkdir()
    for i in range(2):
        write_png(tmp_path / "train" / f"r_{i}.png", np.zeros((20, 40, 3), np.uint8))
    path = tmp_path / "nerf.json"
    path.write_text(json.dumps({"camera_angle_x": 2 * math.atan(0.5), "frames": frames}))
    desc = read_transforms(path, check_files=True)
    assert desc.intrinsics.fx == pytest.approx(40.0, rel=1e-14) and desc.intrinsics.fy == desc.intrinsics.fx
    assert (desc.intrinsics.cx, desc.intrinsics.cy, desc.intrinsics.width, desc.intrinsics.height) == (20, 10, 40, 20)
    assert desc.image_paths[1] == tmp_path / "train" / "r_1.png"


def test_transforms_error_paths(tmp_path):
    eye = np.eye(4).tolist()
    cases = [
        (dict(frames=[]), "missing or empty 'frames' list"),
        (dict(frames=[{"transform_matrix": eye}]), r"frames\[0\]: missing key 'file_path'"),
        (dict(frames=[{"file_path": "a.png"}]), r"frames\[0\]: missing key 'transform_matrix'"),
        (dict(frames=[{"file_path": "a.png", "transform_matrix": eye[:3]}]),
         r"frames\[0\].transform_matrix: must be 4x4, got shape \(3, 4\)"),
        (dict(frames=[{"file_path": "a.png", "transform_matrix": [[1, 0, 0, float("nan")], *eye[1:]]}]),
         r"frames\[0\].transform_matrix: contains NaN or inf"),
        (dict(frames=[{"file_path": "a.png", "transform_matrix": (2 * np.eye(4)).tolist()}]), "last row must be"),
        (dict(frames=[{"file_path": "a.png", "transform_matrix": np.diag([2.0, 1, 1, 1]).tolist()}]),
         "not a rotation"),
        (dict(frames=[{"file_path": "/abs/a.png", "transform_matrix": eye}]), "must be a relative POSIX path"),
        (dict(frames=[{"file_path": "../other/a.png", "transform_matrix": eye}]),
         r"frames\[0\].file_path: must stay inside the dataset folder \(no '..'\)"),
        (dict(frames=[{"file_path": "a.png", "gt_file_path": "gt/../../x.png", "transform_matrix": eye}]),
         r"frames\[0\].gt_file_path: must stay inside the dataset folder"),
        (dict(ply_file_path="../../points.ply"), "ply_file_path: must stay inside the dataset folder"),
        (dict(fl_x=None, camera_angle_x=0), r"camera_angle_x: a field of view must lie between 0 and pi radians"),
        (dict(fl_x=None, camera_angle_x=4.0), "a field of view must lie between 0 and pi"),
        (dict(w=10**400), r"\.w: expected a finite number, got 1000000000.*\.\.\. \(401 characters\)"),
        (dict(frames=[{"file_path": "a.png", "transform_matrix": "eye"}]), "not a numeric 4x4 matrix"),
        (dict(fl_x=None), "missing key 'fl_x'"),
        (dict(fl_x=-3.0), "focal lengths must be positive"),
        (dict(w=64.5), "w and h must be positive integers"),
        (dict(camera_model="PINHOLE", k1=0.1), "camera_model PINHOLE has no distortion coefficient k1"),
        (dict(camera_model="OPENCV", k4=0.1), "camera_model OPENCV has no distortion coefficient k4"),
        (dict(k1="x"), "k1"),
        (dict(k1=-5.0), "cannot be inverted"),
        (dict(camera_model="EQUIRECTANGULAR"), "camera_model 'EQUIRECTANGULAR' is not supported"),
        (dict(spotless=[1]), "spotless: must be an object"),
        (dict(spotless={"schema_version": 2}), r"spotless.schema_version: unsupported version 2"),
        (dict(spotless={"schema_version": 1}),
         r"spotless: missing keys \['scene_id', 'split', 'color_space', 'light'\]"),
    ]
    for overrides, match in cases:
        path = _plain(tmp_path, **overrides)
        with pytest.raises(InputError, match=match):  # DatasetError, or the lens check's InputError
            read_transforms(path)
    frames = json.loads(_plain(tmp_path).read_text())["frames"]
    frames[2]["fl_x"] = 60.0  # a frame of another camera: read, and a step that needs one camera says so
    two = read_transforms(_plain(tmp_path, frames=frames))
    assert [c.fx for c in two.cameras] == [50.0, 50.0, 60.0] + [50.0] * (len(frames) - 3)
    assert two.cameras[0] is two.cameras[1] and not two.has_one_camera
    with pytest.raises(DatasetError, match="the frames use 2 different cameras; this step needs one camera"):
        two.intrinsics  # noqa: B018
    frames[2]["k1"] = -5.0  # that camera's lens folds: named by its frame
    with pytest.raises(InputError, match=r"frames\[2\]: the opencv distortion .* cannot be inverted"):
        read_transforms(_plain(tmp_path, frames=frames))
    (tmp_path / "bad.json").write_text("{not json")
    with pytest.raises(DatasetError, match="bad.json: not valid JSON"):
        read_transforms(tmp_path / "bad.json")
    (tmp_path / "deep.json").write_text("[" * 100_000 + "]" * 100_000)
    with pytest.raises(DatasetError, match=r"deep.json: not valid JSON \(nested too deeply\)"):
        read_transforms(tmp_path / "deep.json")
    (tmp_path / "list.json").write_text("[]")
    with pytest.raises(DatasetError, match="top level must be an object"):
        read_transforms(tmp_path / "list.json")
    with pytest.raises(FileNotFoundError, match="transforms file not found"):
        read_transforms(tmp_path / "nothing.json")
    with pytest.raises(FileNotFoundError, match=r"frames\[0\]: image file .*images/0.jpg does not exist"):
        read_transforms(_plain(tmp_path), check_files=True)


def test_spotless_block_error_paths(tmp_path):
    _write_dataset(tmp_path, n=12, make_files=False)
    good = json.loads((tmp_path / "transforms.json").read_text())

    def check(mutate, match, exc=DatasetError):
        data = json.loads(json.dumps(good))
        mutate(data["spotless"])
        (tmp_path / "m.json").write_text(json.dumps(data))
        with pytest.raises(exc, match=match):
            read_transforms(tmp_path / "m.json")

    check(lambda b: b.update(color_space="linear"), r"color_space: unsupported 'linear'")
    check(lambda b: b["split"].update(test=[0, 11, 12]), r"split.test: indices \[12\] out of range for 12 frames")
    check(lambda b: b["split"].update(test=[0, 1, 11]), r"frames \[1\] are in both train and test")
    check(lambda b: b["split"].update(test=[11, 0]), "indices must be sorted and unique")
    check(lambda b: b["split"].update(train=b["split"]["train"][1:]), "cover 11 of 12 frames")
    check(lambda b: b["split"].update(test=[0, 2], train=[1] + list(range(3, 12))), "do not follow rule 'every_11th'")
    check(lambda b: b["split"].update(test_every=0), "test_every: must be a positive integer")
    check(lambda b: b["split"].pop("rule"), r"split: missing keys \['rule'\]")
    check(lambda b: b.update(split=None), "missing or invalid 'split' object")
    check(lambda b: b["light"].update(blend=2.0), r"spotless.light: .*blend: must be in \[0, 1\]")
    # A custom rule is accepted when the lists partition the frames.
    data = json.loads(json.dumps(good))
    data["spotless"]["split"] = {"rule": "manual", "test_every": 11, "train": list(range(1, 12)), "test": [0]}
    (tmp_path / "m.json").write_text(json.dumps(data))
    assert read_transforms(tmp_path / "m.json").split.rule == "manual"


def test_write_transforms_error_paths(tmp_path):
    intr = Intrinsics.from_fov(60.0, 8, 6)
    meta = DatasetMeta(scene_id="s")
    with pytest.raises(DatasetError, match="no frames to write"):
        write_transforms(tmp_path / "t.json", intr, [], meta)
    with pytest.raises(DatasetError, match=r"frames\[0\].transform_matrix: contains NaN"):
        write_transforms(tmp_path / "t.json", intr, [FrameRecord("a.png", np.full((4, 4), np.nan))], meta)
    with pytest.raises(DatasetError, match=r"frames\[0\].gt_file_path: must be a relative POSIX path"):
        write_transforms(tmp_path / "t.json", intr, [FrameRecord("a.png", np.eye(4), "/x/gt.png")], meta)
    one = [FrameRecord("a.png", np.eye(4))]
    with pytest.raises(DatasetError, match="color_space must be 'srgb'"):
        write_transforms(tmp_path / "t.json", intr, one, DatasetMeta("s", color_space="raw"))
    with pytest.raises(DatasetError, match="not JSON-serialisable"):
        write_transforms(tmp_path / "t.json", intr, one, DatasetMeta("s", renderer={"x": {1, 2}}))
    with pytest.raises(DatasetError, match="not JSON-serialisable"):
        write_transforms(tmp_path / "t.json", intr, one, DatasetMeta("s", renderer={"x": math.inf}))
    assert not (tmp_path / "t.json").exists()


def test_read_dataset_dispatch_and_colmap_folder(tmp_path):
    _write_dataset(tmp_path / "ours", n=4, make_files=True)
    ours = read_dataset(tmp_path / "ours", check_files=True)
    assert ours.n_frames == 4
    cloud = load_initial_points(ours)
    assert cloud is not None and cloud.xyz.shape == (1, 3)
    # A plain COLMAP folder written by pycolmap (binary) with one camera.
    folder = tmp_path / "colmap"
    intr, c2w, names, xyz, rgb, model = _model(13)
    write_colmap_text(folder / "sparse" / "0", model)
    pycolmap.Reconstruction(str(folder / "sparse" / "0")).write_binary(str(folder / "sparse" / "0"))
    desc = read_dataset(folder)
    assert desc.intrinsics == intr and desc.n_frames == 13 and desc.split.test == (0, 11)
    np.testing.assert_allclose(desc.c2w_opengl, c2w, atol=1e-12)
    assert desc.image_paths[0] == folder / "images" / "frame_00000.png"
    cloud = load_initial_points(desc)
    np.testing.assert_allclose(cloud.xyz, xyz.astype(np.float32))
    with pytest.raises(FileNotFoundError, match=r"image 1 file .*frame_00000.png does not exist"):
        read_colmap_dataset(folder, check_files=True)
    for name in ("../outside.png", "/etc/hostname"):  # a name that leaves the images folder
        renamed = dict(model.images)
        renamed[1] = dataclasses.replace(renamed[1], name=name)
        write_colmap_text(tmp_path / "escape" / "sparse" / "0", dataclasses.replace(model, images=renamed))
        with pytest.raises(DatasetError, match=rf"escape/sparse/0/images.txt: image 1 is named '{re.escape(name)}'; "
                                               "COLMAP names a frame by its path inside the images folder"):
            read_dataset(tmp_path / "escape")
    with pytest.raises(FileNotFoundError, match="neither transforms.json nor a COLMAP sparse/ folder"):
        read_dataset(tmp_path / "empty")
    (tmp_path / "bad" / "sparse").mkdir(parents=True)
    with pytest.raises(FileNotFoundError, match="no COLMAP model in sparse/0 or sparse"):
        read_dataset(tmp_path / "bad")
    distorted = tmp_path / "distorted" / "sparse" / "0"
    distorted.mkdir(parents=True)
    _pycolmap_reconstruction().write_binary(str(distorted))  # a pinhole and an OPENCV camera, images 1-3
    mixed = read_dataset(tmp_path / "distorted")  # each image keeps its own camera, as pycolmap has it
    assert [(c.lens, c.width, c.fy) for c in mixed.cameras] == [("pinhole", 64, 101.0), ("opencv", 80, 91.0),
                                                                 ("pinhole", 64, 101.0)]
    assert mixed.cameras[1].distortion == (0.01, -0.02, 0.001, 0.002)
    second = ColmapCamera(2, "PINHOLE", 320, 240, (200.0, 200.0, 160.0, 120.0))
    images = dict(model.images)
    images[2] = dataclasses.replace(images[2], camera_id=2)
    two_camera_model = dataclasses.replace(model, cameras={**model.cameras, 2: second}, images=images)
    write_colmap_text(tmp_path / "two" / "sparse", two_camera_model)
    two = read_dataset(tmp_path / "two")
    assert [c.fx for c in two.cameras] == [intr.fx if im.camera_id == 1 else 200.0
                                           for im in sorted(images.values(), key=lambda im: im.name)]
    with pytest.raises(DatasetError, match="two/sparse: the frames use 2 different cameras; this step needs one"):
        two.intrinsics  # noqa: B018


def test_initial_points_that_are_not_finite_are_left_out(tmp_path, caplog):
    """A depth camera's PLY with NaN rows for invalid pixels: those rows go, with a warning; none left is an error
    naming the file. A COLMAP point's colour outside 0..255 is named by file and line."""
    _write_dataset(tmp_path / "d", n=4)
    xyz = np.array([[0.0, 0.0, 1.0], [np.nan, 0.0, 1.0], [1.0, 2.0, 3.0], [0.0, np.inf, 1.0]])
    rgb = np.array([[1, 2, 3], [4, 5, 6], [7, 8, 9], [10, 11, 12]], np.uint8)

    def write_raw_ply(path, xyz, rgb):  # as another program writes it: our writer refuses NaN
        vertices = np.zeros(len(xyz), dtype=[(a, "<f4") for a in "xyz"] + [(c, "u1") for c in ("red", "green", "blue")])
        for k, name in enumerate(("x", "y", "z", "red", "green", "blue")):
            vertices[name] = (xyz if k < 3 else rgb)[:, k % 3]
        PlyData([PlyElement.describe(vertices, "vertex")]).write(str(path))

    write_raw_ply(tmp_path / "d" / "points3D.ply", xyz, rgb)
    with caplog.at_level("WARNING"):
        cloud = load_initial_points(read_dataset(tmp_path / "d"))
    np.testing.assert_array_equal(cloud.xyz, xyz[[0, 2]].astype(np.float32))
    np.testing.assert_array_equal(cloud.rgb, rgb[[0, 2]])
    assert "points3D.ply: 2 of 4 points left out" in caplog.text
    write_raw_ply(tmp_path / "d" / "points3D.ply", xyz[[1, 3]], rgb[:2])
    with pytest.raises(InputError, match=r"points3D.ply: none of its 2 points has a finite position"):
        load_initial_points(read_dataset(tmp_path / "d"))
    *_, model = _model(3)
    write_colmap_text(tmp_path / "c", model)
    lines = (tmp_path / "c" / "points3D.txt").read_text().splitlines(keepends=True)
    entry = next(k for k, line in enumerate(lines) if not line.startswith("#"))
    fields = lines[entry].split(" ")
    fields[4] = "300"
    (tmp_path / "c" / "points3D.txt").write_text("".join(lines[:entry] + [" ".join(fields)] + lines[entry + 1:]))
    with pytest.raises(ValueError, match=rf"points3D.txt:{entry + 1}: bad point line \(colour \[300, .*outside 0..255"):
        read_colmap_text(tmp_path / "c")


def test_cameras_of_a_colmap_dataset_project_points_as_pycolmap_does(tmp_path):
    """Independent reference: pycolmap's own projection of the model's 3D points into each image."""
    intr, c2w, names, xyz, rgb, model = _model(5)
    write_colmap_text(tmp_path / "sparse" / "0", model)
    rec = pycolmap.Reconstruction(str(tmp_path / "sparse" / "0"))
    cams = Cameras.from_dataset(read_dataset(tmp_path))
    assert len(cams) == 5 and cams.is_batch and cams.c2w.dtype == torch.float32 and cams.intrinsics == intr
    for i in range(5):
        cam = cams[i]
        assert not cam.is_batch and (cam.width, cam.height) == (320, 240)
        # points 1-3 m in front of camera i (pycolmap gives NaN behind a camera)
        ahead = c2w[i, :3, 3] - np.outer(np.linspace(1, 3, 6), c2w[i, :3, 2]) + 0.1 * xyz
        points = torch.as_tensor(ahead, dtype=torch.float32)
        in_camera = points @ cam.viewmat[:3, :3].T + cam.viewmat[:3, 3]
        pixels = in_camera @ cam.K.T
        expected = rec.camera(1).img_from_cam(rec.image(i + 1).cam_from_world() * ahead)
        assert np.isfinite(expected).all()
        np.testing.assert_allclose((pixels[:, :2] / pixels[:, 2:]).numpy(), expected, rtol=1e-4, atol=1e-3)
        np.testing.assert_allclose(cam.centres.numpy(), rec.image(i + 1).projection_center(), atol=1e-5)
    half = cams.with_intrinsics(intr.scaled(0.5))
    assert (half.width, half.height) == (160, 120) and half.viewmat is cams.viewmat
    torch.testing.assert_close(half.K, torch.tensor([[150.0, 0, 80.25], [0, 155.0, 59.625], [0, 0, 1]]))


def test_cameras_errors():
    intr = Intrinsics.from_fov(60.0, 8, 6)
    with pytest.raises(ValueError, match=r"c2w must be \(4, 4\) or \(V, 4, 4\), got \(3, 4\)"):
        Cameras(torch.eye(4)[:3], intr)
    with pytest.raises(ValueError, match="viewmat .* does not match c2w"):
        Cameras(torch.eye(4)[None].repeat(2, 1, 1), intr, torch.eye(4))
    one = Cameras(torch.eye(4), intr)
    with pytest.raises(TypeError, match="single view cannot be indexed"):
        one[0]
    with pytest.raises(TypeError, match="single view has no length"):
        len(one)


# --------------------------------------------------------------------------------------------------- point clouds


def test_backprojection_of_analytic_plane_lands_on_plane_and_reprojects():
    intr = Intrinsics(80.0, 75.0, 31.0, 25.5, 60, 48)
    c2w = np.eye(4)
    c2w[:3, :3] = Rotation.from_rotvec([0.3, -0.2, 0.1]).as_matrix()  # OpenGL camera looking roughly down (-z)
    c2w[:3, 3] = [0.4, -0.3, 1.5]
    normal, offset = np.array([0.1, 0.2, 1.0]) / np.linalg.norm([0.1, 0.2, 1.0]), -1.0  # plane n.x = offset
    # Independent pinhole model: pixel centre rays K^-1 [u, v, 1], rotated to the world by the OpenCV pose.
    cv = c2w @ np.diag([1.0, -1.0, -1.0, 1.0])
    v, u = np.mgrid[0:48, 0:60] + 0.5
    rays_cam = np.stack([u, v, np.ones_like(u)], -1) @ np.linalg.inv(intr.K()).T
    rays_world = rays_cam @ cv[:3, :3].T
    depth = (offset - normal @ cv[:3, 3]) / (rays_world @ normal)  # planar depth: the ray's z component is 1
    assert (depth > 0).all()
    depth[0, :5] = [np.inf, np.nan, 0.0, -1.0, np.inf]  # invalid values are skipped
    rgb = np.random.default_rng(0).integers(0, 256, (48, 60, 3), dtype=np.uint8)
    normals = np.broadcast_to(normal * 3.0, (48, 60, 3))
    pts = backproject_depth(depth, rgb, normals, intr, c2w)
    assert len(pts.xyz) == 48 * 60 - 5
    np.testing.assert_allclose(pts.xyz @ normal, offset, atol=1e-9)
    np.testing.assert_allclose(pts.normals, np.broadcast_to(normal, pts.normals.shape), atol=1e-12)
    cam = (np.linalg.inv(cv) @ np.c_[pts.xyz, np.ones(len(pts.xyz))].T)[:3].T
    pix = cam @ intr.K().T
    pix = pix[:, :2] / pix[:, 2:]
    valid = np.ones((48, 60), bool)
    valid[0, :5] = False
    np.testing.assert_allclose(pix, np.stack([u[valid], v[valid]], -1), atol=1e-9)
    np.testing.assert_array_equal(pts.rgb, rgb[valid])
    strided = backproject_depth(depth, rgb, None, intr, c2w, stride=4)
    assert len(strided.xyz) == 12 * 15 - 2 and strided.normals is None  # (0,0) and (0,4) are invalid
    far = depth.copy()
    far[5, 7] = 1e10  # Blender's background value
    assert len(backproject_depth(far, rgb, None, intr, c2w, max_depth=100.0).xyz) == 48 * 60 - 6
    sub = backproject_depth(depth, rgb, None, intr, c2w, max_points=100, rng=np.random.default_rng(1))
    assert len(sub.xyz) == 100
    np.testing.assert_allclose(sub.xyz @ normal, offset, atol=1e-9)


def test_backprojection_errors():
    intr = Intrinsics.from_fov(60.0, 4, 3)
    depth, rgb = np.ones((3, 4)), np.zeros((3, 4, 3), np.uint8)
    with pytest.raises(ValueError, match=r"depth shape \(4, 3\) does not match intrinsics 3x4"):
        backproject_depth(depth.T, rgb, None, intr, np.eye(4))
    with pytest.raises(ValueError, match="rgb must be uint8"):
        backproject_depth(depth, rgb.astype(float), None, intr, np.eye(4))
    with pytest.raises(ValueError, match=r"normals must be \(3, 4, 3\)"):
        backproject_depth(depth, rgb, np.zeros((3, 4)), intr, np.eye(4))
    with pytest.raises(ValueError, match="stride must be >= 1"):
        backproject_depth(depth, rgb, None, intr, np.eye(4), stride=0)
    with pytest.raises(ValueError, match="max_points needs a non-negative value and an rng"):
        backproject_depth(depth, rgb, None, intr, np.eye(4), max_points=3)


def test_merge_point_clouds_voxel_average_and_cap():
    a = Points(np.array([[0.1, 0.1, 0.1], [0.3, 0.2, 0.1], [1.5, 0.1, 0.1]]),
               np.array([[0, 0, 0], [100, 50, 1], [7, 7, 7]], np.uint8),
               np.array([[0, 0, 1.0], [0, 1.0, 0], [1.0, 0, 0]]))
    b = Points(np.array([[0.2, 0.4, 0.3], [-0.1, 0.0, 0.0]]), np.array([[50, 250, 2], [9, 9, 9]], np.uint8),
               np.array([[0, 0, -1.0], [0, 0, 1.0]]))
    merged = merge_point_clouds([a, b], voxel_size=0.5, max_points=None, rng=np.random.default_rng(0))
    # Voxels: (-1,0,0) <- b[1]; (0,0,0) <- a[0], a[1], b[0]; (3,0,0) <- a[2]; sorted by voxel index.
    np.testing.assert_allclose(merged.xyz, [[-0.1, 0, 0], [0.2, 0.7 / 3, 0.5 / 3], [1.5, 0.1, 0.1]])
    np.testing.assert_array_equal(merged.rgb, [[9, 9, 9], [50, 100, 1], [7, 7, 7]])  # 150/3 = 50, 300/3, 3/3
    np.testing.assert_allclose(merged.normals, [[0, 0, 1], [0, 1, 0], [1, 0, 0]], atol=1e-12)  # z's cancel
    capped = merge_point_clouds([a, b], 0.5, max_points=2, rng=np.random.default_rng(0))
    assert len(capped.xyz) == 2 and all(any(np.allclose(p, q) for q in merged.xyz) for p in capped.xyz)
    cancel = Points(np.array([[0.1, 0.1, 0.1], [0.2, 0.2, 0.2]]), np.zeros((2, 3), np.uint8),
                    np.array([[0, 0, 1.0], [0, 0, -1.0]]))
    np.testing.assert_allclose(merge_point_clouds([cancel], 1.0, None, np.random.default_rng(0)).normals, [[0, 0, 1]])
    with pytest.raises(ValueError, match="some clouds have normals and others do not"):
        merge_point_clouds([a, Points(b.xyz, b.rgb, None)], 0.5, None, np.random.default_rng(0))
    with pytest.raises(ValueError, match="voxel_size must be positive"):
        merge_point_clouds([a], 0.0, None, np.random.default_rng(0))
    with pytest.raises(ValueError, match="no point clouds given"):
        merge_point_clouds([], 0.1, None, np.random.default_rng(0))


def test_frames_numbered_without_leading_zeros_come_in_video_order(tmp_path):
    """frame_2 before frame_10 in a folder listing, a COLMAP dataset and prepare's SfM copies (whose names COLMAP's
    sequential matcher takes in text order: renamed with an index only where that order differs)."""
    from spotlessgs.io.cameras import Intrinsics
    from spotlessgs.io.colmap_text import model_from_poses, write_colmap_text
    from spotlessgs.io.images import natural_order
    from spotlessgs.prepare.images import copy_names

    names = [f"frame_{k}.png" for k in (10, 2, 1, 11, 0)]
    video = [f"frame_{k}.png" for k in (0, 1, 2, 10, 11)]
    assert sorted(names, key=natural_order) == video
    padded = [f"frame_{k:05d}.png" for k in (10, 2, 1, 11, 0)]
    assert sorted(padded, key=natural_order) == sorted(padded)  # zero-padded names keep their text order
    folder = tmp_path / "frames"
    folder.mkdir()
    for name in names:
        write_png(folder / name, np.zeros((4, 6, 3), np.float32))
    listed = list_image_files(folder)
    assert [p.name for p in listed] == video
    assert copy_names(listed) == [f"{k:06d}_{name}" for k, name in enumerate(video)]
    assert sorted(copy_names(listed)) == copy_names(listed)
    assert copy_names([folder / n for n in sorted(padded)]) == sorted(padded)  # already in text order: kept

    data = tmp_path / "colmap"
    (data / "images").mkdir(parents=True)
    for name in names:
        write_png(data / "images" / name, np.zeros((4, 6, 3), np.float32))
    poses = np.tile(np.eye(4), (len(names), 1, 1))
    poses[:, 0, 3] = [int(n[6:-4]) for n in names]  # x = the frame number
    write_colmap_text(data / "sparse" / "0", model_from_poses(Intrinsics(5.0, 5.0, 3.0, 2.0, 6, 4), names, poses))
    dataset = read_dataset(data)
    assert list(dataset.file_paths) == [f"images/{n}" for n in video]
    assert dataset.c2w_opencv[:, 0, 3].tolist() == [0.0, 1.0, 2.0, 10.0, 11.0]
