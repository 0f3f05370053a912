"""The unit of the spotlight's radiance (TrainConfig.spot_radiance_unit): where training starts on the albedo/light
scale that the images cannot tell.

An image fixes only the product of albedo and light: albedo × k and light / k render the same. The albedo is capped
at 1 (a sigmoid), the light is not. The spotlight starts with its profile at 0.68 and the fall-off (τ + d²)^(-γ),
1/12.5 at 3.5 m, so on our rooms it starts about ten times too dim for the images and the albedo runs up against its
cap. The light then grows only until the brightest surfaces reach albedo 1 and stop asking for more (a clipped pixel
never asks: its loss is one-sided). Everything brighter than that in the scale the light stops at is flattened to 1.
On the saturated bedroom (docs/results.md, "The albedo's cap and the light's unit") the learned albedo stood
1.33-1.38 times the true one, which puts a fifth of the pixels above the cap, and a sharp angular profile stopped
higher than the MLP's (1.38 against 1.33), which cost it 0.7-1.3 dB against the uniform ground truth.

"median_depth" counts the radiance in a unit that starts the light as bright as the images ask: a factor
s = (τ0 + z²)^γ0 on the spotlight, z the median depth of the scene's points in the training views, so that the
initial fall-off is 1 where most of the scene is. "fixed" is s = 1, the research code's.
"""

from __future__ import annotations

from collections.abc import Sequence

import torch

from spotlessgs.io.camera_batch import Cameras
from spotlessgs.models.geometry import pinhole_pixels, points_in_view
from spotlessgs.training.config import SPOT_RADIANCE_UNITS

#: Points nearer than this (m) to a camera's image plane do not count as seen.
MIN_DEPTH_M = 0.01


def median_view_depth(points: torch.Tensor, cameras: Cameras, indices: Sequence[int]) -> float:
    """The median over the views ``indices`` of the median depth (m) of the ``points`` (N, 3) that project into the
    view's image, in front of it.

    Raises:
        ValueError: no point projects into any of the views.
    """
    medians = []
    for k in indices:
        camera = cameras[k]
        x = points_in_view(points.to(camera.viewmat.dtype), camera.viewmat)
        z = x[:, 2]
        u, v = pinhole_pixels(x, camera.K, MIN_DEPTH_M)
        seen = (z > MIN_DEPTH_M) & (u >= 0) & (u < camera.width) & (v >= 0) & (v < camera.height)
        if seen.any():
            medians.append(z[seen].median())
    if not medians:
        raise ValueError("median_view_depth: no point of the scene projects into any training view")
    return float(torch.stack(medians).median())


def spot_radiance_scale(unit: str, points: torch.Tensor, cameras: Cameras, indices: Sequence[int], tau: float,
                        gamma: float) -> float:
    """The spotlight's radiance unit s for ``unit`` (:data:`SPOT_RADIANCE_UNITS`; module docstring), given the
    initial fall-off's ``tau`` (m²) and ``gamma``, and the scene's points (N, 3) seen by the training views
    ``indices``."""
    if unit not in SPOT_RADIANCE_UNITS:
        raise ValueError(f"spot_radiance_unit must be one of {SPOT_RADIANCE_UNITS}, got {unit!r}")
    if unit == "fixed":
        return 1.0
    depth = median_view_depth(points, cameras, indices)
    return float((tau + depth * depth) ** gamma)
