"""Temporal consistency: plain consecutive-frame metrics, depth-based warping, masked metrics, error paths."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from spotlessgs.metrics import masked_psnr, masked_ssim, ssim
from evaluation.synthetic import render_room_sequence
from evaluation.temporal import (
    PAIR_PSNR_CAP_DB,
    PosedFrame,
    sequence_flicker,
    temporal_scores,
    warp_into,
    warped_temporal_scores,
)
from spotlessgs.io.cameras import opengl_to_opencv_c2w

pytestmark = pytest.mark.usefixtures("one_torch_thread")



@pytest.fixture(scope="module")
def room():
    seq = render_room_sequence(num_frames=6, width=120, height=90, seed=5)
    K = torch.from_numpy(seq.intrinsics.K())
    frames = [
        PosedFrame(torch.from_numpy(seq.even[k]).permute(2, 0, 1), torch.from_numpy(seq.depth[k]),
                   torch.from_numpy(opengl_to_opencv_c2w(seq.c2w_opengl[k])))
        for k in range(len(seq.even))
    ]
    return K, frames


def test_plain_scores_by_hand():
    a = torch.zeros(3, 16, 16)
    frames = [a, a + 0.1, a + 0.1]  # pair 0: MSE 0.01 → 20 dB; pair 1: identical
    s = temporal_scores(iter(frames))
    assert s.psnr[0] == pytest.approx(20.0, abs=1e-4)
    assert math.isinf(s.psnr[1]) and s.ssim[1] == pytest.approx(1.0)
    # the identical pair counts as the cap: one paused frame made the sequence's mean +inf (null in results.json)
    assert s.mean_psnr == pytest.approx((20.0 + PAIR_PSNR_CAP_DB) / 2) and s.identical_pairs == 1
    assert s.ssim[0] == pytest.approx(float(ssim(frames[1], frames[0])[0]))


def test_flicker_is_the_mean_log_step_of_linear_brightness():
    """sRGB 0.5 is linear 0.21404; sRGB 0.25 is linear 0.05087 (the sRGB formula by hand): frames 0.5, 0.25, 0.5
    step by |log(0.05087 / 0.21404)| = 1.4369 twice; a constant sequence does not flicker."""
    grey = torch.ones(3, 16, 16)
    s = temporal_scores(iter([0.5 * grey, 0.25 * grey, 0.5 * grey]))
    step = abs(math.log(((0.25 + 0.055) / 1.055) ** 2.4 / ((0.5 + 0.055) / 1.055) ** 2.4))
    assert s.brightness_step == pytest.approx([step, step]) and s.flicker == pytest.approx(1.4369, abs=1e-3)
    assert temporal_scores(iter([0.3 * grey] * 3)).flicker == 0.0
    assert sequence_flicker(iter([0.5 * grey, 0.25 * grey, 0.5 * grey])) == pytest.approx(step)  # without the PSNRs


def test_warp_with_identical_pose_is_the_identity(room):
    K, frames = room
    f = frames[0]
    warped, valid = warp_into(f.image, f.depth, K, f.c2w, f.c2w, src_depth=f.depth)
    assert bool(valid.all())
    assert torch.allclose(warped, f.image, atol=1e-6)
    assert math.isinf(masked_psnr(warped, f.image, valid))


def test_warping_removes_camera_motion(room):
    K, frames = room
    warped = warped_temporal_scores(frames, K)
    plain = temporal_scores(f.image for f in frames)
    assert len(warped.psnr) == len(frames) - 1
    # an evenly lit static scene: after reprojection consecutive frames agree up to resampling blur
    assert min(warped.psnr) > 28.0 and max(plain.psnr) < 23.0
    assert warped.mean_ssim > plain.mean_ssim + 0.4


def test_occlusion_test_rejects_inconsistent_depth(room):
    K, frames = room
    a, b = frames[0], frames[1]
    _, valid = warp_into(b.image, a.depth, K, a.c2w, b.c2w, src_depth=b.depth)
    _, valid_bad = warp_into(b.image, a.depth, K, a.c2w, b.c2w, src_depth=b.depth * 2.0)
    assert valid.float().mean() > 0.3 and not bool(valid_bad.any())
    wrong = [PosedFrame(f.image, f.depth * 2.0 if k % 2 else f.depth, f.c2w) for k, f in enumerate(frames)]
    with pytest.raises(ValueError, match="none of the 5 consecutive pairs overlaps enough"):
        warped_temporal_scores(wrong, K)


def test_background_depth_is_invalid(room):
    K, frames = room
    f = frames[0]
    depth = f.depth.clone()
    depth[:, :40] = float("inf")
    _, valid = warp_into(f.image, depth, K, f.c2w, f.c2w)
    assert not bool(valid[:, :40].any()) and bool(valid[:, 40:].all())


def test_masked_metrics():
    g = torch.Generator().manual_seed(0)
    a, b = torch.rand(3, 30, 30, generator=g), torch.rand(3, 30, 30, generator=g)
    full = torch.ones(30, 30, dtype=torch.bool)
    assert masked_ssim(a, b, full) == pytest.approx(float(ssim(a, b)[0]), abs=1e-6)
    c = b.clone()
    c[:, :, 15:] = a[:, :, 15:]  # right half identical
    right = torch.zeros(30, 30, dtype=torch.bool)
    right[:, 15:] = True
    assert math.isinf(masked_psnr(c, a, right))
    assert masked_ssim(c, a, right) == pytest.approx(1.0, abs=1e-6)


def test_errors(room):
    K, frames = room
    f = frames[0]
    with pytest.raises(ValueError, match="at least two frames"):
        temporal_scores([torch.rand(3, 16, 16)])
    with pytest.raises(ValueError, match=r"frames 1 and 2 differ in shape"):
        temporal_scores([torch.rand(3, 16, 16)] * 2 + [torch.rand(3, 16, 17)])
    with pytest.raises(ValueError, match="at least two frames"):
        warped_temporal_scores(frames[:1], K)
    with pytest.raises(ValueError, match=r"depth shape \(90, 119\) does not match image size 90x120"):
        warp_into(f.image, f.depth[:, :119], K, f.c2w, f.c2w)
    with pytest.raises(ValueError, match=r"src_depth shape"):
        warp_into(f.image, f.depth, K, f.c2w, f.c2w, src_depth=f.depth[:10])
    with pytest.raises(ValueError, match=r"K must be \(3, 3\)"):
        warp_into(f.image, f.depth, K[:2], f.c2w, f.c2w)
    empty = torch.zeros(90, 120, dtype=torch.bool)
    with pytest.raises(ValueError, match="no valid pixels to score"):
        masked_psnr(f.image, f.image, empty)
    with pytest.raises(ValueError, match="no 11x11 window lies entirely inside"):
        masked_ssim(f.image, f.image, empty)
    with pytest.raises(ValueError, match="mask shape"):
        masked_psnr(f.image, f.image, empty[:5])


def test_warping_through_a_lens_removes_camera_motion():
    """The ray-cast room's frames seen through a barrel lens (images bilinear, depth nearest, as the robot-camera copy
    of a dataset resamples its renders): warped through the lens, consecutive frames agree as well as the pinhole
    frames do; read as a pinhole camera (the lens ignored) the reprojection lands elsewhere and they do not."""
    import cv2
    import numpy as np

    from simulator.sensor_noise import CameraEffects
    from spotlessgs.io.cameras import Intrinsics
    from spotlessgs.io.lens import distort_maps, remap

    seq = render_room_sequence(num_frames=5, width=120, height=90, seed=5)
    lens = CameraEffects(lens="opencv", distortion=(-0.25, 0.05, 0.0, 0.0)).camera(seq.intrinsics)
    map_x, map_y, valid = distort_maps(lens, seq.intrinsics)
    assert valid.all()
    frames = [PosedFrame(torch.from_numpy(remap(seq.even[k], map_x, map_y)).permute(2, 0, 1),
                         torch.from_numpy(cv2.remap(seq.depth[k].astype(np.float32), map_x, map_y, cv2.INTER_NEAREST)),
                         torch.from_numpy(opengl_to_opencv_c2w(seq.c2w_opengl[k]))) for k in range(5)]
    through_lens = warped_temporal_scores(frames, lens)
    pinhole = warped_temporal_scores(
        [PosedFrame(torch.from_numpy(seq.even[k]).permute(2, 0, 1), torch.from_numpy(seq.depth[k]),
                    torch.from_numpy(opengl_to_opencv_c2w(seq.c2w_opengl[k]))) for k in range(5)],
        torch.from_numpy(seq.intrinsics.K()))
    ignored = warped_temporal_scores(frames, torch.from_numpy(lens.K()))
    assert through_lens.mean_psnr > pinhole.mean_psnr - 2.0 and through_lens.mean_psnr > 26.0
    assert ignored.mean_psnr < through_lens.mean_psnr - 3.0
    identity, ok = warp_into(frames[0].image, frames[0].depth, lens, frames[0].c2w, frames[0].c2w)
    assert bool(ok.all()) and torch.allclose(identity, frames[0].image, atol=1e-4)
    with pytest.raises(ValueError, match="camera is 120x90, the images 119x90"):
        warp_into(frames[0].image[:, :, :119], frames[0].depth[:, :119], lens, frames[0].c2w, frames[0].c2w)
    assert isinstance(lens, Intrinsics) and not lens.is_pinhole


def test_exposure_leak_is_the_slope_of_the_brightness_ratio_against_the_gain():
    """A prediction that is the reference times gain^0.5 leaks half the exposure (slope 0.5, pinned by hand: the
    log ratio is exactly 0.5·log g); one that is the reference times a constant leaks nothing; gains that never change
    give NaN; mismatched lengths are refused."""
    from evaluation.temporal import exposure_leak
    from spotlessgs.io.colorspace import linear_to_srgb

    rng = np.random.default_rng(3)
    reference = [rng.uniform(0.05, 0.3, (8, 10, 3)) for _ in range(6)]
    gains = [1.0, 1.7, 3.2, 2.1, 4.0, 1.3]

    def frames(images):
        return [torch.from_numpy(linear_to_srgb(im)).permute(2, 0, 1) for im in images]

    half = [im * g ** 0.5 for im, g in zip(reference, gains)]
    assert exposure_leak(frames(half), frames(reference), gains) == pytest.approx(0.5, abs=0.02)  # 8-bit-free
    steady = [im * 1.8 for im in reference]
    assert exposure_leak(frames(steady), frames(reference), gains) == pytest.approx(0.0, abs=0.01)
    assert math.isnan(exposure_leak(frames(steady), frames(reference), [2.0] * 6))
    with pytest.raises(ValueError, match="6 frames but 5 gains"):
        exposure_leak(frames(steady), frames(reference), gains[:5])


def test_excess_flicker_counts_only_the_brightness_steps_the_reference_does_not_take():
    """A prediction that follows its reference's brightness, however much that changes, has no excess flicker; one
    that is the reference times gains g_t has exactly mean |log(g_t+1 / g_t)| (pinned by hand: log(2) + log(2) +
    log(1.5), over three pairs); fewer than two frames give NaN; sequences of different lengths are refused."""
    from evaluation.temporal import excess_flicker
    from spotlessgs.io.colorspace import linear_to_srgb

    rng = np.random.default_rng(5)
    reference = [rng.uniform(0.02, 0.15, (6, 8, 3)) * level for level in (1.0, 3.0, 0.5, 2.0)]  # none clipped

    def frames(images):
        return [torch.from_numpy(linear_to_srgb(im)).permute(2, 0, 1) for im in images]

    assert sequence_flicker(iter(frames(reference))) > 0.5  # the scene's own steps are large ...
    assert excess_flicker(frames(reference), frames(reference)) == 0.0  # ... and do not count
    assert excess_flicker(frames([1.7 * im for im in reference]), frames(reference)) == pytest.approx(0.0, abs=1e-9)
    gains = [1.0, 2.0, 1.0, 1.5]
    expected = (math.log(2.0) + math.log(2.0) + math.log(1.5)) / 3  # 0.59728
    assert excess_flicker(frames([g * im for g, im in zip(gains, reference)]), frames(reference)) == \
        pytest.approx(expected, abs=1e-9)
    assert math.isnan(excess_flicker(frames(reference[:1]), frames(reference[:1])))
    with pytest.raises(ValueError, match="excess_flicker: the prediction and the reference differ in length"):
        excess_flicker(frames(reference), frames(reference[:3]))
