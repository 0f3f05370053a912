"""A dataset's fingerprint: one hash of every file training reads from it.

A run records it (``run.json``'s ``data_fingerprint``) so that later a resume, or a benchmark about to reuse a
finished run, can tell the run's own dataset from another one, wherever either lies: the hash covers each file's
path relative to the dataset folder and its bytes, so a dataset moved or copied as a whole keeps its fingerprint, and
a changed, added or removed frame, pose or point cloud changes it. The ground truths are not training input and are
left out (a dataset rendered again with another ground truth trains the same).
"""

from __future__ import annotations

import hashlib
import os
from pathlib import Path

from spotlessgs.io.errors import InputError
from spotlessgs.io.transforms import DatasetDescription

#: What a fingerprint starts with (the hash that makes it), so that another hash can follow without confusion.
FINGERPRINT_PREFIX = "sha256:"
#: A COLMAP model's files (text or binary), those of them that exist are hashed.
COLMAP_MODEL_FILES = ("cameras.txt", "images.txt", "points3D.txt", "cameras.bin", "images.bin", "points3D.bin")


def training_input_files(dataset: DatasetDescription) -> list[Path]:
    """The files training reads from ``dataset``, each once, in a fixed order: its description (``transforms.json``,
    or the COLMAP model's files), each frame's image and its exposure sidecar (``<image>.json``, where there is one:
    :mod:`spotlessgs.io.exposure`), and its initial point cloud (where there is one)."""
    source = Path(dataset.source)
    described = ([source / name for name in COLMAP_MODEL_FILES if (source / name).is_file()] if source.is_dir()
                 else [source])
    frames: list[Path] = []
    for image in dataset.image_paths:
        sidecar = Path(image).with_suffix(".json")
        frames += [Path(image), sidecar] if sidecar.is_file() else [Path(image)]
    points = [Path(dataset.ply_path)] if dataset.ply_path is not None else []
    return list(dict.fromkeys(described + frames + points))


def dataset_fingerprint(dataset: DatasetDescription) -> str:
    """``sha256:<hex>`` over each of :func:`training_input_files` (its path relative to ``dataset.root``, POSIX
    separators, and the SHA-256 of its bytes), in that order.

    Raises:
        InputError: a file cannot be read (names it).
    """
    root = Path(dataset.root)
    whole = hashlib.sha256()
    for path in training_input_files(dataset):
        try:
            with open(path, "rb") as f:
                digest = hashlib.file_digest(f, "sha256").hexdigest()
        except OSError as exc:
            raise InputError(f"{path}: cannot read the dataset file ({exc.strerror or exc})") from None
        name = Path(os.path.relpath(path, root)).as_posix()
        whole.update(f"{name}\0{digest}\n".encode())
    return FINGERPRINT_PREFIX + whole.hexdigest()


def other_dataset(recorded: object, fingerprint: str) -> bool:
    """Whether a run whose ``run.json`` records the fingerprint ``recorded`` was trained on other files than those
    whose fingerprint is ``fingerprint``; False for a run saved before fingerprints (``recorded`` None), which has
    nothing to compare."""
    return recorded is not None and recorded != fingerprint
