"""The spotlight's angular profile (RID) as a non-increasing piecewise-linear function of the angle off its axis.

    Φ(θ) = linear interpolation of v_0 ≥ v_1 ≥ … ≥ v_{K-1} > 0 on K knots θ_k = k · (π/2) / (K - 1), constant v_{K-1}
           beyond π/2,
    log v_0 = a (learned),  log v_k = a - Σ_{j ≤ k} softplus(c_j)  (learned c_j: each knot is at most as bright as the
    one before it).

The paper's RID is an MLP of cosine features of θ up to cos 8θ (models.light). Its smallest feature period, 45°, cannot
bend as sharply as a spot lamp's edge: on the bedroom (a Blender spot, 65°, blend 0.35) the MLP rounds the knee at 27°
off into a shoulder from about 22°, and the lamp slides back along its axis to make up for it (docs/results.md, "A
piecewise-linear angular profile"). K = 48 knots resolve 1.9°, and the ordering is what a lamp's beam has: brightest on
the axis, dimming outwards. A lamp whose beam has a dark centre or rings is not monotone; the MLP stays for it
(ModelConfig.rid_model).
"""

from __future__ import annotations

import math

import torch
import torch.nn.functional as F
from torch import nn

# Knots of the piecewise-linear profile over [0, π/2]: 1.9° apart.
PROFILE_KNOTS = 48
# The initial profile: peak 0.68 (the MLP's initial output, so both forms start as bright) and a decrement of
# softplus(-4) = 0.018 nepers per knot (0.42 of the peak at 90° off the axis), a featureless start.
PROFILE_INIT_PEAK = 0.68
PROFILE_INIT_DECREMENT_LOGIT = -4.0
# The profile covers the angles off the axis up to this; beyond it the last knot's value holds.
PROFILE_MAX_ANGLE = math.pi / 2


class MonotoneProfile(nn.Module):
    """Φ(θ) > 0, non-increasing in θ, piecewise linear on `knots` knots over [0, π/2] (module docstring).

    Args:
        knots: K ≥ 2.
    Parameters: `log_peak` () = log v_0, `decrement_logits` (K - 1,) = c_j.
    """

    def __init__(self, knots: int = PROFILE_KNOTS) -> None:
        super().__init__()
        if knots < 2:
            raise ValueError(f"MonotoneProfile: need knots >= 2, got {knots}")
        self.knots = knots
        self.log_peak = nn.Parameter(torch.tensor(math.log(PROFILE_INIT_PEAK)))
        self.decrement_logits = nn.Parameter(torch.full((knots - 1,), PROFILE_INIT_DECREMENT_LOGIT))

    def knot_values(self) -> torch.Tensor:
        """v_k (K,), positive and non-increasing."""
        drops = torch.cumsum(F.softplus(self.decrement_logits), dim=0)
        return torch.exp(torch.cat([self.log_peak[None], self.log_peak - drops]))

    def forward(self, theta: torch.Tensor) -> torch.Tensor:
        """Φ at angles (N, 1) radians → (N, 1), > 0."""
        values = self.knot_values().to(theta.dtype)
        position = (theta / PROFILE_MAX_ANGLE * (self.knots - 1)).clamp(0.0, self.knots - 1)
        lower = position.floor().clamp(max=self.knots - 2).long()
        weight = position - lower
        return values[lower] * (1.0 - weight) + values[lower + 1] * weight
