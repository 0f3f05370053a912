"""Spotlight shadows: how much of the lamp each Gaussian sees, from shadow maps rendered at the lamp and the camera.

The lamp rides on the camera a few centimetres off its centre, so the camera sees thin shadows beside every depth edge.
Without a shadow term they are painted into the albedo and relighting shows them as dark outlines.

For one view (camera-to-world ``c2w``) the lamp is a pinhole at the learned light origin o = C + R_cw t, looking down
the light's +z axis (axes R_cw R: :class:`~spotlessgs.models.light.SpotLight`'s pose). The Gaussians are composited
once from there, without a gradient, into a moment shadow map: per pixel u of the lamp,

    A(u) = Σ_j w_j,   S1(u) = Σ_j w_j z_j,   S2(u) = Σ_j w_j z_j²,   w_j = α_j T_j

(the compositing weights along the lamp's ray, z_j the light-frame depths). Because the compositor sorts by depth, the
weight of everything in front of a depth z is the opacity that blocks the lamp there. Gaussian i, at light-frame depth
z_i and map position u_i, takes the ray's weight as two parts: q in front of it (the occluders, at one depth d) and
A - q at its own depth r_i = (1 - b) z_i (b = SHADOW_BIAS: what lies less than b z_i in front of it is its own
surface). The moments then give q exactly:

    q = (A r - S1)² / (A r² - 2 r S1 + S2)  (0 where A r ≤ S1),   V_i = 1 - clamp(q, 0, 1)

the lamp's lit fraction (the variance shadow map's Chebyshev bound, with the ray's missing weight 1 - A escaping). A
Gaussian on the first surface is lit (V = 1), one behind an occluder gets V ≈ 1 - the occluder's opacity, one behind
the faint tail of an occluder's Gaussian is only dimmed by that tail's opacity. Outside the map or behind the lamp
V = 1. The moments are sampled bilinearly (moments may be filtered, depths may not).

Relative to the camera: the same moments are rendered from the camera (at the map's pinhole) and give the camera's
own lit fraction C_i of each Gaussian, the part of it the camera sees past what lies in front. The spotlight reaches

    S_i = min(1, V_i / max(C_i, MIN_CAMERA_LIT))

of what the camera sees of Gaussian i. A lamp at the camera casts no shadow the camera can see (V = C); only the
lamp's offset from the camera (parallax) shows shadows: beside depth edges, where the camera sees a surface that the
lamp does not. This matters for a loosely fitted surface (a thick, half-transparent cloud of Gaussians, as a sparse
SfM start leaves it): the lamp sees its back half behind its front half (V ≈ 0.6 in a cloud 20 cm deep), and without
the division the albedo would be fitted brighter there by 1/V and relighting would show it; the camera sees the cloud
the same way (C ≈ V), so S ≈ 1 (tests/test_models_shadow.py). Only Gaussians with V < 1 need C.

Gradient: only the lamp's position t (SpotLight.translation) gets one, and it is the shadows' cue for it. The map is
rendered without a gradient, so the gradient of V through the point's map position alone would be wrong: moving the
lamp by δ moves the receiver's image in the map by -f δ / z, but also the occluder's, by -f δ / d (d its depth), and
shadows follow their difference, f δ (1/d - 1/z) (the wrong sign without the second part: d < z). So the map position
is differentiated with t's gradient scaled by 1 - z/d, per Gaussian, d the occluders' depth that the moments give
(d = r - (A r - S1)/q); where nothing blocks the lamp (q ≈ 0) V does not depend on t, and C never does. The depth
compare has no gradient (the lamp moving along its axis shifts occluder and receiver alike). Rotating the lamp moves
no shadow: no gradient for its rotation, and none for the Gaussians (a fixed map would not see an occluder move).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch
import torch.nn.functional as F

from spotlessgs.models.gaussians import GaussianParams
from spotlessgs.models.geometry import check_c2w, points_in_view
from spotlessgs.models.light import SpotLight
from spotlessgs.rasterizer import rasterize

#: Relative depth bias b: what lies less than b·z in front of a Gaussian at depth z is its own surface (5 cm at 1 m).
SHADOW_BIAS = 0.05
#: The lamp-position gradient treats an occluder closer to the lamp than this (metres) as that close, so the factor
#: 1 - z/d stays finite. (Bounding it harder, d ≥ 0.05 z, left the bedroom's lamp 4.5 cm off instead of about 3:
#: docs/results.md, "Spotlight shadows".)
MIN_OCCLUDER_DEPTH = 1e-3
#: The map covers the camera's field of view plus this margin on every side (degrees): the lamp is a few centimetres
#: and about a degree off the camera, so every Gaussian the camera sees lands in the map.
MAP_MARGIN_DEG = 5.0
#: The camera's own lit fraction of a Gaussian is taken as at least this when the lamp's is divided by it (a Gaussian
#: the camera hardly sees adds almost nothing to its view).
MIN_CAMERA_LIT = 1e-3


def light_to_world(light: SpotLight, c2w: torch.Tensor) -> torch.Tensor:
    """(4, 4) the lamp's frame → world, OpenCV-like axes (z along the light's axis)."""
    check_c2w(c2w)
    rot = c2w[:3, :3] @ light.rotation().to(c2w)
    origin = light.origin_world(c2w)
    top = torch.cat([rot, origin[:, None]], dim=1)
    return torch.cat([top, c2w.new_tensor([[0.0, 0.0, 0.0, 1.0]])], dim=0)


def shadow_map_camera(K: torch.Tensor, width: int, height: int, map_scale: float = 1.0
                      ) -> tuple[torch.Tensor, int, int]:
    """The lamp's pinhole for one camera: (K_map (3, 3), map width, map height).

    Its focal length is the camera's times ``map_scale`` (the map resolves what the camera resolves at 1.0), its
    principal point in the middle, and it spans the camera's half-angles plus :data:`MAP_MARGIN_DEG` on every side.
    """
    if not (math.isfinite(map_scale) and map_scale > 0):
        raise ValueError(f"shadow map scale must be finite and > 0, got {map_scale}")
    fx, fy, cx, cy = (float(v) for v in (K[0, 0], K[1, 1], K[0, 2], K[1, 2]))
    margin = math.radians(MAP_MARGIN_DEG)

    def span(f: float, c: float, size: int) -> int:
        half_angle = math.atan(max(c, size - c) / f) + margin
        return max(2, int(math.ceil(2.0 * map_scale * f * math.tan(min(half_angle, math.radians(80.0))))))

    width_map, height_map = span(fx, cx, width), span(fy, cy, height)
    K_map = K.new_tensor([[map_scale * fx, 0.0, width_map / 2.0], [0.0, map_scale * fy, height_map / 2.0],
                          [0.0, 0.0, 1.0]])
    return K_map, width_map, height_map


@dataclass(frozen=True)
class ShadowMap:
    """The lamp's moment shadow map for one view, the camera's own moment map beside it, and the poses they were
    rendered from (all without a gradient)."""

    moments: torch.Tensor  # (3, H_map, W_map) [A, S1, S2], depths in metres along the light's axis
    K_map: torch.Tensor  # (3, 3) the pinhole of both maps
    world_to_lamp: torch.Tensor  # (4, 4) the lamp's view matrix when it was rendered
    lamp_rotation: torch.Tensor  # (3, 3) light → camera rotation then (SpotLight.rotation())
    camera_moments: torch.Tensor  # (3, H_map, W_map) the same moments seen from the camera, depths along its axis
    world_to_camera: torch.Tensor  # (4, 4) the camera's view matrix


def render_shadow_map(gaussians: GaussianParams, light: SpotLight, c2w: torch.Tensor, K: torch.Tensor, width: int,
                      height: int, map_scale: float = 1.0, backend: str = "auto", num_threads: int | None = None
                      ) -> ShadowMap:
    """The lamp's moment shadow map and the camera's own (see the module docstring) for the view ``c2w`` (camera
    ``K``, ``width`` × ``height``: the maps cover its field of view, at ``map_scale`` times its focal length), without
    a gradient."""
    with torch.no_grad():
        K_map, width_map, height_map = shadow_map_camera(K, width, height, map_scale)
        lamp_view = torch.linalg.inv(light_to_world(light, c2w))
        camera_view = torch.linalg.inv(c2w.to(gaussians.means))

        def moments_from(viewmat: torch.Tensor) -> torch.Tensor:
            g = gaussians
            z = g.means @ viewmat[2, :3] + viewmat[2, 3]
            out = rasterize(g.means, g.quats, g.scales, g.opacities, torch.stack([z, z * z], dim=1), viewmat, K_map,
                            width_map, height_map, backend=backend, num_threads=num_threads)
            return torch.cat([out.alpha[None], out.image.permute(2, 0, 1)], dim=0)

        return ShadowMap(moments_from(lamp_view), K_map, lamp_view, light.rotation().detach(),
                         moments_from(camera_view), camera_view)


def _sample_moments(moments: torch.Tensor, points_light: torch.Tensor, K_map: torch.Tensor
                    ) -> tuple[torch.Tensor, torch.Tensor]:
    """Bilinear samples (3, N) of the moment map (3, H, W) at the map positions of points (N, 3) in the lamp's frame,
    and (N,) whether each point is ahead of the lamp and inside the map."""
    _, height, width = moments.shape
    z = points_light[:, 2]
    ahead = z > 1e-3
    z_safe = torch.where(ahead, z, torch.ones_like(z))
    u = K_map[0, 0] * points_light[:, 0] / z_safe + K_map[0, 2]
    v = K_map[1, 1] * points_light[:, 1] / z_safe + K_map[1, 2]
    inside = ahead & (u >= 0) & (u <= width) & (v >= 0) & (v <= height)
    grid = torch.stack([2.0 * u / width - 1.0, 2.0 * v / height - 1.0], dim=-1).to(moments.dtype)
    sampled = F.grid_sample(moments[None], grid[None, :, None, :], mode="bilinear", padding_mode="border",
                            align_corners=False)[0, :, :, 0].to(points_light.dtype)
    return sampled, inside


def _blocked(sampled: torch.Tensor, depth: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """The blocked fraction q (N,) of the lamp's light for receivers at light-frame depths (N,) from the moment
    samples (3, N), and the occluders' depth d (N,) (0 where q ≈ 0)."""
    total, first, second = sampled
    r = (1.0 - SHADOW_BIAS) * depth
    ahead_of_r = (total * r - first).clamp_min(0.0)  # q (r - d): the occluders' weight times their distance ahead
    # Σ w (r - z_j)² = q (r - d)² + ...; its floor keeps float32 rounding (relative to A r²) out of the ratio
    spread = torch.maximum(total * r * r - 2.0 * r * first + second, 1e-6 * total * r * r + 1e-12)
    blocked = (ahead_of_r * ahead_of_r / spread).clamp(0.0, 1.0)
    occluder_depth = torch.where(blocked > 1e-3, r - ahead_of_r / blocked.clamp_min(1e-3), torch.zeros_like(r))
    return blocked, occluder_depth


def _lit_fraction(moments: torch.Tensor, points_light: torch.Tensor, K_map: torch.Tensor, depth: torch.Tensor
                  ) -> tuple[torch.Tensor, torch.Tensor]:
    """(N, 1) lit fraction of points (N, 3) in the lamp's frame whose own depth counts as ``depth`` (N,), and the
    occluders' depth d (N,) (see :func:`_blocked`); 1 behind the lamp and outside the map."""
    sampled, inside = _sample_moments(moments, points_light, K_map)
    blocked, occluder_depth = _blocked(sampled, depth)
    return torch.where(inside, 1.0 - blocked, torch.ones_like(blocked))[:, None], occluder_depth


def map_visibility(moments: torch.Tensor, points_light: torch.Tensor, K_map: torch.Tensor) -> torch.Tensor:
    """(N, 1) lit fraction V ∈ [0, 1] of points (N, 3) in the lamp's frame against its moment shadow map (3, H, W)
    (see the module docstring); 1 behind the lamp and outside the map."""
    return _lit_fraction(moments, points_light, K_map, points_light[:, 2].clamp_min(1e-3))[0]


def spot_visibility(gaussians: GaussianParams, light: SpotLight, shadow_map: ShadowMap, camera_relative: bool = True
                    ) -> torch.Tensor:
    """(N, 1) how much of the spotlight reaches each Gaussian in the view of ``shadow_map``: 1 lit, 0 in the shadow
    of what the lamp sees first; relative to what the camera itself sees of it (S of the module docstring), or with
    ``camera_relative`` False the lamp's V alone. Its value is the maps' (from the poses they were rendered at, so
    maps may be reused for a few steps); its gradient reaches the lamp's current position only, the shadows' own
    (see the module docstring)."""
    with torch.no_grad():
        points = points_in_view(gaussians.means, shadow_map.world_to_lamp)
        depth = points[:, 2].clamp_min(1e-3)
        lamp_lit, occluder_depth = _lit_fraction(shadow_map.moments, points, shadow_map.K_map, depth)
        # only what the lamp does not fully see can be in a shadow: the rest of the work is on these
        blocked = torch.nonzero(lamp_lit[:, 0] < 1.0)[:, 0]
        if camera_relative:
            seen = points_in_view(gaussians.means[blocked], shadow_map.world_to_camera)
            camera_lit = _lit_fraction(shadow_map.camera_moments, seen, shadow_map.K_map, seen[:, 2].clamp_min(1e-3))[0]
            own = camera_lit.clamp_min(MIN_CAMERA_LIT)
        else:
            own = torch.ones_like(lamp_lit[blocked])
        visibility = lamp_lit.index_copy(0, blocked, (lamp_lit[blocked] / own).clamp_max(1.0))
    if not (light.translation.requires_grad and torch.is_grad_enabled()):
        return visibility
    # The same values, with the position's gradient scaled per Gaussian by 1 - z/d (the occluders' motion in the
    # map): a lamp moved by δ (camera frame) moves the points by -Rᵀ δ in its frame.
    depth_b, occluder_b = depth[blocked], occluder_depth[blocked]
    scale = torch.where(occluder_b > 0, 1.0 - depth_b / occluder_b.clamp_min(MIN_OCCLUDER_DEPTH),
                        torch.zeros_like(depth_b))
    moved = (light.translation - light.translation.detach())[None, :] * scale[:, None]  # value 0
    lamp_lit_b = _lit_fraction(shadow_map.moments, points[blocked] - moved @ shadow_map.lamp_rotation,
                               shadow_map.K_map, depth_b)[0]
    return visibility.index_copy(0, blocked, (lamp_lit_b / own).clamp_max(1.0))
