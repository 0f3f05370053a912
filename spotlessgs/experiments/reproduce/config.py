"""Settings of ``spotless reproduce``: a frozen dataclass with a comment per field and four named presets.

``tiny`` finishes in a few minutes on a 2-core CPU (the tests run it), ``quick`` in about half an hour there (the
README's main job), ``paper`` is the paper's scale (316 frames at native size, the full training schedule) for a GPU;
``components`` trains the DarkGS ablation with three seeds on the rooms where the SH light, the BRDF and
interreflection matter.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from spotlessgs.io.cameras import LENS_MODELS

# Every model the trainer knows; the tables read them by these names. "auto" is ``spotless train --model auto
# --gaussian-budget``: the light/reflectance model chosen on held-out training views (spotlessgs.training.selection)
# and densification that stops when held-out error stops improving (spotlessgs.training.budget).
METHODS_3D: tuple[str, ...] = ("3dgs", "darkgs", "darkgs-calibrated", "darkgs+sh", "darkgs+brdf", "spotless", "auto")
# Single-view 2D baselines (spotlessgs.baselines2d).
METHODS_2D: tuple[str, ...] = ("clahe", "msrcr", "cyclegan")
# Dataset variants: the simulator's spotlight presets of docs/method.md §11, and "residual": the uneven spotlight
# with the room's own lamps left on at ReproduceConfig.residual_light of their power in the spotlit input (light the
# spotlight does not explain: ``spotless-sim render --residual-light``).
RESIDUAL_VARIANT = "residual"
VARIANTS: tuple[str, ...] = ("uneven", "saturated", RESIDUAL_VARIANT)
# The variants of the quick, tiny and paper presets (Tables I-IV).
PAPER_VARIANTS: tuple[str, ...] = ("uneven", "saturated")
# The copy of a room's ``uneven`` dataset with camera sensor noise (ReproduceConfig.sensor_noise): Table III's
# robot-camera case.
NOISY_VARIANT = "uneven-noisy"
# The copy of a room's ``uneven`` dataset seen through a robot camera (ReproduceConfig.robot_camera).
ROBOT_VARIANT = "robot"
# The same robot camera with an RGB-D camera's depth images, started from them (ReproduceConfig.robot_depth_camera).
RGBD_VARIANT = "rgbd"
# The stage that scores a dataset's inputs once for every method (its folder: OUT/inputs/<dataset>).
INPUTS_STAGE = "eval-inputs"
# Stage name prefix of the relighting ceiling of each dataset (tasks.evaluate_ceiling).
CEILING_STAGE = "ceiling"
# Room kinds shipped under scenes/<kind>/house.json.
SHIPPED_ROOMS: tuple[str, ...] = ("bedroom", "living_room", "office", "storage_room", "corridor", "white_room")
# The default location of the shipped rooms (the repository's scenes/ folder).
DEFAULT_SCENES_DIR = Path(__file__).resolve().parents[3] / "scenes"


# Fields added after reproduction folders existed whose default is how those folders were made: a folder whose
# reproduce.json lacks one of them is resumed when the field has its default (pipeline.check_or_record_config).
NEUTRAL_NEW_FIELDS: tuple[str, ...] = ("extra_datasets", "residual_light", "extra_seeds")


def dataset_id(room: str, variant: str) -> str:
    """Name of a test dataset: ``bedroom-uneven``."""
    return f"{room}-{variant}"


def split_dataset_id(name: str) -> tuple[str, str]:
    """(room, variant) of a test dataset's name (the inverse of :func:`dataset_id` for a variant without "-")."""
    room, _, variant = name.rpartition("-")
    return room, variant


def _is_shot_read(value: Any) -> bool:
    """Is ``value`` (shot, read) of simulator.sensor_noise.SensorNoise: two finite numbers >= 0?"""
    return len(value) == 2 and all(isinstance(v, (int, float)) and math.isfinite(v) and v >= 0 for v in value)


@dataclass(frozen=True)
class ReproduceConfig:
    """Everything that determines a reproduction run besides the output folder (which records it)."""

    # Preset name this config started from.
    preset: str = "quick"
    # Test rooms (shipped room kinds): every 3D method and 2D baseline is scored on each.
    scenes: tuple[str, ...] = ("bedroom",)
    # Dataset variants rendered for every test room.
    variants: tuple[str, ...] = PAPER_VARIANTS
    # Test datasets besides every room x variant, as "room-variant" (e.g. "bedroom-residual"), rendered, trained and
    # scored like them.
    extra_datasets: tuple[str, ...] = ()
    # The room's own lamps left on in the spotlit input of a "residual" dataset, as a fraction of their power.
    residual_light: float = 0.1
    # Frames along the camera loop of a test room (every 11th is a test view). quick: 60, as scripts/demo.sh (with 36
    # the held-out test views were blurrier than the inputs by LPIPS: too few views to pin the geometry).
    frames: int = 60
    # Rendered image size of the test rooms (pixels).
    width: int = 160
    height: int = 120
    # Cycles samples per pixel.
    samples: int = 16
    # Also render every test room's uniform ground truth (even, shadow-free environment light, lamps unlit:
    # ``spotless-sim render --gt uniform``) and score every row against it beside the lamps-on one.
    uniform_gt: bool = True
    # 3D models trained on every test dataset.
    methods: tuple[str, ...] = METHODS_3D
    # Trainer preset (spotlessgs.training.config) and overrides (None keeps the preset's value). quick: the trainer's
    # quick preset, 3000 steps at 160 px (32-50 ms/step per model on one core; at 1000 steps the relit views were
    # still blurrier than the inputs by LPIPS).
    train_preset: str = "quick"
    train_iterations: int | None = None
    train_width: int | None = None
    # Training is interrupted at these fractions of the schedule to score the relit test views (the speed-against-
    # error curve); 1.0 is always included.
    curve_fractions: tuple[float, ...] = (0.25, 0.5, 0.75)
    # Method "auto": the shortest proxy run of model selection (SelectionConfig.min_proxy_iterations; None keeps the
    # selection default of 100 steps, which would make selection cost several times a 150-step tiny run).
    selection_min_proxy_iterations: int | None = None
    # Single-view 2D baselines, run on the dataset variants in ``baseline_variants`` only.
    baselines: tuple[str, ...] = METHODS_2D
    baseline_variants: tuple[str, ...] = ("uneven",)
    # Rooms whose renders train the Cycle-GAN (never a test room), at least two: the uneven inputs of the rooms at even
    # positions and the evenly lit ground truth of the rooms at odd positions are the two domains, so no image of one
    # domain has a pixel-aligned partner in the other (unpaired by construction).
    gan_rooms: tuple[str, ...] = ("office", "living_room")
    # Frames, size and samples of the Cycle-GAN's training renders.
    gan_frames: int = 24
    gan_width: int = 160
    gan_height: int = 120
    gan_samples: int = 8
    # Cycle-GAN preset (spotlessgs.baselines2d.cyclegan.config) and optional step count override.
    cyclegan_preset: str = "quick"
    cyclegan_steps: int | None = 600
    # Run SfM on the original and every method's relit sequence (Table III).
    sfm: bool = True
    # Table III's robot-camera case. The paper's SfM test runs on its real-world sequence, whose camera adds sensor
    # noise (most of all in the dark corners); Cycles renders are clean and denoised, and on clean renders COLMAP's
    # mean reprojection error rewards the spotlight's contrast (README, "SfM"). When not None, (shot, read) of
    # simulator.sensor_noise.SensorNoise: every room's ``uneven`` dataset also gets a copy with that noise
    # (``<room>-uneven-noisy``, the same renders and ground truth), on which ``noisy_methods`` are trained, relit and
    # evaluated like the other datasets (no 2D baselines). Default: a moderate gain (Brooks et al. 2019 sample shot
    # variance in [1e-4, 0.012]), at which COLMAP still registers part of the original sequence.
    sensor_noise: tuple[float, float] | None = (0.002, 0.004)
    # 3D models trained on the noisy copies.
    noisy_methods: tuple[str, ...] = ("spotless",)
    # A robot's camera and start (``<room>-robot``): every room's ``uneven`` renders seen through an OpenCV lens
    # (``robot_distortion``: k1, k2, p1, p2), with auto-exposure, vignetting (35 % at the corners) and sensor noise
    # (``robot_noise``: shot, read) as ``spotless-sim add-noise --robot-camera --no-point-cloud`` makes them, and no
    # depth-derived point cloud: the trainer starts from sparse points triangulated on those images with the poses
    # (``spotless prepare --points``). ``robot_methods`` are trained on it; the report sets each against the same
    # method on the ideal input (``<room>-uneven``).
    robot_camera: bool = True
    robot_lens: str = "opencv"
    robot_distortion: tuple[float, ...] = (-0.18, 0.03, 0.0, 0.0)
    robot_noise: tuple[float, float] = (0.002, 0.004)
    # What the robot's sensor records of the render at gain 1 (a dark scene: auto-exposure raises the gain up to 4x).
    robot_sensitivity: float = 0.25
    robot_methods: tuple[str, ...] = METHODS_3D
    # The robot with an RGB-D camera (``<room>-rgbd``): the robot copy's images, and depth images registered to them
    # (``spotless-sim add-noise --depth-camera``: σ = ``robot_depth_noise`` · z² metres, 16-bit millimetres); the
    # start is those depth images back-projected (``spotless prepare --points``: dense, with normals), which the
    # trainer trusts (``TrainConfig.trust_start_geometry``). ``rgbd_methods`` are trained on it.
    robot_depth_camera: bool = True
    robot_depth_noise: float = 0.0025
    rgbd_methods: tuple[str, ...] = ("darkgs", "spotless", "auto")
    # SfM pairing: "sequential" or "exhaustive" (short sequences with wide baselines need exhaustive).
    sfm_matcher: str = "sequential"
    # Compute LPIPS (AlexNet) besides PSNR and SSIM.
    lpips: bool = True
    # The command seed (renders, training, Cycle-GAN and SfM derive their own streams from it).
    seed: int = 0
    # Training seeds besides ``seed``: every 3D method is trained again with each on every rendered test dataset
    # (not the noisy or robot copies), and the seed table gives each method's mean, min and max over all the seeds.
    extra_seeds: tuple[int, ...] = ()
    # Folder with the shipped rooms (scenes/<kind>/house.json).
    scenes_dir: Path = DEFAULT_SCENES_DIR

    def __post_init__(self) -> None:
        def check_subset(name: str, allowed: tuple[str, ...]) -> None:
            values = getattr(self, name)
            if not values:
                raise ValueError(f"ReproduceConfig.{name} is empty")
            bad = [v for v in values if v not in allowed]
            if bad:
                raise ValueError(f"ReproduceConfig.{name}: unknown {bad}; choose from {list(allowed)}")
            if len(set(values)) != len(values):
                raise ValueError(f"ReproduceConfig.{name} lists an entry twice: {list(values)}")

        check_subset("scenes", SHIPPED_ROOMS)
        check_subset("variants", VARIANTS)
        for name in self.extra_datasets:
            room, variant = split_dataset_id(name)
            if room not in SHIPPED_ROOMS or variant not in VARIANTS:
                raise ValueError(f"ReproduceConfig.extra_datasets: {name!r} is not ROOM-VARIANT with a room of "
                                 f"{list(SHIPPED_ROOMS)} and a variant of {list(VARIANTS)}")
        names = [dataset_id(room, variant) for room, variant in self.datasets()]
        if len(set(names)) != len(names):
            raise ValueError(f"ReproduceConfig.extra_datasets repeats a test dataset: {names}")
        if not (math.isfinite(self.residual_light) and 0.0 < self.residual_light <= 1.0):
            raise ValueError(f"ReproduceConfig.residual_light must lie in (0, 1], got {self.residual_light!r}")
        if self.seed in self.extra_seeds or len(set(self.extra_seeds)) != len(self.extra_seeds):
            raise ValueError(f"ReproduceConfig.extra_seeds must differ from each other and from seed {self.seed}, "
                             f"got {list(self.extra_seeds)}")
        check_subset("methods", METHODS_3D)
        if self.baselines:
            check_subset("baselines", METHODS_2D)
            check_subset("baseline_variants", self.variants)
        if "cyclegan" in self.baselines:
            check_subset("gan_rooms", SHIPPED_ROOMS)
            if len(self.gan_rooms) < 2:
                raise ValueError(f"ReproduceConfig.gan_rooms needs at least two rooms (one per unpaired domain), "
                                 f"got {list(self.gan_rooms)}")
            shared = sorted(set(self.gan_rooms) & set(self.scenes))
            if shared:
                raise ValueError(f"ReproduceConfig: Cycle-GAN training rooms {shared} are also test rooms; the 2D "
                                 "baseline must never see the test room")
        for name in ("frames", "width", "height", "samples", "gan_frames", "gan_width", "gan_height", "gan_samples"):
            if getattr(self, name) < 1:
                raise ValueError(f"ReproduceConfig.{name} must be at least 1, got {getattr(self, name)}")
        if self.frames < 2:
            raise ValueError(f"ReproduceConfig.frames must be at least 2 (one test view, one training view), "
                             f"got {self.frames}")
        if self.selection_min_proxy_iterations is not None and self.selection_min_proxy_iterations < 1:
            raise ValueError(f"ReproduceConfig.selection_min_proxy_iterations must be at least 1 (or None), "
                             f"got {self.selection_min_proxy_iterations}")
        if any(not 0.0 < f < 1.0 for f in self.curve_fractions):
            raise ValueError(f"ReproduceConfig.curve_fractions must lie in (0, 1), got {self.curve_fractions}")
        if self.sensor_noise is not None:
            if not _is_shot_read(self.sensor_noise):
                raise ValueError(f"ReproduceConfig.sensor_noise must be (shot, read), two finite numbers >= 0, or "
                                 f"None; got {self.sensor_noise!r}")
            if "uneven" not in self.variants:
                raise ValueError("ReproduceConfig.sensor_noise needs the 'uneven' variant (the noisy copy is made "
                                 f"from it); variants are {list(self.variants)}")
            check_subset("noisy_methods", METHODS_3D)
        if self.robot_camera:
            if "uneven" not in self.variants:
                raise ValueError("ReproduceConfig.robot_camera needs the 'uneven' variant (the robot copy is made from "
                                 f"it); variants are {list(self.variants)}")
            if self.robot_lens not in LENS_MODELS:
                raise ValueError(f"ReproduceConfig.robot_lens must be pinhole, opencv or fisheye, got "
                                 f"{self.robot_lens!r}")
            if not _is_shot_read(self.robot_noise):
                raise ValueError(f"ReproduceConfig.robot_noise must be (shot, read), two finite numbers >= 0; got "
                                 f"{self.robot_noise!r}")
            if not (math.isfinite(self.robot_sensitivity) and self.robot_sensitivity > 0):
                raise ValueError(f"ReproduceConfig.robot_sensitivity must be > 0, got {self.robot_sensitivity!r}")
            check_subset("robot_methods", METHODS_3D)
            if self.robot_depth_camera:
                if not (math.isfinite(self.robot_depth_noise) and self.robot_depth_noise >= 0):
                    raise ValueError(f"ReproduceConfig.robot_depth_noise must be finite and >= 0, got "
                                     f"{self.robot_depth_noise!r}")
                check_subset("rgbd_methods", METHODS_3D)
        if self.sfm_matcher not in ("sequential", "exhaustive"):
            raise ValueError(f"ReproduceConfig.sfm_matcher must be sequential or exhaustive, got {self.sfm_matcher!r}")

    def replace(self, **changes: Any) -> "ReproduceConfig":
        """A copy with some fields changed (unknown names are an error)."""
        unknown = set(changes) - {f.name for f in dataclasses.fields(self)}
        if unknown:
            raise ValueError(f"unknown ReproduceConfig field(s): {sorted(unknown)}")
        return dataclasses.replace(self, **changes)

    def scene_file(self, room: str) -> Path:
        """``scenes_dir/<room>/house.json`` (FileNotFoundError naming it when absent)."""
        path = Path(self.scenes_dir) / room / "house.json"
        if not path.is_file():
            raise FileNotFoundError(f"{path}: shipped room {room!r} not found (is --scenes-dir right?)")
        return path

    def datasets(self) -> list[tuple[str, str]]:
        """(room, variant) of every rendered test dataset, in table order: every room x variant, then
        ``extra_datasets``."""
        return ([(room, variant) for room in self.scenes for variant in self.variants]
                + [split_dataset_id(name) for name in self.extra_datasets])

    def seeds(self) -> tuple[int, ...]:
        """Every training seed of the rendered test datasets: ``seed`` first, then ``extra_seeds``."""
        return (self.seed,) + tuple(self.extra_seeds)

    def noisy_datasets(self) -> list[tuple[str, str]]:
        """(room, NOISY_VARIANT) of every sensor-noise copy (empty when ``sensor_noise`` is None)."""
        return [] if self.sensor_noise is None else [(room, NOISY_VARIANT) for room in self.scenes]

    def robot_datasets(self) -> list[tuple[str, str]]:
        """(room, ROBOT_VARIANT) of every robot-camera copy (empty when ``robot_camera`` is off)."""
        return [(room, ROBOT_VARIANT) for room in self.scenes] if self.robot_camera else []

    def rgbd_datasets(self) -> list[tuple[str, str]]:
        """(room, RGBD_VARIANT) of every RGB-D robot copy (empty unless ``robot_camera`` and
        ``robot_depth_camera``)."""
        return [(room, RGBD_VARIANT) for room in self.scenes] if self.robot_camera and self.robot_depth_camera else []

    def all_datasets(self) -> list[tuple[str, str]]:
        """Every test dataset, rendered ones, then noisy, robot-camera and RGB-D copies, in table order."""
        return self.datasets() + self.noisy_datasets() + self.robot_datasets() + self.rgbd_datasets()

    def methods_for(self, variant: str) -> tuple[str, ...]:
        """The 3D methods trained on a dataset of this variant."""
        return {NOISY_VARIANT: self.noisy_methods, ROBOT_VARIANT: self.robot_methods,
                RGBD_VARIANT: self.rgbd_methods}.get(variant, self.methods)

    def gan_domains(self) -> tuple[tuple[str, ...], tuple[str, ...]]:
        """(rooms whose uneven inputs form the Cycle-GAN's source domain, rooms whose ground truth forms its target)."""
        return tuple(self.gan_rooms[0::2]), tuple(self.gan_rooms[1::2])

    def to_dict(self) -> dict[str, Any]:
        """Plain-JSON form (recorded in results.json)."""
        out = dataclasses.asdict(self)
        out["scenes_dir"] = str(self.scenes_dir)
        return out


PRESETS: dict[str, ReproduceConfig] = {
    # Tests: one room, a dozen frames at 96x72, a 150-step trainer, a 60-step Cycle-GAN; a few minutes on 2 cores.
    # Model selection's proxies: 20 steps each (a shared base and five candidates: 120 steps, under one tiny run).
    "tiny": ReproduceConfig(
        preset="tiny", frames=12, width=96, height=72, samples=4, train_preset="tiny", train_iterations=150,
        train_width=64, curve_fractions=(0.5,), selection_min_proxy_iterations=20, gan_rooms=("office", "living_room"),
        gan_frames=6, gan_width=96, gan_height=72, gan_samples=4, cyclegan_preset="tiny", cyclegan_steps=None,
        sfm_matcher="exhaustive", robot_methods=("spotless",), rgbd_methods=("spotless",),
    ),
    # README main job: about half an hour on a 2-core CPU.
    "quick": ReproduceConfig(),
    # The paper's scale (GPU): 316 frames at 640x480 (the Cycle-GAN's 256x256 crops need images at least that big),
    # the trainer's paper schedule, on the living room (the L-shaped room; the bedroom and office train the Cycle-GAN).
    "paper": ReproduceConfig(
        preset="paper", scenes=("living_room",), gan_rooms=("office", "bedroom"), frames=316, width=640, height=480,
        samples=64, train_preset="paper", train_iterations=None,
        curve_fractions=(0.1, 0.25, 0.5, 0.75), gan_frames=120, gan_width=640, gan_height=480, gan_samples=32,
        cyclegan_preset="paper", cyclegan_steps=None,
    ),
    # Rooms where the relighting components matter (issue 18), at the quick preset's size, trained with three seeds:
    # the bedroom with residual light (a dimmed ceiling light stays on in the spotlit input: the SH light has
    # something to explain), the glossy and metallic storage room (the learned BRDF), and the small white room
    # (interreflection). The DarkGS ablation only; no 2D baselines, camera copies or SfM.
    "components": ReproduceConfig(
        preset="components", scenes=("storage_room", "white_room"), variants=("uneven",),
        extra_datasets=("bedroom-residual",), methods=("darkgs", "darkgs+sh", "darkgs+brdf", "spotless"),
        extra_seeds=(1, 2), baselines=(), sensor_noise=None, robot_camera=False, sfm=False,
    ),
}


def preset(name: str, **overrides: Any) -> ReproduceConfig:
    """The named preset with some fields changed."""
    if name not in PRESETS:
        raise ValueError(f"unknown reproduce preset {name!r}; choose one of {sorted(PRESETS)}")
    return PRESETS[name].replace(**overrides)


def train_stage(ds: str, method: str, seed: int, config: ReproduceConfig) -> str:
    """The stage that trains ``method`` on dataset ``ds`` with ``seed``: ``train/<ds>/<method>`` for the command
    seed, ``train/<ds>/seed-<seed>/<method>`` for one of ``extra_seeds`` (its run folder: the same under runs/)."""
    return f"train/{ds}/{method}" if seed == config.seed else f"train/{ds}/seed-{seed}/{method}"
