"""Downstream structure-from-motion with pycolmap on CPU: SIFT features, matching, incremental mapping.

Used to ask whether relit images help a classical SfM pipeline (METHOD §7): run it on the original (uneven) and on the
relit sequence with the same settings and compare reprojection error, observations per image, registered images and
points, and the trajectory against the true poses when they are known.
"""

from __future__ import annotations

import os
import shutil
from dataclasses import dataclass
from pathlib import Path
from typing import Callable, Literal, Mapping, Sequence

import numpy as np

from evaluation.trajectory import TrajectoryErrors, trajectory_errors
from spotlessgs.io.cameras import Intrinsics


@dataclass(frozen=True)
class SfmConfig:
    """Settings of the SfM pipeline (the same for every sequence that is compared)."""

    matcher: Literal["sequential", "exhaustive"] = "sequential"  # image pairing strategy
    sequential_overlap: int = 10  # sequential matching: each image is matched with this many successors
    max_num_features: int = 8192  # SIFT features kept per image
    min_num_matches: int = 15  # verified matches needed for an image pair to count in mapping
    num_threads: int = 1  # CPU threads for extraction, matching and mapping (1: bit-reproducible; more may vary)
    seed: int = 0  # random seed for COLMAP's RANSAC and mapping (deterministic runs)
    refine_intrinsics: bool = False  # let bundle adjustment refine known intrinsics (False keeps them fixed)
    verbose: bool = False  # let COLMAP log its INFO messages to stderr (False: warnings and errors only)

    def __post_init__(self) -> None:
        if self.matcher not in ("sequential", "exhaustive"):
            raise ValueError(f"matcher must be 'sequential' or 'exhaustive', got {self.matcher!r}")
        for name in ("sequential_overlap", "max_num_features", "min_num_matches", "num_threads"):
            if getattr(self, name) < 1:
                raise ValueError(f"SfmConfig.{name} must be at least 1, got {getattr(self, name)}")


@dataclass(frozen=True)
class SfmResult:
    """Outcome of one SfM run: statistics, registered poses and the sparse cloud of the largest model."""

    total_images: int  # images given to the pipeline
    registered_images: int  # images registered in the largest model
    points3d: int  # 3D points of the largest model
    reprojection_error_px: float | None  # mean reprojection error (px); None when nothing was reconstructed
    observations_per_image: float | None  # mean observations per registered image; None when nothing registered
    poses_c2w: dict[str, np.ndarray]  # image name → (4, 4) camera-to-world, OpenCV axes, model's arbitrary frame
    points_xyz: np.ndarray  # (P, 3) sparse points in the model's frame
    points_rgb: np.ndarray  # (P, 3) uint8 colours of the points

    def summary(self, true_c2w: Mapping[str, np.ndarray] | None = None, order: Sequence[str] | None = None) -> dict:
        """JSON-ready statistics; with true poses (name → (4, 4) c2w, OpenCV axes) also trajectory errors.

        Args:
            true_c2w: true camera-to-world poses by image name.
            order: image names in time order (for the relative rotation error); default sorted names.
        """
        out: dict = {
            "reprojection_error_px": self.reprojection_error_px,
            "observations_per_image": self.observations_per_image,
            "registered_images": self.registered_images,
            "total_images": self.total_images,
            "points3d": self.points3d,
        }
        if true_c2w is not None:
            errs = self.trajectory_errors(true_c2w, order)
            out["trajectory"] = None if errs is None else {
                "ate_rmse": errs.ate_rmse,
                "ate_mean": errs.ate_mean,
                "rre_mean_deg": errs.rre_mean_deg,
                "num_poses": errs.num_poses,
                "sim3_scale": errs.alignment.scale,
            }
        return out

    def trajectory_errors(
        self, true_c2w: Mapping[str, np.ndarray], order: Sequence[str] | None = None
    ) -> TrajectoryErrors | None:
        """Errors of the registered poses against ``true_c2w`` (OpenCV axes); None with fewer than 3 common poses."""
        names = [n for n in (order or sorted(true_c2w)) if n in self.poses_c2w and n in true_c2w]
        if len(names) < 3:
            return None
        est = np.stack([self.poses_c2w[n] for n in names])
        true = np.stack([np.asarray(true_c2w[n], dtype=np.float64) for n in names])
        return trajectory_errors(est, true)


def run_sfm(
    image_dir: str | os.PathLike,
    image_names: Sequence[str],
    work_dir: str | os.PathLike,
    config: SfmConfig = SfmConfig(),
    intrinsics: Intrinsics | None = None,
    progress: Callable[[str], None] | None = None,
) -> SfmResult:
    """Run feature extraction, matching and incremental mapping on ``image_names`` in ``image_dir``.

    Args:
        image_dir: folder holding the images.
        image_names: file names (in time order, which sequential matching relies on).
        work_dir: scratch folder for the COLMAP database and models (emptied first).
        config: pipeline settings.
        intrinsics: known pinhole intrinsics (one camera for all images; kept fixed unless
            ``config.refine_intrinsics``); None lets COLMAP estimate a SIMPLE_RADIAL camera.
        progress: called with the name of each step as it starts.

    Raises:
        ValueError: no image names, or an image's size differs from ``intrinsics``.
        FileNotFoundError: an image is missing.
    """
    import pycolmap

    image_dir = Path(image_dir)
    names = list(image_names)
    if not names:
        raise ValueError("SfM needs at least one image")
    for n in names:
        if not (image_dir / n).is_file():
            raise FileNotFoundError(f"{image_dir / n}: image listed for SfM does not exist")
    if intrinsics is not None:
        _check_sizes(image_dir, names, intrinsics)
    work = Path(work_dir)
    if work.exists():
        shutil.rmtree(work)
    (work / "sparse").mkdir(parents=True)
    database = work / "database.db"
    step = progress or (lambda _s: None)
    pycolmap.set_random_seed(config.seed)
    old_level = pycolmap.logging.minloglevel
    pycolmap.logging.minloglevel = 0 if config.verbose else 1
    try:
        return _pipeline(pycolmap, image_dir, names, work, database, config, intrinsics, step)
    finally:
        pycolmap.logging.minloglevel = old_level


def _pipeline(
    pycolmap, image_dir: Path, names: list[str], work: Path, database: Path, config: SfmConfig,
    intrinsics: Intrinsics | None, step: Callable[[str], None],
) -> SfmResult:
    """The COLMAP steps of :func:`run_sfm` (arguments as there; ``step`` reports progress)."""
    reader = pycolmap.ImageReaderOptions()
    if intrinsics is not None:
        reader.camera_model = "PINHOLE"
        reader.camera_params = f"{intrinsics.fx},{intrinsics.fy},{intrinsics.cx},{intrinsics.cy}"
    else:
        reader.camera_model = "SIMPLE_RADIAL"
    extraction = pycolmap.FeatureExtractionOptions()
    extraction.num_threads = config.num_threads
    extraction.use_gpu = False
    extraction.sift.max_num_features = config.max_num_features
    step("features")
    pycolmap.extract_features(
        database, image_dir, image_names=names, camera_mode=pycolmap.CameraMode.SINGLE,
        reader_options=reader, extraction_options=extraction, device=pycolmap.Device.cpu,
    )
    matching = pycolmap.FeatureMatchingOptions()
    matching.num_threads = config.num_threads
    matching.use_gpu = False
    step(f"matching ({config.matcher})")
    if config.matcher == "sequential":
        pairing = pycolmap.SequentialPairingOptions()
        pairing.overlap = config.sequential_overlap
        pairing.num_threads = config.num_threads
        pycolmap.match_sequential(database, matching_options=matching, pairing_options=pairing,
                                  device=pycolmap.Device.cpu)
    else:
        pycolmap.match_exhaustive(database, matching_options=matching, device=pycolmap.Device.cpu)
    options = pycolmap.IncrementalPipelineOptions()
    options.num_threads = config.num_threads
    options.random_seed = config.seed
    options.min_num_matches = config.min_num_matches
    options.multiple_models = False
    if intrinsics is not None and not config.refine_intrinsics:
        options.ba_refine_focal_length = False
        options.ba_refine_principal_point = False
        options.ba_refine_extra_params = False
    step("mapping")
    models = pycolmap.incremental_mapping(database, image_dir, work / "sparse", options=options)
    return _result_from_models(models, total=len(names))


def _check_sizes(image_dir: Path, names: Sequence[str], intr: Intrinsics) -> None:
    """Raise ValueError naming the first image whose size differs from the intrinsics' width × height."""
    from PIL import Image

    for n in names:
        with Image.open(image_dir / n) as im:
            if im.size != (intr.width, intr.height):
                raise ValueError(
                    f"{image_dir / n}: image is {im.size[0]}x{im.size[1]} but the intrinsics are for "
                    f"{intr.width}x{intr.height}"
                )


def _result_from_models(models: Mapping[int, object], total: int) -> SfmResult:
    """Statistics, poses and points of the model with the most registered images (empty result when none)."""
    if not models:
        return SfmResult(total, 0, 0, None, None, {}, np.zeros((0, 3)), np.zeros((0, 3), dtype=np.uint8))
    rec = max(models.values(), key=lambda r: (r.num_reg_images(), r.num_points3D()))
    poses = {}
    for image_id in rec.reg_image_ids():
        image = rec.image(image_id)
        cam_from_world = np.eye(4)
        cam_from_world[:3, :4] = image.cam_from_world().matrix()
        poses[image.name] = np.linalg.inv(cam_from_world)
    xyz = np.array([p.xyz for p in rec.points3D.values()], dtype=np.float64).reshape(-1, 3)
    rgb = np.array([p.color for p in rec.points3D.values()], dtype=np.uint8).reshape(-1, 3)
    n_reg = rec.num_reg_images()
    return SfmResult(
        total_images=total,
        registered_images=n_reg,
        points3d=rec.num_points3D(),
        reprojection_error_px=float(rec.compute_mean_reprojection_error()) if rec.num_points3D() else None,
        observations_per_image=float(rec.compute_mean_observations_per_reg_image()) if n_reg else None,
        poses_c2w=poses,
        points_xyz=xyz,
        points_rgb=rgb,
    )
