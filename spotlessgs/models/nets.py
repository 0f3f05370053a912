"""Seeded small MLPs and the sinusoidal positional encoding used by the RID and BRDF networks.

No global random state: every initialisation draws from an explicit `torch.Generator`
(see `spotlessgs.io.seeding.torch_generator`).
"""

from __future__ import annotations

import math

import torch
from torch import nn


def seeded_linear(in_features: int, out_features: int, generator: torch.Generator) -> nn.Linear:
    """An `nn.Linear` initialised like PyTorch's default (uniform ±1/sqrt(fan_in) for weight and bias) from `generator`."""
    layer = nn.Linear(in_features, out_features)
    bound = 1.0 / math.sqrt(in_features)
    with torch.no_grad():
        layer.weight.copy_(torch.rand(layer.weight.shape, generator=generator) * (2 * bound) - bound)
        layer.bias.copy_(torch.rand(layer.bias.shape, generator=generator) * (2 * bound) - bound)
    return layer


def sinusoidal_encoding(x: torch.Tensor, num_frequencies: int) -> torch.Tensor:
    """NeRF-style encoding γ(x) = [x, sin(2⁰πx), cos(2⁰πx), …, sin(2^{F-1}πx), cos(2^{F-1}πx)].

    Args:
        x: (..., D) inputs (unit-vector components in [-1, 1] here).
        num_frequencies: F ≥ 0.
    Returns:
        (..., D · (1 + 2F)) features, grouped [x, then per frequency (sin of all D, cos of all D)].
    """
    if num_frequencies < 0:
        raise ValueError(f"num_frequencies must be >= 0, got {num_frequencies}")
    feats = [x]
    for k in range(num_frequencies):
        arg = (math.pi * 2.0**k) * x
        feats += [torch.sin(arg), torch.cos(arg)]
    return torch.cat(feats, dim=-1)


def encoding_size(dims: int, num_frequencies: int) -> int:
    """Output width of `sinusoidal_encoding` for `dims` inputs: dims · (1 + 2F)."""
    return dims * (1 + 2 * num_frequencies)
