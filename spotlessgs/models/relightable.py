"""A relightable scene: Gaussians + the variant's light and BRDF modules, rendered through the one rasterizer.

Shading is per Gaussian before compositing: only the Gaussians that can touch the view are shaded (the learned BRDF MLP
dominates CPU time), the rest get zero colour and are culled by the rasterizer anyway.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence

import torch
from torch import nn

from spotlessgs.io.camera_batch import Cameras
from spotlessgs.models.gaussians import GaussianParams
from spotlessgs.models.geometry import points_in_view
from spotlessgs.models import shadow
from spotlessgs.models.lamp_bounce import MIN_ALPHA, one_bounce_irradiance
from spotlessgs.models.shading import (AppearanceModels, ModelConfig, build_appearance_models, resolve_variant, shade,
                                       shading_normals, view_directions)
from spotlessgs.rasterizer import RasterOutput, may_touch_image, rasterize


@dataclasses.dataclass(frozen=True)
class SceneRender(RasterOutput):
    """What :meth:`RelightableScene.render` returns: the rasterizer's output and, for a variant with the lamp's
    bounce light rendered under the spotlight, the one-bounce irradiance (H, W, 3) it used (given, or computed in
    the same pass: a caller keeps it to reuse for a few steps); None otherwise."""

    lamp_irradiance: torch.Tensor | None = None


class RelightableScene(nn.Module):
    """Gaussians and the appearance modules of one model variant.

    Args:
        variant: preset name or ModelConfig (``3dgs``, ``darkgs``, ``darkgs+sh``, ``darkgs+brdf``, ``spotless``).
        gaussians: the per-Gaussian parameters.
        appearance: light / low-frequency light / BRDF modules (from :func:`build_appearance_models`).
    """

    def __init__(self, variant: str | ModelConfig, gaussians: GaussianParams, appearance: AppearanceModels) -> None:
        super().__init__()
        self.config = resolve_variant(variant)
        self.gaussians = gaussians
        self.appearance = appearance
        self.modules_ = appearance.module_dict()  # registered for .to() and state_dict

    @classmethod
    def create(cls, variant: str | ModelConfig, gaussians: GaussianParams, seed: int, **light_init) -> "RelightableScene":
        """Build the appearance modules of ``variant`` (``light_init``: see build_appearance_models)."""
        return cls(variant, gaussians, build_appearance_models(variant, seed=seed, **light_init))

    def colours(
        self, c2w: torch.Tensor, mask: torch.Tensor | None = None,
        relight_l0: torch.Tensor | Sequence[float] | None = None, split_lights: bool = False,
        spot_visibility: torch.Tensor | None = None, with_spot_part: bool = False,
    ) -> torch.Tensor:
        """(N, 3) linear colours of all Gaussians seen from ``c2w`` (OpenCV); zero outside ``mask`` (N,) bool.
        ``split_lights``: (N, 6), lit by the spotlight alone and by the low-frequency light alone (see ``shade``);
        ``with_spot_part``: (N, 6), the colour and, detached, the first of those halves; ``spot_visibility``: (N, 1)
        spotlight shadows of all Gaussians, or None (see ``shade``)."""
        app = self.appearance
        if mask is None:
            return shade(self.config, self.gaussians, app.light, app.lf_light, app.brdf, c2w, relight_l0,
                         split_lights, app.bounce_light, spot_visibility, with_spot_part)
        idx = torch.nonzero(mask).squeeze(1)
        visibility = None if spot_visibility is None else spot_visibility[idx]
        colours = shade(self.config, self.gaussians.subset(idx), app.light, app.lf_light, app.brdf, c2w, relight_l0,
                        split_lights, app.bounce_light, visibility, with_spot_part)
        out = colours.new_zeros((len(self.gaussians), colours.shape[1]))
        return out.index_copy(0, idx, colours)

    def render(
        self, camera: Cameras, *, relight_l0: torch.Tensor | Sequence[float] | None = None, backend: str = "auto",
        num_threads: int | None = None, background: torch.Tensor | None = None, split_lights: bool = False,
        shadow_map: shadow.ShadowMap | None = None, lamp_irradiance: torch.Tensor | None = None,
    ) -> SceneRender:
        """Render one view (``camera``: a single view): under the learned spotlight, or relit by L0 when
        ``relight_l0`` is given; ``split_lights``: a six-channel image, [spotlight part, low-frequency part] (their sum
        is the normal render). A variant with ``spot_shadows`` shades the spotlight with the lamp's shadow map
        (models.shadow): ``shadow_map``, one rendered for this view a few steps ago, or else a new one. A variant with
        ``lamp_bounce`` adds the lamp's bounce light of ``lamp_irradiance`` (H, W, 3), one computed for this view a
        few steps ago (the ``lamp_irradiance`` of an earlier render), or else a new one, computed from this render's
        own spotlit colours, depth and normals (six more channels composited in the same pass)."""
        return self._render(camera, relight_l0, backend, num_threads, background, split_lights, shadow_map,
                            lamp_irradiance)

    def render_with_depth_moments(
        self, camera: Cameras, *, backend: str = "auto", num_threads: int | None = None,
        shadow_map: shadow.ShadowMap | None = None, lamp_irradiance: torch.Tensor | None = None,
    ) -> tuple[SceneRender, torch.Tensor]:
        """:meth:`render` under the learned spotlight, and the depth moments (H, W, 2) [Σ w z, Σ w z²] of the same
        compositing (w the weights, z each Gaussian's camera-frame depth; Σ w is the output's alpha), rendered in the
        same pass as two more channels (training's depth-spread term: losses.depth_spread_loss)."""
        out = self._render(camera, None, backend, num_threads, None, False, shadow_map, lamp_irradiance,
                           depth_moments=True)
        return dataclasses.replace(out, image=out.image[..., :-2]), out.image[..., -2:]

    def _render(self, camera: Cameras, relight_l0: torch.Tensor | Sequence[float] | None, backend: str,
                num_threads: int | None, background: torch.Tensor | None, split_lights: bool,
                shadow_map: shadow.ShadowMap | None, lamp_irradiance: torch.Tensor | None,
                depth_moments: bool = False) -> SceneRender:
        """:meth:`render`; ``depth_moments`` (no ``background``): two more channels, Σ w z and Σ w z²."""
        if camera.is_batch:
            raise ValueError("RelightableScene.render: expected one view, got a batch of cameras")
        g = self.gaussians
        scales = g.scales
        K, width, height = camera.K, camera.width, camera.height
        mask = may_touch_image(g.means, scales, camera.viewmat, K, width, height)  # the rest: zero colour
        lit_by_lamp = relight_l0 is None
        if self.has_spot_shadows and lit_by_lamp and shadow_map is None:
            shadow_map = self.shadow_map(camera, backend, num_threads)
        bouncing = self.appearance.lamp_bounce is not None and lit_by_lamp
        new_bounce = bouncing and lamp_irradiance is None
        feats = self.colours(camera.c2w, mask=mask, relight_l0=relight_l0, split_lights=split_lights,
                             spot_visibility=self._spot_visibility(shadow_map) if lit_by_lamp else None,
                             with_spot_part=new_bounce and not split_lights)
        if new_bounce:  # the bounce's emitters: the spotlight's part of the colour, set aside for the last channels
            spot = feats[:, :3].detach() if split_lights else feats[:, 3:]
            feats = feats if split_lights else feats[:, :3]
        if bouncing:  # the receivers' albedo, for the bounce light
            feats = torch.cat([feats, g.albedo], dim=1)
        if depth_moments:
            depth = points_in_view(g.means, camera.viewmat)[:, 2:3]  # (N, 1) camera-frame z
            feats = torch.cat([feats, depth, depth * depth], dim=1)
        if new_bounce:
            # and every Gaussian's normal (those outside the frustum are culled by the rasterizer)
            with torch.no_grad():
                normals = self.camera_normals(camera.c2w)
            feats = torch.cat([feats, spot, normals], dim=1)
        out = rasterize(g.means, g.quats, scales, g.opacities, feats, camera.viewmat, K, width, height,
                        background=None if bouncing else background, backend=backend, num_threads=num_threads,
                        rigid_camera_grad=True)  # a view matrix with a gradient is a pose correction's
        if new_bounce:
            lamp_irradiance = self._lamp_bounce_irradiance(out, camera.K)
            out = dataclasses.replace(out, image=out.image[..., :-6])
        if bouncing:
            out = self._add_lamp_bounce(out, lamp_irradiance, split_lights, background)
        return SceneRender(**{f.name: getattr(out, f.name) for f in dataclasses.fields(out)},
                           lamp_irradiance=lamp_irradiance if bouncing else None)

    def _spot_visibility(self, shadow_map: shadow.ShadowMap | None) -> torch.Tensor | None:
        """(N, 1) the spotlight's shadows of all Gaussians from ``shadow_map`` (None: a variant without them)."""
        if not self.has_spot_shadows:
            return None
        return shadow.spot_visibility(self.gaussians, self.appearance.light, shadow_map,
                                      self.config.shadow_camera_relative)

    def camera_normals(self, c2w: torch.Tensor) -> torch.Tensor:
        """(N, 3) the Gaussians' unit normals in the camera frame (OpenCV), turned to face the camera as shading
        turns them (ModelConfig.two_sided_normals)."""
        g, center = self.gaussians, c2w[:3, 3]
        normals = shading_normals(self.config, g, view_directions(g.means, center), center)
        return normals @ c2w[:3, :3].to(normals)

    def lamp_bounce_irradiance(self, camera: Cameras, backend: str = "auto", num_threads: int | None = None,
                               shadow_map: shadow.ShadowMap | None = None) -> torch.Tensor:
        """(H, W, 3) the one-bounce irradiance that the view's spotlit render gives every visible surface
        (models.lamp_bounce.one_bounce_irradiance; no gradient): the ``lamp_irradiance`` of :meth:`render`'s spotlit
        render of the view. ``shadow_map``: as :meth:`render`'s."""
        if self.appearance.lamp_bounce is None:
            raise ValueError(f"RelightableScene.lamp_bounce_irradiance: the variant {self.config.name!r} has no "
                             "lamp bounce (ModelConfig.lamp_bounce)")
        with torch.no_grad():
            return self.render(camera, backend=backend, num_threads=num_threads, shadow_map=shadow_map).lamp_irradiance

    @staticmethod
    def _lamp_bounce_irradiance(out: RasterOutput, K: torch.Tensor) -> torch.Tensor:
        """(H, W, 3) :meth:`lamp_bounce_irradiance` from a render whose last six channels are the spotlight's part of
        the colour and the camera-frame normals (intrinsics ``K`` (3, 3))."""
        with torch.no_grad():
            surface = out.alpha >= MIN_ALPHA
            normals = torch.nn.functional.normalize(out.image[..., -3:], dim=-1)
            return one_bounce_irradiance(out.image[..., -6:-3], out.depth, normals, surface, K)

    def _add_lamp_bounce(self, out: RasterOutput, irradiance: torch.Tensor, split_lights: bool,
                         background: torch.Tensor | None) -> RasterOutput:
        """``out`` rendered with channels [lit (3, or with ``split_lights`` 6: spotlight part, low-frequency part),
        albedo (3), extra...] → [lit + bounce light, extra...] (with ``split_lights``: the bounce light added to the
        low-frequency part), the bounce light that of ``irradiance`` (H, W, 3) on the albedo; ``background`` added as
        rasterize adds it."""
        image = out.image
        lit_channels = 6 if split_lights else 3
        lit, albedo = image[..., :lit_channels], image[..., lit_channels:lit_channels + 3]
        bounce = self.appearance.lamp_bounce.colour(albedo, irradiance)
        lit = torch.cat([lit[..., :3], lit[..., 3:] + bounce], -1) if split_lights else lit + bounce
        if background is not None:
            lit = lit + (1.0 - out.alpha)[..., None] * background
        return dataclasses.replace(out, image=torch.cat([lit, image[..., lit_channels + 3:]], -1))

    @property
    def has_spot_shadows(self) -> bool:
        """Whether the variant shades its spotlight with the lamp's shadow map (``ModelConfig.spot_shadows``)."""
        return self.config.spot_shadows and self.config.light_model == "spotlight"

    def shadow_map(self, camera: Cameras, backend: str = "auto", num_threads: int | None = None) -> shadow.ShadowMap:
        """The lamp's shadow map for one view (``camera``), at the variant's ``shadow_map_scale``."""
        return shadow.render_shadow_map(self.gaussians, self.appearance.light, camera.c2w, camera.K, camera.width,
                                        camera.height, self.config.shadow_map_scale, backend, num_threads)
