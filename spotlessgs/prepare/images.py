"""``spotless prepare --images DIR --out DATA``: a folder of spotlit frames becomes a dataset (COLMAP model + images).

Dark spotlit frames starve feature detectors, so structure from motion runs on brightened copies (a light blur against
the sensor noise, then CLAHE on the lightness, ``spotlessgs.baselines2d.clahe``, as DarkGS brightens its frames for
COLMAP) while the dataset keeps the original frames for training. The camera (model given, intrinsics estimated by
bundle adjustment unless given) and the poses come from pycolmap's incremental mapper (``evaluation.sfm.run_sfm``,
sequential matching for video order). The largest model becomes ``DATA/sparse/0``; every frame it does not register is
named in the summary and in a warning, never dropped silently.

    DATA/images/          the original frames (copied)
    DATA/sparse/0/        the COLMAP model of the registered frames (binary)
    DATA/sfm/             the brightened copies and COLMAP's work folder
    DATA/prepare.json     what registered, the camera, and (with --truth) the pose error after similarity alignment
"""

from __future__ import annotations

import contextlib
import dataclasses
import logging
import shutil
from collections.abc import Callable, Iterator, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from evaluation.sfm import SfmConfig, run_sfm
from evaluation.trajectory import trajectory_errors
from spotlessgs.baselines2d.clahe import clahe
from spotlessgs.io.atomic import atomic_path, partial_sibling, swap_in_folder, write_json
from spotlessgs.io.cameras import Intrinsics
from spotlessgs.io.colmap_text import read_colmap_model
from spotlessgs.io.dataset import read_dataset
from spotlessgs.io.errors import InputError
from spotlessgs.io.folder_lock import folder_lock
from spotlessgs.io.frame_quality import noise_level
from spotlessgs.io.images import list_image_files, read_image, write_png
from spotlessgs.io.json_files import read_json
from spotlessgs.io.paths import refuse_foreign_folder, refuse_overlap
from spotlessgs.io.provenance import provenance
from spotlessgs.training.validation import evenly_spaced

log = logging.getLogger(__name__)

SUMMARY_FILE = "prepare.json"
#: Written into ``--out`` before anything else (the summary comes last): an interrupted prepare's folder is its own.
STARTED_FILE = ".spotless_prepare.json"
# Beside the brightened copies: which file and blur made each one (write_brightened_copies), and how often it is saved.
COPIES_RECORD = "sources.json"
COPIES_RECORD_EVERY = 50
# Registration below this share of the frames is reported as a warning (the dataset is still written).
MIN_REGISTERED_SHARE = 0.9


# Gaussian blur (standard deviation, pixels) of noisy frames before CLAHE brightens them: CLAHE lifts the sensor
# noise of the dark periphery with the signal, and SIFT then matches noise. Measured on the bedroom's robot-camera
# copies (60 frames of 160x120, noise shot 0.002 / read 0.004 at sensitivity 0.25), largest model without -> with the
# blur: the robot's camera path 31 -> 60 of 60 frames, the paper's loop 2 -> 16 (as many as its noise-free renders,
# whose four sides share no view); sigma 1.5 lost frames (14 of 60), non-local-means denoising lost all (2 of 60). On
# clean frames the blur costs detail (the ray-cast test room: focal length 280 px instead of 217.5, truth 216), so it
# is applied only to a sequence whose noise level reaches NOISY_FRAMES.
DENOISE_SIGMA_PX = 0.7
# Median noise level (spotlessgs.io.frame_quality.noise_level, grey, sRGB encoding) from which frames are blurred:
# clean renders measure 0.003-0.007, the sensor-noise and robot-camera copies 0.017-0.018.
NOISY_FRAMES = 0.01
# Frames (evenly spaced) whose noise level decides.
NOISE_SAMPLE = 24


def brighten(image: np.ndarray, blur_sigma: float = 0.0) -> np.ndarray:
    """(H, W, 3) sRGB in [0, 1] -> the copy SfM sees: a Gaussian blur of ``blur_sigma`` pixels against sensor noise
    (none at 0; see :func:`brightening_blur`), then CLAHE of its lightness (dark corners get features too)."""
    if blur_sigma > 0:
        import cv2

        image = np.clip(cv2.GaussianBlur(np.ascontiguousarray(image, dtype=np.float32), (0, 0), blur_sigma), 0, 1)
    return clahe(image)


def brightening_blur(images: Sequence[np.ndarray]) -> tuple[float, float]:
    """(median noise level of ``images`` (sRGB in [0, 1]), the blur for :func:`brighten`: DENOISE_SIGMA_PX when that
    level reaches NOISY_FRAMES, else 0)."""
    level = float(np.median([noise_level(image) for image in images])) if images else 0.0
    return level, DENOISE_SIGMA_PX if level >= NOISY_FRAMES else 0.0


def write_brightened_copies(folder: Path, sources: Sequence[tuple[str, Path]], read: Callable[[Path], np.ndarray],
                            blur: float) -> None:
    """Write ``folder/name``, :func:`brighten` (with ``blur``) of ``read(path)``, for each (name, path) of ``sources``.

    A copy from an earlier run is reused only where ``folder/COPIES_RECORD`` says it was made from the same file (its
    path, size and modification time) with the same blur: an interrupted run resumes, and frames that changed since
    (the same names re-extracted from another video) are brightened again instead of feeding SfM the old ones. The
    record is written every :data:`COPIES_RECORD_EVERY` copies and at the end, always after the copies it names."""
    record_path = folder / COPIES_RECORD
    try:
        record = read_json(record_path, "the record of the brightened copies") if record_path.is_file() else {}
    except InputError as exc:  # a damaged record only costs the copies it named
        log.warning("%s; brightening every frame again", exc)
        record = {}
    written = 0
    for name, path in sources:
        status = path.stat()
        origin = [str(path.resolve()), status.st_size, status.st_mtime_ns, blur]
        if record.get(name) == origin and (folder / name).is_file():
            continue
        write_png(folder / name, brighten(read(path), blur))
        record[name] = origin
        written += 1
        if written % COPIES_RECORD_EVERY == 0:
            write_json(record_path, record)
    if written or not record_path.is_file():
        write_json(record_path, record)


def _read_frames(names: list[Path]) -> tuple[int, int]:
    """(width, height) shared by every frame; InputError naming a frame that cannot be decoded or has another size."""
    size = None
    for path in names:
        try:
            image = read_image(path)
        except (OSError, ValueError) as exc:
            raise InputError(f"{path}: cannot be decoded as an image ({exc})") from None
        if size is None:
            size = (image.shape[1], image.shape[0])
        elif (image.shape[1], image.shape[0]) != size:
            raise InputError(f"{path}: image is {image.shape[1]}x{image.shape[0]}, the first frame {names[0].name} is "
                             f"{size[0]}x{size[1]}; one camera needs one image size")
    return size


def prepare_images(
    images_dir: str | Path, out: str | Path, camera_model: str = "SIMPLE_RADIAL", matcher: str = "sequential",
    intrinsics: Intrinsics | None = None, truth: str | Path | None = None, threads: int = 1, seed: int = 0,
    progress: Callable[[str], None] | None = None,
) -> dict[str, Any]:
    """Turn the frames in ``images_dir`` into a COLMAP dataset in ``out`` (see the module docstring).

    Args:
        images_dir: the spotlit frames, in time order by file name.
        out: the dataset folder to write (must not overlap ``images_dir``).
        camera_model: the COLMAP model estimated (``OPENCV``, ``SIMPLE_RADIAL``, ``OPENCV_FISHEYE``, ...) when
            ``intrinsics`` is not given.
        matcher: ``sequential`` (video order) or ``exhaustive``.
        intrinsics: the known camera (kept fixed), or None.
        truth: a dataset whose poses are the truth for these frames (by file name): the summary then has the pose
            error after similarity alignment.
        threads, seed: COLMAP's threads and random seed.
        progress: called with each step's name.
    Returns:
        the summary written to ``out/prepare.json``.
    Raises:
        InputError: a frame cannot be decoded or has another size, ``out`` overlaps the input, or SfM registered
            fewer than two frames (the summary is written first).
    """
    images_dir, out = Path(images_dir), Path(out)
    refuse_overlap(out, {"--images": images_dir}, "--out")
    frames = checked_frames(images_dir)  # before anything is written
    with prepared_folder(out, {"images": str(images_dir.resolve())}):
        return write_image_dataset(images_dir, frames, out, camera_model, matcher, intrinsics, truth, threads, seed,
                                   progress)


def checked_frames(images_dir: Path) -> list[Path]:
    """The frames of ``images_dir`` in time (natural file-name) order; InputError naming a frame that cannot be
    decoded, has another size than the first, or whose dataset name would clash with another's."""
    frames = list_image_files(images_dir)
    _check_copy_names(images_dir, frames)
    _read_frames(frames)
    return frames


@contextlib.contextmanager
def prepared_folder(out: Path, source: dict[str, Any]) -> Iterator[None]:
    """Hold ``out`` for one prepare: refuse a folder of files that no prepare began (InputError: its dataset files
    would be overwritten or mixed with ours), lock it (a second prepare into it: FolderLockedError), and mark it as
    begun by this command (``source``: what it is prepared from)."""
    refuse_foreign_folder(out, [SUMMARY_FILE, STARTED_FILE], "--out", "a dataset that `spotless prepare` began")
    with folder_lock(out, "spotless prepare"):
        if not (out / STARTED_FILE).is_file():
            write_json(out / STARTED_FILE, {"source": source, "provenance": provenance()})
        yield


def write_image_dataset(images_dir: Path, frames: list[Path], out: Path, camera_model: str, matcher: str,
                        intrinsics: Intrinsics | None, truth: str | Path | None, threads: int, seed: int,
                        progress: Callable[[str], None] | None, source_name: str | None = None) -> dict[str, Any]:
    """:func:`prepare_images` of the :func:`checked_frames` ``frames`` of ``images_dir`` with ``out`` held
    (:func:`prepared_folder`); ``source_name``: how messages name the frames (a bag's topic, whose frames were
    written to the temporary ``images_dir``)."""
    label = source_name or str(images_dir)
    names = [p.name for p in frames]
    step = progress or (lambda _name: None)
    step("brightened copies")
    noise, blur = brightening_blur([read_image(frames[k]) for k in evenly_spaced(range(len(frames)), NOISE_SAMPLE)])
    brightened = out / "sfm" / "input"
    sfm_names = copy_names(frames)
    write_brightened_copies(brightened, list(zip(sfm_names, frames)), read_image, blur)
    # every sub-model the mapper can build (it starts a new one where registration breaks off), the largest kept: with
    # one model only, a mapper whose first initial pair was poor stopped there (the robot camera's noisy frames: 2 of
    # 60 registered, against 60 of 60 in the largest of two models)
    config = SfmConfig(matcher=matcher, num_threads=threads, seed=seed, camera_model=camera_model, all_models=True)
    result = run_sfm(brightened, sfm_names, out / "sfm" / "work", config, intrinsics, progress=step)
    model_dir = _largest_model(out / "sfm" / "work" / "sparse")
    registered = set() if model_dir is None else {im.name for im in read_colmap_model(model_dir).images.values()}
    missing = [n for n, s in zip(names, sfm_names) if s not in registered]
    summary: dict[str, Any] = {
        "images": source_name or str(images_dir.resolve()), "frames": len(names),
        "registered": len(names) - len(missing),
        "not_registered": missing, "camera_model": camera_model if intrinsics is None else "given",
        "matcher": matcher, "brightening": {"noise_level": noise, "blur_sigma_px": blur}, "sfm": result.summary(),
        "provenance": provenance(seed=seed, extra_packages=("pycolmap",)),
    }
    if model_dir is not None:
        # an earlier prepare's posed dataset would be read instead of this model (transforms.json comes first)
        (out / "transforms.json").unlink(missing_ok=True)
        _write_dataset(frames, sfm_names, model_dir, out)
        try:
            summary["camera"] = dataclasses.asdict(read_dataset(out).intrinsics)
        except InputError as exc:  # e.g. a many-parameter lens fitted to too few features folds the image
            summary["error"] = str(exc)
            write_json(out / SUMMARY_FILE, summary)
            raise InputError(f"{label}: structure from motion estimated a {camera_model} camera that cannot be "
                             f"used ({exc}); try a simpler --camera-model such as {_simpler_model(camera_model)}"
                             ) from None
        if truth is not None:
            summary["pose_error"] = pose_error(out, Path(truth), {c: f"{p.stem}.png" for c, p in zip(sfm_names, frames)})
    write_json(out / SUMMARY_FILE, summary)
    if summary["registered"] < 2:
        raise InputError(f"{label}: structure from motion registered {summary['registered']} of {len(names)} "
                         f"frames; no dataset written (see {out / SUMMARY_FILE})")
    if missing:
        log.warning("%s: %d of %d frames did not register and are not in the dataset: %s", label, len(missing),
                    len(names), ", ".join(missing))
    if summary["registered"] < MIN_REGISTERED_SHARE * len(names):
        log.warning("%s: only %.0f%% of the frames registered", label, 100 * summary["registered"] / len(names))
    return summary


def copy_names(frames: list[Path]) -> list[str]:
    """The names of the frames' PNG copies, for SfM and the dataset (``frames`` in natural order): the file stems,
    as ``NNNNNN_stem.png`` when their text order differs from the frames' order (``frame_2`` before ``frame_10``),
    since COLMAP's sequential matcher and the dataset's frames follow the text order of the names."""
    names = [f"{p.stem}.png" for p in frames]
    if names == sorted(names):
        return names
    width = max(6, len(str(len(frames) - 1)))
    return [f"{k:0{width}d}_{name}" for k, name in enumerate(names)]


def _check_copy_names(images_dir: Path, frames: list[Path]) -> None:
    """InputError where two frames would share a name in the dataset: their PNG copies are named by the file stem
    (``a.jpg`` and ``a.png``, ``a.JPG`` and ``a.jpg`` both become ``a.png``; ``a.png`` and ``A.png`` are one file on
    macOS and Windows)."""
    seen: dict[str, Path] = {}
    for path in frames:
        name = f"{path.stem}.png"
        if name.casefold() in seen:
            raise InputError(f"{images_dir}: {seen[name.casefold()].name} and {path.name} would both become {name} "
                             "in the dataset (up to letter case); rename one of them")
        seen[name.casefold()] = path


def _simpler_model(camera_model: str) -> str:
    """A camera model with fewer lens parameters than ``camera_model`` (for the hint of a lens that folds)."""
    return "SIMPLE_RADIAL" if camera_model in ("RADIAL", "OPENCV", "FULL_OPENCV", "OPENCV_FISHEYE") else "PINHOLE"


def _largest_model(sparse: Path) -> Path | None:
    """The sub-model folder of ``sparse`` with the most registered images, or None."""
    best, count = None, 0
    for folder in sorted(p for p in sparse.iterdir() if p.is_dir()) if sparse.is_dir() else []:
        images = len(read_colmap_model(folder).images)
        if images > count:
            best, count = folder, images
    return best


def _write_dataset(frames: list[Path], sfm_names: list[str], model_dir: Path, out: Path) -> None:
    """``out/images`` (the originals, under their names as registered) and ``out/sparse/0`` (the model)."""
    for path, name in zip(frames, sfm_names):
        target = out / "images" / name
        if path.suffix.lower() == ".png":
            with atomic_path(target) as tmp:
                shutil.copy2(path, tmp)
        else:  # the model names the frames by their PNG copies: store the original pixels as PNG too, a 16-bit
            write_png(target, read_image(path), bits=None)  # frame's in 16 bits
    sparse = out / "sparse" / "0"  # the new model replaces an earlier run's in one step
    sparse.parent.mkdir(parents=True, exist_ok=True)
    tmp = partial_sibling(sparse)
    try:
        shutil.copytree(model_dir, tmp)
        swap_in_folder(tmp, sparse)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise


def pose_error(out: Path, truth: Path, truth_names: dict[str, str] | None = None) -> dict[str, Any] | None:
    """ATE (m, after similarity alignment) and mean relative rotation error of the dataset's poses against the
    poses of the same file names in ``truth`` (``truth_names``: the name in ``truth`` of a dataset frame named
    otherwise, e.g. a :func:`copy_names` copy)."""
    mine, true = read_dataset(out), read_dataset(truth)
    true_by_name = {p.name: c for p, c in zip(true.image_paths, true.c2w_opencv)}
    names = [(truth_names or {}).get(p.name, p.name) for p in mine.image_paths]
    common = [i for i, name in enumerate(names) if name in true_by_name]
    if len(common) < 3:
        return None
    errors = trajectory_errors(mine.c2w_opencv[common], np.stack([true_by_name[names[i]] for i in common]))
    return {"poses": len(common), "ate_rmse_m": errors.ate_rmse, "ate_mean_m": errors.ate_mean,
            "rre_mean_deg": errors.rre_mean_deg, "sim3_scale": errors.alignment.scale}
