"""Exposure alignment: sRGB transfer, least-squares gain recovery, error paths."""

from __future__ import annotations

import math

import pytest
import torch

from evaluation.alignment import GainAccumulator, apply_gain, exposure_gain
from spotlessgs.metrics import psnr
from spotlessgs.io.colorspace import linear_to_srgb, srgb_to_linear

pytestmark = pytest.mark.usefixtures("one_torch_thread")



def test_gain_recovers_a_known_exposure_and_aligned_psnr_is_perfect():
    g = torch.Generator().manual_seed(0)
    gt = torch.rand(3, 3, 24, 24, generator=g, dtype=torch.float64) * 0.8
    pred = linear_to_srgb(srgb_to_linear(gt) / 2.5)  # the same images, 2.5× darker in linear light
    gain = exposure_gain(pred, gt)
    assert gain == pytest.approx(2.5, rel=1e-10)
    assert math.isinf(float(psnr(apply_gain(pred, gain), gt).min())) or float(
        psnr(apply_gain(pred, gain), gt).min()) > 200


def test_gain_is_least_squares_by_hand():
    # linear values: pred (0.2, 0.4), gt (0.3, 0.5): g = (0.06 + 0.2) / (0.04 + 0.16) = 1.3
    pred = linear_to_srgb(torch.tensor([0.2, 0.4], dtype=torch.float64))
    gt = linear_to_srgb(torch.tensor([0.3, 0.5], dtype=torch.float64))
    assert exposure_gain(pred, gt) == pytest.approx(1.3, rel=1e-12)


def test_streaming_equals_batch():
    g = torch.Generator().manual_seed(1)
    pred, gt = torch.rand(4, 3, 8, 8, generator=g), torch.rand(4, 3, 8, 8, generator=g)
    acc = GainAccumulator()
    for p, t in zip(pred, gt):
        acc.add(p, t)
    assert acc.gain() == pytest.approx(exposure_gain(pred, gt), rel=1e-12)
    assert acc.count == 4


def test_apply_gain_clips_and_keeps_dtype():
    x = torch.full((3, 2, 2), 0.9, dtype=torch.float32)
    y = apply_gain(x, 10.0)
    assert y.dtype == torch.float32 and float(y.max()) == pytest.approx(1.0, abs=1e-6)


def test_errors():
    with pytest.raises(ValueError, match="no images were added"):
        GainAccumulator().gain()
    with pytest.raises(ValueError, match="every predicted pixel is black"):
        exposure_gain(torch.zeros(1, 3, 4, 4), torch.rand(1, 3, 4, 4))
    with pytest.raises(ValueError, match=r"shapes differ: \(3, 4, 4\) vs \(3, 4, 5\)"):
        GainAccumulator().add(torch.rand(3, 4, 4), torch.rand(3, 4, 5))
    with pytest.raises(ValueError, match="gain must be a non-negative number, got -1"):
        apply_gain(torch.rand(3, 4, 4), -1.0)
    with pytest.raises(ValueError, match="gain must be a non-negative number, got nan"):
        apply_gain(torch.rand(3, 4, 4), float("nan"))
