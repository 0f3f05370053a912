"""PSNR and SSIM: golden values from scikit-image on fixed images, identities, symmetry, error paths."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
import torch

from spotlessgs.metrics import PSNR, SSIM, gaussian_kernel1d, psnr, ssim, ssim_map
from spotlessgs.io.images import read_image

IMAGES = Path(__file__).parent / "golden" / "lpips_images"
# (pred, gt, PSNR dB, SSIM) computed with scikit-image 0.26: peak_signal_noise_ratio(gt, pred, data_range=1) and
# structural_similarity(pred, gt, gaussian_weights=True, sigma=1.5, use_sample_covariance=False, data_range=1,
# channel_axis=2) on float64 images read with spotlessgs.io.images.read_image.
GOLDEN = [
    ("astronaut_noise.png", "astronaut.png", 22.31981971013446, 0.505067122460022),
    ("astronaut_blur.png", "astronaut.png", 23.15022732672929, 0.7742405755876426),
    ("chelsea.png", "astronaut.png", 8.80606866019934, 0.10544457748758294),
]

pytestmark = pytest.mark.usefixtures("one_torch_thread")



def _chw(name: str) -> torch.Tensor:
    return torch.from_numpy(read_image(IMAGES / name)).permute(2, 0, 1).double()


@pytest.mark.parametrize("pred,gt,want_psnr,want_ssim", GOLDEN)
def test_golden_values_match_scikit_image(pred, gt, want_psnr, want_ssim):
    x, y = _chw(pred), _chw(gt)
    assert float(psnr(x, y)[0]) == pytest.approx(want_psnr, abs=1e-9)
    assert float(ssim(x, y)[0]) == pytest.approx(want_ssim, abs=1e-9)
    # float32 path stays close to the float64 reference
    assert float(ssim(x.float(), y.float())[0]) == pytest.approx(want_ssim, abs=2e-5)


def test_live_scikit_image_agreement_on_random_batch():
    skm = pytest.importorskip("skimage.metrics")
    rng = np.random.default_rng(3)
    a = rng.random((3, 3, 40, 53))
    b = np.clip(a + rng.normal(0, 0.1, a.shape), 0, 1)
    got_s = ssim(torch.from_numpy(a), torch.from_numpy(b)).numpy()
    got_p = psnr(torch.from_numpy(a), torch.from_numpy(b)).numpy()
    for i in range(3):
        want_s = skm.structural_similarity(a[i], b[i], gaussian_weights=True, sigma=1.5, use_sample_covariance=False,
                                           data_range=1.0, channel_axis=0)
        want_p = skm.peak_signal_noise_ratio(b[i], a[i], data_range=1.0)
        assert got_s[i] == pytest.approx(want_s, abs=1e-10)
        assert got_p[i] == pytest.approx(want_p, abs=1e-10)


def test_psnr_by_hand():
    gt = torch.zeros(1, 3, 4, 4)
    pred = torch.full((1, 3, 4, 4), 0.1)  # MSE = 0.01 → 20 dB
    assert float(psnr(pred, gt)[0]) == pytest.approx(20.0, abs=1e-5)
    assert float(psnr(pred * 255, gt, data_range=255.0)[0]) == pytest.approx(20.0, abs=1e-4)


def test_identities_and_symmetry():
    x, y = _chw("astronaut.png"), _chw("coffee.png")
    assert math.isinf(float(psnr(x, x)[0]))
    assert float(ssim(x, x)[0]) == pytest.approx(1.0, abs=1e-12)
    assert float(psnr(x, y)[0]) == pytest.approx(float(psnr(y, x)[0]), abs=1e-12)
    assert float(ssim(x, y)[0]) == pytest.approx(float(ssim(y, x)[0]), abs=1e-12)
    # batch results equal single-image results, and (C, H, W) input works
    batch = ssim(torch.stack([x, y]), torch.stack([y, y]))
    assert batch.shape == (2,)
    assert float(batch[0]) == pytest.approx(float(ssim(x, y)[0]), abs=1e-12)
    assert float(batch[1]) == pytest.approx(1.0, abs=1e-12)


def test_ssim_map_shape_and_kernel():
    m = ssim_map(torch.rand(2, 3, 20, 30), torch.rand(2, 3, 20, 30))
    assert m.shape == (2, 3, 10, 20)
    k = gaussian_kernel1d(11, 1.5)
    assert float(k.sum()) == pytest.approx(1.0, abs=1e-6)
    assert torch.allclose(k, k.flip(0))


def test_modules_match_functions():
    a, b = torch.rand(2, 3, 16, 16), torch.rand(2, 3, 16, 16)
    assert torch.equal(PSNR()(a, b), psnr(a, b))
    assert torch.equal(SSIM()(a, b), ssim(a, b))
    assert SSIM(window_size=7, sigma=1.0)(a, b).shape == (2,)


def test_integer_inputs_are_accepted():
    a = torch.randint(0, 255, (3, 16, 16))
    assert float(psnr(a, a, data_range=255.0)[0]) == math.inf


@pytest.mark.parametrize(
    "pred,gt,kwargs,exc,match",
    [
        (torch.rand(3, 16, 16), torch.rand(3, 16, 15), {}, ValueError, r"shapes differ: \(3, 16, 16\) vs \(3, 16, 15\)"),
        (torch.rand(16, 16), torch.rand(16, 16), {}, ValueError, r"must have shape \(B, C, H, W\)"),
        (np.zeros((3, 16, 16)), torch.rand(3, 16, 16), {}, TypeError, "pred must be a torch.Tensor, got ndarray"),
        (torch.rand(3, 8, 16), torch.rand(3, 8, 16), {}, ValueError, "8x16 pixels are smaller than the 11x11 window"),
        (torch.full((3, 16, 16), float("nan")), torch.rand(3, 16, 16), {}, ValueError, "pred contains NaN"),
        (torch.rand(0, 3, 16, 16), torch.rand(0, 3, 16, 16), {}, ValueError, "empty images"),
        (torch.rand(3, 16, 16), torch.rand(3, 16, 16), {"data_range": 0.0}, ValueError, "data_range must be positive"),
        (torch.rand(3, 16, 16), torch.rand(3, 16, 16), {"window_size": 4}, ValueError, "positive odd integer, got 4"),
        (torch.rand(3, 16, 16), torch.rand(3, 16, 16), {"sigma": -1.0}, ValueError, "sigma must be positive"),
    ],
)
def test_ssim_errors(pred, gt, kwargs, exc, match):
    with pytest.raises(exc, match=match):
        ssim(pred, gt, **kwargs)


def test_psnr_errors():
    with pytest.raises(ValueError, match="data_range must be positive, got -1"):
        psnr(torch.rand(3, 4, 4), torch.rand(3, 4, 4), data_range=-1)
    with pytest.raises(ValueError, match="gt contains NaN or infinite"):
        psnr(torch.rand(3, 4, 4), torch.full((3, 4, 4), float("inf")))


def test_agrees_with_kornia_valid_padding():
    kornia = pytest.importorskip("kornia")
    g = torch.Generator().manual_seed(7)
    a = torch.rand(2, 3, 33, 47, generator=g)
    b = (a + 0.1 * torch.randn(a.shape, generator=g)).clamp(0, 1)
    want = kornia.metrics.ssim(a, b, 11, max_val=1.0, padding="valid").flatten(1).mean(1)
    assert torch.allclose(ssim(a, b), want, atol=2e-6)
