"""The photometric camera: what the camera does to the light that reaches it, learned beside the scene.

A real robot camera records ``I_k(p) = g_k · V(r(p)) · L_k(p)``: the scene's radiance ``L_k`` (what the scene and the
spotlight model render) times the frame's exposure ``g_k`` (auto-exposure: shutter time × analogue gain, changing frame
to frame) and the lens's vignetting ``V`` (a fall-off with the distance ``r`` from the principal point, the same in
every frame). Learning both keeps them out of the albedo and the light:

* exposure: one log-gain per frame, used relative to the mean over the fitted frames, ``g_k = exp(l_k − mean l)``, so
  that a common factor cannot drift between the gains and the albedo (the mean frame is the reference exposure);
  frames with a known exposure (``spotlessgs.io.exposure``) start from it; a frame that is never fitted (a test view)
  keeps its known exposure relative to the fitted frames' known ones, or the reference exposure;
* vignetting: ``V(r) = 1 + a1 r² + a2 r⁴ + a3 r⁶`` (r = 1 at the image corner farthest from the principal point),
  clamped to at least 0.05, starting at V = 1.

Relit images use the reference exposure and no vignetting: they are what the scene looks like, not what this camera
recorded. See docs/method.md ("Photometric camera") for how vignetting is kept apart from the spotlight's profile.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import torch
from torch import nn

# Vignetting never darkens a pixel below this share of the centre's value (keeps the gradient alive at the corners).
MIN_FALLOFF = 0.05


class PhotometricCamera(nn.Module):
    """Per-frame exposure and vignetting of V frames of H × W pixels.

    One vignetting curve serves every frame, in each frame's own normalised radius: frames from several cameras (a
    rig, or COLMAP's camera per image) share it, so that a curve per camera cannot take up the spotlight's profile
    on the few frames of that camera.

    Args:
        num_views: V.
        fitted: the frames whose images are fitted (their mean log-gain is the reference, 0).
        radius: (H, W) distance of each (training-resolution) pixel from the principal point in the input image, 1 at
            the farthest corner, or (V, H, W) one per frame (frames of different cameras); derived from the dataset,
            so not part of the state dict.
        exposure, vignetting: which of the two to learn.
        log_gain_prior: (V,) known log exposures (any common offset), or None (all frames start equal).
    """

    def __init__(self, num_views: int, fitted: Sequence[int], radius: torch.Tensor, exposure: bool = True,
                 vignetting: bool = True, log_gain_prior: torch.Tensor | None = None) -> None:
        super().__init__()
        if not fitted:
            raise ValueError("PhotometricCamera: no fitted frames")
        start = torch.zeros(num_views) if log_gain_prior is None else torch.as_tensor(log_gain_prior).float()
        if start.shape != (num_views,) or not torch.isfinite(start).all():
            raise ValueError(f"PhotometricCamera: log_gain_prior must be {num_views} finite values")
        self.log_gain = nn.Parameter(start.clone()) if exposure else None
        self.exposure_known = log_gain_prior is not None  # from the dataset, so not part of the state dict
        self.coefficients = nn.Parameter(torch.zeros(3)) if vignetting else None
        self.register_buffer("fitted", torch.as_tensor(list(fitted), dtype=torch.long))
        is_fitted = torch.zeros(num_views, dtype=torch.bool)
        is_fitted[self.fitted] = True
        self.register_buffer("is_fitted", is_fitted)
        self.register_buffer("start", start - start[self.fitted].mean())  # known log exposures, fitted mean 0
        if radius.ndim not in (2, 3) or (radius.ndim == 3 and radius.shape[0] != num_views):
            raise ValueError(f"PhotometricCamera: radius must be (H, W) or ({num_views}, H, W), got "
                             f"{tuple(radius.shape)}")
        self.register_buffer("radius", radius.float(), persistent=False)

    def log_gains(self) -> torch.Tensor:
        """(V,) log exposure of every frame relative to the fitted frames' mean (frames never fitted: their known
        exposure, else 0)."""
        if self.log_gain is None:
            return torch.zeros_like(self.start)
        return torch.where(self.is_fitted, self.log_gain - self.log_gain[self.fitted].mean(), self.start)

    def exposure_unknown(self, view: int) -> bool:
        """True for a frame whose exposure is learned but was neither fitted nor recorded (a held-out frame of an
        auto-exposure camera without exposure records): its gain can only come from its own pixels."""
        return self.log_gain is not None and not self.exposure_known and not bool(self.is_fitted[view])

    def gains(self) -> torch.Tensor:
        """(V,) exposure of every frame relative to the fitted frames' (geometric) mean."""
        return torch.exp(self.log_gains())

    def falloff(self, radius: torch.Tensor | None = None) -> torch.Tensor:
        """V(r) at ``radius`` (default: every pixel, (H, W) or (V, H, W) as given); ones without vignetting."""
        r2 = (self.radius if radius is None else radius) ** 2
        if self.coefficients is None:
            return torch.ones_like(r2)
        a1, a2, a3 = self.coefficients
        return (1.0 + r2 * (a1 + r2 * (a2 + r2 * a3))).clamp(min=MIN_FALLOFF)

    def forward(self, image: torch.Tensor, view: int) -> torch.Tensor:
        """What the camera records of the rendered radiance ``image`` (H, W, C) in frame ``view``."""
        out = image
        if self.coefficients is not None:
            out = out * self.falloff(self.radius if self.radius.ndim == 2 else self.radius[view])[..., None]
        if self.log_gain is not None:
            out = out * torch.exp(self.log_gains()[view])
        return out

    @torch.no_grad()
    def report(self, names: Sequence[str]) -> dict[str, Any]:
        """A JSON-able summary: the gain of every frame (by file name) and the vignetting curve."""
        radii = torch.linspace(0.0, 1.0, 6, device=self.radius.device)
        return {
            "exposure": None if self.log_gain is None else {
                "reference": "the geometric mean gain of the fitted frames",
                "gains": {name: float(g) for name, g in zip(names, self.gains())}},
            "vignetting": None if self.coefficients is None else {
                "model": "V(r) = max(1 + a1 r^2 + a2 r^4 + a3 r^6, 0.05), r = 1 at the farthest image corner",
                "coefficients": [float(a) for a in self.coefficients],
                "falloff": {f"{float(r):.1f}": float(v) for r, v in zip(radii, self.falloff(radii))}},
        }
