"""Held-out validation views taken from the training split, and what is measured on them.

Automatic model selection and the Gaussian budget need an error on views the model was not fitted to, computed from
the uneven input images alone (a real user has no ground truth, and the test split stays untouched for evaluation).
Every k-th training view (by position in the training split) is held out; the rest are fitted.

Also here: :func:`gaussian_contributions`, the total blending weight of every Gaussian over a set of views, which says
how much removing a Gaussian can change the renders.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import torch

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


@torch.no_grad()
def validation_psnr(
    scene: RelightableScene, c2ws: torch.Tensor, viewmats: torch.Tensor, K: torch.Tensor, images: torch.Tensor,
    indices: Sequence[int], width: int, height: int, backend: str = "auto", num_threads: int | None = None,
) -> float:
    """PSNR (dB) of the spotlight-lit renders against the input images, from the mean squared error over ``indices``.

    Args:
        scene: the model; c2ws, viewmats: (V, 4, 4) cameras (OpenCV); K: (3, 3); images: (V, H, W, 3) linear inputs.
        indices: the views to render (non-empty).
    The MSE is averaged over all pixels of all views before the log, so one easy view cannot hide a bad one.
    """
    if len(indices) == 0:
        raise ValueError("validation_psnr: no views given")
    total = 0.0
    for k in indices:
        out = scene.render(c2ws[k], viewmats[k], K, width, height, backend=backend, num_threads=num_threads)
        total += float(torch.mean((out.image.clamp(0, 1) - images[k]) ** 2))
    mse = total / len(indices)
    return float("inf") if mse <= 0 else -10.0 * math.log10(mse)


def evenly_spaced(indices: Sequence[int], count: int) -> list[int]:
    """At most ``count`` entries of ``indices``, evenly spaced, in order (all of them when there are fewer)."""
    indices = list(indices)
    if count >= len(indices):
        return indices
    step = len(indices) / count
    return [indices[int(i * step)] for i in range(count)]


def gaussian_contributions(
    means: torch.Tensor, quats: torch.Tensor, scales: torch.Tensor, opacities: torch.Tensor,
    viewmats: torch.Tensor, K: torch.Tensor, width: int, height: int, indices: Sequence[int],
    backend: str = "auto", num_threads: int | None = None,
) -> torch.Tensor:
    """(N,) total blending weight Σ_views Σ_pixels α_i T_i of every Gaussian (pixel units, ≥ 0).

    One render per view of a constant one-channel feature f_i = 1: the image is Σ_i f_i α_i T_i, so the gradient of
    the image sum with respect to f_i is exactly Σ_pixels α_i T_i. Removing Gaussian i changes any render by at most
    its weight times the colour difference to what lies behind it, so a Gaussian with a negligible total weight does
    not change the renders.

    Args:
        means (N, 3), quats (N, 4), scales (N, 3), opacities (N,): the Gaussians (activated values; no gradient is
        taken for them). viewmats: (V, 4, 4) world-to-camera; K: (3, 3); indices: views to sum over.
    """
    means, quats, scales, opacities = (t.detach() for t in (means, quats, scales, opacities))
    total = torch.zeros(len(means), dtype=means.dtype, device=means.device)
    for k in indices:
        ones = torch.ones((len(means), 1), dtype=means.dtype, device=means.device, requires_grad=True)
        out = rasterize(means, quats, scales, opacities, ones, viewmats[k], K, width, height,
                        background=torch.zeros(1, dtype=means.dtype, device=means.device), backend=backend,
                        num_threads=num_threads)
        (grad,) = torch.autograd.grad(out.image.sum(), ones)
        total += grad[:, 0].clamp_min(0.0)
    return total
