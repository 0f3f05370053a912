"""Exposure alignment: one least-squares gain for a whole sequence, in linear light.

The relighting constant L0 sets an arbitrary global brightness, so raw PSNR mostly measures that gain. The aligned
metrics first solve  g* = argmin_g Σ ‖g · lin(pred) − lin(gt)‖²  = Σ lin(pred)·lin(gt) / Σ lin(pred)²  over every pixel
and channel of every image of the sequence (lin = inverse sRGB transfer), then score srgb(clip(g* · lin(pred), 0, 1)).
"""

from __future__ import annotations

from dataclasses import dataclass, field

from torch import Tensor

from spotlessgs.io.colorspace import linear_to_srgb, srgb_to_linear


@dataclass
class GainAccumulator:
    """Running sums for the sequence-wide least-squares gain; feed image pairs one at a time."""

    sum_pg: float = 0.0  # Σ lin(pred) · lin(gt) over all pixels seen so far
    sum_pp: float = 0.0  # Σ lin(pred)² over all pixels seen so far
    count: int = field(default=0)  # number of image pairs added

    def add(self, pred: Tensor, gt: Tensor) -> None:
        """Add one pair (or a batch) of sRGB images in [0, 1]; ``pred`` and ``gt`` share any shape."""
        if pred.shape != gt.shape:
            raise ValueError(f"pred and gt shapes differ: {tuple(pred.shape)} vs {tuple(gt.shape)}")
        lp, lg = srgb_to_linear(pred.double()), srgb_to_linear(gt.double())
        self.sum_pg += float((lp * lg).sum())
        self.sum_pp += float((lp * lp).sum())
        self.count += 1

    def gain(self) -> float:
        """The least-squares gain g*.

        Raises:
            ValueError: nothing was added, or every prediction pixel is black (the gain is undefined).
        """
        if self.count == 0:
            raise ValueError("no images were added: the exposure gain is undefined")
        if self.sum_pp <= 0.0:
            raise ValueError("every predicted pixel is black: the exposure gain is undefined")
        return self.sum_pg / self.sum_pp


def exposure_gain(preds: Tensor, gts: Tensor) -> float:
    """Least-squares linear-light gain for a sequence held in memory.

    Args:
        preds: (N, 3, H, W) sRGB predictions in [0, 1].
        gts: (N, 3, H, W) sRGB references in [0, 1].

    Returns:
        the scalar gain g* (see the module docstring).
    """
    acc = GainAccumulator()
    acc.add(preds, gts)
    return acc.gain()


def apply_gain(pred: Tensor, gain: float) -> Tensor:
    """srgb(clip(gain · lin(pred), 0, 1)); any shape, sRGB in [0, 1] → same shape and dtype."""
    if not gain >= 0:
        raise ValueError(f"gain must be a non-negative number, got {gain}")
    out = linear_to_srgb((srgb_to_linear(pred.double()) * gain).clamp(0.0, 1.0))
    return out.to(pred.dtype)
