"""Temporal consistency: PSNR and SSIM between consecutive frames of a sequence.

Plain variant: frame t against frame t+1 (views assumed close). Warped variant, when depth and poses are known:
frame t+1 is reprojected into frame t through frame t's depth and both poses, and only valid pixels (finite depth,
in front of both cameras, inside frame t+1, not occluded when frame t+1's depth is known) are scored. Camera motion then
no longer counts as inconsistency, so the warped figures separate flicker from motion.

Camera convention here: OpenCV axes (x right, y down, z forward), camera-to-world 4×4 matrices, pinhole intrinsics
K = [[fx, 0, cx], [0, fy, cy], [0, 0, 1]] with pixel (i, j) centred at (i + 0.5, j + 0.5), or a camera with a lens
(:class:`~spotlessgs.io.cameras.Intrinsics`: the rays of its pixels and the pixels of points through OpenCV's camera
models, :mod:`spotlessgs.io.lens`).
"""

from __future__ import annotations

import itertools
import math
from dataclasses import dataclass
from typing import Iterable, Iterator, Sequence

import torch
import torch.nn.functional as F
from torch import Tensor

from spotlessgs.io.cameras import Intrinsics
from spotlessgs.io.colorspace import srgb_to_linear
from spotlessgs.io.lens import distort, undistort
from spotlessgs.metrics import masked_psnr, masked_ssim, psnr, ssim


#: The most a consecutive pair counts for in a sequence's mean PSNR (dB): an identical pair (a robot that paused, a
#: repeated frame) has PSNR +inf, which made the whole sequence's mean +inf (null in JSON) whatever its other pairs.
#: Pairs that differ visibly score far below 100 dB (two 8-bit frames one level apart everywhere: 48 dB); only
#: near-identical ones reach it (one level in one channel of one pixel: 88 dB at 64 x 48, 122 dB at 3840 x 2160).
PAIR_PSNR_CAP_DB = 100.0


@dataclass(frozen=True)
class TemporalScores:
    """Per-pair temporal scores of one sequence (pair k compares frames k and k+1)."""

    psnr: list[float]  # PSNR (dB) per consecutive pair
    ssim: list[float]  # SSIM per consecutive pair
    # |log(mean linear brightness of frame k+1 / that of frame k)| per pair: the exposure flicker of a sequence (an
    # auto-exposure camera's pumps in and out); camera motion changes it little where the lighting is even
    brightness_step: list[float] = ()  # type: ignore[assignment]

    @property
    def mean_psnr(self) -> float:
        """Mean PSNR over pairs, each counted at most :data:`PAIR_PSNR_CAP_DB` (an identical pair's is +inf)."""
        return float(sum(min(p, PAIR_PSNR_CAP_DB) for p in self.psnr) / len(self.psnr))

    @property
    def identical_pairs(self) -> int:
        """How many pairs are identical (PSNR +inf)."""
        return sum(1 for p in self.psnr if math.isinf(p))

    @property
    def mean_ssim(self) -> float:
        """Mean SSIM over pairs."""
        return float(sum(self.ssim) / len(self.ssim))

    @property
    def flicker(self) -> float:
        """Mean brightness step over pairs (0: constant brightness; 0.69: every frame half or twice the last)."""
        if not self.brightness_step:
            return math.nan
        return float(sum(self.brightness_step) / len(self.brightness_step))


def mean_linear_brightness(frame: Tensor) -> float:
    """Mean linear intensity of a (3, H, W) sRGB frame in [0, 1] (at least 1e-6, so that its log is finite)."""
    return max(float(srgb_to_linear(frame.double().clamp(0.0, 1.0)).mean()), 1e-6)


def brightness_step(a: Tensor, b: Tensor) -> float:
    """|log(mean linear brightness of frame ``b`` / that of frame ``a``)| (see TemporalScores.brightness_step)."""
    return abs(math.log(mean_linear_brightness(b) / mean_linear_brightness(a)))


def sequence_flicker(frames: Iterable[Tensor]) -> float:
    """TemporalScores.flicker of a sequence of (3, H, W) frames without the pairs' PSNR and SSIM (NaN for fewer
    than two frames)."""
    return TemporalScores([], [], [brightness_step(a, b) for a, b in consecutive_pairs(frames)]).flicker


def excess_flicker(pred: Iterable[Tensor], reference: Iterable[Tensor]) -> float:
    """The flicker of a predicted sequence that its reference does not have: the mean over consecutive pairs of
    |log(b(pred, t+1) / b(pred, t)) - log(b(ref, t+1) / b(ref, t))|, b the mean linear brightness of a (3, H, W) sRGB
    frame. 0: the prediction's brightness changes from frame to frame exactly as the reference's (a relit sequence
    whose steps all come from what enters the view); the brightness steps of the scene itself do not count, unlike
    :func:`sequence_flicker`'s. NaN for fewer than two frames.

    Raises:
        ValueError: the sequences differ in length.
    """
    levels, missing = [], object()
    for p, r in itertools.zip_longest(pred, reference, fillvalue=missing):
        if p is missing or r is missing:
            raise ValueError("excess_flicker: the prediction and the reference differ in length")
        levels.append((math.log(mean_linear_brightness(p)), math.log(mean_linear_brightness(r))))
    if len(levels) < 2:
        return math.nan
    steps = [abs((p1 - p0) - (r1 - r0)) for (p0, r0), (p1, r1) in zip(levels, levels[1:])]
    return float(sum(steps) / len(steps))


def exposure_leak(pred: Iterable[Tensor], reference: Iterable[Tensor], gains: Sequence[float]) -> float:
    """How much of a camera's exposure changes a predicted sequence carries: the least-squares slope of
    log(mean linear brightness of the prediction / that of the reference) against log(exposure gain), over the frames
    of three aligned sequences ((3, H, W) sRGB frames and one gain per frame). 0: the prediction's brightness relative
    to the evenly lit reference does not follow the exposure; 1: it follows it fully, as frames recorded with those
    gains would. NaN when fewer than two frames or the gains do not vary.

    Raises:
        ValueError: the sequences and the gains differ in length, or a gain is not positive.
    """
    levels = [(mean_linear_brightness(p), mean_linear_brightness(r)) for p, r in zip(pred, reference, strict=True)]
    gains = [float(g) for g in gains]
    if len(gains) != len(levels):
        raise ValueError(f"exposure_leak: {len(levels)} frames but {len(gains)} gains")
    if any(not g > 0 for g in gains):
        raise ValueError("exposure_leak: every gain must be positive")
    x = torch.tensor([math.log(g) for g in gains], dtype=torch.float64)
    y = torch.tensor([math.log(p / r) for p, r in levels], dtype=torch.float64)
    if len(gains) < 2 or float(x.var()) == 0.0:
        return math.nan
    xc = x - x.mean()
    return float((xc * (y - y.mean())).sum() / (xc * xc).sum())


def consecutive_pairs(frames: Iterable[Tensor]) -> Iterator[tuple[Tensor, Tensor]]:
    """Yield (frame t, frame t+1) from an iterable of (3, H, W) frames, holding only two in memory."""
    prev = None
    for frame in frames:
        if prev is not None:
            yield prev, frame
        prev = frame


def temporal_scores(frames: Iterable[Tensor]) -> TemporalScores:
    """PSNR and SSIM between consecutive frames.

    Args:
        frames: ordered (3, H, W) frames in [0, 1], all the same size; at least two.

    Raises:
        ValueError: fewer than two frames, or frames of different sizes (the pair index is named).
    """
    ps, ss, steps = [], [], []
    for k, (a, b) in enumerate(consecutive_pairs(frames)):
        if a.shape != b.shape:
            raise ValueError(f"frames {k} and {k + 1} differ in shape: {tuple(a.shape)} vs {tuple(b.shape)}")
        ps.append(float(psnr(b, a)[0]))
        ss.append(float(ssim(b, a)[0]))
        steps.append(brightness_step(a, b))
    if not ps:
        raise ValueError("temporal metrics need at least two frames")
    return TemporalScores(ps, ss, steps)


def _rays_and_projection(camera: Tensor | Intrinsics, h: int, w: int):
    """The normalised ray (x/z, y/z) of every pixel centre, each (H*W,) float64, and the projection of normalised
    points to pixels (u, v), for a (3, 3) pinhole K or a camera with a lens; the projection also says which points the
    camera sees (a lens only maps the normalised points of its own field of view faithfully: a radial polynomial
    folds points far outside it back into the image)."""
    dt = torch.float64
    jj, ii = torch.meshgrid(torch.arange(h, dtype=dt) + 0.5, torch.arange(w, dtype=dt) + 0.5, indexing="ij")
    if isinstance(camera, Intrinsics):
        if (camera.width, camera.height) != (w, h):
            raise ValueError(f"camera is {camera.width}x{camera.height}, the images {w}x{h}")
        rays = torch.from_numpy(undistort(camera, torch.stack([ii, jj], -1).reshape(-1, 2).numpy()))
        edge_u, edge_v = torch.linspace(0, w, 4 * w + 1, dtype=dt), torch.linspace(0, h, 4 * h + 1, dtype=dt)
        edges = torch.cat([torch.stack([edge_u, torch.full_like(edge_u, side)], -1) for side in (0.0, h)]
                          + [torch.stack([torch.full_like(edge_v, side), edge_v], -1) for side in (0.0, w)])
        bounds = torch.from_numpy(undistort(camera, edges.numpy()))  # the field of view's edge (beyond the centres)
        lo, hi = bounds.min(0).values, bounds.max(0).values

        def project(x: Tensor, y: Tensor) -> tuple[Tensor, Tensor, Tensor]:
            xy = torch.stack([x, y], -1)
            seen = ((xy >= lo) & (xy <= hi)).all(-1)
            px = torch.from_numpy(distort(camera, torch.where(seen[:, None], xy, torch.zeros_like(xy)).numpy()))
            return px[:, 0], px[:, 1], seen

        return rays[:, 0], rays[:, 1], project
    K = camera.to(dt)
    if K.shape != (3, 3):
        raise ValueError("K must be (3, 3) and camera poses (4, 4)")

    def project_pinhole(x: Tensor, y: Tensor) -> tuple[Tensor, Tensor, Tensor]:
        return K[0, 0] * x + K[0, 2], K[1, 1] * y + K[1, 2], torch.ones_like(x, dtype=torch.bool)

    return ((ii - K[0, 2]) / K[0, 0]).reshape(-1), ((jj - K[1, 2]) / K[1, 1]).reshape(-1), project_pinhole


def warp_into(
    src: Tensor,
    depth: Tensor,
    K: Tensor | Intrinsics,
    c2w_dst: Tensor,
    c2w_src: Tensor,
    src_depth: Tensor | None = None,
    occlusion_tolerance: float = 0.05,
) -> tuple[Tensor, Tensor]:
    """Reproject image ``src`` (seen from camera src) into the pixel grid of camera dst using dst's depth.

    Args:
        src: (C, H, W) image of the source camera (e.g. frame t+1).
        depth: (H, W) planar depth of the destination camera (frame t), metres; inf/NaN/≤0 where there is no surface.
        K: (3, 3) pinhole intrinsics shared by both cameras, or their camera with its lens (its size the images').
        c2w_dst: (4, 4) camera-to-world of the destination camera (OpenCV axes).
        c2w_src: (4, 4) camera-to-world of the source camera (OpenCV axes).
        src_depth: optional (H, W) planar depth of the source camera, for an occlusion test.
        occlusion_tolerance: relative depth difference above which a reprojected point counts as occluded.

    Returns:
        warped (C, H, W) — ``src`` resampled bilinearly at the reprojected positions (0 where invalid) — and
        valid (H, W) bool.
    """
    c, h, w = src.shape
    if depth.shape != (h, w):
        raise ValueError(f"depth shape {tuple(depth.shape)} does not match image size {h}x{w}")
    if c2w_dst.shape != (4, 4) or c2w_src.shape != (4, 4):
        raise ValueError("K must be (3, 3) and camera poses (4, 4)")
    dt = torch.float64
    ray_x, ray_y, project = _rays_and_projection(K, h, w)
    c2w_dst, c2w_src = c2w_dst.to(dt), c2w_src.to(dt)
    z = depth.to(dt)
    finite = torch.isfinite(z) & (z > 0)
    z = torch.where(finite, z, torch.ones_like(z)).reshape(-1)
    pts = torch.stack([ray_x * z, ray_y * z, z, torch.ones_like(z)], dim=-1)  # (H*W, 4) in dst camera
    src_from_dst = torch.linalg.inv(c2w_src) @ c2w_dst
    p = pts @ src_from_dst.T
    zs = p[:, 2]
    in_front = zs > 1e-9
    zs_safe = torch.where(in_front, zs, torch.ones_like(zs))
    u, v, seen = project(p[:, 0] / zs_safe, p[:, 1] / zs_safe)
    tol = 1e-6  # pixels: round-off at the border must not drop the outermost pixel centres
    inside = (u >= 0.5 - tol) & (u <= w - 0.5 + tol) & (v >= 0.5 - tol) & (v <= h - 0.5 + tol)  # bilinear support
    valid = finite.reshape(-1) & in_front & inside & seen
    grid = torch.stack([2 * u / w - 1, 2 * v / h - 1], dim=-1).reshape(1, h, w, 2)
    warped = F.grid_sample(src[None].to(dt), grid, mode="bilinear", padding_mode="border", align_corners=False)[0]
    if src_depth is not None:
        if src_depth.shape != (h, w):
            raise ValueError(f"src_depth shape {tuple(src_depth.shape)} does not match image size {h}x{w}")
        sd = src_depth.to(dt)
        sd = torch.where(torch.isfinite(sd), sd, torch.full_like(sd, 1e30))
        seen = F.grid_sample(sd[None, None], grid, mode="nearest", padding_mode="border", align_corners=False)
        seen = seen.reshape(-1)
        valid &= (zs - seen).abs() <= occlusion_tolerance * zs.abs()
    valid = valid.reshape(h, w)
    warped = torch.where(valid[None], warped, torch.zeros_like(warped))
    return warped.to(src.dtype), valid


@dataclass(frozen=True)
class PosedFrame:
    """One frame of a sequence with its geometry, for the warped temporal metrics."""

    image: Tensor  # (3, H, W) sRGB in [0, 1]
    depth: Tensor  # (H, W) planar depth in metres, inf where there is no surface
    c2w: Tensor  # (4, 4) camera-to-world, OpenCV axes


def warped_temporal_scores(frames: Iterable[PosedFrame], K: Tensor | Intrinsics,
                           min_valid_fraction: float = 0.05) -> TemporalScores:
    """PSNR and SSIM between frame t and frame t+1 warped into frame t, on valid pixels only.

    Args:
        frames: ordered frames with depth and pose; at least two.
        K: (3, 3) pinhole intrinsics shared by all frames, or their camera with its lens.
        min_valid_fraction: a pair whose valid pixels cover less than this fraction of the image is skipped (too little
            overlap to say anything); NaN is never reported.

    Raises:
        ValueError: fewer than two frames, or no pair has enough valid pixels.
    """
    ps, ss = [], []
    n_pairs = 0
    for a, b in consecutive_pairs(frames):
        n_pairs += 1
        warped, valid = warp_into(b.image, a.depth, K, a.c2w, b.c2w, src_depth=b.depth)
        if float(valid.double().mean()) < min_valid_fraction:
            continue
        try:
            s = masked_ssim(warped, a.image, valid)
        except ValueError:
            continue
        ps.append(masked_psnr(warped, a.image, valid))
        ss.append(s)
    if n_pairs == 0:
        raise ValueError("temporal metrics need at least two frames")
    if not ps:
        raise ValueError(f"none of the {n_pairs} consecutive pairs overlaps enough to score after warping")
    return TemporalScores(ps, ss)
