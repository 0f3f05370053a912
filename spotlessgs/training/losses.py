"""Photometric loss: (1 - λ) L1 + λ (1 - SSIM), with clipped input pixels handled one-sidedly."""

from __future__ import annotations

import torch

from spotlessgs.metrics import ssim


def clipped_l1(pred: torch.Tensor, target: torch.Tensor, saturated: torch.Tensor) -> torch.Tensor:
    """Mean absolute error where clipped pixels only penalise predictions darker than the observation.

    A clipped pixel says only that the true radiance is at least the observed value, so there the error is
    ``max(0, target - pred)``: the model may explain a hot spot brighter than the sensor could record, and clipping
    cannot drag the spotlight model down.

    Args:
        pred: (H, W, 3) rendered linear image.
        target: (H, W, 3) observed linear image.
        saturated: (H, W) bool mask of clipped input pixels.
    """
    diff = pred - target
    err = torch.where(saturated[..., None], torch.relu(-diff), diff.abs())
    return err.mean()


def photometric_loss(
    pred: torch.Tensor, target: torch.Tensor, saturated: torch.Tensor, ssim_lambda: float = 0.2
) -> tuple[torch.Tensor, dict[str, float]]:
    """(1 - λ) clipped L1 + λ (1 - SSIM) between a render and an input view.

    SSIM compares the render clamped to the recordable range [0, 1] with the input (where the input is clipped, a
    brighter render clamps to the same value). Shapes: pred, target (H, W, 3); saturated (H, W).

    Returns:
        the loss (scalar tensor) and its parts as floats (``l1``, ``ssim``).
    """
    l1 = clipped_l1(pred, target, saturated)
    if ssim_lambda > 0:
        s = ssim(pred.clamp(0.0, 1.0).permute(2, 0, 1)[None], target.permute(2, 0, 1)[None])[0]
        loss = (1.0 - ssim_lambda) * l1 + ssim_lambda * (1.0 - s)
        return loss, {"l1": float(l1.detach()), "ssim": float(s.detach())}
    return l1, {"l1": float(l1.detach()), "ssim": float("nan")}
