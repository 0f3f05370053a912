"""Downstream structure-from-motion with pycolmap on CPU: SIFT features, matching, incremental mapping.

Used to ask whether relit images help a classical SfM pipeline (docs/method.md §10): run it on the original (uneven)
and on the relit sequence with the same settings and compare reprojection error, observations per image, registered
images and points, and the trajectory against the true poses when they are known.

COLMAP's incremental mapper may split a sequence into several sub-models where consecutive images share too few
matches: on the simulator's rectangular loops the camera turns by 90 degrees between two frames at every corner, so a
loop reconstructs as one sub-model per side (60 frames at 160x120: four sub-models of 14-16 images; the largest alone
would measure a quarter of the sequence). With ``SfmConfig.all_models`` (default) the statistics pool every sub-model:
registered images and points are summed, the reprojection error is COLMAP's mean over all 3D points of all sub-models,
observations per image are all observations over all registered images, and each sub-model is aligned to the true
poses on its own before the trajectory errors are pooled.
"""

from __future__ import annotations

import contextlib
import os
import shutil
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable, Iterator, Literal, Mapping, Sequence

import numpy as np

from evaluation.trajectory import TrajectoryErrors, pool_trajectory_errors, trajectory_errors
from spotlessgs.io.cameras import Intrinsics
from spotlessgs.io.colmap_text import SUPPORTED_MODELS, ColmapCamera
from spotlessgs.io.errors import InputError


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
    all_models: bool = True  # pool the statistics of every sub-model the mapper builds (False: the largest only)
    verbose: bool = False  # let COLMAP log its INFO messages to stderr (False: errors only)
    camera_model: str = "SIMPLE_RADIAL"  # the COLMAP camera model estimated when the intrinsics are not given

    def __post_init__(self) -> None:
        if self.matcher not in ("sequential", "exhaustive"):
            raise ValueError(f"matcher must be 'sequential' or 'exhaustive', got {self.matcher!r}")
        if self.camera_model not in SUPPORTED_MODELS:
            raise ValueError(f"SfmConfig.camera_model must be one of {list(SUPPORTED_MODELS)}, got "
                             f"{self.camera_model!r}")
        for name in ("sequential_overlap", "max_num_features", "min_num_matches", "num_threads"):
            if getattr(self, name) < 1:
                raise ValueError(f"SfmConfig.{name} must be at least 1, got {getattr(self, name)}")


@dataclass(frozen=True)
class SfmModel:
    """One sub-model of an SfM run: registered poses and sparse points, in the sub-model's own arbitrary frame."""

    poses_c2w: dict[str, np.ndarray]  # image name → (4, 4) camera-to-world, OpenCV axes
    points_xyz: np.ndarray  # (P, 3) sparse points
    points_rgb: np.ndarray  # (P, 3) uint8 colours of the points
    point_errors_px: np.ndarray  # (P,) mean reprojection error of each point over its track (px)
    observations: int  # 2D observations of the points (sum of the track lengths)
    # (O, 4) every 2D observation: x, y (pixels), reprojection error (px), radius from the image centre as a fraction
    # of the half-diagonal (0 = centre, 1 = corner)
    observation_errors: np.ndarray = field(default_factory=lambda: np.zeros((0, 4)))


@dataclass(frozen=True)
class SfmResult:
    """Outcome of one SfM run: statistics over the sub-models it pools, and each sub-model (largest first)."""

    total_images: int  # images given to the pipeline
    registered_images: int  # images registered in the pooled sub-models
    points3d: int  # 3D points of the pooled sub-models
    reprojection_error_px: float | None  # mean reprojection error over all points (px); None when nothing was built
    observations_per_image: float | None  # observations per registered image; None when nothing registered
    models: tuple[SfmModel, ...] = ()  # the pooled sub-models, most registered images first

    @property
    def poses_c2w(self) -> dict[str, np.ndarray]:
        """Image name → (4, 4) camera-to-world of every pooled sub-model (each in its own frame)."""
        return {name: pose for model in self.models for name, pose in model.poses_c2w.items()}

    @property
    def largest_model_images(self) -> int:
        """Images registered in the largest sub-model (0 when none)."""
        return len(self.models[0].poses_c2w) if self.models else 0

    def errors_by_radius(self, bins: int = 4) -> list[dict]:
        """Reprojection error of the observations in ``bins`` equal rings of image radius (fraction of the
        half-diagonal, corners at 1): ``radius`` [lo, hi), ``observations``, ``mean_error_px`` (None when empty).

        Where in the image the features lie matters: under a camera-mounted spotlight they crowd in the bright centre.
        """
        if bins < 1:
            raise ValueError(f"errors_by_radius: bins must be >= 1, got {bins}")
        obs = np.concatenate([m.observation_errors for m in self.models]) if self.models else np.zeros((0, 4))
        ring = np.minimum((obs[:, 3] * bins).astype(int), bins - 1)
        return [{"radius": [k / bins, (k + 1) / bins], "observations": int((ring == k).sum()),
                 "mean_error_px": float(obs[ring == k, 2].mean()) if (ring == k).any() else None}
                for k in range(bins)]

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
            "models": len(self.models),
            "largest_model_images": self.largest_model_images,
            "reprojection_error_by_radius": self.errors_by_radius(),
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

    def model_alignments(
        self, true_c2w: Mapping[str, np.ndarray], order: Sequence[str] | None = None
    ) -> list[tuple[SfmModel, list[str], TrajectoryErrors]]:
        """Each sub-model with at least 3 poses that have true poses: (model, its image names in time order, its
        errors after its own similarity alignment to the truth)."""
        names = list(order or sorted(true_c2w))
        out = []
        for model in self.models:
            common = [n for n in names if n in model.poses_c2w and n in true_c2w]
            if len(common) < 3:
                continue
            est = np.stack([model.poses_c2w[n] for n in common])
            true = np.stack([np.asarray(true_c2w[n], dtype=np.float64) for n in common])
            out.append((model, common, trajectory_errors(est, true)))
        return out

    def trajectory_errors(
        self, true_c2w: Mapping[str, np.ndarray], order: Sequence[str] | None = None
    ) -> TrajectoryErrors | None:
        """Errors of the registered poses against ``true_c2w`` (OpenCV axes), each sub-model aligned on its own and
        the errors pooled (:func:`~evaluation.trajectory.pool_trajectory_errors`); None when no sub-model has 3 poses
        with true poses."""
        parts = [errs for _m, _n, errs in self.model_alignments(true_c2w, order)]
        return pool_trajectory_errors(parts) if parts else None


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
        intrinsics: known intrinsics (lens included) (one camera for all images; kept fixed unless
            ``config.refine_intrinsics``); None lets COLMAP estimate a SIMPLE_RADIAL camera.
        progress: called with the name of each step as it starts.

    Raises:
        ValueError: no image names, or an image's size differs from ``intrinsics``.
        FileNotFoundError: an image is missing.
    """
    import pycolmap

    image_dir, names = Path(image_dir), list(image_names)
    work, database = _new_work_folder(image_dir, names, work_dir, intrinsics, "SfM")
    step = progress or (lambda _s: None)
    with _colmap_logging(pycolmap, config):
        return _pipeline(pycolmap, image_dir, names, work, database, config, intrinsics, step)


def _new_work_folder(image_dir: Path, names: list[str], work_dir: str | os.PathLike, intrinsics: Intrinsics | None,
                     what: str) -> tuple[Path, Path]:
    """Check the images (at least one, each present, each of ``intrinsics``' size when given), empty ``work_dir``
    and return it with the path of its new COLMAP database."""
    if not names:
        raise ValueError(f"{what} needs at least one image")
    for n in names:
        if not (image_dir / n).is_file():
            raise FileNotFoundError(f"{image_dir / n}: image listed for {what} does not exist")
    if intrinsics is not None:
        _check_sizes(image_dir, names, intrinsics)
    work = Path(work_dir)
    if work.exists():
        shutil.rmtree(work)
    (work / "sparse").mkdir(parents=True)
    return work, work / "database.db"


@contextlib.contextmanager
def _colmap_logging(pycolmap, config: SfmConfig) -> Iterator[None]:
    """COLMAP's random seed set from ``config``, and its log level INFO when ``config.verbose``, else errors only,
    restored afterwards. Not warnings: the triangulator logs every image, and bundle adjustment logs each step its
    solver retries ("Linear solver failure ... Cholesky", 48 lines in one demo run); what the reconstruction became
    (registered images, sub-models, errors) is reported from its result."""
    pycolmap.set_random_seed(config.seed)
    old_level = pycolmap.logging.minloglevel
    pycolmap.logging.minloglevel = 0 if config.verbose else 2
    try:
        yield
    finally:
        pycolmap.logging.minloglevel = old_level


def _mapper_options(pycolmap, config: SfmConfig):
    """COLMAP's mapper options with ``config``'s threads, seed and minimum matches per image pair."""
    options = pycolmap.IncrementalPipelineOptions()
    options.num_threads = config.num_threads
    options.random_seed = config.seed
    options.min_num_matches = config.min_num_matches
    return options


def _pipeline(
    pycolmap, image_dir: Path, names: list[str], work: Path, database: Path, config: SfmConfig,
    intrinsics: Intrinsics | None, step: Callable[[str], None],
) -> SfmResult:
    """The COLMAP steps of :func:`run_sfm` (arguments as there; ``step`` reports progress)."""
    _features_and_matches(pycolmap, image_dir, names, database, config, intrinsics, step)
    options = _mapper_options(pycolmap, config)
    options.multiple_models = config.all_models
    if intrinsics is not None and not config.refine_intrinsics:
        options.ba_refine_focal_length = False
        options.ba_refine_principal_point = False
        options.ba_refine_extra_params = False
    step("mapping")
    models = pycolmap.incremental_mapping(database, image_dir, work / "sparse", options=options)
    return _result_from_models(models, total=len(names), all_models=config.all_models)


def _features_and_matches(
    pycolmap, image_dir: Path, names: list[str], database: Path, config: SfmConfig, intrinsics: Intrinsics | None,
    step: Callable[[str], None],
) -> None:
    """SIFT features of ``names`` (one camera: ``intrinsics`` or ``config.camera_model``) and their verified matches
    (``config.matcher``), written to the new COLMAP ``database``."""
    reader = pycolmap.ImageReaderOptions()
    if intrinsics is not None:
        camera = ColmapCamera.from_intrinsics(1, intrinsics)  # the lens model too
        reader.camera_model = camera.model
        reader.camera_params = ",".join(repr(float(v)) for v in camera.params)
    else:
        reader.camera_model = config.camera_model
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


def triangulate_known_poses(
    image_dir: str | os.PathLike,
    image_names: Sequence[str],
    c2w_opencv: np.ndarray,
    intrinsics: Intrinsics,
    work_dir: str | os.PathLike,
    config: SfmConfig = SfmConfig(),
    progress: Callable[[str], None] | None = None,
) -> SfmResult:
    """Sparse 3D points of images whose camera and poses are known (a robot's VIO or odometry): SIFT features,
    matching as :func:`run_sfm`, then COLMAP's point triangulator with the poses and the camera held fixed.

    Args:
        image_dir: folder holding the images.
        image_names: their file names, in time order.
        c2w_opencv: (V, 4, 4) camera-to-world pose of each image (OpenCV axes, metres).
        intrinsics: the camera of every image (lens included).
        work_dir: scratch folder for the COLMAP database and the model (``work_dir/sparse/0``; emptied first).
        config: feature, matching and threading settings (``camera_model`` and the mapper's are not used).
        progress: called with the name of each step as it starts.

    Returns:
        one model: the given poses (every image counts as registered) and the triangulated points, in the poses'
        frame and units.

    Raises:
        ValueError: no images, poses of another count, or an image's size differs from ``intrinsics``;
        FileNotFoundError: an image is missing.
    """
    import pycolmap

    image_dir, names = Path(image_dir), list(image_names)
    c2w = np.asarray(c2w_opencv, dtype=np.float64)
    if c2w.shape != (len(names), 4, 4):
        raise ValueError(f"triangulate_known_poses: {len(names)} images need ({len(names)}, 4, 4) poses, got "
                         f"{c2w.shape}")
    work, database = _new_work_folder(image_dir, names, work_dir, intrinsics, "triangulation")
    step = progress or (lambda _s: None)
    with _colmap_logging(pycolmap, config):
        _features_and_matches(pycolmap, image_dir, names, database, config, intrinsics, step)
        known = pycolmap.Reconstruction()
        pose_of = dict(zip(names, c2w))
        db = pycolmap.Database.open(database)
        try:
            for camera in db.read_all_cameras():
                known.add_camera_with_trivial_rig(camera)
            for image in db.read_all_images():
                cam_from_world = np.linalg.inv(pose_of[image.name])[:3, :4]
                known.add_image_with_trivial_frame(
                    pycolmap.Image(name=image.name, camera_id=image.camera_id, image_id=image.image_id),
                    pycolmap.Rigid3d(cam_from_world))
        finally:
            db.close()
        step("triangulation")
        (work / "sparse" / "0").mkdir()
        model = pycolmap.triangulate_points(known, database, image_dir, work / "sparse" / "0",
                                            options=_mapper_options(pycolmap, config), refine_intrinsics=False)
    return _result_from_models({0: model}, total=len(names))


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


def _result_from_models(models: Mapping[int, object], total: int, all_models: bool = True) -> SfmResult:
    """Pooled statistics of every sub-model (``all_models``) or of the one with the most registered images."""
    recs = sorted(models.values(), key=lambda r: (r.num_reg_images(), r.num_points3D()), reverse=True)
    recs = [r for r in recs if r.num_reg_images() > 0][: None if all_models else 1]
    if not recs:
        return SfmResult(total, 0, 0, None, None)
    parts = tuple(_model_from_reconstruction(r) for r in recs)
    errors = np.concatenate([m.point_errors_px for m in parts])
    registered = sum(len(m.poses_c2w) for m in parts)
    return SfmResult(
        total_images=total,
        registered_images=registered,
        points3d=len(errors),
        reprojection_error_px=float(errors.mean()) if len(errors) else None,
        observations_per_image=sum(m.observations for m in parts) / registered,
        models=parts,
    )


def ring_cell(ring: dict, total_observations: int) -> str:
    """One ring of :meth:`SfmResult.errors_by_radius` as text: share of the observations · mean error (px),
    e.g. ``32% · 0.153``."""
    error = ring["mean_error_px"]
    share = 100.0 * ring["observations"] / max(total_observations, 1)
    return f"{share:.0f}% · " + ("n/a" if error is None else f"{error:.3f}")


def _model_from_reconstruction(rec) -> SfmModel:
    """Poses (camera-to-world, OpenCV axes), points, colours, point errors and observation count of one sub-model."""
    poses, observed = {}, []
    for image_id in rec.reg_image_ids():
        image = rec.image(image_id)
        rigid = image.cam_from_world()
        cam_from_world = np.eye(4)
        cam_from_world[:3, :4] = rigid.matrix()
        poses[image.name] = np.linalg.inv(cam_from_world)
        camera = rec.camera(image.camera_id)
        half_diagonal = 0.5 * float(np.hypot(camera.width, camera.height))
        for p2d in image.points2D:
            if not p2d.has_point3D():
                continue
            xy = np.asarray(p2d.xy, dtype=np.float64)
            projected = camera.img_from_cam(rigid * rec.points3D[p2d.point3D_id].xyz)
            error = np.inf if projected is None else float(np.linalg.norm(np.asarray(projected) - xy))
            radius = float(np.hypot(xy[0] - 0.5 * camera.width, xy[1] - 0.5 * camera.height)) / half_diagonal
            observed.append((xy[0], xy[1], error, radius))
    points = list(rec.points3D.values())
    return SfmModel(
        poses_c2w=poses,
        points_xyz=np.array([p.xyz for p in points], dtype=np.float64).reshape(-1, 3),
        points_rgb=np.array([p.color for p in points], dtype=np.uint8).reshape(-1, 3),
        point_errors_px=np.array([p.error for p in points], dtype=np.float64),
        observations=int(sum(p.track.length() for p in points)),
        observation_errors=np.array(observed, dtype=np.float64).reshape(-1, 4),
    )


def load_sfm_result(sparse_root: str | os.PathLike, total_images: int | None = None) -> SfmResult:
    """The :class:`SfmResult` of a finished run from its COLMAP models (``sparse_root/<k>/``, as written by
    :func:`run_sfm` under ``work_dir/sparse``); ``total_images`` defaults to the registered ones.

    Raises:
        FileNotFoundError: ``sparse_root`` holds no COLMAP model. InputError: a model's files are damaged (named).
    """
    import pycolmap

    root = Path(sparse_root)
    dirs = sorted(d for d in root.iterdir() if d.is_dir()) if root.is_dir() else []
    dirs = [d for d in dirs if (d / "images.bin").is_file() or (d / "images.txt").is_file()]
    if not dirs:
        raise FileNotFoundError(f"{root}: no COLMAP model (expected numbered folders with images.bin)")
    models = {}
    for k, d in enumerate(dirs):
        try:
            models[k] = pycolmap.Reconstruction(str(d))
        except Exception as exc:  # noqa: BLE001 - pycolmap reports a damaged model as IndexError, ValueError, ...
            detail = " ".join(str(exc).split())[:200] or type(exc).__name__
            raise InputError(f"{d}: unreadable COLMAP model ({detail})") from None
    registered = sum(r.num_reg_images() for r in models.values())
    return _result_from_models(models, total=registered if total_images is None else total_images)


def ring_table(runs: dict[str, Path], bins: int) -> str:
    """Markdown table of :meth:`evaluation.sfm.SfmResult.errors_by_radius` for every labelled sparse folder."""
    rows = []
    for label, sparse in runs.items():
        result = load_sfm_result(sparse)
        rings = result.errors_by_radius(bins)
        total = sum(r["observations"] for r in rings)
        cells = [ring_cell(r, total) for r in rings]
        mean = "n/a" if result.reprojection_error_px is None else f"{result.reprojection_error_px:.3f}"
        rows.append(f"| {label} | {total} | {mean} | " + " | ".join(cells) + " |")
    edges = [f"r {k / bins:.2f}–{(k + 1) / bins:.2f}" for k in range(bins)]
    header = "| run | observations | reprojection error (px) | " + " | ".join(edges) + " |"
    return "\n".join([header, "|" + "---|" * (3 + bins)] + rows)
