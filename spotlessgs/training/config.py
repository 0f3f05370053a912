"""Training settings: a frozen dataclass with a comment per field, and named presets.

``tiny`` runs in seconds (tests), ``quick`` in minutes on a 2-core CPU at ~160x120, ``paper`` is the paper's schedule
(30k iterations, native resolution) for a GPU. docs/method.md §6 gives the research code's learning rates.
"""

from __future__ import annotations

import dataclasses
import math
import re
import types
import typing
from dataclasses import dataclass
from typing import Any

from spotlessgs.clitools import MAX_THREADS


#: Spaces the photometric loss compares images in (TrainConfig.loss_space; spotlessgs.training.losses).
LOSS_SPACES = ("linear", "srgb")

#: Units of the spotlight's radiance (TrainConfig.spot_radiance_unit; spotlessgs.training.light_unit).
SPOT_RADIANCE_UNITS = ("fixed", "median_depth")

#: Rasterizer backends (TrainConfig.raster_backend): spotlessgs.rasterizer.BACKENDS, named here without loading torch.
RASTER_BACKENDS = ("auto", "cpp", "torch", "gsplat")

#: Values of the TrainConfig switches whose "auto" the trainer resolves from the data (photometric, depth_spread).
SWITCH_VALUES = ("auto", "on", "off")

#: Settings whose default is not what a run trained with before the setting existed. Absent from an older run's saved
#: settings, such a setting takes this value instead of the default, so the run reloads and resumes as it trained.
PREDATING_VALUES: dict[str, Any] = {"bounce_light_degree": -1, "shadow_camera_relative": False,
                                    "depth_spread_weight": 0.0, "depth_spread": "on", "depth_spread_every": 1,
                                    "lamp_bounce_every": 1, "trust_start_geometry": "off", "rid_model": "mlp"}


def field_type_errors(cls: type, values: dict[str, Any]) -> list[str]:
    """The entries of ``values`` (fields of the settings dataclass ``cls`` as JSON gave them) whose type is not the
    field's: ``bool`` takes true/false only, ``int`` a whole number, ``float`` any number, ``str`` text, ``X | None``
    also null, a tuple a list; one message per entry (``"seed: expected an int, got 'abc'"``). Names ``cls`` does not
    have are left to its constructor."""
    hints = typing.get_type_hints(cls)
    return [f"{name}: expected {_type_name(hints[name])}, got {value!r}" for name, value in values.items()
            if name in hints and not _fits(value, hints[name])]


def _fits(value: Any, kind: Any) -> bool:
    """Whether the JSON value ``value`` can stand for the annotation ``kind`` (see :func:`field_type_errors`)."""
    origin, args = typing.get_origin(kind), typing.get_args(kind)
    if origin in (typing.Union, types.UnionType):
        return any(_fits(value, arg) for arg in args)
    if kind is type(None):
        return value is None
    if kind is bool:
        return isinstance(value, bool)
    if kind is int:
        return isinstance(value, int) and not isinstance(value, bool)
    if kind is float:
        return isinstance(value, (int, float)) and not isinstance(value, bool)
    if kind is str:
        return isinstance(value, str)
    if origin is typing.Literal:
        return value in args
    if origin is tuple:
        return isinstance(value, (list, tuple))
    return True  # another type: its constructor or __post_init__ checks it


def _type_name(kind: Any) -> str:
    args = [a for a in typing.get_args(kind) if a is not type(None)]
    if typing.get_origin(kind) in (typing.Union, types.UnionType):
        return " or ".join(_type_name(a) for a in args) + " or null"
    if typing.get_origin(kind) is typing.Literal:
        return "one of " + ", ".join(repr(a) for a in typing.get_args(kind))
    if typing.get_origin(kind) is tuple:
        return "a list"
    return {bool: "true or false", int: "a whole number", float: "a number", str: "text"}.get(kind, str(kind))


def with_defaults(cls: type, saved: dict[str, Any]) -> dict[str, Any]:
    """``saved``, the fields of a settings dataclass ``cls`` (TrainConfig, ModelConfig) as a run wrote them, completed
    for the fields added since: with :data:`PREDATING_VALUES` where listed, else the field's default."""
    missing = {f.name: PREDATING_VALUES.get(f.name, f.default) for f in dataclasses.fields(cls)
               if f.name not in saved and (f.name in PREDATING_VALUES or f.default is not dataclasses.MISSING)}
    return {**missing, **saved}


@dataclass(frozen=True)
class TrainConfig:
    """Everything that determines a training run besides the data, the model variant and the seed."""

    # Preset name this config started from (recorded in the run folder).
    preset: str = "quick"
    # Optimisation steps (one training view per step).
    iterations: int = 3000
    # Width the input images are area-downscaled to (height keeps the aspect ratio); None = native size.
    image_width: int | None = 160
    # Weight λ of the (1 - SSIM) term: loss = (1 - λ) L1 + λ (1 - SSIM).
    ssim_lambda: float = 0.2
    # Space of the photometric loss (LOSS_SPACES): "linear" light (the paper's) or "srgb" encoded values, in which the
    # dim periphery counts about as much as it shows after relighting.
    loss_space: str = "linear"
    # sRGB value at or above which an input pixel counts as clipped: there the loss only penalises predictions darker
    # than the observation (the true radiance is at least the clipped value), so clipping cannot drag the light down.
    saturation_threshold: float = 250.0 / 255.0
    # The input images are linear already (RAW); default: 8-bit sRGB, linearised on load.
    linear_input: bool = False

    # Learning rates (Adam). Positions decay exponentially from init to final, both times the scene extent.
    lr_means_init: float = 1.6e-4
    lr_means_final: float = 1.6e-6
    lr_quats: float = 1e-3
    lr_scales: float = 5e-3
    lr_opacity: float = 5e-2
    lr_albedo: float = 5e-2
    lr_normals: float = 5e-2
    lr_roughness: float = 5e-2
    lr_metalness: float = 5e-2
    # Vanilla 3DGS colour: DC band and higher bands (3DGS uses 1/20 of the DC rate for the higher bands).
    lr_sh0: float = 2.5e-3
    lr_shN: float = 1.25e-4
    # Spotlight RID MLP, fall-off τ/γ, low-frequency SH light / ambient. The RID and fall-off at 3e-3 are a candidate
    # (--set lr_light=3e-3 --set lr_lf_light=1e-3): the learned lamp nearer the truth on every simulator room (bedroom
    # 8.0-8.4 cm instead of 10.9-13.0, the axis within 0.5°), SpotlessGS better against the uniform ground truth, but
    # the robot copy's DarkGS -0.19 dB over three seeds and its auto row up to -1.15 dB in the quick reproduction, and
    # the calibrated DarkGS -0.13 / -0.36 dB on the bedroom (docs/results.md, "The angular profile's learning rate").
    lr_light: float = 1e-3
    # Low-frequency light (SH coefficients / constant ambient); None = lr_light.
    lr_lf_light: float | None = None
    # Light pose relative to the camera (so3 rotation and translation). With spotlight shadows 3e-4 placed the lamp
    # closer (docs/results.md, "Spotlight shadows"); alone it is no consistent gain.
    lr_light_pose: float = 1e-3
    # The monotone angular profile's log-values (rid_model "monotone"): ten times lr_light, so that its knots can
    # drop the 4-5 nepers of a lamp's edge within the first few hundred steps (a prototype at lr_light, 24 knots, was
    # still forming the edge at the end, the lamp 19-21 cm in front of the camera; docs/results.md).
    lr_rid_profile: float = 1e-2
    # Learned BRDF MLP.
    lr_brdf: float = 1e-4

    # Densification (strategy.DensifyStrategy): grow from densify_from until densify_until every densify_every steps.
    densify_from: int = 300
    densify_until: int = 2000
    densify_every: int = 100
    # Average screen-space gradient (NDC units, as in 3DGS) above which a Gaussian is cloned or split.
    densify_grad_threshold: float = 2e-4
    # Gaussians larger than this fraction of the scene extent are split, smaller ones cloned.
    percent_dense: float = 0.01
    # Opacity below which Gaussians are pruned at densification steps.
    prune_opacity: float = 0.005
    # Reset all opacities to at most reset_opacity_value every this many steps while densifying (0 = never).
    opacity_reset_every: int = 1000
    reset_opacity_value: float = 0.01
    # Hard cap on the number of Gaussians (densification picks the highest-gradient candidates first).
    max_gaussians: int = 20_000
    # At most this many initial Gaussians (a seeded random subset of the point cloud); None = every point.
    init_points: int | None = 12_000

    # Hidden width of the learned BRDF MLP (paper 256; it dominates CPU shading time).
    brdf_hidden: int = 32
    # How the low-frequency light shades a Gaussian in the spotlit training images (ModelConfig.low_frequency_shading):
    # "spot_cosine" (the paper's equation) or "irradiance" (as relighting shades it). A trusted start sets
    # "irradiance" with the monotone profile (trust_start_geometry); alone it cost the residual-light and glossy rooms
    # 0.18 and 0.23 dB against the uniform ground truth (docs/results.md, "The irradiance shading on a trusted start").
    low_frequency_shading: str = "spot_cosine"
    # The spotlight's fall-off (τ + d²)^(-γ): initial τ (m²) and γ, and whether they learn
    # (ModelConfig.falloff_*).
    falloff_tau: float = 0.3
    falloff_gamma: float = 1.0
    learn_falloff: bool = True
    # The spotlight's angular profile: "mlp" (the paper's) or "monotone" (a non-increasing piecewise-linear profile,
    # ModelConfig.rid_model), which learns at lr_rid_profile; "auto" (the default; trainer.resolved_rid_model):
    # "monotone" for a model with an SH light and a learned BRDF (SpotlessGS), "mlp" for the others, on any start. On
    # the robot copy's sparse start "auto" relit SpotlessGS −0.01 / +0.45 dB (lamps-on / uniform, three seeds) with the
    # lamp 2.6 cm from the truth instead of 4.5 (docs/results.md, "The lamp model on a sparse start ..."). A trusted
    # start sets "monotone" with the irradiance shading (trust_start_geometry): the bedroom's lamp within 3 cm, 9.8 with
    # the MLP. `--model auto` keeps the MLP on a start it does not trust (selection.proxy_light): the monotone profile
    # cost it 0.19 / 0.11 dB on the robot copy (three seeds). A run resumes with the profile it began with (runs saved
    # before the setting existed: "mlp").
    rid_model: str = "auto"
    # The unit of the spotlight's radiance (training.light_unit): "fixed" (the research code's) or "median_depth" (a
    # factor (τ0 + z²)^γ0 on the spotlight, z the scene's median depth in the training views: the light starts as
    # bright as the images ask, and the albedo below its cap). With rid_model=monotone it relit the saturated bedroom
    # 1.2 dB better (24.70 dB, two seeds) and the quick reproduction's rows up to 0.87 dB better against the uniform
    # ground truth, but the robot copy's up to 0.32 dB worse against the lamps-on one: not the default
    # (docs/results.md, "The albedo's cap and the light's unit").
    spot_radiance_unit: str = "fixed"
    # The learned BRDF's f̃ clamped at 1 (the research code's) or not (ModelConfig.brdf_upper_clamp).
    brdf_upper_clamp: bool = True
    # The learned BRDF's diffuse lobe with Burley's retro-reflection factor (the paper's) or Lambertian
    # (ModelConfig.brdf_burley_diffuse).
    brdf_burley_diffuse: bool = True
    # Whether the learned BRDF's network passes its gradient on to the directions it reads
    # (ModelConfig.brdf_network_input_gradients; True: the paper's). False: 8 % less time per SpotlessGS step (idle
    # A/B, two pairs), but four rows lose 0.14-0.24 dB against the uniform ground truth on the mean of three seeds
    # (docs/results.md, "The learned BRDF's network without its gradient to the directions").
    brdf_network_input_gradients: bool = True
    # Degree of the lamp's bounce light, an SH of the camera-frame normal that is part of the SH light and left out of
    # relighting (ModelConfig.bounce_light_degree; -1: none, the paper's). Degree 2 relit the bedroom best (uniform
    # ground truth: 23.79 / 24.41 / 24.22 dB for degrees 1 / 2 / 3, 23.18 without; docs/results.md). A trusted start
    # sets -1 (trust_start_geometry below): there the geometric bounce (lamp_bounce) takes its place.
    bounce_light_degree: int = 2
    # The lamp's bounce light computed from the model's own geometry (ModelConfig.lamp_bounce; models.lamp_bounce):
    # one bounce of the spotlit render in screen space, learned through one gain, left out of relighting.
    lamp_bounce: bool = False
    # Trust a dense start's geometry (training.trainer.start_geometry_settings): hold the start's normals (lr_normals
    # 0), turn the lamp's bounce light from the model's geometry on (lamp_bounce) and the camera-frame one off
    # (bounce_light_degree -1: beside the geometric one it over-lit the glossy room outside the lamp's cone, 0.63 dB
    # against the uniform ground truth) and take the learned BRDF's clamp f̃ ≤ 1 off (brdf_upper_clamp). The bounce
    # needs normals that face the way the surfaces do (learned ones lean towards the camera's height, and the bounce
    # then costs 1.1-1.35 dB against the uniform ground truth); held
    # normals leave a smooth metal's glint to the BRDF's specular lobe, which the clamp flattens (with the clamp the
    # glossy storage room loses 0.8 dB against the uniform ground truth; unclamped it gains 1.36); and place the lamp
    # with the monotone angular profile and the irradiance shading (rid_model, low_frequency_shading: the bedroom's
    # lamp 1.6-2.9 cm from the truth instead of 9.8; docs/results.md, "The lamp by default on a trusted start").
    # "auto": for a start cloud that is not sparse (SPARSE_START_SHARE) and has or gets normals (a depth camera's, the
    # simulator's), not for a sparse SfM start (its estimated normals are too rough to hold) or a random one; "on":
    # any start; "off": those settings as set. Only SpotlessGS's models (an SH light and a learned BRDF:
    # training.trainer.trusts_start_geometry) are trusted so: the bounce is part of the SH light, as the SH bounce
    # light is, and a Lambertian albedo with held normals paints a metal's glint in (the storage room's DarkGS + SH
    # light −1.8 dB). With "auto" SpotlessGS gains +0.1-0.3 / +1.1-1.6 dB (lamps-on / uniform ground truth) on every
    # simulator room with a dense start, at +8.7 % per step since the bounce shares the training render's pass (idle
    # A/B; docs/results.md, "Trusting a dense start, with the BRDF unclamped", "The bounce computed in the training
    # render's own pass").
    trust_start_geometry: str = "auto"
    # The low-frequency light's gradient reaches the normals (ModelConfig.low_frequency_turns_normals; True: the paper's).
    low_frequency_turns_normals: bool = True
    # Spotlight shadows from a shadow map rendered at the learned light pose (ModelConfig.spot_shadows; models.shadow):
    # the lamp's shadows go into the light, not the albedo, and their gradient places the lamp. Off: the paper's (no
    # shadow term). Not the default: on in the quick reproduction, they placed every variant's lamp closer but several
    # rows lost 0.1-0.7 dB on one seed (docs/results.md, "Shadows relative to the camera").
    spot_shadows: bool = False
    # The shadow map's focal length as a fraction of the camera's (ModelConfig.shadow_map_scale).
    shadow_map_scale: float = 0.5
    # Shadows relative to what the camera itself sees of each Gaussian (ModelConfig.shadow_camera_relative); False:
    # the lamp's map alone, under which a sparse start's loosely fitted surfaces shadow themselves (docs/results.md).
    shadow_camera_relative: bool = True
    # Training re-renders a view's shadow maps (the lamp's and the camera's) when they are this many steps old (1:
    # every step); in between the view reuses them (values from the lamp pose they were rendered at, the gradient to
    # the lamp's position as now). Each cached map pair is 6 float32 channels at the map's size. 180 on the quick
    # bedroom (54 training views): a map serves about three visits of its view, for +7 % per step (90: +17 %) with the
    # lamp as well placed within the seeds' spread (docs/results.md, "Shadows relative to the camera").
    shadow_map_every: int = 180
    # Steps a training view's lamp bounce irradiance is reused for (lamp_bounce only; training.view_caches): at 180 on
    # the bedroom (54 training views) it is recomputed about every fourth visit of its view.
    lamp_bounce_every: int = 180
    # Weight of the light-translation prior ‖t - t_prior‖ (used only when a prior is given).
    light_prior_weight: float = 1.0
    # Weight of the normal-shape term mean(1 - |n̂·â|) over the visible Gaussians, â each one's shortest axis
    # (losses.normal_shape_loss): ties the free shading normals to the splats' shape (0: off, the paper's).
    normal_axis_weight: float = 0.0
    # Weight of a prior that turns each shading normal towards the nearer of horizontal and vertical, the up direction
    # taken from the training cameras (losses.normal_gravity_loss: walls, floors and ceilings of a room seen by a level
    # camera). 0: off.
    normal_gravity_weight: float = 0.0
    # Weight of the depth-spread term (losses.depth_spread_loss): the spread of the Gaussians' depths along each
    # pixel's ray, relative to their mean, over the pixels the render covers. It draws each surface's slab of Gaussians
    # together (0: off, the paper's loss). The weight of the steps it trains on (depth_spread_every): 0.4 on every 4th
    # step weighs as much over a run as 0.1 on every step.
    depth_spread_weight: float = 0.4
    # When the term trains (trainer.depth_spread_weight_for): "auto": for models with a light on datasets from real
    # cameras (no "spotless" block; their starts are sparse SfM points) or our simulator's copies that imitate one
    # (their block lists camera effects), where at 0.1 on every step every model with a light relit as well or better
    # (the robot copy: SpotlessGS +0.18 / +1.17 dB, lamps-on / uniform ground truth, three seeds; docs/results.md,
    # "The depth-spread term: on for real cameras"), and for SpotlessGS (an SH light and a learned BRDF:
    # trainer.trusts_start_geometry) on every dataset: on our simulator's dense starts it relit the bedroom and its
    # copies −0.02 to +0.12 / +0.07 to +0.31 dB, the glossy storage room +0.04 / −0.06 (three seeds each; "The lamp
    # model on a sparse start ..."); off for 3DGS, and for the DarkGS variants on our simulator's renders (up to
    # −0.34 dB on the glossy room). A run resumes with the weight it began with (its checkpoint records it). "on":
    # every model, 3DGS included; "off".
    depth_spread: str = "auto"
    # The term trains on every this-many-th step only (1: every step): its extra rasterized channels and their
    # backward are paid on those steps alone. On the robot copy (SpotlessGS, quick preset; idle A/B against the term
    # off, and three seeds of relit PSNR; docs/results.md, "The depth-spread term on every 4th step"): 0.1 on every
    # step +24.7 % per step for +0.18 / +1.17 dB (lamps-on / uniform ground truth), 0.1 on every 4th +3.4 % for
    # +0.14 / +0.83 dB (one seed −0.11 against the lamps-on truth), 0.4 on every 4th (the default) +4.9 % for
    # +0.21 / +0.97 dB, every seed at least +0.18.
    depth_spread_every: int = 4

    # Photometric camera (spotlessgs.models.photometric): learn a per-frame exposure and the lens's vignetting.
    # "auto": on for datasets from real cameras (no "spotless" block), off for our simulator's renders (one fixed
    # exposure, no vignetting) unless their block lists camera effects; "on"; "off".
    photometric: str = "auto"
    # What the photometric camera learns when on: the frames' exposures, the vignetting.
    learn_exposure: bool = True
    learn_vignetting: bool = True
    # Adam learning rates of the frames' log-gains and of the vignetting coefficients. The vignetting learns slowly:
    # at 2e-3, on the robot-camera bedroom's sparse start, it collapsed to the 0.05 floor beyond r = 0.8 and the relit
    # sequence flickered 0.131 (truth 0.089); at 2e-4 it learned V(1) = 0.61 (truth 0.65), flicker 0.081 and +0.10 dB
    # (docs/results.md, "Real robot cameras").
    lr_exposure: float = 2e-2
    lr_vignetting: float = 2e-4

    # A start from points without normals (an SfM cloud): estimate them from each point's neighbours (True) or start
    # the Gaussians facing the camera (False). A start with few points densifies from the first densification step
    # (True; see spotlessgs.training.trainer.SPARSE_START_SHARE) or from densify_from as any other (False).
    estimate_normals: bool = True
    sparse_start: bool = True

    # ---- camera pose refinement (spotlessgs.models.pose, spotlessgs.training.pose_alignment) -------------------------
    # Learn a rigid correction of every training view's pose beside the scene (c2w · Δ_k in the camera's frame,
    # starting at the identity); the test views are then aligned (model frozen, against their spotlit inputs) before
    # they are rendered and scored. False: the dataset's poses as given.
    refine_poses: bool = False
    # Learning rate of the corrections (lazy Adam: only the fitted view's correction moves): metres per step for the
    # translation, the 6D rotation offset's units (about radians) for the rotation.
    lr_pose: float = 1e-3
    # The corrections learn from this step on (before it the scene takes a rough shape on the given poses).
    pose_refine_from: int = 500
    # Weight of the penalty ‖δ_k‖² (δ_k: the fitted view's translation in m and 6D rotation offset) that pulls each
    # correction towards the identity.
    pose_penalty: float = 1e-2
    # Weight of the texture loss (spotlessgs.training.losses.texture_loss: local contrast, which the camera-mounted
    # light moving with a pose hypothesis hardly changes) added to the training loss while the poses learn; its
    # gradient dominates the corrections' and keeps the light from biasing them. On the bedroom with 3 cm / 0.3 deg
    # per-frame errors: 0.2 refined the training views to 0.78 cm / 0.12 deg, the training loss alone (0) to 1.32 cm /
    # 0.22 deg (docs/results.md, "Camera pose refinement").
    pose_texture_weight: float = 0.2
    # Test-view alignment: Adam steps and learning rate per view, and its loss: "texture" (local contrast, which the
    # camera-mounted light hardly changes) or "photometric" (the training loss).
    pose_align_steps: int = 150
    pose_align_lr: float = 2e-3
    pose_align_loss: str = "texture"

    # ---- held-out validation views and the Gaussian budget (spotlessgs.training.validation / .budget) ----------------
    # Hold out every k-th training view (by position in the training split, never a test view) as a validation view
    # that is not fitted; 0 = fit every training view.
    validation_every: int = 0
    # Instead of whole views: hold out this fraction of the validation_block×validation_block pixel blocks of every
    # fitted view (seeded; never fitted, scored as the validation PSNR); 0 = off. Model selection uses it.
    validation_blocks: float = 0.0
    # Block side in pixels of the training resolution; None = 1/20 of the image width (at least 2).
    validation_block: int | None = None
    # The validation views rejoin the fitted views once densification ends (step densify_until); False = they stay
    # held out for the whole run (model selection proxies).
    validation_rejoin: bool = False
    # The final validation score is the mean of this many scores taken at evenly spaced steps over the last third of
    # the run (ending at the last step): it smooths the step-to-step noise of a short run. 1 = the last step only.
    validation_average: int = 1
    # Gaussian budget: stop densifying when the validation PSNR stops improving and prune Gaussians whose removal does
    # not change the renders (needs validation_every > 0).
    gaussian_budget: bool = False
    # Budget: densification stops after this many validation checks (one per densify_every) without a gain of at least
    # budget_min_gain_db over the best earlier value (the count restarts after an opacity reset).
    budget_patience: int = 3
    budget_min_gain_db: float = 0.05
    # Budget: at each densification step, prune the least-contributing Gaussians whose summed contribution (alpha ·
    # transmittance summed over pixels of the contribution views) is at most this fraction of all Gaussians' total.
    # Measured on the 36-frame quick bedroom / storage room (relit aligned PSNR vs the default strategy, mean of 3
    # seeds, docs/results.md "Model selection and Gaussian budget"): 0.03 -40% / -37% Gaussians at -0.19 / -0.05 dB;
    # 0.02 on the bedroom -31% at -0.24 dB (seed-to-seed noise ~0.1 dB is as large as the difference).
    budget_prune_fraction: float = 0.03
    # Budget: number of fitted views (evenly spaced) over which contributions are summed.
    budget_contribution_views: int = 16

    # Write a checkpoint every this many steps (and at the end).
    checkpoint_every: int = 500
    # Log metrics every this many steps.
    log_every: int = 25
    # CPU threads for torch and the rasterizer (None = torch's default).
    num_threads: int | None = None
    # Rasterizer backend: auto, cpp, torch or gsplat.
    raster_backend: str = "auto"
    # Device: "auto" (CUDA when present), "cpu" or "cuda".
    device: str = "auto"

    def _check_general_ranges(self) -> None:
        """ValueError for a setting of the wrong type (a whole number where one is expected, ...) or out of the range
        every field of its kind has: numbers finite, learning rates and loss weights >= 0 (the means' rate > 0: its
        schedule is log-linear), step counts and intervals >= 1, sizes >= 1 (an image width >= 8), fractions and
        opacities in [0, 1), a positive saturation threshold, a known device and rasterizer."""
        wrong = field_type_errors(TrainConfig, {f.name: getattr(self, f.name) for f in dataclasses.fields(self)})
        if wrong:  # a float width, a bool step count, text for a number: the run could not be read back
            raise ValueError(f"TrainConfig: {wrong[0]}")
        for f in dataclasses.fields(self):
            value = getattr(self, f.name)
            if isinstance(value, float) and not math.isfinite(value):
                raise ValueError(f"TrainConfig: {f.name} must be finite, got {value}")
            learning_rate = f.name.startswith("lr_") or f.name.endswith("_lr")
            if (learning_rate or f.name.endswith("_weight")) and value is not None and value < 0:
                kind = "the learning rate" if learning_rate else "the loss weight"
                raise ValueError(f"TrainConfig: {kind} {f.name} must be >= 0, got {value}")
        at_least = {"iterations": 1, "log_every": 1, "checkpoint_every": 1, "densify_every": 1, "max_gaussians": 1,
                    "brdf_hidden": 1, "init_points": 1, "num_threads": 1, "image_width": 8, "opacity_reset_every": 0,
                    "densify_from": 0, "densify_until": 0, "densify_grad_threshold": 0.0, "percent_dense": 0.0,
                    "validation_block": 2}
        for name, low in at_least.items():
            value = getattr(self, name)
            if value is not None and value < low:
                raise ValueError(f"TrainConfig: {name} must be >= {low}, got {value}")
        within = {"ssim_lambda": (0.0, 1.0, True), "prune_opacity": (0.0, 1.0, False),
                  "reset_opacity_value": (0.0, 1.0, False), "validation_blocks": (0.0, 1.0, False),
                  "budget_prune_fraction": (0.0, 1.0, False)}  # name: (low, high, high included)
        for name, (low, high, closed) in within.items():
            value = getattr(self, name)
            if not (low <= value <= high if closed else low <= value < high):
                raise ValueError(f"TrainConfig: {name} must be in [{low:g}, {high:g}{']' if closed else ')'}, "
                                 f"got {value}")
        if self.num_threads is not None and self.num_threads > MAX_THREADS:
            raise ValueError(f"TrainConfig: num_threads must be at most {MAX_THREADS}, got {self.num_threads}")
        if self.raster_backend not in RASTER_BACKENDS:
            raise ValueError(f"TrainConfig: raster_backend must be one of {', '.join(RASTER_BACKENDS)}, got "
                             f"{self.raster_backend!r}")
        if not re.fullmatch(r"auto|cpu|cuda(:\d+)?", self.device):
            raise ValueError(f"TrainConfig: device must be auto, cpu, cuda or cuda:N, got {self.device!r}")
        if self.lr_means_init <= 0 or self.lr_means_final <= 0:
            raise ValueError(f"TrainConfig: lr_means_init and lr_means_final must be > 0 (a log-linear schedule), got "
                             f"{self.lr_means_init} and {self.lr_means_final}")
        if self.saturation_threshold <= 0:
            raise ValueError(f"TrainConfig: saturation_threshold must be > 0, got {self.saturation_threshold}")

    def __post_init__(self) -> None:
        self._check_general_ranges()
        if self.photometric not in SWITCH_VALUES:
            raise ValueError(f"TrainConfig: photometric must be 'auto', 'on' or 'off', got {self.photometric!r}")
        if self.trust_start_geometry not in SWITCH_VALUES:
            raise ValueError(f"TrainConfig: trust_start_geometry must be 'auto', 'on' or 'off', "
                             f"got {self.trust_start_geometry!r}")
        if self.depth_spread not in SWITCH_VALUES:
            raise ValueError(f"TrainConfig: depth_spread must be 'auto', 'on' or 'off', got {self.depth_spread!r}")
        if self.depth_spread_every < 1:
            raise ValueError(f"TrainConfig: depth_spread_every must be >= 1, got {self.depth_spread_every}")
        if self.spot_radiance_unit not in SPOT_RADIANCE_UNITS:
            raise ValueError(f"TrainConfig: spot_radiance_unit must be one of {SPOT_RADIANCE_UNITS}, "
                             f"got {self.spot_radiance_unit!r}")
        if self.loss_space not in LOSS_SPACES:
            raise ValueError(f"TrainConfig: loss_space must be 'linear' or 'srgb', got {self.loss_space!r}")
        if self.pose_texture_weight < 0 or self.pose_penalty < 0 or self.lr_pose <= 0:
            raise ValueError(f"TrainConfig: pose_texture_weight and pose_penalty must be >= 0 and lr_pose > 0, got "
                             f"{self.pose_texture_weight}, {self.pose_penalty}, {self.lr_pose}")
        if self.pose_align_loss not in ("texture", "photometric"):
            raise ValueError(f"TrainConfig: pose_align_loss must be 'texture' or 'photometric', got "
                             f"{self.pose_align_loss!r}")
        if self.pose_align_steps < 0 or self.pose_refine_from < 0:
            raise ValueError(f"TrainConfig: pose_align_steps and pose_refine_from must be >= 0, got "
                             f"{self.pose_align_steps} and {self.pose_refine_from}")
        if self.validation_every < 0 or self.validation_every == 1:
            raise ValueError(f"TrainConfig: validation_every must be 0 (off) or >= 2, got {self.validation_every}")
        if self.shadow_map_every < 1:
            raise ValueError(f"TrainConfig: shadow_map_every must be >= 1, got {self.shadow_map_every}")
        if self.lamp_bounce_every < 1:
            raise ValueError(f"TrainConfig: lamp_bounce_every must be >= 1, got {self.lamp_bounce_every}")
        if self.validation_average < 1:
            raise ValueError(f"TrainConfig: validation_average must be >= 1, got {self.validation_average}")
        if not 0.0 <= self.validation_blocks < 1.0:
            raise ValueError(f"TrainConfig: validation_blocks must be in [0, 1), got {self.validation_blocks}")
        if self.validation_blocks > 0 and self.validation_every > 0:
            raise ValueError("TrainConfig: hold out whole views (validation_every) or pixel blocks "
                             "(validation_blocks), not both")
        if self.validation_block is not None and self.validation_block < 1:
            raise ValueError(f"TrainConfig: validation_block must be >= 1, got {self.validation_block}")
        if self.gaussian_budget and self.validation_every == 0:
            raise ValueError("TrainConfig: gaussian_budget needs held-out validation views (set validation_every >= 2)")
        if self.budget_patience < 1:
            raise ValueError(f"TrainConfig: budget_patience must be >= 1, got {self.budget_patience}")
        if not 0.0 <= self.budget_prune_fraction < 1.0:
            raise ValueError(f"TrainConfig: budget_prune_fraction must be in [0, 1), got {self.budget_prune_fraction}")
        if self.budget_contribution_views < 1:
            raise ValueError(
                f"TrainConfig: budget_contribution_views must be >= 1, got {self.budget_contribution_views}")

    def replace(self, **changes: Any) -> "TrainConfig":
        """A copy with some fields changed (unknown names are an error)."""
        unknown = set(changes) - {f.name for f in dataclasses.fields(self)}
        if unknown:
            raise ValueError(f"unknown TrainConfig field(s): {sorted(unknown)}")
        return dataclasses.replace(self, **changes)


PRESETS: dict[str, TrainConfig] = {
    "tiny": TrainConfig(
        preset="tiny", iterations=200, image_width=64, densify_from=60, densify_until=150, densify_every=30,
        opacity_reset_every=0, checkpoint_every=100, log_every=10, max_gaussians=8000, init_points=4000,
        brdf_hidden=32, pose_refine_from=30,
    ),
    "quick": TrainConfig(),
    "paper": TrainConfig(
        preset="paper", iterations=30_000, image_width=None, densify_from=2000, densify_until=15_000,
        densify_every=300, opacity_reset_every=5000, checkpoint_every=5000, log_every=100, max_gaussians=1_000_000,
        init_points=None,
        brdf_hidden=256, pose_refine_from=5000,
    ),
}


#: Step-count fields of the densification schedule, scaled with the iteration count (see :func:`preset`).
SCHEDULE_FIELDS = ("densify_from", "densify_until", "densify_every", "opacity_reset_every", "pose_refine_from")


#: Densification strategies, chosen by name as gsplat's ``Config.strategy``: the TrainConfig fields each one sets.
#: ``budget`` is ``spotless train --gaussian-budget``: every 8th training view held out until densification ends,
#: densification stops when held-out error stops improving, Gaussians that do not change the renders are pruned
#: (spotlessgs.training.budget).
STRATEGIES: dict[str, dict[str, Any]] = {
    "default": {},
    "budget": {"gaussian_budget": True, "validation_every": 8, "validation_rejoin": True},
}


def preset(name: str, strategy: str = "default", **overrides: Any) -> TrainConfig:
    """The named preset with the fields of a densification ``strategy`` (:data:`STRATEGIES`) and some fields changed
    (``overrides`` win over the strategy's fields).

    Overriding ``iterations`` scales the densification schedule (``SCHEDULE_FIELDS`` not overridden themselves) by
    the same factor, as gsplat's ``steps_scaler`` does: with 1000 instead of 3000 iterations densification stops at
    step 667, not 2000, and opacities are not reset at the very last step.
    """
    if name not in PRESETS:
        raise ValueError(f"unknown preset {name!r}; choose one of {sorted(PRESETS)}")
    if strategy not in STRATEGIES:
        raise ValueError(f"unknown densification strategy {strategy!r}; choose one of {sorted(STRATEGIES)}")
    overrides = {**STRATEGIES[strategy], **overrides}
    base = PRESETS[name]
    if "iterations" in overrides and overrides["iterations"] != base.iterations:
        factor = overrides["iterations"] / base.iterations
        for field in SCHEDULE_FIELDS:
            if field not in overrides and getattr(base, field) > 0:
                overrides[field] = max(1, round(getattr(base, field) * factor))
    return base.replace(**overrides)


def parse_setting(text: str) -> tuple[str, Any]:
    """``"KEY=VALUE"`` → (KEY, VALUE typed as the TrainConfig field is annotated: a bool from true/false/1/0, an int, a
    finite float or text; a field that may be None also takes ``none``). ValueError naming the problem for an unknown
    field or a value of the wrong type (its range is TrainConfig's to check)."""
    key, sep, raw = text.partition("=")
    hints = typing.get_type_hints(TrainConfig)
    if not sep or key not in hints:
        raise ValueError(f"{text!r} is not KEY=VALUE with KEY a TrainConfig field "
                         f"(e.g. loss_space=srgb, falloff_tau=0.01)")
    kinds = [k for k in (typing.get_args(hints[key]) or (hints[key],)) if k is not type(None)]
    if len(kinds) < len(typing.get_args(hints[key])) and raw.lower() in ("none", "null"):
        return key, None
    kind = kinds[0]
    try:
        if kind is bool:
            if raw.lower() not in ("true", "false", "1", "0"):
                raise ValueError(raw)
            return key, raw.lower() in ("true", "1")
        value = kind(raw)
        if kind is float and not math.isfinite(value):
            raise ValueError(raw)
        return key, value
    except ValueError:
        nullable = " or none" if len(kinds) < len(typing.get_args(hints[key])) else ""
        what = "a finite number" if kind is float else _type_name(kind)
        raise ValueError(f"{key}: {raw!r} is not {what}{nullable}") from None
