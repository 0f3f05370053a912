"""The lamp's own bounce light, computed from the model's geometry in screen space (one bounce, no visibility).

A camera-mounted lamp lights a patch of the room and that patch lights the rest. The light it sends on is known from
the render itself: every pixel of the view's spotlight-lit image is a small diffuse emitter with the radiance it shows,
at the rendered depth, facing the rendered normal. The irradiance that these emitters give every other visible surface
is the one-bounce light

    E(x, n̂) = Σ_y L_y A_y cos θ_y max(0, n̂·d̂_xy) / (r²_xy + A_y / π),

(A_y the emitter's area, θ_y its emission angle, d̂_xy the unit direction x → y, the A / π term a disk's form factor at
short range), and the surface reflects ρ_x E / π of it. On the bedroom's training views this sum over the true
geometry rises from floor to ceiling as the renderer's indirect light does (0.50 → 1.33 against 0.59 → 1.26 relative to
the mean, from the lowest 40 cm band to 2.0-2.4 m), where the normal-only SH light stays flat; over the model's learned
normals, which lean towards the camera's height, it stays flat too (docs/results.md, "A bounce light from the model's
geometry").

Cost: emitters are pooled into cells of ``SENDER_CELL`` pixels a side and receivers evaluated on cells of
``RECEIVER_CELL`` pixels a side, each receiver cell holding the incident light's moments Σ w, Σ w d̂, Σ w d̂ d̂ᵀ (the
clamped cosine to degree 2 in Legendre polynomials, as a degree-2 SH would hold it: within a few per cent of the
irradiance, Ramamoorthi and Hanrahan 2001), interpolated to every pixel and evaluated at its normal; every sum over
the receiver-emitter pairs is a matrix product. Near an edge between two surfaces the pooled emitters sit further
than the true ones, and the light there comes out low. Everything here is computed without a gradient: the model
learns from it through the receivers' albedo and one gain (:class:`LampBounce`).
"""

from __future__ import annotations

import math

import torch
import torch.nn.functional as F
from torch import nn


#: Emitters are pooled into square cells of this many pixels a side.
SENDER_CELL = 8
#: The incident light is evaluated on square cells of this many pixels a side and interpolated in between.
RECEIVER_CELL = 8
#: A pixel counts as a surface (emitter or receiver) where the render's alpha reaches this.
MIN_ALPHA = 0.5
#: The emitter's area is its pixel footprint divided by |cos| of the viewing angle, that cosine at least this
#: (a surface seen edge-on does not become an emitter of unbounded area).
MIN_VIEW_COSINE = 0.2
#: The clamped cosine max(0, c) to degree 2 in Legendre polynomials: 1/4 + c / 2 + (5/16) (3c² - 1) / 2.
_LEGENDRE = (0.25, 0.5, 5.0 / 16.0)


def _pool(x: torch.Tensor, cell: int) -> torch.Tensor:
    """Sum of (H, W, C) over square cells → (ceil(H / cell), ceil(W / cell), C) (the image padded with zeros)."""
    h, w, c = x.shape
    pad_h, pad_w = (-h) % cell, (-w) % cell
    x = F.pad(x.permute(2, 0, 1), (0, pad_w, 0, pad_h))
    return F.avg_pool2d(x[None], cell, divisor_override=1)[0].permute(1, 2, 0)


def _cell_means(weight: torch.Tensor, values: torch.Tensor, cell: int) -> tuple[torch.Tensor, torch.Tensor]:
    """Per cell: Σ weight (Hc, Wc) and the weighted mean of ``values`` (H, W, C) → (Hc, Wc, C) (0 where Σ weight = 0)."""
    total = _pool(weight[..., None], cell)[..., 0]
    mean = _pool(values * weight[..., None], cell) / total.clamp_min(1e-12)[..., None]
    return total, mean


def _incident_moments(receivers: torch.Tensor, senders: torch.Tensor, sender_normals: torch.Tensor,
                      sender_area: torch.Tensor, flux: torch.Tensor) -> torch.Tensor:
    """(R, 30) the incident light's moments at each receiver point (R, 3): per colour channel Σ w (3), Σ w d̂ (3 × 3,
    channel-major) and Σ w d̂ d̂ᵀ (3 × 6: xx, yy, zz, xy, xz, yz), w = Φ cos θ / (r² + A / π) of each sender
    (points (S, 3), unit normals (S, 3), area (S,), flux Φ = Σ L A (S, 3)).

    Every sum over senders is a matrix product: with t = p_s - p_r, Σ w t = (h p_s) - p_r (h 1) and likewise for
    t tᵀ, so that only a few element-wise operations touch the R × S pairs.
    """
    dot = receivers @ senders.T  # (R, S)
    distance2 = ((receivers * receivers).sum(-1, keepdim=True) + (senders * senders).sum(-1)[None] - 2.0 * dot)
    distance2 = distance2.clamp_min(0.0)
    # r² + A / π: a disk's form factor at short range, and a sender at the receiver's own place sends nothing there
    softened = distance2 + sender_area[None] / math.pi
    inverse_length = softened.clamp_min(1e-12).rsqrt()
    facing = (sender_normals * senders).sum(-1)[None] - receivers @ sender_normals.T  # n_s · (p_s - p_r), (R, S)
    strength = (-facing * inverse_length).clamp_min(0.0) / softened
    h1 = strength * inverse_length  # for Σ w t / |t|
    h2 = h1 * inverse_length  # for Σ w t tᵀ / |t|²
    x, y, z = senders.unbind(-1)
    second = torch.stack([x * x, y * y, z * z, x * y, x * z, y * z], -1)  # (S, 6) p_s p_sᵀ
    flux_p = (flux[:, :, None] * senders[:, None, :]).reshape(-1, 9)  # (S, 9) Φ p_s per channel
    flux_pp = (flux[:, :, None] * second[:, None, :]).reshape(-1, 18)  # (S, 18) Φ p_s p_sᵀ per channel
    total = strength @ flux  # (R, 3)
    sums1 = h1 @ torch.cat([flux, flux_p], -1)  # (R, 12)
    sums2 = h2 @ torch.cat([flux, flux_p, flux_pp], -1)  # (R, 30)
    # Σ h Φ t = Σ h Φ p_s - p_r Σ h Φ → (R, 3 channels, 3)
    first_1 = sums1[:, 3:].reshape(-1, 3, 3) - sums1[:, :3, None] * receivers[:, None]
    # Σ h Φ t tᵀ = Σ h Φ p_s p_sᵀ - (Σ h Φ p_s) p_rᵀ - p_r (Σ h Φ p_s)ᵀ + p_r p_rᵀ Σ h Φ
    b, a, c = sums2[:, :3], sums2[:, 3:12].reshape(-1, 3, 3), sums2[:, 12:].reshape(-1, 3, 6)
    rx, ry, rz = receivers.unbind(-1)
    pairs = ((0, 0), (1, 1), (2, 2), (0, 1), (0, 2), (1, 2))
    outer_r = torch.stack([rx * rx, ry * ry, rz * rz, rx * ry, rx * rz, ry * rz], -1)  # (R, 6)
    cross = torch.stack([a[..., i] * receivers[:, None, j] + a[..., j] * receivers[:, None, i] for i, j in pairs], -1)
    second_2 = c - cross + b[..., None] * outer_r[:, None]  # (R, 3, 6)
    return torch.cat([total, first_1.reshape(-1, 9), second_2.reshape(-1, 18)], -1)


def _clamped_cosine_irradiance(moments: torch.Tensor, normals: torch.Tensor) -> torch.Tensor:
    """(..., 3) E(n̂) = Σ w max(0, n̂·d̂) to degree 2 from the moments (..., 30) of :func:`_incident_moments` and unit
    normals (..., 3)."""
    total = moments[..., 0:3]
    first = moments[..., 3:12].unflatten(-1, (3, 3))
    second = moments[..., 12:30].unflatten(-1, (3, 6))
    nx, ny, nz = normals.unbind(-1)
    outer_n = torch.stack([nx * nx, ny * ny, nz * nz, 2 * nx * ny, 2 * nx * nz, 2 * ny * nz], -1)[..., None, :]
    along = (first * normals[..., None, :]).sum(-1)  # Σ w n̂·d̂
    along2 = (second * outer_n).sum(-1)  # Σ w (n̂·d̂)²
    return _LEGENDRE[0] * total + _LEGENDRE[1] * along + _LEGENDRE[2] * (3.0 * along2 - total) / 2.0


def _pixel_rays(height: int, width: int, K: torch.Tensor, dtype: torch.dtype) -> torch.Tensor:
    """(H, W, 3) each pixel centre's ray (x / z, y / z, 1) through the pinhole ``K`` (pixel centres at +0.5)."""
    v = torch.arange(height, dtype=dtype, device=K.device) + 0.5
    u = torch.arange(width, dtype=dtype, device=K.device) + 0.5
    return torch.stack(torch.broadcast_tensors(((u - K[0, 2]) / K[0, 0]).to(dtype)[None, :],
                                               ((v - K[1, 2]) / K[1, 1]).to(dtype)[:, None],
                                               torch.ones((height, width), dtype=dtype, device=K.device)), dim=-1)


def one_bounce_irradiance(
    radiance: torch.Tensor, depth: torch.Tensor, normals: torch.Tensor, surface: torch.Tensor, K: torch.Tensor,
) -> torch.Tensor:
    """(H, W, 3) one-bounce irradiance at every pixel's surface from every other pixel's (see the module docstring).

    Args:
        radiance: (H, W, 3) linear radiance each pixel's surface sends towards the camera (a diffuse emitter's).
        depth: (H, W) camera-frame z (metres); normals: (H, W, 3) unit normals, camera frame (OpenCV), facing the
            camera; surface: (H, W) bool, the pixels that hold a surface; K: (3, 3) pinhole intrinsics (pixel centres
            at +0.5).
    Returns:
        (H, W, 3) irradiance E ≥ 0 (radiance × solid angle: a Lambertian surface of albedo ρ there reflects ρ E / π);
        0 off the surface.
    """
    with torch.no_grad():
        h, w = depth.shape
        dtype = radiance.dtype
        rays = _pixel_rays(h, w, K, dtype)
        z = torch.where(surface, depth, torch.zeros_like(depth))
        points = rays * z[..., None]  # (H, W, 3)
        ray_length = rays.norm(dim=-1)
        view_cosine = ((normals * rays).sum(-1).abs() / ray_length).clamp_min(MIN_VIEW_COSINE)
        # a pixel's footprint on its surface: solid angle (1 / (fx fy ℓ³)) × distance² (z² ℓ²) / |cos| of viewing
        area = z * z / (K[0, 0] * K[1, 1] * ray_length * view_cosine) * surface.to(dtype)
        flux = _pool(radiance * area[..., None], SENDER_CELL)  # Σ L A per cell, (Hs, Ws, 3)
        # a cell emits from the flux-weighted mean of its pixels, facing their flux-weighted mean normal (a cell
        # across an edge emits from the side that glows)
        emitted = (radiance.sum(-1) * area).clamp_min(0.0)
        _, sender_geometry = _cell_means(emitted, torch.cat([points, normals], -1), SENDER_CELL)
        sender_points, sender_normals = sender_geometry[..., :3], sender_geometry[..., 3:]
        sender_area = _pool(area[..., None], SENDER_CELL)[..., 0]
        emitting = (sender_area > 0) & (flux.sum(-1) > 0)
        sender_points, sender_normals = sender_points[emitting], F.normalize(sender_normals[emitting], dim=-1)
        sender_area, flux = sender_area[emitting], flux[emitting]  # (S,), (S, 3)

        weight = surface.to(dtype)
        receiver_count, receiver_points = _cell_means(weight, points, RECEIVER_CELL)  # (Hr, Wr), (Hr, Wr, 3)
        hr, wr = receiver_count.shape
        moments = _incident_moments(receiver_points.reshape(-1, 3), sender_points, sender_normals, sender_area, flux)
        occupied = (receiver_count > 0).to(dtype).reshape(-1, 1)  # cells without a surface hold nothing
        moments = torch.cat([moments * occupied, occupied], -1).reshape(hr, wr, -1)
        # interpolated to the pixels (the cells' centres sit at the pixels' cell centres) among occupied cells only
        grid = F.interpolate(moments.permute(2, 0, 1)[None], scale_factor=RECEIVER_CELL, mode="bilinear",
                             align_corners=False)[0, :, :h, :w].permute(1, 2, 0)
        grid = grid[..., :-1] / grid[..., -1:].clamp_min(1e-6)
        irradiance = _clamped_cosine_irradiance(grid, normals)
        return irradiance.clamp_min(0.0) * surface[..., None].to(dtype)


class LampBounce(nn.Module):
    """The lamp's bounce light as a learned gain on :func:`one_bounce_irradiance`: colour = g · ρ · E / π.

    g = exp(log_gain) starts at 1 (the model's albedo in the true one's unit) and learns the unit the albedo settles
    in and the share of further bounces.
    """

    def __init__(self) -> None:
        super().__init__()
        self.log_gain = nn.Parameter(torch.zeros(()))

    @property
    def gain(self) -> torch.Tensor:
        """g > 0 (a scalar tensor)."""
        return self.log_gain.exp()

    def colour(self, albedo: torch.Tensor, irradiance: torch.Tensor) -> torch.Tensor:
        """(H, W, 3) the bounce light's colour g · albedo · E / π of an albedo image (H, W, 3) and irradiance (H, W, 3)."""
        return self.gain * albedo * irradiance / math.pi
