"""Held-out validation views taken from the training split, and what is measured on them.

Automatic model selection and the Gaussian budget need an error on views the model was not fitted to, computed from
the uneven input images alone (a real user has no ground truth, and the test split stays untouched for evaluation).
Two held-out sets: every k-th training view (by position in the training split), or a seeded random fraction of the
pixel blocks of every fitted view (:func:`holdout_blocks`): those pixels are never fitted, so their error measures how
well the model predicts new observations of surfaces whose geometry the other views pin down — the appearance model,
not the extrapolation of geometry to a new viewpoint.

Also here: :func:`gaussian_contributions`, the total blending weight of every Gaussian over a set of views, which says
how much removing a Gaussian can change the renders.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import torch

from spotlessgs.io.camera_batch import Cameras
from spotlessgs.io.seeding import torch_generator
from spotlessgs.metrics import psnr_from_mse
from spotlessgs.models.photometric import PhotometricCamera
from spotlessgs.models.relightable import RelightableScene
from spotlessgs.rasterizer import rasterize


@dataclass(frozen=True)
class ViewSplit:
    """Training views divided into fitted and held-out validation views (dataset indices)."""

    # Views the optimiser fits.
    fit: list[int]
    # Held-out validation views (every k-th training view); empty when validation is off.
    validation: list[int]


def split_training_views(train: Sequence[int], every: int) -> ViewSplit:
    """Hold out every ``every``-th training view (positions every-1, 2·every-1, …) as validation; 0 = none.

    The first held-out view is the ``every``-th, not the first, so that the fitted set starts where the loop starts.

    Raises:
        ValueError: ``every`` is 1 or negative, or the split would leave no fitted or no validation view.
    """
    train = [int(k) for k in train]
    if every == 0:
        return ViewSplit(train, [])
    if every < 2:
        raise ValueError(f"validation_every must be 0 (off) or >= 2, got {every}")
    validation = [k for pos, k in enumerate(train) if (pos + 1) % every == 0]
    fit = [k for pos, k in enumerate(train) if (pos + 1) % every != 0]
    if not validation:
        raise ValueError(f"validation_every={every} holds out no view of the {len(train)} training views "
                         f"(use a smaller value or more frames)")
    return ViewSplit(fit, validation)


def block_size(width: int, block: int | None = None) -> int:
    """Side (px) of a held-out pixel block: ``block`` when given, else 1/20 of the image width (at least 2 px)."""
    return block or max(2, round(width / 20))


def holdout_blocks(views: int, height: int, width: int, fraction: float, block: int, seed: int) -> torch.Tensor:
    """(views, height, width) bool: a seeded random ``fraction`` of the ``block``×``block`` pixel blocks of each view
    (at least one block per view; blocks at the right/bottom edge are cut to the image)."""
    if not 0.0 < fraction < 1.0:
        raise ValueError(f"holdout_blocks: fraction must be in (0, 1), got {fraction}")
    if block < 1:
        raise ValueError(f"holdout_blocks: block must be >= 1, got {block}")
    rows, cols = -(-height // block), -(-width // block)
    count = max(1, int(round(fraction * rows * cols)))
    if count >= rows * cols:  # every block held out: nothing left to fit
        raise ValueError(f"validation_blocks={fraction} of {block} px blocks holds out every pixel of a {width} x "
                         f"{height} training image; use smaller blocks (validation_block) or a smaller fraction")
    gen = torch_generator(seed, "holdout_blocks")
    chosen = torch.zeros(views, rows * cols, dtype=torch.bool)
    for v in range(views):
        chosen[v, torch.randperm(rows * cols, generator=gen)[:count]] = True
    grid = chosen.reshape(views, rows, cols)
    return grid.repeat_interleave(block, 1).repeat_interleave(block, 2)[:, :height, :width].contiguous()


def fitted_and_scored_pixels(
    held_out: torch.Tensor | None, unseen: torch.Tensor | None, views: int,
) -> tuple[torch.Tensor | None, torch.Tensor | None]:
    """Which pixels the loss leaves alone and which the held-out scores use.

    Args:
        held_out: (V, H, W) bool held-out pixel blocks, or None; unseen: (V, H, W) (or (H, W), the same in every
        view) bool working-camera pixels without an input sample (``TrainingViews.unseen``), or None; views: V.
    Returns:
        ``ignored`` (V, H, W): held-out or unseen, never fitted; ``scored`` (V, H, W): what the held-out scores use,
        the held-out blocks (or, without blocks, every pixel) that are not unseen. Each is None where it would select
        nothing (``ignored``) or everything (``scored``).
    """
    if unseen is None:
        return held_out, held_out
    unseen = unseen.expand(views, *unseen.shape[-2:])
    if held_out is None:
        return unseen, ~unseen
    return held_out | unseen, held_out & ~unseen


@dataclass(frozen=True)
class HeldOutScore:
    """Spotlight-lit PSNR of held-out pixels: all of them, and the darkest of them."""

    psnr: float  # dB, from the mean squared error over every scored pixel
    # dB over the scored pixels whose observed brightness (channel mean) is at most the dark_quantile of all scored
    # pixels: where the spotlight barely reaches, so the low-frequency (ambient and bounce) light is what lights them.
    psnr_dark: float


@torch.no_grad()
def held_out_score(
    scene: RelightableScene, cameras: Cameras, images: torch.Tensor, indices: Sequence[int], backend: str = "auto",
    num_threads: int | None = None, pixel_masks: torch.Tensor | None = None, dark_quantile: float = 0.5,
    photometric: PhotometricCamera | None = None,
) -> HeldOutScore:
    """PSNR (dB) of the spotlight-lit renders against the input images over ``indices``, on all scored pixels and on
    the darkest ``dark_quantile`` of them.

    Args:
        scene: the model; cameras: V views; images: (V, H, W, 3) linear inputs.
        indices: the views to render (non-empty).
        pixel_masks: optional (V, H, W) bool: score only these pixels of each view (held-out blocks).
        dark_quantile: in (0, 1]: the share of scored pixels, darkest first by observed brightness, in ``psnr_dark``.
        photometric: the run's photometric camera: renders are compared as the camera records them; a held-out
            frame whose exposure is unknown (auto-exposure, no record) gets its least-squares gain
            (:func:`frame_gain`) first, so that the camera's exposure changes are not scored as model error (scored
            at the fitted frames' mean exposure, the held-out PSNR of the robot-camera bedroom stayed at 18.2-18.3 dB
            from step 300 on, and the Gaussian budget stopped growth at 848 Gaussians).

    The squared error is averaged over all scored pixels of all views before the log, so one easy view cannot hide a
    bad one. Relighting removes the spotlight but keeps the low-frequency light, so an error of that light matters in
    the relit image much more than its share of the spotlight-lit error; ``psnr_dark`` measures it where it dominates.
    """
    if len(indices) == 0:
        raise ValueError("held_out_score: no views given")
    if not 0.0 < dark_quantile <= 1.0:
        raise ValueError(f"held_out_score: dark_quantile must be in (0, 1], got {dark_quantile}")
    errors, brightness = [], []
    for k in indices:
        out = scene.render(cameras[k], backend=backend, num_threads=num_threads)
        recorded = out.image if photometric is None else photometric(out.image, k)
        mask = None if pixel_masks is None else pixel_masks[k].to(recorded.device)
        if photometric is not None and photometric.exposure_unknown(k):
            recorded = recorded * frame_gain(recorded, images[k], mask)
        sq = ((recorded.clamp(0, 1) - images[k]) ** 2).mean(-1)  # (H, W), mean over the colour channels
        seen = images[k].mean(-1)
        if mask is not None:
            sq, seen = sq[mask], seen[mask]
        errors.append(sq.reshape(-1).double().cpu())
        brightness.append(seen.reshape(-1).double().cpu())
    err, bright = torch.cat(errors), torch.cat(brightness)
    if err.numel() == 0:
        raise ValueError("held_out_score: the masks select no pixel")
    dark = torch.argsort(bright, stable=True)[: max(1, int(math.ceil(dark_quantile * err.numel())))]
    return HeldOutScore(psnr_from_mse(float(err.mean())), psnr_from_mse(float(err[dark].mean())))


def frame_gain(recorded: torch.Tensor, observed: torch.Tensor, mask: torch.Tensor | None = None) -> float:
    """The gain g minimising Σ (g · recorded − observed)² over the pixels of ``mask`` (all when None) that are not
    clipped in ``observed`` (every channel below 1); 1.0 when nothing is left or the render is black there. One
    frame's version of the evaluation's sequence gain (``evaluation.alignment``), in linear light.

    Args:
        recorded: (H, W, C) render as the camera records it (linear); observed: (H, W, C) linear image.
        mask: (H, W) bool.
    """
    use = (observed < 1.0).all(-1)
    if mask is not None:
        use &= mask
    r, o = recorded[use].double(), observed[use].double()
    denominator = float((r * r).sum())
    return float((r * o).sum()) / denominator if denominator > 0 else 1.0


def validation_psnr(
    scene: RelightableScene, cameras: Cameras, images: torch.Tensor, indices: Sequence[int], backend: str = "auto",
    num_threads: int | None = None, pixel_masks: torch.Tensor | None = None,
    photometric: PhotometricCamera | None = None,
) -> float:
    """PSNR (dB) over all scored pixels (:func:`held_out_score` ``.psnr``; arguments as there)."""
    return held_out_score(scene, cameras, images, indices, backend, num_threads, pixel_masks,
                          photometric=photometric).psnr


def evenly_spaced(indices: Sequence[int], count: int) -> list[int]:
    """At most ``count`` entries of ``indices``, evenly spaced, in order (all of them when there are fewer)."""
    indices = list(indices)
    if count >= len(indices):
        return indices
    step = len(indices) / count
    return [indices[int(i * step)] for i in range(count)]


def gaussian_contributions(
    means: torch.Tensor, quats: torch.Tensor, scales: torch.Tensor, opacities: torch.Tensor, cameras: Cameras,
    indices: Sequence[int], backend: str = "auto", num_threads: int | None = None,
) -> torch.Tensor:
    """(N,) total blending weight Σ_views Σ_pixels α_i T_i of every Gaussian (pixel units, ≥ 0).

    One render per view of a constant one-channel feature f_i = 1: the image is Σ_i f_i α_i T_i, so the gradient of
    the image sum with respect to f_i is exactly Σ_pixels α_i T_i. Removing Gaussian i changes any render by at most
    its weight times the colour difference to what lies behind it, so a Gaussian with a negligible total weight does
    not change the renders.

    Args:
        means (N, 3), quats (N, 4), scales (N, 3), opacities (N,): the Gaussians (activated values; no gradient is
        taken for them). cameras: V views; indices: views to sum over.
    """
    means, quats, scales, opacities = (t.detach() for t in (means, quats, scales, opacities))
    total = torch.zeros(len(means), dtype=means.dtype, device=means.device)
    for k in indices:
        view = cameras[k]
        ones = torch.ones((len(means), 1), dtype=means.dtype, device=means.device, requires_grad=True)
        out = rasterize(means, quats, scales, opacities, ones, view.viewmat, view.K, view.width, view.height,
                        background=torch.zeros(1, dtype=means.dtype, device=means.device), backend=backend,
                        num_threads=num_threads)
        (grad,) = torch.autograd.grad(out.image.sum(), ones)
        total += grad[:, 0].clamp_min(0.0)
    return total
