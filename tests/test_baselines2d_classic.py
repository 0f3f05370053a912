"""CLAHE, MSRCR, the Lab conversion and enhance_folder on synthetic images with known structure."""

from __future__ import annotations

import json

import numpy as np
import pytest
from scipy.ndimage import gaussian_filter, zoom

from spotlessgs.baselines2d import ClaheConfig, MsrcrConfig, clahe, enhance_folder, msrcr
from spotlessgs.baselines2d.clahe import clahe_lightness
from spotlessgs.baselines2d.lab import lab_to_srgb, srgb_to_lab
from spotlessgs.baselines2d.msrcr import box_widths_for_gaussian, gaussian_blur, simplest_colour_balance
from spotlessgs.io.colorspace import to_uint8
from spotlessgs.io.images import read_image, write_png


def even_texture(rng: np.random.Generator, height: int, width: int) -> np.ndarray:
    """(H, W, 3) smooth random texture in [0.35, 0.75], evenly lit."""
    base = rng.random((height // 8 + 2, width // 8 + 2, 3))
    return 0.35 + 0.4 * zoom(base, (8, 8, 1), order=1)[:height, :width]


def vignette(height: int, width: int) -> np.ndarray:
    """(H, W) spotlight-like fall-off, 1 at the centre, ~0.1 in the corners."""
    yy, xx = np.mgrid[0:height, 0:width]
    r2 = ((yy - height / 2) ** 2 + (xx - width / 2) ** 2) / (0.35 * max(height, width)) ** 2
    return np.exp(-r2)


def corner_centre_ratio(img: np.ndarray) -> float:
    """Mean brightness of the four corner patches over that of the centre patch (1 = evenly lit)."""
    h, w = img.shape[:2]
    k = max(h // 5, 1)
    grey = img.mean(axis=2)
    corners = np.mean([grey[:k, :k].mean(), grey[:k, -k:].mean(), grey[-k:, :k].mean(), grey[-k:, -k:].mean()])
    centre = grey[h // 2 - k // 2 : h // 2 + k // 2 + 1, w // 2 - k // 2 : w // 2 + k // 2 + 1].mean()
    return float(corners / centre)


@pytest.fixture(scope="module")
def scene():
    tex = even_texture(np.random.default_rng(3), 96, 128)
    return tex, np.clip(tex * vignette(96, 128)[..., None] * 1.3, 0.0, 1.0)


METHODS = [pytest.param(clahe, id="clahe"), pytest.param(msrcr, id="msrcr")]


@pytest.mark.parametrize("method", METHODS)
def test_dark_corners_are_brightened(method, scene):
    _, uneven = scene
    before = corner_centre_ratio(uneven)
    after = corner_centre_ratio(method(uneven))
    assert before < 0.15
    assert after > before + 0.07  # measured: 0.12 -> 0.21 (CLAHE) / 0.24 (MSRCR)


@pytest.mark.parametrize("method", METHODS)
def test_even_image_changes_little(method, scene):
    even, _ = scene
    out = method(even)
    assert abs(corner_centre_ratio(out) - corner_centre_ratio(even)) < 0.1
    assert np.abs(out - even).mean() < 0.15  # measured 0.07 (CLAHE), 0.13 (MSRCR: it stretches to [0, 1])
    assert np.corrcoef(out.ravel(), even.ravel())[0, 1] > 0.8


@pytest.mark.parametrize("method", METHODS)
@pytest.mark.parametrize("shape", [(1, 1), (1, 7), (5, 1), (3, 2), (40, 30)])
@pytest.mark.parametrize("value", [0.0, 1.0])
def test_black_and_saturated_frames_stay_put(method, shape, value):
    out = method(np.full((*shape, 3), value, dtype=np.float32))
    assert out.shape == (*shape, 3) and out.dtype == np.float32
    np.testing.assert_allclose(out, value, atol=1e-6)


@pytest.mark.parametrize("method", METHODS)
def test_partly_saturated_and_noisy_tiny_images_are_finite_and_in_range(method):
    rng = np.random.default_rng(0)
    for shape in [(1, 1), (2, 3), (4, 4), (9, 13)]:
        img = rng.random((*shape, 3))
        img[0, 0] = 1.0
        out = method(img)
        assert np.isfinite(out).all() and out.min() >= 0.0 and out.max() <= 1.0


@pytest.mark.parametrize("method", METHODS)
def test_deterministic(method, scene):
    _, uneven = scene
    np.testing.assert_array_equal(method(uneven), method(uneven.copy()))


@pytest.mark.parametrize("method", METHODS)
@pytest.mark.parametrize(
    "bad, match",
    [
        (np.zeros((4, 4)), r"expected an \(H, W, 3\) image"),
        (np.zeros((0, 4, 3)), r"expected an \(H, W, 3\) image"),
        (np.full((2, 2, 3), np.nan), "NaN or inf"),
        (np.full((2, 2, 3), "a"), "expected float values"),
        (np.full((2, 2, 3), 255, dtype=np.uint8), r"got dtype uint8 \(divide 8-bit data by 255\)"),
    ],
)
def test_bad_inputs_are_refused(method, bad, match):
    with pytest.raises(ValueError, match=match):
        method(bad)


def test_lab_matches_scikit_image_and_round_trips():
    color = pytest.importorskip("skimage.color")
    rgb = np.random.default_rng(1).random((20, 30, 3))
    # scikit-image uses a rounded D65 white (0.95047, 1, 1.08883); ours is the matrix row sum: < 0.01 L*a*b* units.
    np.testing.assert_allclose(srgb_to_lab(rgb), color.rgb2lab(rgb), atol=0.01)
    np.testing.assert_allclose(lab_to_srgb(srgb_to_lab(rgb)), rgb, atol=1e-9)
    np.testing.assert_allclose(srgb_to_lab(np.ones(3)), [100.0, 0.0, 0.0], atol=1e-9)


def test_clahe_keeps_a_tile_with_a_flat_histogram():
    ramp = (np.arange(256) + 0.5) / 256.0
    lightness = np.tile(ramp, (4, 1))  # each row holds every bin once: a flat histogram
    out = clahe_lightness(lightness, ClaheConfig(tiles_y=1, tiles_x=1, clip_limit=2.0))
    np.testing.assert_allclose(out, lightness, atol=1e-12)


def test_clahe_without_clipping_on_one_tile_is_global_histogram_equalisation():
    values = np.random.default_rng(2).random((30, 40)) ** 3
    config = ClaheConfig(tiles_y=1, tiles_x=1, clip_limit=1e9, nbins=64)
    out = clahe_lightness(values, config)
    # Reference: the empirical CDF sampled at the bin edges, interpolated linearly inside bins.
    edges = np.linspace(0.0, 1.0, 65)
    cdf_at_edges = np.concatenate([[0.0], np.cumsum(np.histogram(values, bins=edges)[0]) / values.size])
    np.testing.assert_allclose(out, np.interp(values, edges, cdf_at_edges), atol=1e-12)


def test_clahe_clip_limit_bounds_the_change():
    even = even_texture(np.random.default_rng(4), 64, 64)
    small = np.abs(clahe(even, ClaheConfig(clip_limit=1.2)) - even).mean()
    large = np.abs(clahe(even, ClaheConfig(clip_limit=8.0)) - even).mean()
    assert small < 0.5 * large


def test_clahe_keeps_chroma_of_a_grey_image():
    grey = np.repeat(even_texture(np.random.default_rng(5), 32, 32)[..., :1], 3, axis=2)
    out = clahe(grey)
    np.testing.assert_allclose(out[..., 0], out[..., 1], atol=2e-6)
    np.testing.assert_allclose(out[..., 1], out[..., 2], atol=2e-6)


@pytest.mark.parametrize("sigma", [0.7, 3.0, 9.0, 25.0, 140.0])
def test_gaussian_blur_matches_scipy(sigma):
    img = np.random.default_rng(6).random((48, 64))
    ref = gaussian_filter(img, sigma, mode="reflect", truncate=8.0)
    # Exact kernel up to sigma 8; three box filters above (incl. windows wider than the image at sigma 140).
    # The exact path truncates its kernel at 4 sigma (tail mass ~6e-5).
    np.testing.assert_allclose(gaussian_blur(img, sigma), ref, atol=5e-5 if sigma <= 8 else 4e-3)


def test_box_widths_reproduce_the_variance():
    for sigma in [9.0, 30.0, 250.0]:
        widths = box_widths_for_gaussian(sigma)
        assert all(w % 2 == 1 for w in widths)
        variance = sum((w * w - 1) / 12.0 for w in widths)
        assert abs(np.sqrt(variance) - sigma) / sigma < 0.03


def test_simplest_colour_balance_stretches_percentiles():
    values = np.linspace(-2.0, 3.0, 101)[None, :]
    out = simplest_colour_balance(values, 10.0, 90.0)
    np.testing.assert_allclose(out[0, 10], 0.0, atol=1e-12)
    np.testing.assert_allclose(out[0, 90], 1.0, atol=1e-12)
    np.testing.assert_allclose(out[0, 50], 0.5, atol=1e-12)
    assert simplest_colour_balance(np.full((3, 3), 0.25), 1.0, 99.0) is None


def test_msrcr_removes_smooth_illumination_gradient():
    tex = even_texture(np.random.default_rng(7), 64, 96)
    ramp = np.linspace(0.15, 1.0, 96)[None, :, None]
    before = (tex * ramp)[:, :24].mean() / (tex * ramp)[:, -24:].mean()
    out = msrcr(tex * ramp)
    after = out[:, :24].mean() / out[:, -24:].mean()
    assert before < 0.3
    assert after > before + 0.1  # measured 0.28 -> 0.43


@pytest.mark.parametrize(
    "kwargs, match",
    [
        ({"clip_limit": 0.5}, "clip_limit"),
        ({"tiles_x": 0}, "tiles_x"),
        ({"nbins": 1}, "nbins"),
    ],
)
def test_clahe_config_errors(kwargs, match):
    with pytest.raises(ValueError, match=match):
        ClaheConfig(**kwargs)


@pytest.mark.parametrize(
    "kwargs, match",
    [
        ({"sigma_fractions": ()}, "sigma_fractions"),
        ({"sigma_fractions": (0.1, -1.0)}, "sigma_fractions"),
        ({"offset": 0.0}, "offset"),
        ({"low_percent": 60.0, "high_percent": 40.0}, "low_percent < high_percent"),
    ],
)
def test_msrcr_config_errors(kwargs, match):
    with pytest.raises(ValueError, match=match):
        MsrcrConfig(**kwargs)


def test_enhance_folder_keeps_names_and_sizes(tmp_path, scene):
    _, uneven = scene
    write_png(tmp_path / "in" / "frame_000.png", uneven)
    write_png(tmp_path / "in" / "frame_001.png", uneven[:33, :47])
    (tmp_path / "in" / "notes.txt").write_text("not an image")
    for method in ("clahe", "msrcr"):
        written = enhance_folder(method, tmp_path / "in", tmp_path / method)
        assert [p.name for p in written] == ["frame_000.png", "frame_001.png"]
        assert read_image(written[1]).shape == (33, 47, 3)
        record = json.loads((tmp_path / method / "baseline2d_provenance.json").read_text())
        assert record["method"] == method and record["images"] == ["frame_000.png", "frame_001.png"]
    expected = to_uint8(clahe(read_image(tmp_path / "in" / "frame_000.png")))
    np.testing.assert_array_equal(np.rint(read_image(tmp_path / "clahe" / "frame_000.png") * 255), expected)


def test_enhance_folder_options_reach_the_method(tmp_path, scene):
    _, uneven = scene
    write_png(tmp_path / "in" / "a.png", uneven)
    enhance_folder("clahe", tmp_path / "in", tmp_path / "mild", clip_limit=1.05)
    enhance_folder("clahe", tmp_path / "in", tmp_path / "strong", clip_limit=6.0)
    source = read_image(tmp_path / "in" / "a.png")
    mild = np.abs(read_image(tmp_path / "mild" / "a.png") - source).mean()
    strong = np.abs(read_image(tmp_path / "strong" / "a.png") - source).mean()
    assert mild < 0.5 * strong


def test_enhance_folder_errors(tmp_path, scene):
    _, uneven = scene
    write_png(tmp_path / "in" / "a.png", uneven)
    with pytest.raises(ValueError, match="unknown method 'sharpen'"):
        enhance_folder("sharpen", tmp_path / "in", tmp_path / "out")
    with pytest.raises(ValueError, match=r"unknown options \['sigma'\] for method 'clahe'"):
        enhance_folder("clahe", tmp_path / "in", tmp_path / "out", sigma=3)
    with pytest.raises(ValueError, match=r"needs a checkpoint \(--checkpoint"):
        enhance_folder("cyclegan", tmp_path / "in", tmp_path / "out")
    with pytest.raises(FileNotFoundError, match="image folder not found"):
        enhance_folder("msrcr", tmp_path / "missing", tmp_path / "out")
    (tmp_path / "empty").mkdir()
    with pytest.raises(ValueError, match="no image files"):
        enhance_folder("msrcr", tmp_path / "empty", tmp_path / "out")
    write_png(tmp_path / "in" / "a.jpg", uneven)  # written as PNG bytes; only the name matters here
    with pytest.raises(ValueError, match="would overwrite its output PNG"):
        enhance_folder("msrcr", tmp_path / "in", tmp_path / "out")


def test_an_output_replaces_an_earlier_one_whole_and_never_a_foreign_folder(tmp_path, scene):
    """OUT_DIR with other files (e.g. a dataset's gt/) is refused, its files untouched; an earlier output is replaced
    whole (a rerun on fewer images leaves none of the old ones); a failed run leaves the earlier output as it was;
    stems that differ only in letter case are refused (one file on macOS and Windows)."""
    from spotlessgs.io.errors import InputError

    _, uneven = scene
    for name in ("a", "b"):
        write_png(tmp_path / "in" / f"{name}.png", uneven)
    write_png(tmp_path / "gt" / "a.png", np.full_like(uneven, 0.5))
    before = (tmp_path / "gt" / "a.png").read_bytes()
    with pytest.raises(InputError, match=r"gt: holds files but no baseline2d_provenance\.json \(a\.png\): not an "
                                         r"earlier output of this command"):
        enhance_folder("clahe", tmp_path / "in", tmp_path / "gt")
    assert (tmp_path / "gt" / "a.png").read_bytes() == before

    assert [p.name for p in enhance_folder("clahe", tmp_path / "in", tmp_path / "out")] == ["a.png", "b.png"]
    (tmp_path / "in" / "b.png").unlink()
    assert [p.name for p in enhance_folder("msrcr", tmp_path / "in", tmp_path / "out")] == ["a.png"]
    assert sorted(p.name for p in (tmp_path / "out").iterdir()) == ["a.png", "baseline2d_provenance.json"]
    kept = {p.name: p.read_bytes() for p in (tmp_path / "out").iterdir()}
    (tmp_path / "in" / "c.png").write_bytes(b"damaged")
    with pytest.raises(ValueError, match=r"c\.png: cannot decode image"):
        enhance_folder("clahe", tmp_path / "in", tmp_path / "out")
    assert {p.name: p.read_bytes() for p in (tmp_path / "out").iterdir()} == kept
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".out")]  # no temporary folder left
    (tmp_path / "in" / "c.png").unlink()
    write_png(tmp_path / "in" / "A.png", uneven)
    with pytest.raises(ValueError, match=r"a\.png: has the same name as .*A\.png \(up to letter case\)"):
        enhance_folder("clahe", tmp_path / "in", tmp_path / "out2")
