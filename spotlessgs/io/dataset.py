"""One entry point for the trainer: read any supported dataset folder into a :class:`DatasetDescription`.

Supported layouts:

* our dataset folder or any nerfstudio folder: ``transforms.json`` (see :mod:`spotlessgs.io.transforms`);
* a plain COLMAP folder: ``images/`` + ``sparse/0/`` (or ``sparse/``) with a text or binary model. Images are
  ordered by name, the split is every 11th frame, there is no ground truth and no light truth.
"""

from __future__ import annotations

import glob
import logging
import os
from pathlib import Path
from typing import Any

import numpy as np

from spotlessgs.io.cameras import opencv_to_opengl_c2w
from spotlessgs.io.colmap_text import model_files, read_colmap_model
from spotlessgs.io.errors import InputError
from spotlessgs.io.images import is_image_name, natural_order
from spotlessgs.io.json_files import read_json
from spotlessgs.io.lens import check_invertible
from spotlessgs.io.ply import PointCloud, read_point_cloud
from spotlessgs.io.transforms import DatasetDescription, DatasetError, Split, read_transforms

log = logging.getLogger(__name__)


def _find_sparse_dir(folder: Path) -> Path:
    for candidate in (folder / "sparse" / "0", folder / "sparse"):
        if (candidate / "cameras.bin").is_file() or (candidate / "cameras.txt").is_file():
            return candidate
    raise FileNotFoundError(f"{folder}: no COLMAP model in sparse/0 or sparse (cameras.bin or cameras.txt)")


def read_colmap_dataset(folder: str | os.PathLike, check_files: bool = False) -> DatasetDescription:
    """Read a COLMAP folder (``images/`` + ``sparse/0``) whose cameras (one, or several: a rig, or COLMAP's camera per
    image) are of supported models (:data:`spotlessgs.io.colmap_text.SUPPORTED_MODELS`) with lenses that can be
    inverted over their images. With a ``raw/``
    folder (DarkGS's layout) the frames are ``raw/``'s, linear (``meta["linear_images"]``), matched by file stem."""
    folder = Path(folder)
    sparse = _find_sparse_dir(folder)
    model = read_colmap_model(sparse)
    if not model.images:
        raise DatasetError(f"{sparse}: COLMAP model has no registered images")
    images = sorted(model.images.values(), key=lambda im: natural_order(im.name))  # frame_2 before frame_10
    for im in images:  # names are relative to the images folder: one that leaves it is damage, not a frame
        if not im.name or Path(im.name).is_absolute() or ".." in Path(im.name).parts:
            raise DatasetError(f"{model_files(sparse)[1]}: image {im.image_id} is named {im.name!r}; COLMAP names a "
                               "frame by its path inside the images folder")
    names = [im.name for im in images]
    if len(set(names)) < len(names):
        twice = next(n for n, m in zip(names, names[1:]) if n == m)
        raise DatasetError(f"{model_files(sparse)[1]}: two images are named {twice!r}")
    try:
        intrinsics = {cid: model.cameras[cid].to_intrinsics() for cid in {im.camera_id for im in images}}
    except ValueError as exc:  # a camera model we cannot use: name the file that defines it
        raise DatasetError(f"{model_files(sparse)[0]}: {exc}") from None
    for cid, camera in sorted(intrinsics.items()):
        check_invertible(camera, f"{model_files(sparse)[0]}: COLMAP camera {cid}")
    c2w_opencv = np.stack([im.c2w_opencv() for im in images])
    image_paths = tuple(folder / "images" / im.name for im in images)
    meta: dict = {"source_format": "colmap", "sparse_dir": str(sparse)}
    if (folder / "raw").is_dir():  # DarkGS's layout: COLMAP ran on brightened copies, training uses raw/
        image_paths = tuple(_raw_frame(folder / "raw", im.name) for im in images)
        meta = {**meta, "source_format": "darkgs", "linear_images": True}
    if check_files:
        for im, p in zip(images, image_paths):
            if not p.is_file():
                raise FileNotFoundError(f"{sparse}: image {im.image_id} file {p} does not exist")
    n = len(images)
    return DatasetDescription(
        root=folder,
        source=sparse,
        cameras=tuple(intrinsics[im.camera_id] for im in images),
        c2w_opengl=opencv_to_opengl_c2w(c2w_opencv),
        c2w_opencv=c2w_opencv,
        file_paths=tuple(f"images/{im.name}" for im in images),
        image_paths=image_paths,
        gt_paths=(None,) * n,
        exr_paths=(None,) * n,
        split=Split.every_nth(n),
        light=None,
        ply_path=None,
        meta=meta,
    )


def _raw_frame(raw: Path, name: str) -> Path:
    """The frame of ``raw/`` with the stem of the registered image ``name`` (any image suffix): DarkGS keeps the
    linear (RAW-like) frames there and their brightened copies in ``input/`` or ``images/``; DatasetError when
    there is none or more than one."""
    stem = Path(name).stem
    found = sorted(p for p in raw.glob(f"{glob.escape(stem)}.*") if is_image_name(p.name))
    if len(found) != 1:
        raise DatasetError(f"{raw}: {'no' if not found else len(found)} linear frame(s) for the registered image "
                           f"{name} (DarkGS layout: raw/<name> beside sparse/0)")
    return found[0]


def read_dataset(folder: str | os.PathLike, check_files: bool = False) -> DatasetDescription:
    """Read ``transforms.json`` when the folder has one, else a COLMAP model under ``sparse/``."""
    folder = Path(folder)
    if folder.is_file():
        return read_transforms(folder, check_files=check_files)
    if (folder / "transforms.json").is_file():
        return read_transforms(folder / "transforms.json", check_files=check_files)
    if (folder / "sparse").is_dir():
        return read_colmap_dataset(folder, check_files=check_files)
    raise FileNotFoundError(f"{folder}: neither transforms.json nor a COLMAP sparse/ folder")


#: The ground truths a dataset may hold: ``lamps`` (the lamps-on render, each frame's ``gt_file_path``) and
#: ``uniform`` (even, shadow-free environment light; ``spotless-sim render --gt uniform``).
GROUND_TRUTHS = ("lamps", "uniform")
#: The folder the simulator writes the uniform ground truth's PNGs to, beside ``gt/`` (same file names).
UNIFORM_GT_DIR = "gt_uniform"


def _ground_truth_folders(dataset: DatasetDescription) -> dict[str, Any]:
    """The renderer settings' ``ground_truths`` map (kind -> folder of its PNGs), {} when the dataset has none."""
    folders = (dataset.meta.get("renderer") or {}).get("ground_truths")
    return folders if isinstance(folders, dict) else {}


def available_ground_truths(dataset: DatasetDescription) -> tuple[str, ...]:
    """The ground truths of :data:`GROUND_TRUTHS` that ``dataset`` holds (``lamps`` when its frames have a
    ``gt_file_path``; the others when its renderer settings list their folder)."""
    folders = _ground_truth_folders(dataset)
    has_lamps = any(p is not None for p in dataset.gt_paths)
    return tuple(name for name in GROUND_TRUTHS if (has_lamps if name == "lamps" else name in folders))


def ground_truth_paths(dataset: DatasetDescription, which: str = "lamps") -> tuple[Path | None, ...]:
    """Each frame's ground-truth image of the kind ``which`` (see :data:`GROUND_TRUTHS`): ``lamps`` are the frames'
    ``gt_file_path``; another kind has the same file name in the folder its renderer settings name.

    Raises:
        DatasetError: ``which`` is unknown, or the dataset was rendered without it (naming the file).
    """
    if which not in GROUND_TRUTHS:
        raise DatasetError(f"unknown ground truth {which!r}; choose from {list(GROUND_TRUTHS)}")
    if which == "lamps":
        return tuple(dataset.gt_paths)
    folder = _ground_truth_folders(dataset).get(which)
    if not isinstance(folder, str) or not folder or Path(folder).is_absolute() or ".." in Path(folder).parts:
        raise DatasetError(f"{dataset.source}: the dataset has no {which!r} ground truth (render it with "
                           f"`spotless-sim render --gt {which}`)")
    return tuple(None if p is None else dataset.root / folder / p.name for p in dataset.gt_paths)


def true_exposure_gains(dataset: DatasetDescription) -> tuple[float, ...] | None:
    """Each frame's true exposure gain where the dataset is a simulated robot camera's copy (``spotless-sim add-noise
    --robot-camera``: its ``camera_effects`` block names the record, whose ``gains`` map image file names to gains);
    None for any other dataset, or when a frame has no gain.

    Raises:
        InputError: the record is not a readable JSON object or its gains are not a name → number map (named).
    """
    effects = dataset.meta.get("camera_effects")
    record = effects.get("record") if isinstance(effects, dict) else None
    if not isinstance(record, str) or not (dataset.root / record).is_file():
        return None
    gains = read_json(dataset.root / record, "a robot camera's exposure record").get("gains")
    if not isinstance(gains, dict) or not all(isinstance(v, (int, float)) for v in gains.values()):
        raise InputError(f"{dataset.root / record}: 'gains' must map image file names to numbers")
    names = [p.name for p in dataset.image_paths]
    return tuple(float(gains[n]) for n in names) if all(n in gains for n in names) else None


def load_initial_points(dataset: DatasetDescription) -> PointCloud | None:
    """The initial point cloud: the PLY named by the dataset, else the COLMAP model's 3D points, else None; relative
    to the dataset's :attr:`~spotlessgs.io.transforms.DatasetDescription.working_origin`, as its cameras. Points
    whose position (or normal) is not finite (a depth camera's invalid pixels, exported as NaN) are left out with a
    warning; InputError naming the file where none is left."""
    origin = dataset.working_origin
    if dataset.ply_path is not None:
        source, cloud = dataset.ply_path, read_point_cloud(dataset.ply_path, origin)
    elif dataset.meta.get("sparse_dir") is not None:
        points = read_colmap_model(dataset.meta["sparse_dir"]).points
        if not len(points.ids):
            return None
        source = model_files(dataset.meta["sparse_dir"])[2]
        cloud = PointCloud((points.xyz.astype(np.float64) - origin).astype(np.float32), points.rgb, None)
    else:
        return None
    finite = np.isfinite(cloud.xyz).all(axis=1)
    if cloud.normals is not None:
        finite &= np.isfinite(cloud.normals).all(axis=1)
    if finite.all():
        return cloud
    if not finite.any():
        raise InputError(f"{source}: none of its {len(finite)} points has a finite position")
    log.warning("%s: %d of %d points left out (a position or normal that is not finite)", source,
                int((~finite).sum()), len(finite))
    return PointCloud(cloud.xyz[finite], cloud.rgb[finite], None if cloud.normals is None else cloud.normals[finite])
