"""Image reading (8/16-bit, greyscale, alpha, palette) and folder matching, with every error path."""

from __future__ import annotations

import struct
import zlib
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from evaluation.folders import ImagePair, image_names, match_folders, read_named_images
from spotlessgs.io.images import is_image_name, read_image


def load_image(path: Path) -> np.ndarray:
    """How the evaluation reads every image: the shared reader, alpha composited over black."""
    return read_image(path, alpha="over_black")


def _png16_rgb(path: Path, a: np.ndarray) -> None:
    """Write a 16-bit RGB PNG by hand (Pillow cannot write them)."""
    h, w, _ = a.shape
    raw = b"".join(b"\x00" + a[y].astype(">u2").tobytes() for y in range(h))

    def chunk(kind: bytes, data: bytes) -> bytes:
        return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data) & 0xFFFFFFFF)

    path.write_bytes(b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", struct.pack(">IIBBBBB", w, h, 16, 2, 0, 0, 0))
                     + chunk(b"IDAT", zlib.compress(raw)) + chunk(b"IEND", b""))


def test_8bit_rgb_exact(tmp_path):
    a = np.arange(4 * 5 * 3, dtype=np.uint8).reshape(4, 5, 3) * 4
    Image.fromarray(a).save(tmp_path / "x.png")
    got = load_image(tmp_path / "x.png")
    assert got.dtype == np.float32 and got.shape == (4, 5, 3)
    np.testing.assert_allclose(got, a / 255.0, atol=1e-7)


def test_16bit_grey_exact_and_replicated(tmp_path):
    g = (np.arange(20).reshape(4, 5) * 3000).astype(np.uint16)
    Image.fromarray(g).save(tmp_path / "g.png")
    got = load_image(tmp_path / "g.png")
    assert got.shape == (4, 5, 3)
    np.testing.assert_allclose(got[..., 1], g / 65535.0, atol=1e-7)
    np.testing.assert_array_equal(got[..., 0], got[..., 2])


def test_16bit_rgb_exact(tmp_path):
    a = (np.arange(4 * 4 * 3).reshape(4, 4, 3) * 1357 % 65536).astype(np.uint16)
    _png16_rgb(tmp_path / "c.png", a)
    got = load_image(tmp_path / "c.png")
    np.testing.assert_allclose(got, a / 65535.0, atol=1e-7)


@pytest.mark.parametrize("channels", [3, 4, 1])
def test_16bit_tiff_exact(tmp_path, channels):
    """A 16-bit TIFF keeps its 16 bits (Pillow would read colour ones as 8-bit), in RGB order; grey repeats."""
    import cv2

    a = (np.arange(4 * 5 * channels).reshape(4, 5, channels) * 1357 % 65536).astype(np.uint16)
    stored = a[..., 0] if channels == 1 else cv2.cvtColor(a, cv2.COLOR_RGB2BGR if channels == 3 else cv2.COLOR_RGBA2BGRA)
    assert cv2.imwrite(str(tmp_path / "c.tif"), stored)
    got = load_image(tmp_path / "c.tif")
    expected = (np.repeat(a, 3, axis=2) if channels == 1 else a[..., :3]) / 65535.0
    if channels == 4:  # the evaluation composites alpha over black
        expected = expected * a[..., 3:] / 65535.0
    np.testing.assert_allclose(got, expected, atol=1e-6)
    Image.fromarray(np.full((3, 3, 3), 77, np.uint8)).save(tmp_path / "eight.tif")  # 8-bit: as before
    np.testing.assert_allclose(load_image(tmp_path / "eight.tif"), 77 / 255.0, atol=1e-7)


def test_alpha_composited_over_black(tmp_path):
    rgba = np.zeros((2, 2, 4), np.uint8)
    rgba[..., :3] = 200
    rgba[..., 3] = [[255, 0], [51, 255]]
    Image.fromarray(rgba, "RGBA").save(tmp_path / "a.png")
    got = load_image(tmp_path / "a.png")
    np.testing.assert_allclose(got[..., 0], [[200 / 255, 0.0], [200 / 255 * 0.2, 200 / 255]], atol=1e-6)


def test_greyscale_and_palette(tmp_path):
    Image.fromarray(np.full((3, 3), 128, np.uint8), "L").save(tmp_path / "l.png")
    np.testing.assert_allclose(load_image(tmp_path / "l.png"), 128 / 255.0, atol=1e-7)
    p = Image.fromarray(np.full((3, 3, 3), [10, 20, 30], np.uint8)).convert("P", palette=Image.ADAPTIVE)
    p.save(tmp_path / "p.png")
    np.testing.assert_allclose(load_image(tmp_path / "p.png")[0, 0], np.array([10, 20, 30]) / 255.0, atol=1e-7)


def test_image_errors(tmp_path):
    with pytest.raises(FileNotFoundError, match="none.png: image file not found"):
        load_image(tmp_path / "none.png")
    (tmp_path / "bad.png").write_bytes(b"not a png at all")
    with pytest.raises(ValueError, match="bad.png: cannot decode image"):
        load_image(tmp_path / "bad.png")
    Image.fromarray(np.zeros((2, 2), np.float32), "F").save(tmp_path / "f.tiff")
    with pytest.raises(ValueError, match="f.tiff: unsupported image mode 'F'"):
        load_image(tmp_path / "f.tiff")
    noise = np.random.default_rng(0).integers(0, 255, (64, 64, 3)).astype(np.uint8)
    Image.fromarray(noise).save(tmp_path / "t.png")
    data = (tmp_path / "t.png").read_bytes()
    (tmp_path / "trunc.png").write_bytes(data[: len(data) // 2])
    with pytest.raises(ValueError, match="trunc.png: cannot decode image"):
        load_image(tmp_path / "trunc.png")


def _folder(root: Path, names: list[str]) -> Path:
    root.mkdir(parents=True, exist_ok=True)
    for n in names:
        Image.fromarray(np.zeros((12, 12, 3), np.uint8)).save(root / n)
    return root


def test_match_by_name(tmp_path):
    p = _folder(tmp_path / "p", ["b.png", "a.png"])
    g = _folder(tmp_path / "g", ["a.png", "b.png"])
    (p / ".hidden").write_text("x")
    (p / "sub").mkdir()
    pairs = match_folders(p, g)
    assert [x.name for x in pairs] == ["a.png", "b.png"]
    assert pairs[0] == ImagePair("a.png", p / "a.png", g / "a.png")
    assert [x.name for x in match_folders(p, g, names=["b.png"])] == ["b.png"]
    assert is_image_name("X.JPG") and not is_image_name("x.exr")


def test_folder_errors(tmp_path):
    p = _folder(tmp_path / "p", ["a.png", "b.png", "c.png"])
    g = _folder(tmp_path / "g", ["a.png", "b.png", "d.png", "e.png"])
    with pytest.raises(ValueError, match=r"holds 3 images and .* holds 4; missing from predictions: d.png, e.png; "
                                         r"extra in predictions: c.png"):
        match_folders(p, g)
    with pytest.raises(ValueError, match=r"missing requested images: c.png"):
        match_folders(p, g, names=["a.png", "c.png"])
    with pytest.raises(ValueError, match="requested image names contain duplicates"):
        match_folders(p, g, names=["a.png", "a.png"])
    (g / "notes.txt").write_text("x")
    with pytest.raises(ValueError, match="non-image files found: notes.txt"):
        image_names(g)
    with pytest.raises(FileNotFoundError, match="nope: image folder not found"):
        image_names(tmp_path / "nope")
    (tmp_path / "empty").mkdir()
    with pytest.raises(ValueError, match="empty: no image files"):
        image_names(tmp_path / "empty")


def test_read_named_images_stacks_them_in_the_order_asked_and_names_what_is_wrong(tmp_path):
    """The named images of a folder, in the order given (not the folder's), as one (N, H, W, 3) stack of the shared
    reader's values; a missing name is a FileNotFoundError naming it, images of different sizes a ValueError naming
    the folder."""
    rng = np.random.default_rng(0)
    pixels = {name: rng.integers(0, 256, (4, 5, 3), dtype=np.uint8) for name in ("a.png", "b.png")}
    for name, a in pixels.items():
        Image.fromarray(a).save(tmp_path / name)
    stack = read_named_images(tmp_path, ["b.png", "a.png"])
    assert stack.shape == (2, 4, 5, 3)
    assert np.array_equal(stack[0], pixels["b.png"] / np.float32(255)) and np.array_equal(stack[1], read_image(
        tmp_path / "a.png"))
    with pytest.raises(FileNotFoundError, match="c.png"):
        read_named_images(tmp_path, ["a.png", "c.png"])
    Image.fromarray(np.zeros((3, 5, 3), np.uint8)).save(tmp_path / "small.png")
    with pytest.raises(ValueError, match=str(tmp_path)):
        read_named_images(tmp_path, ["a.png", "small.png"])
