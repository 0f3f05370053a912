"""The optimisation loop: one training view per step, all parameters optimised jointly.

``train(data_dir, run_dir, variant, config, seed)`` creates (or, with ``resume=True``, continues) a run folder; see
:mod:`spotlessgs.training.checkpoint` for its layout. Same seed, same result; a resumed run equals an uninterrupted one.
"""

from __future__ import annotations

import contextlib
import dataclasses
import json
import logging
import math
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Sequence

import numpy as np
import torch

from spotlessgs.io.dataset import read_dataset
from spotlessgs.io.dataset_fingerprint import dataset_fingerprints, other_dataset
from spotlessgs.io.atomic import remove_partial_files, write_json
from spotlessgs.io.errors import InputError, write_error
from spotlessgs.io.folder_lock import folder_lock
from spotlessgs.io.json_files import read_json, require_keys
from spotlessgs.io.paths import refuse_overlap
from spotlessgs.io.signals import StopRequest, deferred_interrupts
from spotlessgs.io.ply import PointCloud
from spotlessgs.io.provenance import provenance
from spotlessgs.io.seeding import numpy_rng, torch_generator
from spotlessgs.metrics import psnr_from_mse
from spotlessgs.models.angular_profile import MonotoneProfile
from spotlessgs.models.gaussians import GaussianParams
from spotlessgs.models.light import RID_MODELS
from spotlessgs.models.photometric import PhotometricCamera
from spotlessgs.models.pose import PoseCorrection, corrected_camera
from spotlessgs.models.relightable import RelightableScene
from spotlessgs.models.sh import MAX_SH_DEGREE
from spotlessgs.models.shading import LOW_FREQUENCY_SHADINGS, MODEL_VARIANTS, ModelConfig, resolve_variant
from spotlessgs.rasterizer.cpp_kernel import numerics_record
from spotlessgs.training.checkpoint import (
    RUN_SCHEMA_VERSION, check_schema_version, checkpoint_path, data_dir_fields, existing_checkpoint, load_checkpoint,
    read_run_info, recorded_data_fingerprint, resolve_data_dir, save_checkpoint, truncate_metrics,
)
from spotlessgs.training.config import TrainConfig, field_type_errors, with_defaults
from spotlessgs.training.data import TrainingViews, initial_point_cloud, load_training_views
from spotlessgs.training.light_report import write_light_report
from spotlessgs.training.light_unit import spot_radiance_scale
from spotlessgs.training.losses import (camera_up, depth_spread_loss, normal_gravity_loss, normal_shape_loss,
                                        photometric_loss, pose_refinement_terms)
from spotlessgs.training.pose_alignment import AlignedView, align_views
from spotlessgs.training.pose_file import write_refined_poses
from spotlessgs.training.strategy import DensifyConfig, DensifyStrategy
from spotlessgs.training.view_caches import LampBounceCache, ShadowMapCache
from spotlessgs.training.warm_start import warm_start_scene
from spotlessgs.training.budget import BudgetConfig, BudgetStrategy, budget_report
from spotlessgs.training.validation import (
    ViewSplit, block_size, evenly_spaced, fitted_and_scored_pixels, gaussian_contributions, held_out_score,
    holdout_blocks, split_training_views, validation_psnr,
)

log = logging.getLogger(__name__)


class TrainingDivergedError(RuntimeError):
    """A step produced NaN/Inf; the last good checkpoint is left intact."""


@dataclass
class TrainResult:
    """Summary of a finished training run."""

    run_dir: Path
    steps: int
    seconds: float
    ms_per_step: float
    num_gaussians: int
    final_loss: float
    test_psnr: float | None
    # Spotlight-lit PSNR of the held-out validation views (validation_every > 0 and the views never fitted) or of the
    # held-out pixel blocks (validation_blocks > 0), else None; with validation_average > 1 the mean of that many
    # scores over the last third of the run.
    validation_psnr: float | None = None
    # The same on the darkest half of the scored pixels (HeldOutScore.psnr_dark), else None.
    validation_psnr_dark: float | None = None


#: The TrainConfig fields that choose the machine, not the model: a resume may change them (the run records it).
EXECUTION_SETTINGS: tuple[str, ...] = ("num_threads", "device")

#: The ModelConfig fields that a TrainConfig sets (the fields the two dataclasses share).
MODEL_SETTINGS: tuple[str, ...] = tuple(sorted({f.name for f in dataclasses.fields(ModelConfig)}
                                               & {f.name for f in dataclasses.fields(TrainConfig)}))


def model_config(variant: str | ModelConfig, config: TrainConfig) -> ModelConfig:
    """The variant's ModelConfig (a preset name or a ModelConfig) with every field that ``config`` also has taken from
    it (:data:`MODEL_SETTINGS`: the CPU/GPU-dependent BRDF width, the low-frequency shading, the spotlight fall-off,
    the BRDF's clamp, the angular profile as :func:`resolved_rid_model` gives it)."""
    if not isinstance(variant, ModelConfig) and variant not in MODEL_VARIANTS:
        raise ValueError(f"unknown model {variant!r}; choose one of {sorted(MODEL_VARIANTS)}")
    base = variant if isinstance(variant, ModelConfig) else MODEL_VARIANTS[variant]
    settings = {name: getattr(config, name) for name in MODEL_SETTINGS}
    settings["rid_model"] = resolved_rid_model(config, base)
    return dataclasses.replace(base, **settings)


def resolved_rid_model(config: TrainConfig, variant: str | ModelConfig) -> str:
    """The spotlight's angular profile a run of ``variant`` trains with: ``config.rid_model``, or for "auto" the
    monotone profile for a model with an SH light and a learned BRDF (SpotlessGS: :func:`trusts_start_geometry`, on
    any start) and the paper's MLP for the others (the DarkGS variants, whose rows it was not measured on)."""
    if config.rid_model != "auto":
        return config.rid_model
    return "monotone" if trusts_start_geometry(variant) else "mlp"


def resolve_device(name: str) -> torch.device:
    """``auto`` → CUDA when available, else CPU; ``cuda`` / ``cuda:N`` only where that GPU exists (RuntimeError)."""
    if name == "auto":
        return torch.device("cuda" if torch.cuda.is_available() else "cpu")
    device = torch.device(name)
    if device.type == "cuda":
        if not torch.cuda.is_available():
            raise RuntimeError(f"device {name!r} was requested but no CUDA GPU is available")
        if device.index is not None and device.index >= torch.cuda.device_count():
            raise RuntimeError(f"device {name!r} was requested but this machine has {torch.cuda.device_count()} "
                               "CUDA GPU(s) (cuda:0 ...)")
    return device


# ---- model construction --------------------------------------------------------------------------------------------


# A start with fewer points than this share of the initial-Gaussian limit (a robot's SfM start of a few hundred or
# thousand points, against 12,000 in the quick preset) densifies from the first densification step instead of
# ``densify_from``: on the robot-camera bedroom (647 triangulated points, quick preset, one seed) +0.17 dB aligned
# PSNR; a lower gradient threshold as well lost 0.4 dB (docs/results.md, "Real robot cameras").
SPARSE_START_SHARE = 0.25

#: The light model ``trust_start_geometry`` sets (:data:`TRUSTED_START_SETTINGS`), also for every proxy run of a
#: trusted start's model selection (each proxy's lamp and SH light start from the shared base's): the monotone angular
#: profile, and the low-frequency light shading the spotlit images as relighting shades it (the irradiance shading).
#: Together they put the bedroom's lamp within 3 cm of the truth (1.6-2.9 cm on three seeds; 9.8 with the MLP profile)
#: with six of seven datasets' relit scores within 0.1 dB on the mean of three seeds (the glossy room -0.15 dB against
#: the uniform ground truth, its lamp 8-14 cm off instead of 2-4); either alone costs a room more (docs/results.md,
#: "The irradiance shading on a trusted start" and "The lamp by default on a trusted start").
TRUSTED_START_LIGHT: dict[str, object] = {"rid_model": "monotone", "low_frequency_shading": "irradiance"}
#: What ``trust_start_geometry`` sets (:func:`start_geometry_settings`): the start's normals held, the lamp's bounce
#: light from the model's geometry, the learned BRDF without its f̃ ≤ 1 clamp (held normals cannot turn a smooth
#: metal's glint into the Lambertian shading of a surface that faces the lamp; the clamp flattens the lobe that can),
#: no camera-frame bounce SH beside the geometric bounce (it lit the glossy room's grazing side walls outside the
#: lamp's cone: +0.63 dB against its uniform ground truth, every dense-start dataset within 0.1 dB on the mean of three
#: seeds; docs/results.md, "Where the glossy room's SpotlessGS loses against DarkGS"), and :data:`TRUSTED_START_LIGHT`.
TRUSTED_START_SETTINGS: dict[str, object] = {"lr_normals": 0.0, "lamp_bounce": True, "brdf_upper_clamp": False,
                                             "bounce_light_degree": -1, **TRUSTED_START_LIGHT}
#: The model settings a checkpoint records, so that a finished run loads as it trained (:func:`load_run`), and the
#: values each may take.
RECORDED_MODEL_SETTINGS: dict[str, tuple[object, ...]] = {"lamp_bounce": (True, False),
                                                          "brdf_upper_clamp": (True, False),
                                                          "spot_shadows": (True, False), "rid_model": RID_MODELS,
                                                          "low_frequency_shading": LOW_FREQUENCY_SHADINGS,
                                                          "bounce_light_degree": (-1, *range(MAX_SH_DEGREE + 1))}


def initial_gaussian_limit(config: TrainConfig) -> int:
    """The most Gaussians a run starts with (a seeded subset of a larger point cloud)."""
    return config.max_gaussians if config.init_points is None else min(config.init_points, config.max_gaussians)


def _start_is_sparse(config: TrainConfig, cloud: PointCloud) -> bool:
    """Whether the dataset's ``cloud`` has fewer points than SPARSE_START_SHARE of the start's Gaussians."""
    return len(cloud.xyz) < SPARSE_START_SHARE * initial_gaussian_limit(config)


def sparse_start_schedule(config: TrainConfig, views: TrainingViews) -> TrainConfig:
    """``config`` with ``densify_from`` at the first densification step when the dataset's point cloud is sparse
    (see SPARSE_START_SHARE); unchanged for a dense cloud or none (the random start has enough points)."""
    if not config.sparse_start:
        return config
    cloud = views.start_points
    sparse = cloud is not None and _start_is_sparse(config, cloud)
    if not sparse or config.densify_from <= config.densify_every:
        return config
    log.info("%s: a sparse start (%d points): densifying from step %d", views.dataset.root, len(cloud.xyz),
             config.densify_every)
    return dataclasses.replace(config, densify_from=config.densify_every)


def start_is_trusted(config: TrainConfig, cloud: PointCloud | None) -> bool:
    """Whether ``config.trust_start_geometry`` trusts a start from the dataset's point ``cloud`` (None: it has none):
    "on", or "auto" and a dense cloud (not sparse by SPARSE_START_SHARE; a depth camera's or the simulator's) whose
    normals the run has or estimates (``config.estimate_normals``)."""
    if config.trust_start_geometry != "auto":
        return config.trust_start_geometry == "on"
    if cloud is None or len(cloud.xyz) == 0 or _start_is_sparse(config, cloud):
        return False
    return config.estimate_normals or (cloud.normals is not None and bool(np.any(cloud.normals)))


def start_geometry_settings(config: TrainConfig, views: TrainingViews, variant: str | ModelConfig) -> TrainConfig:
    """``config`` for a run of ``variant`` with ``trust_start_geometry`` applied: where the start is trusted
    (:func:`start_is_trusted`), :data:`TRUSTED_START_SETTINGS` (the start's normals held, the lamp's bounce light from
    the model's geometry on and the camera-frame one off, the learned BRDF unclamped, the monotone profile, the
    irradiance shading), for a model with an SH light and a learned BRDF only (:func:`trusts_start_geometry`);
    elsewhere ``config`` unchanged. Derived from the dataset: the same on a resume and when a finished run is
    loaded."""
    if not trusts_start_geometry(variant) or not start_is_trusted(config, views.start_points):
        return config
    if config.trust_start_geometry == "auto":
        log.info("%s: a dense start: its normals held, the lamp's bounce light from the geometry (no camera-frame "
                 "SH), the BRDF unclamped, the lamp's profile monotone, the room light shaded as relit "
                 "(trust_start_geometry=auto)", views.dataset.root)
    return dataclasses.replace(config, **TRUSTED_START_SETTINGS)


def trusts_start_geometry(variant: str | ModelConfig) -> bool:
    """Whether ``trust_start_geometry`` applies to ``variant``: a model with an SH light (the geometric bounce is part
    of its low-frequency light, as the SH bounce light is) and a learned BRDF (with the normals held, a glint on a
    smooth metal is the BRDF's to show; a Lambertian albedo paints it in, and the storage room's DarkGS + SH light
    then loses 1.8 dB against the uniform ground truth: docs/results.md)."""
    cfg = resolve_variant(variant)
    return cfg.ambient == "sh" and cfg.brdf == "mlp"


def build_scene(
    views: TrainingViews, variant: str | ModelConfig, config: TrainConfig, seed: int,
    light_prior: Sequence[float] | None = None,
) -> RelightableScene:
    """Initial Gaussians from the dataset's points and the variant's light/BRDF modules."""
    cfg = model_config(variant, config)
    cloud = initial_point_cloud(views, numpy_rng(seed, "init_points"), estimate=config.estimate_normals)
    xyz, rgb, normals = cloud.xyz, cloud.rgb, cloud.normals
    limit = initial_gaussian_limit(config)
    if len(xyz) > limit:
        keep = np.sort(numpy_rng(seed, "init_subsample").choice(len(xyz), limit, replace=False))
        xyz, rgb = xyz[keep], rgb[keep]
        normals = None if normals is None else normals[keep]
    gaussians = GaussianParams.from_point_cloud(xyz, rgb, normals, rgb_is_srgb=True)
    light_init: dict[str, Any] = {}
    if cfg.calibrated:
        if views.light is None:
            raise ValueError(f"{views.dataset.root}: model {cfg.name!r} is calibrated but the dataset has no light truth")
        light_init = {
            "light_rotation": views.light.rotation_in_camera,
            "light_translation": views.light.position_in_camera,
            "cone": (math.radians(views.light.cone_angle_deg) / 2.0, views.light.blend),
        }
    elif light_prior is not None:
        light_init = {"light_translation": np.asarray(light_prior, dtype=np.float64)}
    if cfg.light_model == "spotlight":
        light_init["spot_radiance_scale"] = spot_radiance_scale(
            config.spot_radiance_unit, torch.as_tensor(xyz, dtype=torch.float32), views.cameras, views.train,
            cfg.falloff_tau, cfg.falloff_gamma)
    return RelightableScene.create(cfg, gaussians, seed=seed, **light_init)


def build_optimizers(scene: RelightableScene, config: TrainConfig, extent: float,
                     photometric: PhotometricCamera | None = None) -> dict[str, torch.optim.Optimizer]:
    """One Adam per per-Gaussian parameter (so densification can edit its state) plus the appearance modules and the
    photometric camera. Normals at learning rate 0 (a trusted start's) are held: they get no gradient (their Adam keeps
    no moments and leaves them as they are, as it would with the gradient at that rate)."""
    lrs = {
        "means": config.lr_means_init * extent, "quats": config.lr_quats, "log_scales": config.lr_scales,
        "opacity_logits": config.lr_opacity, "albedo_raw": config.lr_albedo, "normals_raw": config.lr_normals,
        "roughness_raw": config.lr_roughness, "metalness_raw": config.lr_metalness, "sh0": config.lr_sh0,
        "shN": config.lr_shN,
    }
    if "normals_raw" in scene.gaussians.params:
        scene.gaussians.params["normals_raw"].requires_grad_(config.lr_normals != 0)
    opts: dict[str, torch.optim.Optimizer] = {
        name: torch.optim.Adam([p], lr=lrs[name], eps=1e-15, fused=True) for name, p in scene.gaussians.params.items()
    }
    app = scene.appearance
    groups = []
    if app.light is not None:
        pose = [p for p in (app.light.rotvec, app.light.translation) if p.requires_grad]
        if pose:
            groups.append({"params": pose, "lr": config.lr_light_pose})
        falloff = [p for p in (app.light.log_gamma, app.light.log_tau) if p.requires_grad]
        if isinstance(app.light.rid, MonotoneProfile):
            if falloff:
                groups.append({"params": falloff, "lr": config.lr_light})
            groups.append({"params": list(app.light.rid.parameters()), "lr": config.lr_rid_profile})
        else:
            groups.append({"params": falloff + list(app.light.rid.parameters()), "lr": config.lr_light})
    for lf in (app.lf_light, app.bounce_light, app.lamp_bounce):
        if lf is not None:
            groups.append({"params": list(lf.parameters()),
                           "lr": config.lr_light if config.lr_lf_light is None else config.lr_lf_light})
    brdf_params = [] if app.brdf is None else list(app.brdf.parameters())
    if brdf_params:
        groups.append({"params": brdf_params, "lr": config.lr_brdf})
    if groups:
        opts["appearance"] = torch.optim.Adam(groups, eps=1e-15, fused=True)
    if photometric is not None:
        camera = [{"params": [p], "lr": lr} for p, lr in ((photometric.log_gain, config.lr_exposure),
                                                           (photometric.coefficients, config.lr_vignetting))
                  if p is not None]
        opts["photometric"] = torch.optim.Adam(camera, eps=1e-15)
    return opts


def pose_optimizer(poses: PoseCorrection, config: TrainConfig) -> torch.optim.Optimizer:
    """The pose corrections' optimiser: a lazy Adam (SparseAdam), so that only the rendered view's row moves (a dense
    Adam would keep moving every row on the momentum of its last visit)."""
    return torch.optim.SparseAdam(list(poses.parameters()), lr=config.lr_pose)


def means_lr(config: TrainConfig, step: int, extent: float) -> float:
    """Exponential decay of the position learning rate from init to final over the run, times the scene extent."""
    t = min(max(step / max(config.iterations, 1), 0.0), 1.0)
    log_lr = (1 - t) * math.log(config.lr_means_init) + t * math.log(config.lr_means_final)
    return math.exp(log_lr) * extent


def view_order(seed: int, epoch: int, train: Sequence[int]) -> list[int]:
    """The training views of one epoch in a seeded random order (stateless, so resuming needs no saved state)."""
    perm = torch.randperm(len(train), generator=torch_generator(seed, f"views/{epoch}"))
    return [train[i] for i in perm.tolist()]


def fitted_view(seed: int, step: int, train: Sequence[int], split: ViewSplit, config: TrainConfig) -> int:
    """The view fitted at ``step``: the training views in a seeded order per epoch, without the held-out validation
    views (until densify_until when they rejoin). Stateless, so resuming needs no saved state."""
    if not split.validation:
        epoch, pos = divmod(step, len(train))
        return view_order(seed, epoch, train)[pos]
    if config.validation_rejoin and step >= config.densify_until:
        epoch, pos = divmod(step - config.densify_until, len(train))
        return view_order(seed, epoch, train)[pos]
    epoch, pos = divmod(step, len(split.fit))
    return view_order(seed, epoch, split.fit)[pos]


# ---- hooks of the Gaussian budget (spotlessgs.training.budget) ---------------------------------------------------


def make_strategy(
    config: TrainConfig, extent: float, seed: int, device: torch.device, scene: RelightableScene,
    views: TrainingViews, split: ViewSplit, photometric: PhotometricCamera | None = None, judge_from: int = 0,
) -> DensifyStrategy:
    """The default densification strategy, or the Gaussian budget's when ``config.gaussian_budget`` (judging growth
    from step ``judge_from``: the preset's ``densify_from`` when a sparse start densifies earlier)."""
    generator = torch_generator(seed, "densify", device=str(device))
    if not config.gaussian_budget:
        return DensifyStrategy(densify_config(config), extent, generator)
    cameras = views.cameras.to(device)
    images = views.images.to(device)
    contribution_views = evenly_spaced(split.fit, config.budget_contribution_views)
    _ignored, scored = fitted_and_scored_pixels(None, _unseen(views, device), len(views.names))

    def validate(_gaussians: GaussianParams) -> float:
        return validation_psnr(scene, cameras, images, split.validation, config.raster_backend, config.num_threads,
                               scored, photometric)

    def contributions(g: GaussianParams) -> torch.Tensor:
        return gaussian_contributions(g.means, g.quats, g.scales, g.opacities, cameras, contribution_views,
                                      config.raster_backend, config.num_threads)

    budget = BudgetConfig(config.budget_patience, config.budget_min_gain_db, config.budget_prune_fraction, judge_from)
    return BudgetStrategy(densify_config(config), budget, extent, generator, validate, contributions)


def densify_config(config: TrainConfig) -> DensifyConfig:
    return DensifyConfig(
        densify_from=config.densify_from, densify_until=config.densify_until, densify_every=config.densify_every,
        grad_threshold=config.densify_grad_threshold, percent_dense=config.percent_dense,
        prune_opacity=config.prune_opacity, opacity_reset_every=config.opacity_reset_every,
        reset_opacity_value=config.reset_opacity_value, max_gaussians=config.max_gaussians,
    )


# ---- checkpoints ---------------------------------------------------------------------------------------------------


def _payload(step: int, scene: RelightableScene, opts, strategy: DensifyStrategy,
             photometric: PhotometricCamera | None, poses: PoseCorrection | None = None,
             shadow_maps: ShadowMapCache | None = None, lamp_bounces: LampBounceCache | None = None,
             depth_spread_weight: float = 0.0) -> dict[str, Any]:
    payload = {
        "step": step,
        "gaussians": {k: v.detach().clone() for k, v in scene.gaussians.params.items()},
        "appearance": scene.modules_.state_dict(),
        "optimizers": {k: o.state_dict() for k, o in opts.items()},
        "strategy": strategy.state_dict(),
        "model_settings": {name: getattr(scene.config, name) for name in RECORDED_MODEL_SETTINGS},
        "depth_spread_weight": depth_spread_weight,  # what a resume trains with (trained_depth_spread_weight)
    }
    if photometric is not None:
        payload["photometric"] = photometric.state_dict()
    if poses is not None:
        payload["pose"] = poses.state_dict()
    if shadow_maps is not None and shadow_maps.kept:
        payload["shadow_maps"] = shadow_maps.state_dict()
    if lamp_bounces is not None and lamp_bounces.kept:
        payload["lamp_bounces"] = lamp_bounces.state_dict()
    return payload


def from_a_real_camera(views: TrainingViews) -> bool:
    """Whether the views come from a real camera (no "spotless" block) or from our simulator's copy that imitates one
    (its block lists ``camera_effects``), not from our simulator's plain renders (one fixed exposure, no vignetting,
    a dense start)."""
    meta = views.dataset.meta
    return "scene_id" not in meta or bool(meta.get("camera_effects"))


def photometric_enabled(config: TrainConfig, views: TrainingViews) -> bool:
    """``config.photometric``, with ``auto`` on for views :func:`from_a_real_camera`."""
    if config.photometric != "auto":
        return config.photometric == "on"
    return from_a_real_camera(views)


def depth_spread_weight_for(config: TrainConfig, views: TrainingViews, model: ModelConfig,
                            dense_starts: bool = True) -> float:
    """The weight the depth-spread term trains ``model`` with (0: not at all): ``config.depth_spread_weight`` when
    ``config.depth_spread`` is "on", or "auto" for a model with a light on views :func:`from_a_real_camera` and for a
    model with an SH light and a learned BRDF (:func:`trusts_start_geometry`: SpotlessGS) on any views.
    ``dense_starts=False``: "auto" as versions before 2026-12-07 resolved it (real cameras only), for a checkpoint
    that does not record its weight."""
    if config.depth_spread == "off":
        return 0.0
    if config.depth_spread == "on":
        return config.depth_spread_weight
    has_light = model.light_model != "none"
    if (has_light and from_a_real_camera(views)) or (dense_starts and trusts_start_geometry(model)):
        return config.depth_spread_weight
    return 0.0


def trained_depth_spread_weight(config: TrainConfig, views: TrainingViews, model: ModelConfig,
                                ckpt: dict | None, where: Path) -> float:
    """The depth-spread weight a run trains with: :func:`depth_spread_weight_for`, or on a resume the weight its
    checkpoint ``ckpt`` (read from ``where``) records (a checkpoint without one: as its version resolved "auto").
    Raises InputError for a recorded weight that is not a finite number >= 0."""
    if ckpt is None:
        return depth_spread_weight_for(config, views, model)
    if "depth_spread_weight" not in ckpt:
        return depth_spread_weight_for(config, views, model, dense_starts=False)
    weight = ckpt["depth_spread_weight"]
    if isinstance(weight, bool) or not isinstance(weight, (int, float)) or not (math.isfinite(weight) and weight >= 0):
        raise InputError(f"{where}: depth_spread_weight must be a finite number >= 0, got {weight!r}")
    return float(weight)


def build_photometric(config: TrainConfig, views: TrainingViews, split: ViewSplit,
                      device: torch.device) -> PhotometricCamera | None:
    """The photometric camera of a run (None when off): exposures start from the frames' known ones when every
    frame has one."""
    if not photometric_enabled(config, views):
        return None
    prior = None if views.exposures is None else torch.log(torch.tensor(views.exposures, dtype=torch.float64))
    return PhotometricCamera(len(views.names), split.fit, views.radius, config.learn_exposure, config.learn_vignetting,
                             log_gain_prior=prior).to(device)


def run_variant(run_info: dict[str, Any], where: str | Path = "run.json") -> str | ModelConfig:
    """The variant a run trained (its run.json ``run_info``, read from ``where``): a preset's name, or the ModelConfig
    that a run of an arbitrary one (``spotless train --model auto``) stores itself. InputError naming ``where`` for a
    model_config of the wrong form."""
    saved = run_info.get("model_config")
    if saved is None:
        return run_info["model"]
    wrong = ["is not a JSON object"] if not isinstance(saved, dict) else field_type_errors(ModelConfig, saved)
    if wrong:
        raise InputError(f"{where}: damaged model_config: {wrong[0]}")
    try:
        return ModelConfig(**with_defaults(ModelConfig, saved))
    except (TypeError, ValueError) as exc:  # an unknown field (another version's run), or a value out of range
        raise InputError(f"{where}: the model_config does not fit this version ({exc})") from None


def restore_scene(ckpt: dict[str, Any], run_info: dict[str, Any], config: TrainConfig, where: Path) -> RelightableScene:
    """Rebuild the model of a checkpoint ``ckpt`` read from ``where`` (modules with the same structure, then their
    saved values); InputError naming ``where`` where its tensors do not fit the run's model."""
    cfg = model_config(run_variant(run_info), config)
    try:
        gaussians = GaussianParams(ckpt["gaussians"])
    except ValueError as exc:  # a missing parameter, or one of another shape
        raise InputError(f"{where}: damaged checkpoint: {exc}") from None
    light_init: dict[str, Any] = {}
    if cfg.calibrated:  # the structure needs a cone; the fitted values are overwritten by the saved state
        light_init = {"light_rotation": None, "light_translation": np.zeros(3), "cone": (0.5, 0.3)}
    scene = RelightableScene.create(cfg, gaussians, seed=run_info["seed"], **light_init)
    try:
        scene.modules_.load_state_dict(ckpt["appearance"])
    except RuntimeError as exc:  # torch names the missing, unexpected and misshapen entries
        detail = " ".join(str(exc).split())
        raise InputError(f"{where}: the checkpoint's light and reflectance do not fit the run's model ({detail})"
                         ) from None
    if cfg.calibrated and scene.appearance.light is not None:
        scene.appearance.light.set_pose_trainable(False)
    return scene


# ---- the loop ------------------------------------------------------------------------------------------------------


def _psnr(pred: torch.Tensor, target: torch.Tensor, unseen: torch.Tensor | None = None) -> float:
    """PSNR (dB) of a render (H, W, 3), clamped to [0, 1], against its linear target image; without the ``unseen``
    (H, W) pixels when given."""
    squared = (pred.detach().clamp(0, 1) - target) ** 2
    return psnr_from_mse(float(torch.mean(squared if unseen is None else squared[~unseen])))


def _unseen(views: TrainingViews, device: torch.device | str) -> torch.Tensor | None:
    """``views.unseen`` (V, H, W) on ``device`` (None when every working pixel has an input sample)."""
    return None if views.unseen is None else views.unseen.to(device)


def _check_finite(scene: RelightableScene, step: int, ckpt: Path, poses: PoseCorrection | None = None) -> None:
    pose_params = [] if poses is None else [(f"pose.{n}", p) for n, p in poses.named_parameters()]
    for name, p in list(scene.gaussians.params.items()) + list(scene.modules_.named_parameters()) + pose_params:
        if not torch.isfinite(p).all():
            raise TrainingDivergedError(
                f"step {step}: parameter {name!r} became NaN/Inf; the last good checkpoint {ckpt} is intact "
                "(lower the learning rates or check the input images)"
            )


def train(
    data_dir: str | Path,
    run_dir: str | Path,
    variant: str | ModelConfig = "spotless",
    config: TrainConfig = TrainConfig(),
    seed: int = 0,
    resume: bool = False,
    light_prior: Sequence[float] | None = None,
    progress: bool = True,
    stop_after: int | None = None,
    init_from: str | Path | None = None,
) -> TrainResult:
    """Train (or resume) a model of ``variant`` on the dataset in ``data_dir``; writes everything to ``run_dir``.

    Args:
        data_dir: dataset folder (ours, nerfstudio or COLMAP).
        run_dir: the run folder.
        variant: ``3dgs``, ``darkgs``, ``darkgs-calibrated``, ``darkgs+sh``, ``darkgs+brdf`` or ``spotless``, or
            any ModelConfig (stored in run.json as ``model_config``; ``model`` is then its name).
        config: training settings.
        seed: the command seed.
        resume: continue from the run's last checkpoint (settings must match).
        light_prior: (3,) prior light translation in camera coordinates (m): adds weight · ‖t − prior‖.
        progress: show a progress bar.
        stop_after: stop (with a checkpoint) after this many total steps, as if interrupted (tests, time budgets).
        init_from: start from the Gaussians and spotlight of this run's checkpoint (model selection's shared warm
            start, see spotlessgs.training.warm_start) instead of the point cloud.
    """
    data_dir, run_dir = Path(data_dir).resolve(), Path(run_dir)
    refuse_overlap(run_dir, {"--data": data_dir}, "the run folder (--out)")
    with folder_lock(run_dir, "spotless train"), deferred_interrupts() as stop:
        return _train_locked(data_dir, run_dir, variant, config, seed, resume, light_prior, progress, stop_after,
                             init_from, stop)


def _train_locked(data_dir: Path, run_dir: Path, variant: str | ModelConfig, config: TrainConfig, seed: int,
                  resume: bool, light_prior: Sequence[float] | None, progress: bool, stop_after: int | None,
                  init_from: str | Path | None, stop: StopRequest) -> TrainResult:
    """:func:`train` with the run folder locked; ``stop`` is checked after every step (Ctrl-C, SIGTERM)."""
    if config.num_threads:
        torch.set_num_threads(config.num_threads)
    device = resolve_device(config.device)
    ckpt_file = checkpoint_path(run_dir)
    run_info = {"schema_version": RUN_SCHEMA_VERSION, **data_dir_fields(data_dir, run_dir),
                "model": variant.name if isinstance(variant, ModelConfig) else variant,
                "seed": seed, "preset": config.preset,
                "light_prior": None if light_prior is None else [float(v) for v in light_prior]}
    if init_from is not None:
        run_info["init_from"] = str(Path(init_from).resolve())
    if isinstance(variant, ModelConfig):
        run_info["model_config"] = dataclasses.asdict(model_config(variant, config))
    resolved = {"train": dataclasses.asdict(config), "run": run_info}
    remove_partial_files(run_dir, recursive=False)
    remove_partial_files(run_dir / "checkpoints", recursive=False)
    has_checkpoint = existing_checkpoint(run_dir) is not None
    machine_changes: list[str] = []  # the EXECUTION_SETTINGS a resume changes
    if has_checkpoint and not resume:
        raise FileExistsError(f"{run_dir} already holds a training run; pass --resume to continue it or use a new --out")
    if not has_checkpoint and not resume and (run_dir / "train_summary.json").is_file():  # shared without checkpoints/
        raise FileExistsError(f"{run_dir} holds a finished training run without its checkpoint "
                              f"({checkpoint_path(run_dir).relative_to(run_dir)}); training again would replace it: "
                              "use a new --out (--resume trains it again from the start)")
    if resume and has_checkpoint:
        old = read_json(run_dir / "config.json", "run settings", ("train", "run"))
        if not isinstance(old["run"], dict):
            raise InputError(f"{run_dir / 'config.json'}: damaged run settings: 'run' is not a JSON object")
        # the dataset may have moved (--data DIR), an older version wrote the file: not another setting; the
        # dataset's files are compared below (data_fingerprint)
        # the warm start's source either (a moved run's own selection/base): the checkpoint supersedes it
        moved = ("data_dir", "data_dir_relative", "schema_version", "data_fingerprint", "views_fingerprint",
                 "init_from")
        # settings added since the run began take their defaults (what the run trained with), the model's too
        old_run = dict(old["run"])
        if isinstance(old_run.get("model_config"), dict):
            old_run["model_config"] = with_defaults(ModelConfig, old_run["model_config"])
        old_train = with_defaults(TrainConfig, old["train"]) if isinstance(old["train"], dict) else old["train"]
        if config.rid_model == "auto" and isinstance(old_train, dict):
            # "auto" resumes a run with the angular profile it began with, also one that an older version began with
            # the MLP profile where "auto" now resolves to the monotone one
            config = dataclasses.replace(config, rid_model=old_train["rid_model"])
            resolved["train"] = dataclasses.asdict(config)
        # the machine's settings may change between sessions (another node, another thread count): not compared,
        # recorded (they change the last bits of what follows, docs/results.md "Determinism")
        machine = {k: resolved["train"][k] for k in EXECUTION_SETTINGS}
        differ = differing_settings(
            {**old_train, **machine} if isinstance(old_train, dict) else old_train, resolved["train"]
        ) + differing_settings(
            {k: v for k, v in old_run.items() if k not in moved}, {k: v for k, v in run_info.items() if k not in moved})
        if differ:
            raise ValueError(f"{run_dir}: --resume with other settings than the run was started with "
                             f"({'; '.join(differ)})")
        # against the settings the run last trained with: the latest resume's, else the start's
        last = old.get("resumed_with")[-1] if isinstance(old.get("resumed_with"), list) and old["resumed_with"] \
            and isinstance(old["resumed_with"][-1], dict) else old_train
        machine_changes = differing_settings({k: last.get(k) for k in EXECUTION_SETTINGS}, machine)

    # what the run trains on, compared on a resume before the images load (a run saved before the fingerprint
    # existed has none to compare, and gets one)
    dataset = read_dataset(data_dir, check_files=True)
    run_info["data_fingerprint"], run_info["views_fingerprint"] = dataset_fingerprints(dataset)
    if resume and has_checkpoint:
        if other_dataset(recorded_data_fingerprint(run_dir), run_info["data_fingerprint"]):
            raise InputError(f"{run_dir}: --resume on another dataset: the files of {data_dir} differ from those the "
                             f"run was trained on; resume it with its own dataset (--data) or use a new --out")
    views = load_training_views(dataset, config.image_width, config.linear_input, config.saturation_threshold)
    if not views.train:
        raise ValueError(f"{data_dir}: the split has no training views")
    _stop_before_training(stop, run_dir)  # Ctrl-C while the images loaded: stop now, before anything is written
    if resume and has_checkpoint:
        write_json(run_dir / "run.json", run_info)  # where the dataset is now
    split = split_training_views(views.train, config.validation_every)
    judge_from = config.densify_from  # the budget judges growth from the preset's start, also after a sparse start
    config = sparse_start_schedule(config, views)  # derived from the dataset: the same on a resume
    ckpt = load_checkpoint(run_dir) if resume and has_checkpoint else None
    config = trained_settings(config, views, variant, ckpt, ckpt_file)  # likewise
    extent = views.scene_extent()
    images, saturated = views.images.to(device), views.saturated.to(device)
    held_out = None  # (V, H, W) bool pixel blocks never fitted (validation_blocks > 0)
    if config.validation_blocks > 0:
        block = block_size(views.cameras.width, config.validation_block)
        held_out = holdout_blocks(len(views.names), views.cameras.height, views.cameras.width,
                                  config.validation_blocks, block, seed).to(device)
    cameras = views.cameras.to(device)
    # pixels the loss leaves alone (held out, or with no input sample) and the pixels the held-out scores use
    unseen = _unseen(views, device)
    ignored, scored = fitted_and_scored_pixels(held_out, unseen, len(views.names))
    photometric = build_photometric(config, views, split, device)  # exposure and vignetting, or None
    poses = PoseCorrection(len(views.names)).to(device) if config.refine_poses else None  # per-view corrections

    shadow_maps = ShadowMapCache(config)  # each view's lamp shadow map (spotlight shadows only)
    lamp_bounces = LampBounceCache(config)  # each view's lamp bounce irradiance (lamp_bounce only)
    start = 0
    if ckpt is not None:
        scene = restore_scene(ckpt, run_info, config, ckpt_file).to(device)
        shadow_maps.load_state_dict(ckpt.get("shadow_maps", {}), device)
        lamp_bounces.load_state_dict(ckpt.get("lamp_bounces", {}), device)
        if photometric is not None:
            if "photometric" not in ckpt:
                raise InputError(f"{ckpt_file}: the run was trained without a photometric camera; resume it with "
                                 "photometric 'off'")
            # runs before 2026-11-24 stored the pixels' radii too; they are derived from the dataset
            photometric.load_state_dict({k: v for k, v in ckpt["photometric"].items() if k != "radius"})
        if poses is not None:
            if "pose" not in ckpt:
                raise InputError(f"{ckpt_file}: the run was trained without pose refinement; resume it without "
                                 "refine_poses")
            poses.load_state_dict(ckpt["pose"])
        strategy = make_strategy(config, extent, seed, device, scene, views, split, photometric, judge_from)
        opts = build_optimizers(scene, config, extent, photometric)
        if poses is not None:
            opts["pose"] = pose_optimizer(poses, config)
        start = int(ckpt["step"])
        missing = [k for k in ("optimizers", "strategy") if not isinstance(ckpt.get(k), dict)]
        missing += [f"optimizers.{k}" for k in opts if not missing and not isinstance(ckpt["optimizers"].get(k), dict)]
        if missing or start > config.iterations:
            problem = (f"it lacks {', '.join(missing)}" if missing else
                       f"it is at step {start}, beyond the run's {config.iterations} iterations")
            raise InputError(f"{ckpt_file}: cannot resume from this checkpoint: {problem}")
        for k, o in opts.items():
            o.load_state_dict(ckpt["optimizers"][k])
        strategy.load_state_dict(ckpt["strategy"])
        truncate_metrics(run_dir / "metrics.jsonl", start)
        log.info("resuming %s at step %d", run_dir, start)
        if machine_changes and start < config.iterations:  # steps will run on the new settings
            _record_machine_change(run_dir / "config.json", old, machine, device, start)
            log.info("resuming on other machine settings (%s): the steps from here differ in their last bits from "
                     "an uninterrupted run's", "; ".join(machine_changes))
    else:
        run_dir.mkdir(parents=True, exist_ok=True)
        scene = build_scene(views, variant, config, seed, light_prior)
        if init_from is not None:
            scene = warm_start_scene(scene, load_checkpoint(Path(init_from)), str(init_from))
        scene = scene.to(device)
        strategy = make_strategy(config, extent, seed, device, scene, views, split, photometric, judge_from)
        opts = build_optimizers(scene, config, extent, photometric)
        if poses is not None:
            opts["pose"] = pose_optimizer(poses, config)
        write_json(run_dir / "run.json", run_info)
        numerics = numerics_record(config.num_threads, device.type)
        write_json(run_dir / "config.json", {"schema_version": RUN_SCHEMA_VERSION, **resolved,
                                             "model_config": dataclasses.asdict(scene.config),
                                             "provenance": provenance(seed=seed, numerics=numerics)})
        (run_dir / "metrics.jsonl").unlink(missing_ok=True)
    prior = None if light_prior is None else torch.as_tensor(light_prior, dtype=torch.float32, device=device)

    from tqdm import tqdm

    end = config.iterations if stop_after is None else min(stop_after, config.iterations)
    held_out_views = split.validation if not config.validation_rejoin else []
    score_views = views.train if held_out is not None else held_out_views
    score_steps = validation_steps(config.iterations, config.validation_average) if score_views else set()

    def score_held_out() -> dict:
        scene.eval()
        score = held_out_score(scene, cameras, images, score_views, config.raster_backend, config.num_threads,
                               pixel_masks=scored, photometric=photometric)
        scene.train()
        return {"validation_psnr": score.psnr, "validation_psnr_dark": score.psnr_dark}

    _stop_before_training(stop, run_dir)  # Ctrl-C during the set-up: the step loop would run (and save) one more step
    bar = tqdm(range(start, end), initial=start, total=config.iterations, desc=f"train {scene.config.name}",
               disable=not progress, unit="it")
    metrics_path = run_dir / "metrics.jsonl"
    try:
        metrics_file = open(metrics_path, "a", encoding="utf-8")
    except OSError as exc:
        bar.close()
        raise (write_error(metrics_path, exc) or exc) from exc
    depth_spread_weight = trained_depth_spread_weight(config, views, scene.config, ckpt, ckpt_file)
    up = (camera_up(cameras.c2w[list(views.train)])  # the normal prior's gravity axis
          if config.normal_gravity_weight > 0 else None)
    t0 = time.perf_counter()
    loss_value = float("nan")
    try:
        for step in bar:
            k = fitted_view(seed, step, views.train, split, config)
            opts["means"].param_groups[0]["lr"] = means_lr(config, step, extent)
            # pose refinement: the view's camera (and the light mounted on it) with its learned correction
            refining = poses is not None and step >= config.pose_refine_from
            row = poses.row(k) if refining else None  # (9,) the view's correction, a sparse gradient
            camera = corrected_camera(cameras[k], row) if refining else cameras[k]
            shadow_map = shadow_maps.get(scene, k, step, camera)
            render_options = {"backend": config.raster_backend, "num_threads": config.num_threads,
                              "shadow_map": shadow_map, "lamp_irradiance": lamp_bounces.fresh(k, step)}
            depth_spread_step = depth_spread_weight > 0 and step % config.depth_spread_every == 0
            if depth_spread_step:
                out, depth_moments = scene.render_with_depth_moments(camera, **render_options)
            else:
                out = scene.render(camera, **render_options)
            if out.lamp_irradiance is not None:  # the one the render was given, or a new one it computed
                lamp_bounces.keep(k, step, out.lamp_irradiance)
            if not torch.isfinite(out.image).all():
                raise TrainingDivergedError(f"step {step}: the render of view {views.names[k]} has NaN/Inf; "
                                            f"the last good checkpoint {ckpt_file} is intact")
            # what the camera records of the rendered radiance: the frame's exposure and the lens's vignetting
            recorded = out.image if photometric is None else photometric(out.image, k)
            target, clipped = images[k], saturated[k]
            # Held-out and unseen pixels show the render itself, clamped to [0, 1], and count as clipped: no error and
            # no gradient there (a render above 1 meets a clipped target of 1, which the clipped L1 does not penalise).
            if ignored is not None:
                target = torch.where(ignored[k][..., None], recorded.detach().clamp(0.0, 1.0), target)
                clipped = clipped | ignored[k]
            loss, parts = photometric_loss(recorded, target, clipped, config.ssim_lambda, config.loss_space)
            if depth_spread_step:
                loss = loss + depth_spread_weight * depth_spread_loss(depth_moments, out.alpha)
            if prior is not None and scene.appearance.light is not None:
                loss = loss + scene.appearance.light.light_prior_loss(prior, config.light_prior_weight)
            if config.normal_gravity_weight > 0:
                loss = loss + config.normal_gravity_weight * normal_gravity_loss(
                    scene.gaussians.normals(camera.c2w[:3, 3]), up, out.visible)
            if config.normal_axis_weight > 0:
                g = scene.gaussians
                loss = loss + config.normal_axis_weight * normal_shape_loss(g.normals(camera.c2w[:3, 3]),
                                                                            g.shortest_axes(), out.visible)
            if refining:  # a texture term, which the light moving with a pose hypothesis hardly changes, + a penalty
                loss = loss + pose_refinement_terms(recorded, target, clipped, row, config.pose_texture_weight,
                                                    config.pose_penalty)
            loss_value = float(loss.detach())
            if not math.isfinite(loss_value):
                raise TrainingDivergedError(f"step {step}: loss is {loss_value} on view {views.names[k]}; "
                                            f"the last good checkpoint {ckpt_file} is intact")
            loss.backward()
            for o in opts.values():
                o.step()
                o.zero_grad(set_to_none=True)
            changes = strategy.step_post_backward(step, scene.gaussians, opts, out.means2d_grad(), out.radii,
                                                  cameras.width, cameras.height)
            s = step + 1
            held = score_held_out() if s in score_steps else {}
            if s % config.log_every == 0 or s == end or held:
                elapsed = time.perf_counter() - t0
                rec = {"step": s, "loss": loss_value, "l1": parts["l1"], "ssim": parts["ssim"],
                       "psnr": _psnr(recorded, images[k], None if unseen is None else unseen[k]), "gaussians": len(scene.gaussians),
                       "ms_per_step": 1000.0 * elapsed / (s - start), **{k2: v for k2, v in changes.items() if v},
                       **held}
                if scene.appearance.light is not None:  # the learned lamp's position, to watch it converge
                    rec["light_translation_m"] = [round(v, 5) for v in scene.appearance.light.translation.tolist()]
                _append_line(metrics_file, metrics_path, json.dumps(rec))
                bar.set_postfix(loss=f"{loss_value:.4f}", psnr=f"{rec['psnr']:.2f}", n=len(scene.gaussians),
                                ms=f"{rec['ms_per_step']:.0f}")
            if s % config.checkpoint_every == 0 or s == end or stop.requested:
                # A NaN parameter of a visible Gaussian already shows in the next render (checked every step);
                # this check, before every save, keeps any other one out of the checkpoint.
                _check_finite(scene, step, ckpt_file, poses)
                save_checkpoint(run_dir, _payload(s, scene, opts, strategy, photometric, poses, shadow_maps,
                                                  lamp_bounces, depth_spread_weight))
            if stop.requested:  # Ctrl-C / SIGTERM: the step is finished and saved; `--resume` continues from it
                log.warning("stopped at step %d; the checkpoint %s holds it (resume with --resume)", s, ckpt_file)
                stop.raise_if_requested()
    finally:
        # every line was flushed when written: a failing close only repeats an error already raised
        with contextlib.suppress(OSError):
            metrics_file.close()
        bar.close()
    seconds = time.perf_counter() - t0
    steps_done = max(end - start, 0)
    # Ctrl-C after the last step's check: its checkpoint is saved (every run saves its last step), so stop before the
    # final evaluation instead of waiting for it; `--resume` evaluates
    _stop_after_training(stop, end, ckpt_file)
    # a run that refined its poses scores its test views at poses aligned to their inputs (model frozen)
    aligned = align_views(scene, views, unrefined_views(views), config, photometric) \
        if poses is not None and end == config.iterations else None
    _stop_after_training(stop, end, ckpt_file)
    test_psnr = evaluate_reconstruction(scene, views, config, photometric, aligned) \
        if end == config.iterations else None
    _stop_after_training(stop, end, ckpt_file)
    val_psnr = val_dark = None
    if end == config.iterations and score_views:
        # the held-out pixel blocks of every training view, or the held-out views: the scores logged at
        # score_steps (a resumed run re-scores its last step when the interrupted session did not log it)
        scores = [r for r in read_metrics(run_dir / "metrics.jsonl") if "validation_psnr" in r]
        if not any(r["step"] == end for r in scores):
            scores.append({"step": end, **score_held_out()})
        val_psnr = sum(r["validation_psnr"] for r in scores) / len(scores)
        val_dark = sum(r["validation_psnr_dark"] for r in scores) / len(scores)
        _stop_after_training(stop, end, ckpt_file)
    ms_per_step = 1000.0 * seconds / max(steps_done, 1)
    if steps_done == 0:  # resumed after its last step: the time per step and last loss of the session that trained
        logged = _last_logged_step(run_dir, end)
        if logged is not None:
            ms_per_step, loss_value = logged
    result = TrainResult(run_dir, end, seconds, ms_per_step, len(scene.gaussians), loss_value, test_psnr, val_psnr,
                         val_dark)
    if end == config.iterations:
        write_light_report(scene, views, run_dir)
        if photometric is not None:
            write_json(run_dir / "photometric.json", {"schema_version": RUN_SCHEMA_VERSION,
                                                      **photometric.report(views.names)})
        if poses is not None:
            write_refined_poses(run_dir, views, poses, aligned or {}, end)
        write_json(run_dir / "train_summary.json", {"schema_version": RUN_SCHEMA_VERSION,
            "steps": result.steps, "seconds_this_session": seconds, "ms_per_step": result.ms_per_step,
            "session_started_at_step": start,  # > 0: resumed, the seconds and ms per step are this session's alone
            "num_gaussians": result.num_gaussians,
            "final_loss": loss_value if math.isfinite(loss_value) else None,  # None: not logged (no step run)
            "test_psnr_reconstruction": test_psnr, "device": str(device),
            "validation_views": split.validation, "validation_psnr": val_psnr, "validation_psnr_dark": val_dark,
            "photometric": photometric is not None, "refine_poses": poses is not None,
            "depth_spread_weight": depth_spread_weight,  # what the term trained with, `depth_spread` resolved,
            "depth_spread_every": config.depth_spread_every,  # on every this-many-th step
            "test_views_aligned": aligned is not None and bool(views.test),
        })
        if isinstance(strategy, BudgetStrategy):
            write_json(run_dir / "gaussian_budget.json", {"schema_version": RUN_SCHEMA_VERSION,
                                                          **budget_report(strategy, len(scene.gaussians), config)})
    return result


def _last_logged_step(run_dir: Path, step: int) -> tuple[float, float] | None:
    """(ms per step, loss) that ``run_dir``'s metrics.jsonl logged at ``step`` (the mean over the session that reached
    it), so that a resume that trains nothing (the run had reached ``step``) reports them instead of timing a session
    without steps; None when no such record exists."""
    for record in reversed(read_metrics(run_dir / "metrics.jsonl")):
        if record.get("step") == step:
            ms_per_step, loss = record.get("ms_per_step"), record.get("loss")
            if isinstance(ms_per_step, (int, float)) and isinstance(loss, (int, float)):
                return float(ms_per_step), float(loss)
            return None
    return None


def _stop_before_training(stop: StopRequest, run_dir: Path) -> None:
    """Raise the interrupt of a stop asked for before the first step (nothing of this session was saved)."""
    if stop.requested:
        log.warning("stopped before training %s; no step of this session was run or saved", run_dir)
        stop.raise_if_requested()


def _stop_after_training(stop: StopRequest, step: int, ckpt_file: Path) -> None:
    """Raise the interrupt of a stop asked for after the last step (whose checkpoint is saved) and before the final
    evaluation is finished; ``--resume`` redoes the evaluation."""
    if stop.requested:
        log.warning("stopped at step %d before the final evaluation; the checkpoint %s holds it (resume with "
                    "--resume to evaluate)", step, ckpt_file)
        stop.raise_if_requested()


def _append_line(fh, path: Path, line: str) -> None:
    """Append ``line`` and a newline to the open text file ``fh`` (``path``) and flush it; a refused write (full disk,
    quota) raises :class:`~spotlessgs.io.errors.WriteError` naming ``path``."""
    try:
        fh.write(line + "\n")
        fh.flush()
    except OSError as exc:
        raise (write_error(path, exc) or exc) from exc


def _record_machine_change(path: Path, saved: dict, machine: dict[str, Any], device: torch.device,
                           step: int) -> None:
    """Append to a run's config.json (``saved``, as read) the machine settings a resume continues with from ``step``
    (``resumed_with``: step, the :data:`EXECUTION_SETTINGS`, the device used and the numerics record)."""
    record = {"step": step, **machine, "device_used": device.type,
              "numerics": numerics_record(machine["num_threads"], device.type)}
    earlier = saved.get("resumed_with")
    write_json(path, {**saved, "resumed_with": [*(earlier if isinstance(earlier, list) else []), record]})


def validation_steps(iterations: int, count: int) -> set[int]:
    """The steps (1-based, counted after the update) whose held-out scores are averaged: ``count`` evenly spaced over
    the last third of ``iterations``, the last one at ``iterations``."""
    if count <= 1:
        return {iterations}
    span = iterations // 3
    return {iterations - round(j * span / (count - 1)) for j in range(count)}


def read_metrics(path: Path) -> list[dict]:
    """The records of a metrics.jsonl file (a line cut by a crash is skipped)."""
    records = []
    for line in path.read_text().splitlines() if path.is_file() else []:
        try:
            records.append(json.loads(line))
        except json.JSONDecodeError:
            continue
    return records


def differing_train_settings(saved: Any, new: dict[str, Any]) -> list[str]:
    """:func:`differing_settings` of a TrainConfig as a run or decision saved it (``saved``; completed with
    :func:`~spotlessgs.training.config.with_defaults` for the settings added since, as the run trained) and the
    fields of a TrainConfig ``new`` (``dataclasses.asdict``)."""
    return differing_settings(with_defaults(TrainConfig, saved) if isinstance(saved, dict) else saved, new)


def differing_settings(old: Any, new: Any) -> list[str]:
    """``name: run X, now Y`` for each top-level key whose JSON value differs between two settings dicts (or one
    entry for two values that are not both dicts)."""
    old, new = json.loads(json.dumps(old)), json.loads(json.dumps(new))
    if not (isinstance(old, dict) and isinstance(new, dict)):
        return [] if old == new else [f"run {old!r}, now {new!r}"]
    return [f"{k}: run {old.get(k)!r}, now {new.get(k)!r}" for k in sorted(set(old) | set(new))
            if old.get(k) != new.get(k)]


def saved_train_config(path: Path) -> TrainConfig:
    """The TrainConfig stored in a run's config.json (key ``train``).

    Raises:
        InputError: the file is missing or damaged, or its settings are not this version's TrainConfig (names the
            file).
    """
    saved = read_json(path, "run settings", ("train",))
    check_schema_version(path, saved)
    if not isinstance(saved["train"], dict):
        raise InputError(f"{path}: damaged run settings: 'train' is not a JSON object")
    wrong = field_type_errors(TrainConfig, saved["train"])
    if wrong:
        raise InputError(f"{path}: damaged run settings: train.{wrong[0]}")
    try:
        return TrainConfig(**with_defaults(TrainConfig, saved["train"]))
    except TypeError as exc:  # an unknown or missing field: another version's run
        raise InputError(f"{path}: the training settings do not fit this version ({exc})") from None
    except ValueError as exc:  # a value out of its range
        raise InputError(f"{path}: damaged run settings: {exc}") from None


def unrefined_views(views: TrainingViews) -> list[int]:
    """The views whose poses pose refinement does not learn, which are aligned instead (model frozen): every view
    outside the training split (the test views, and frames left out of training as black or saturated)."""
    train = set(views.train)
    return [k for k in range(len(views.names)) if k not in train]


@torch.no_grad()
def evaluate_reconstruction(scene: RelightableScene, views: TrainingViews, config: TrainConfig,
                            photometric: PhotometricCamera | None = None,
                            aligned: dict[int, AlignedView] | None = None) -> float | None:
    """Mean PSNR (linear, clamped to [0, 1]) of the spotlight-lit renders of the test views against the inputs
    (through the photometric camera when given: its vignetting, and the test views' exposures, which no loss fits:
    their known ones, else the reference); at their ``aligned`` poses when given (a run that refined its poses)."""
    if not views.test:
        return None
    device = scene.gaussians.means.device  # the model's (views.images stay on the CPU)
    cameras = views.cameras.to(device)
    unseen = _unseen(views, device)
    values = []
    for k in views.test:
        camera = cameras[k]
        if aligned is not None and k in aligned:
            camera = corrected_camera(camera, aligned[k].delta.to(camera.device))
        out = scene.render(camera, backend=config.raster_backend, num_threads=config.num_threads)
        image = out.image if photometric is None else photometric(out.image, k)
        values.append(_psnr(image, views.images[k].to(device), None if unseen is None else unseen[k]))
    return float(np.mean(values))


def load_pose_correction(run_dir: str | Path, num_views: int, device: str | torch.device = "cpu") -> PoseCorrection:
    """The learned pose corrections of a run trained with ``refine_poses`` (its checkpoint's ``pose``).

    Raises:
        InputError: the checkpoint has none, or not one per view of the dataset (names the run).
    """
    ckpt = load_checkpoint(Path(run_dir))
    if "pose" not in ckpt:
        raise InputError(f"{run_dir}: the checkpoint has no pose corrections (the run did not refine its poses)")
    poses = PoseCorrection(num_views)
    try:
        poses.load_state_dict(ckpt["pose"])
    except RuntimeError:
        raise InputError(f"{run_dir}: the checkpoint's pose corrections are for another number of views than the "
                         f"dataset's {num_views}") from None
    return poses.to(device)


def recorded_model_settings(ckpt: dict, saved: TrainConfig, where: Path) -> dict[str, object]:
    """The :data:`RECORDED_MODEL_SETTINGS` a checkpoint ``ckpt`` (read from ``where``) trained with. A checkpoint from
    before 2026-11-27 has no record: the bounce as its modules show; one written before 66edae3 (2026-11-28) records
    the bounce and the clamp only, and one written before 2026-12-07 no ``bounce_light_degree``. What it lacks is as
    the run's saved config ``saved`` set it (trust_start_geometry did not change it then). Raises InputError for a
    record of the wrong form."""
    settings = ckpt.get("model_settings")
    if settings is None:
        settings = {"lamp_bounce": any(name.startswith("lamp_bounce.") for name in ckpt["appearance"])}
    if not isinstance(settings, dict):
        raise InputError(f"{where}: model_settings must be a table of {', '.join(RECORDED_MODEL_SETTINGS)}, "
                         f"got {settings!r}")
    settings = {name: settings.get(name, getattr(saved, name)) for name in RECORDED_MODEL_SETTINGS}
    for name, allowed in RECORDED_MODEL_SETTINGS.items():
        if not any(type(settings[name]) is type(value) and settings[name] == value for value in allowed):
            raise InputError(f"{where}: model_settings must give {name} as one of "
                             f"{', '.join(json.dumps(value) for value in allowed)}, got {settings[name]!r}")
    return settings


def trained_settings(config: TrainConfig, views: TrainingViews, variant: str | ModelConfig, ckpt: dict | None,
                     where: Path) -> TrainConfig:
    """``config`` as a run of ``variant`` on ``views`` trains with it: ``trust_start_geometry`` applied
    (:func:`start_geometry_settings`), and, for a run with a checkpoint ``ckpt`` (read from ``where``), the model
    settings that checkpoint records (:func:`recorded_model_settings`), which a newer version's trust may set
    otherwise."""
    trusted = start_geometry_settings(config, views, variant)
    if ckpt is None:
        return trusted
    return dataclasses.replace(trusted, **recorded_model_settings(ckpt, config, where))


def load_run(run_dir: str | Path, device: str = "auto", data_dir: str | Path | None = None,
             ) -> tuple[RelightableScene, TrainingViews, TrainConfig, dict]:
    """Load a finished (or interrupted) run: its model, its views at the training resolution, config and info.
    ``data_dir`` points at the dataset when it has moved (else run.json's paths: see ``resolve_data_dir``)."""
    run_dir = Path(run_dir)
    info = read_run_info(run_dir)
    # what restore_scene needs: the model (its name, or the config of `--model auto`) and the seed
    require_keys(info, run_dir / "run.json", "run description",
                 ("seed",) if "model_config" in info else ("model", "seed"))
    wrong = [f"{key} {info[key]!r} is not {kind}" for key, kind, ok in (
        ("seed", "a whole number", isinstance(info["seed"], int) and not isinstance(info["seed"], bool)),
        ("model", f"one of {sorted(MODEL_VARIANTS)}", "model_config" in info
                                                   or isinstance(info.get("model"), str) and info["model"] in MODEL_VARIANTS))
        if not ok]
    if wrong:
        raise InputError(f"{run_dir / 'run.json'}: damaged run description: {wrong[0]}")
    variant = run_variant(info, run_dir / "run.json")
    saved = saved_train_config(run_dir / "config.json")
    views = load_training_views(resolve_data_dir(run_dir, info, data_dir), saved.image_width, saved.linear_input,
                                saved.saturation_threshold)
    ckpt = load_checkpoint(run_dir)
    # as the run trained: the model's structure is the checkpoint's, even where the dataset's start cloud has changed
    config = trained_settings(saved, views, variant, ckpt, checkpoint_path(run_dir))
    scene = restore_scene(ckpt, info, config, checkpoint_path(run_dir)).to(resolve_device(device))
    scene.eval()
    return scene, views, config, info
