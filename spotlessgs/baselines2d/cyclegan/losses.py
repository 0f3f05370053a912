"""Cycle-GAN losses: least-squares GAN (Mao et al. 2017) and L1 reconstruction."""

from __future__ import annotations

import torch


def lsgan_loss(scores: torch.Tensor, target_is_real: bool) -> torch.Tensor:
    """Mean of (scores - 1)^2 for real targets, of scores^2 for fake ones. scores: (B, 1, h, w) -> scalar."""
    target = 1.0 if target_is_real else 0.0
    return torch.mean((scores - target) ** 2)


def l1_loss(a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
    """Mean absolute difference of two equally shaped tensors -> scalar."""
    return torch.mean(torch.abs(a - b))
