"""Per-Gaussian shading: one linear RGB colour per Gaussian for a camera, for each model variant.

Spotlight-lit colour (training and novel views), for Gaussian i with albedo a, normal n̂, view direction v̂ (towards the
camera) and light direction l̂ (towards the lamp):

    c_i = f̃(a, ρ, η; v̂, l̂, n̂) · max(0, n̂·l̂) · (L_spot + L_lf(n̂))

f̃ is the π-scaled reflectance (Lambertian: f̃ = a, see `brdf`), L_spot = Ψ Φ the spotlight (see `light`), L_lf the
low-frequency light (DarkGS constant A, or the SH light evaluated at n̂). The cosine multiplies L_lf as well, as in
the research code (there the SH term is multiplied by n̂·l̂); applying it once to the sum keeps DarkGS exactly
a (Ψ Φ + A) max(0, n̂·l̂) and avoids the research code's second cosine inside its BRDF.

Relighting (docs/method.md §8, paper eq. 8): the spotlight is replaced by a constant RGB radiance L0 arriving uniformly
from the whole hemisphere (the paper: "similar to an environment light with constant intensity"). The reflected
radiance of a uniform environment is L_in times the directional albedo R = (1/π) ∫ f̃ cos dω, so

    ĉ_i = R_i · (L0 + L_lf(n̂)),   R_i = mean_k f̃(a, ρ, η; v̂ = n̂, l̂_k, n̂)

with a fixed, deterministic cosine-weighted set of K hemisphere directions l̂_k around n̂ (a Fibonacci spiral on the
disk lifted to the hemisphere). Choices: there is no light direction, so no single cosine (it is inside R); the
Lambertian R is exactly a for any K; L_lf keeps its value at n̂ without the spotlight cosine; and v̂ = n̂, which makes
every Gaussian's relit colour independent of the camera (view-consistent, no flicker between frames) and of the
learned light pose. The spotlight is never evaluated. Relit colours are linear and not clipped: the caller decides.

Normals are two-sided by default: n̂ is flipped into the camera's hemisphere (a splat is seen from its visible side;
point-cloud normals are often unoriented).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Literal

import torch
from torch import nn

from spotlessgs.models.brdf import LambertianBRDF, LearnedBRDF, disney_directional_albedo
from spotlessgs.models.gaussians import GaussianParams
from spotlessgs.models.geometry import check_c2w, orthonormal_basis, safe_normalize
from spotlessgs.models.lamp_bounce import LampBounce
from spotlessgs.models.light import RID_MODELS, ConstantAmbient, LowFrequencyLight, SpotLight
from spotlessgs.models.sh import check_sh_degree, eval_sh

# Default constant relighting radiance L0 (linear RGB): with it a white Lambertian surface relights to 1.0 (+ L_lf).
RELIGHT_L0_DEFAULT = (1.0, 1.0, 1.0)
# 3DGS adds this offset to its SH colour before clamping at 0.
SH_COLOUR_OFFSET = 0.5
#: How the low-frequency light may shade the spotlit images (ModelConfig.low_frequency_shading).
LOW_FREQUENCY_SHADINGS = ("spot_cosine", "irradiance")


@dataclass(frozen=True)
class ModelConfig:
    """Switches of one appearance-model variant."""

    # Preset name, recorded in run folders.
    name: str
    # "none": vanilla 3DGS view-dependent SH colour (no light model); "spotlight": camera-mounted spotlight model.
    light_model: Literal["none", "spotlight"] = "spotlight"
    # Low-frequency light: "none" (3DGS only), "constant" (DarkGS scalar ambient A) or "sh" (SpotlessGS SH light).
    ambient: Literal["none", "constant", "sh"] = "sh"
    # Degree 0..3 of the SH low-frequency light (used when ambient == "sh"; degree 0 = an RGB constant ambient).
    sh_degree: int = 3
    # Reflectance: "lambert" (DarkGS) or "mlp" (learned Disney-modulated BRDF).
    brdf: Literal["lambert", "mlp"] = "mlp"
    # Light pose and RID given (true pose, RID fitted to the known cone) and frozen, instead of optimised jointly.
    calibrated: bool = False
    # Degree 0..3 of the vanilla 3DGS colour SH (light_model == "none").
    colour_sh_degree: int = 3
    # Flip normals into the camera's hemisphere before shading.
    two_sided_normals: bool = True
    # Number of hemisphere directions of the relighting quadrature (learned BRDF only; Lambertian is exact).
    relight_directions: int = 16
    # Hidden width of the learned-BRDF MLP (paper: 256; CPU presets may use less, the MLP dominates shading time).
    brdf_hidden: int = 256
    # How the low-frequency light shades a Gaussian under the spotlight. "spot_cosine" (the paper's equation):
    # f̃ · max(0, n̂·l̂) · (L_spot + L_lf), the low-frequency light scaled by the spotlight's BRDF value and cosine;
    # "irradiance": f̃ · max(0, n̂·l̂) · L_spot + R · L_lf, the low-frequency light as light from all around, shaded by
    # the directional albedo R, and relit with the same R. R is the albedo for a Lambertian BRDF and the Disney
    # model's directional albedo for the learned one (brdf.disney_directional_albedo: a table lookup, no network
    # pass; its MLP residual shapes the spotlight's term only).
    low_frequency_shading: Literal["spot_cosine", "irradiance"] = "spot_cosine"
    # The spotlight's distance fall-off Ψ = (τ + d²)^(-γ) (SpotLight): initial τ (m²) and γ, and whether they learn.
    # τ = 0, γ = 1 is a point light's inverse square; a learned τ and γ can trade against the light's axial offset.
    falloff_tau: float = 0.3
    falloff_gamma: float = 1.0
    learn_falloff: bool = True
    # The spotlight's angular profile (RID): "mlp" (the paper's MLP of cosine features of θ) or "monotone" (a
    # non-increasing piecewise-linear profile on 48 knots, models.angular_profile: sharp enough for a spot lamp's edge).
    rid_model: str = "mlp"
    # The learned BRDF's f̃ clamped at 1 (the research code's; LearnedBRDF.upper_clamp). False: unclamped, and its
    # directional albedo R is the Disney model's, tabulated with an importance-sampled quadrature
    # (brdf.disney_directional_albedo), in relighting and in the irradiance shading alike.
    brdf_upper_clamp: bool = True
    # The learned BRDF's diffuse lobe with Burley's retro-reflection factor (the paper's Disney model) or Lambertian
    # (LearnedBRDF.burley; also the directional albedo's table). Burley's factor brightens a rough surface towards
    # grazing when it is lit and seen from one direction, as a lamp beside the camera does, so it trades against
    # the spotlight's fall-off and position.
    brdf_burley_diffuse: bool = True
    # Whether the learned BRDF's network passes its gradient on to the directions it reads (LearnedBRDF.input_gradients;
    # True: the paper's). False: only the analytic Disney factor moves the Gaussians, their normals and the lamp.
    brdf_network_input_gradients: bool = True
    # Degree 0..3 of a second SH light for the lamp's own bounce light, evaluated at the normal in the camera frame
    # (it moves with the camera, as light bounced off what the lamp lights does), shaded like the low-frequency light
    # in training and left out of relighting; -1: none (the paper's). Only the variants with an SH light have one
    # (ambient "sh"): it is part of that light; DarkGS's constant ambient and 3DGS ignore the setting.
    bounce_light_degree: int = -1
    # The lamp's bounce light computed from the model's geometry (models.lamp_bounce): every pixel of the spotlit
    # render lights the rest of the view (one bounce, screen space, no visibility), added to the render in training
    # through a learned gain and left out of relighting. Unlike the SH bounce light it follows where the lamp's light
    # lands, so it rises towards a ceiling the lit floor faces. Variants with a spotlight only.
    lamp_bounce: bool = False
    # Whether the low-frequency light (the SH light, the SH bounce light) passes its gradient on to the normals. False:
    # it is evaluated at the normals without a gradient to them, so that only the spotlight's shading turns them (the
    # SH light's gradient turns wall normals towards the camera's height; docs/results.md).
    low_frequency_turns_normals: bool = True
    # Spotlight shadows: the spotlight's term of each Gaussian is scaled by how much of the lamp it sees, from a
    # shadow map rendered at the learned light pose (models.shadow); relighting has none (uniform light casts none).
    spot_shadows: bool = False
    # The shadow map's focal length as a fraction of the camera's (1: the map resolves what the camera does).
    shadow_map_scale: float = 0.5
    # The lamp's lit fraction divided by the camera's own (models.shadow): a lamp at the camera casts no visible shadow
    # and a loosely fitted surface does not shadow itself. False: the lamp's map alone.
    shadow_camera_relative: bool = True

    def __post_init__(self) -> None:
        if self.light_model not in ("none", "spotlight"):
            raise ValueError(f"ModelConfig {self.name!r}: light_model must be 'none' or 'spotlight', got {self.light_model!r}")
        if self.ambient not in ("none", "constant", "sh"):
            raise ValueError(f"ModelConfig {self.name!r}: ambient must be 'none', 'constant' or 'sh', got {self.ambient!r}")
        if self.brdf not in ("lambert", "mlp"):
            raise ValueError(f"ModelConfig {self.name!r}: brdf must be 'lambert' or 'mlp', got {self.brdf!r}")
        if (self.light_model == "none") != (self.ambient == "none"):
            raise ValueError(
                f"ModelConfig {self.name!r}: ambient 'none' goes with light_model 'none' only "
                f"(got light_model={self.light_model!r}, ambient={self.ambient!r})"
            )
        if self.light_model == "none" and self.calibrated:
            raise ValueError(f"ModelConfig {self.name!r}: calibrated needs light_model 'spotlight'")
        check_sh_degree(self.sh_degree)
        check_sh_degree(self.colour_sh_degree)
        if self.bounce_light_degree != -1:
            check_sh_degree(self.bounce_light_degree)
        if self.relight_directions < 1:
            raise ValueError(f"ModelConfig {self.name!r}: relight_directions must be >= 1, got {self.relight_directions}")
        if self.brdf_hidden < 1:
            raise ValueError(f"ModelConfig {self.name!r}: brdf_hidden must be >= 1, got {self.brdf_hidden}")
        if not (math.isfinite(self.falloff_tau) and self.falloff_tau > 0 and math.isfinite(self.falloff_gamma)
                and self.falloff_gamma > 0):
            raise ValueError(f"ModelConfig {self.name!r}: falloff_tau and falloff_gamma must be finite and > 0, got "
                             f"{self.falloff_tau} and {self.falloff_gamma}")
        if not (math.isfinite(self.shadow_map_scale) and self.shadow_map_scale > 0):
            raise ValueError(f"ModelConfig {self.name!r}: shadow_map_scale must be finite and > 0, got "
                             f"{self.shadow_map_scale}")
        if self.rid_model not in RID_MODELS:
            raise ValueError(f"ModelConfig {self.name!r}: rid_model must be one of {RID_MODELS}, got {self.rid_model!r}")
        if self.low_frequency_shading not in LOW_FREQUENCY_SHADINGS:
            raise ValueError(f"ModelConfig {self.name!r}: low_frequency_shading must be 'spot_cosine' or "
                             f"'irradiance', got {self.low_frequency_shading!r}")

    @property
    def bounce_degree(self) -> int:
        """The degree of the variant's bounce light, -1 when it has none (no SH light, or switched off)."""
        return self.bounce_light_degree if self.ambient == "sh" else -1


MODEL_VARIANTS: dict[str, ModelConfig] = {
    "3dgs": ModelConfig("3dgs", light_model="none", ambient="none", brdf="lambert"),
    "darkgs": ModelConfig("darkgs", ambient="constant", brdf="lambert"),
    "darkgs-calibrated": ModelConfig("darkgs-calibrated", ambient="constant", brdf="lambert", calibrated=True),
    "darkgs+sh": ModelConfig("darkgs+sh", ambient="sh", brdf="lambert"),
    "darkgs+brdf": ModelConfig("darkgs+brdf", ambient="constant", brdf="mlp"),
    "spotless": ModelConfig("spotless", ambient="sh", brdf="mlp"),
}
"""The variants of the paper's tables; `darkgs-calibrated` is DarkGS with the light pose and cone taken from the
dataset's light truth and frozen (the paper reports the better of it and jointly optimised `darkgs`)."""


def resolve_variant(variant: str | ModelConfig) -> ModelConfig:
    """A preset name or a ModelConfig → ModelConfig (ValueError naming the known presets otherwise)."""
    if isinstance(variant, ModelConfig):
        return variant
    if variant not in MODEL_VARIANTS:
        raise ValueError(f"unknown model variant {variant!r}; known: {sorted(MODEL_VARIANTS)}")
    return MODEL_VARIANTS[variant]


# ---- geometry per Gaussian ---------------------------------------------------------------------------------------
def view_directions(means: torch.Tensor, camera_center: torch.Tensor) -> torch.Tensor:
    """Unit vectors (N, 3) from each Gaussian (N, 3) towards the camera centre (3,); +z for a Gaussian at the centre."""
    return safe_normalize(camera_center.to(means) - means)


def orient_normals(normals: torch.Tensor, view_dirs: torch.Tensor) -> torch.Tensor:
    """Flip unit normals (N, 3) whose dot product with the view directions (N, 3) is negative (two-sided splats)."""
    facing = (normals * view_dirs).sum(-1, keepdim=True)
    return torch.where(facing < 0, -normals, normals)


def shading_normals(cfg: ModelConfig, gaussians: GaussianParams, view_dirs: torch.Tensor,
                    camera_center: torch.Tensor) -> torch.Tensor:
    """(N, 3) the unit world normals a variant shades with, seen from ``camera_center`` (3,): the Gaussians' normals,
    turned into the camera's hemisphere (``view_dirs`` (N, 3), :func:`view_directions`) when
    ``cfg.two_sided_normals``."""
    normals = gaussians.normals(camera_center)
    return orient_normals(normals, view_dirs) if cfg.two_sided_normals else normals


def lambert_cosine(normals: torch.Tensor, light_dirs: torch.Tensor) -> torch.Tensor:
    """max(0, n̂·l̂) for unit vectors (N, 3) → (N, 1)."""
    return (normals * light_dirs).sum(-1, keepdim=True).clamp_min(0.0)


def hemisphere_directions(count: int, dtype: torch.dtype = torch.float32) -> torch.Tensor:
    """Deterministic cosine-weighted hemisphere directions (count, 3) around +z (Fibonacci spiral on the unit disk,
    lifted by Malley's method: z = sqrt(1 - r²)). The mean of g over them estimates (1/π) ∫ g cos dω."""
    if count < 1:
        raise ValueError(f"hemisphere_directions: count must be >= 1, got {count}")
    i = torch.arange(count, dtype=torch.float64)
    r = torch.sqrt((i + 0.5) / count)
    phi = i * (math.pi * (3.0 - math.sqrt(5.0)))
    dirs = torch.stack([r * torch.cos(phi), r * torch.sin(phi), torch.sqrt(1.0 - r * r)], dim=-1)
    return dirs.to(dtype)


# ---- colours -----------------------------------------------------------------------------------------------------
def vanilla_colours(gaussians: GaussianParams, c2w: torch.Tensor, degree: int = 3) -> torch.Tensor:
    """Vanilla 3DGS colour: max(0, SH(d̂) + 0.5) with d̂ the unit direction camera → Gaussian; (N, 3)."""
    check_c2w(c2w)
    dirs = -view_directions(gaussians.means, c2w[:3, 3])
    return (eval_sh(gaussians.sh_colour_coeffs(), dirs, degree) + SH_COLOUR_OFFSET).clamp_min(0.0)


def spot_lit_colours(
    albedo: torch.Tensor,
    roughness: torch.Tensor,
    metalness: torch.Tensor,
    normals: torch.Tensor,
    view_dirs: torch.Tensor,
    light_dirs: torch.Tensor,
    spot_radiance: torch.Tensor,
    low_frequency: torch.Tensor,
    brdf: nn.Module,
    low_frequency_reflectance: torch.Tensor | None = None,
) -> torch.Tensor:
    """c = f̃ · max(0, n̂·l̂) · (L_spot + L_lf), or with ``low_frequency_reflectance`` R (N, 3) given (the
    "irradiance" shading of ModelConfig.low_frequency_shading) c = f̃ · max(0, n̂·l̂) · L_spot + R · L_lf.

    Args:
        albedo (N, 3), roughness (N, 1), metalness (N, 1), normals/view_dirs/light_dirs (N, 3) unit vectors,
        spot_radiance (N, 1), low_frequency (N, 3), brdf: a LambertianBRDF or LearnedBRDF.
    Returns:
        (N, 3) linear colours ≥ 0.
    """
    lit = brdf(albedo, roughness, metalness, normals, view_dirs, light_dirs) * lambert_cosine(normals, light_dirs)
    if low_frequency_reflectance is None:
        return lit * (spot_radiance + low_frequency)
    return lit * spot_radiance + low_frequency_reflectance * low_frequency


def relit_reflectance(
    albedo: torch.Tensor,
    roughness: torch.Tensor,
    metalness: torch.Tensor,
    normals: torch.Tensor,
    brdf: nn.Module,
    directions: int = 16,
) -> torch.Tensor:
    """Directional albedo R = (1/π) ∫ f̃(v̂ = n̂, l̂) cos dω under uniform light, (N, 3).

    Lambertian: exactly the albedo. Learned BRDF: mean over `hemisphere_directions(directions)` rotated to each n̂
    (N rows per direction, so memory stays at one (N, hidden) activation). Depends on the Gaussian only, so a caller
    may cache it across frames.
    """
    if isinstance(brdf, LambertianBRDF):
        return albedo
    t1, t2 = orthonormal_basis(normals)
    local = hemisphere_directions(directions, dtype=normals.dtype).to(normals.device)
    total = torch.zeros_like(albedo)
    for d in local:
        light_dirs = d[0] * t1 + d[1] * t2 + d[2] * normals
        total = total + brdf(albedo, roughness, metalness, normals, normals, light_dirs)
    return total / directions


def model_reflectance(
    cfg: ModelConfig,
    albedo: torch.Tensor,
    roughness: torch.Tensor,
    metalness: torch.Tensor,
    normals: torch.Tensor,
    brdf: nn.Module,
) -> torch.Tensor:
    """The directional albedo R (N, 3) that relights a variant and, with the "irradiance" shading, shades its
    low-frequency light in training: for a learned BRDF that is unclamped or has that shading, the unclamped Disney
    model's (`disney_directional_albedo`: a table lookup, no network pass, right for glossy lobes that the clamp
    f̃ ≤ 1 flattens); otherwise `relit_reflectance` (the albedo itself for a Lambertian BRDF)."""
    if isinstance(brdf, LearnedBRDF) and (not brdf.upper_clamp or cfg.low_frequency_shading == "irradiance"):
        return disney_directional_albedo(albedo, roughness, metalness, brdf.burley)
    return relit_reflectance(albedo, roughness, metalness, normals, brdf, cfg.relight_directions)


def relight_radiance(relight_l0: torch.Tensor | Sequence[float], like: torch.Tensor) -> torch.Tensor:
    """Validate L0 (3,) (finite, ≥ 0) and return it as a (1, 3) tensor with the dtype/device of `like`."""
    l0 = torch.as_tensor(relight_l0, dtype=like.dtype, device=like.device)
    if l0.shape != (3,) or not torch.isfinite(l0).all() or (l0 < 0).any():
        raise ValueError(f"relight_l0 must be three finite non-negative linear RGB values, got {relight_l0!r}")
    return l0.reshape(1, 3)


def shade(
    variant: str | ModelConfig,
    gaussians: GaussianParams,
    light: SpotLight | None,
    lf_light: LowFrequencyLight | ConstantAmbient | None,
    brdf: LambertianBRDF | LearnedBRDF | None,
    c2w: torch.Tensor,
    relight_l0: torch.Tensor | Sequence[float] | None = None,
    split_lights: bool = False,
    bounce_light: LowFrequencyLight | None = None,
    spot_visibility: torch.Tensor | None = None,
    with_spot_part: bool = False,
) -> torch.Tensor:
    """Linear RGB colour of every Gaussian seen from camera `c2w`, (N, 3); differentiable; never clipped above.

    Args:
        variant: preset name of `MODEL_VARIANTS` or a ModelConfig.
        gaussians: the Gaussians (N).
        light: the spotlight (unused by "3dgs" and by relighting; may then be None).
        lf_light: ConstantAmbient for ambient "constant", LowFrequencyLight for "sh" (None for "3dgs").
        brdf: LambertianBRDF for brdf "lambert", LearnedBRDF for "mlp" (None for "3dgs").
        c2w: (4, 4) camera-to-world, OpenCV axes.
        relight_l0: None to render under the learned spotlight, or L0 (3,) to relight (see module docstring);
            "3dgs" ignores it (its relit output is its normal render).
        split_lights: under the spotlight only: return (N, 6), the colour lit by the spotlight alone and by the
            low-frequency light alone, [f̃·cos·L_spot, f̃·cos·L_lf]; the two halves sum to the (N, 3) colour.
        bounce_light: the variant's bounce light (ModelConfig.bounce_degree ≥ 0), else None. Under the
            spotlight its radiance at the camera-frame normal adds to L_lf (and to the second half of split_lights);
            relighting leaves it out.
        spot_visibility: (N, 1) in [0, 1], how much of the lamp each Gaussian sees (``shadow.spot_visibility``), or
            None (all of it): scales L_spot only; ignored by relighting.
        with_spot_part: under the spotlight only, without ``split_lights``: return (N, 6), the colour and, detached,
            the colour lit by the spotlight alone (the first half of ``split_lights``: the lamp bounce's emitters),
            from one evaluation of the BRDF.
    """
    cfg = resolve_variant(variant)
    check_c2w(c2w)
    for name, wanted in (("split_lights", split_lights), ("with_spot_part", with_spot_part)):
        if wanted and (cfg.light_model == "none" or relight_l0 is not None):
            raise ValueError(f"{name} needs a spotlight-lit render of a lit variant, not {cfg.name!r}"
                             + (" relit" if relight_l0 is not None else ""))
    if split_lights and with_spot_part:
        raise ValueError("with_spot_part: the spotlight's part is already the first half of split_lights")
    if cfg.light_model == "none":
        return vanilla_colours(gaussians, c2w, cfg.colour_sh_degree)
    _check_modules(cfg, light, lf_light, brdf, bounce_light, relit=relight_l0 is not None)
    center = c2w[:3, 3]
    view_dirs = view_directions(gaussians.means, center)
    normals = shading_normals(cfg, gaussians, view_dirs, center)
    albedo, rough, metal = gaussians.albedo, gaussians.roughness, gaussians.metalness
    low_frequency = lf_light.radiance(normals if cfg.low_frequency_turns_normals else normals.detach())
    if relight_l0 is not None:
        l0 = relight_radiance(relight_l0, albedo)
        return model_reflectance(cfg, albedo, rough, metal, normals, brdf) * (l0 + low_frequency)
    if bounce_light is not None:
        bounce_normals = normals if cfg.low_frequency_turns_normals else normals.detach()
        low_frequency = low_frequency + bounce_light.radiance(bounce_normals @ c2w[:3, :3].to(normals))
    spot, light_dirs = _visible_spot(light, gaussians.means, c2w, spot_visibility)
    lf_reflect = None
    if cfg.low_frequency_shading == "irradiance":
        lf_reflect = model_reflectance(cfg, albedo, rough, metal, normals, brdf)
    if split_lights or with_spot_part:
        lit = _unit_spot_response(albedo, rough, metal, normals, view_dirs, light_dirs, brdf)
        spot_part = lit * spot
        if split_lights:
            low = lit * low_frequency if lf_reflect is None else lf_reflect * low_frequency
            return torch.cat([spot_part, low], dim=1)
        # as spot_lit_colours combines them (lit is its f̃ · cos: the unit response's × 1 + 0 is exact)
        colour = lit * (spot + low_frequency) if lf_reflect is None else spot_part + lf_reflect * low_frequency
        return torch.cat([colour, spot_part.detach()], dim=1)
    return spot_lit_colours(albedo, rough, metal, normals, view_dirs, light_dirs, spot, low_frequency, brdf,
                            lf_reflect)


def _visible_spot(light: SpotLight, means: torch.Tensor, c2w: torch.Tensor,
                  spot_visibility: torch.Tensor | None) -> tuple[torch.Tensor, torch.Tensor]:
    """The spotlight's radiance at every Gaussian (N, 1), scaled by ``spot_visibility`` (N, 1) when given, and the unit
    directions towards the lamp (N, 3) (:meth:`SpotLight.incident`)."""
    spot, light_dirs = light.incident(means, c2w)
    if spot_visibility is not None:
        if spot_visibility.shape != spot.shape:
            raise ValueError(f"spot_visibility must have shape {tuple(spot.shape)}, got {tuple(spot_visibility.shape)}")
        spot = spot * spot_visibility.to(spot)
    return spot, light_dirs


def _unit_spot_response(albedo: torch.Tensor, rough: torch.Tensor, metal: torch.Tensor, normals: torch.Tensor,
                        view_dirs: torch.Tensor, light_dirs: torch.Tensor, brdf: nn.Module) -> torch.Tensor:
    """(N, 3) f̃ · max(0, n̂·l̂): the colour under a unit spotlight radiance and no low-frequency light."""
    ones = torch.ones((len(normals), 1), dtype=normals.dtype, device=normals.device)
    return spot_lit_colours(albedo, rough, metal, normals, view_dirs, light_dirs, ones, torch.zeros_like(normals),
                            brdf)


def _check_modules(cfg: ModelConfig, light, lf_light, brdf, bounce_light, relit: bool) -> None:
    """Raise ValueError when a module does not match the variant."""
    if not relit and (-1 if bounce_light is None else bounce_light.degree) != cfg.bounce_degree:
        raise ValueError(f"variant {cfg.name!r} wants bounce light degree {cfg.bounce_degree} (-1: none), got "
                         + ("none" if bounce_light is None else f"degree {bounce_light.degree}"))
    if not relit and not isinstance(light, SpotLight):
        raise ValueError(f"variant {cfg.name!r} needs a SpotLight, got {type(light).__name__}")
    want_lf = ConstantAmbient if cfg.ambient == "constant" else LowFrequencyLight
    if not isinstance(lf_light, want_lf):
        raise ValueError(f"variant {cfg.name!r} (ambient={cfg.ambient!r}) needs a {want_lf.__name__}, got {type(lf_light).__name__}")
    if cfg.ambient == "sh" and lf_light.degree != cfg.sh_degree:
        raise ValueError(f"variant {cfg.name!r} wants SH degree {cfg.sh_degree}, the LowFrequencyLight has {lf_light.degree}")
    want_brdf = LambertianBRDF if cfg.brdf == "lambert" else LearnedBRDF
    if not isinstance(brdf, want_brdf):
        raise ValueError(f"variant {cfg.name!r} (brdf={cfg.brdf!r}) needs a {want_brdf.__name__}, got {type(brdf).__name__}")


@dataclass
class AppearanceModels:
    """The shared (non-per-Gaussian) appearance modules of one variant; `None` where the variant has none."""

    # Spotlight (None for "3dgs").
    light: SpotLight | None
    # ConstantAmbient or LowFrequencyLight (None for "3dgs").
    lf_light: LowFrequencyLight | ConstantAmbient | None
    # LambertianBRDF or LearnedBRDF (None for "3dgs").
    brdf: LambertianBRDF | LearnedBRDF | None
    # The lamp's bounce light, an SH of the camera-frame normal (None unless ModelConfig.bounce_degree ≥ 0).
    bounce_light: LowFrequencyLight | None = None
    # The lamp's bounce light from the model's geometry (None unless ModelConfig.lamp_bounce).
    lamp_bounce: LampBounce | None = None

    def module_dict(self) -> nn.ModuleDict:
        """The present modules by name ("light", "lf_light", "brdf", "bounce_light", "lamp_bounce"), e.g. for
        `.to(device)` and optimizer groups."""
        return nn.ModuleDict({k: m for k, m in vars(self).items() if m is not None})


def build_appearance_models(
    variant: str | ModelConfig,
    seed: int = 0,
    light_rotation=None,
    light_translation=None,
    cone: tuple[float, float] | None = None,
    ambient_init: float = 0.05,
    spot_radiance_scale: float = 1.0,
) -> AppearanceModels:
    """Create the light, low-frequency light and BRDF of a variant.

    Args:
        variant: preset name or ModelConfig.
        seed: command seed (the RID and BRDF networks draw from their own stages of it).
        light_rotation: initial light→camera rotation, (3, 3) or axis-angle (3,); default identity.
        light_translation: initial light origin in camera coordinates (3,), metres; default 0.
        cone: (half_angle rad, blend) of the known spot cone; required when calibrated.
        ambient_init: initial DarkGS ambient A.
        spot_radiance_scale: the spotlight's fixed radiance unit (SpotLight's ``radiance_scale``).
    Calibrated variants start from the given pose and freeze it, and fit the RID to the cone (unit peak); the RID,
    τ and γ stay trainable so that the unknown lamp power can still be learned.
    """
    cfg = resolve_variant(variant)
    if cfg.light_model == "none":
        return AppearanceModels(None, None, None)
    light = SpotLight(rotation=light_rotation, translation=light_translation, gamma=cfg.falloff_gamma,
                      tau=cfg.falloff_tau, seed=seed, rid_model=cfg.rid_model, radiance_scale=spot_radiance_scale)
    light.set_falloff_trainable(cfg.learn_falloff)
    if cfg.calibrated:
        if cone is None or light_translation is None:
            raise ValueError(f"variant {cfg.name!r} is calibrated: pass light_translation (and rotation) and cone")
        light.fit_rid_to_cone(*cone)
        light.set_pose_trainable(False)
    lf_light = ConstantAmbient(ambient_init) if cfg.ambient == "constant" else LowFrequencyLight(cfg.sh_degree)
    brdf = LambertianBRDF() if cfg.brdf == "lambert" else LearnedBRDF(hidden=cfg.brdf_hidden, seed=seed,
                                                                     upper_clamp=cfg.brdf_upper_clamp,
                                                                     burley=cfg.brdf_burley_diffuse,
                                                                     input_gradients=cfg.brdf_network_input_gradients)
    bounce = LowFrequencyLight(cfg.bounce_degree) if cfg.bounce_degree >= 0 else None
    return AppearanceModels(light, lf_light, brdf, bounce, LampBounce() if cfg.lamp_bounce else None)
