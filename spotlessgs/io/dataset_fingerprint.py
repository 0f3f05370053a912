"""A dataset's fingerprint: one hash of everything training reads from it.

A run records it (``run.json``'s ``data_fingerprint``) so that later a resume, or a benchmark about to reuse a
finished run, can tell the run's own dataset from another one, wherever either lies: the hash covers each file's
path relative to the dataset folder and its content, so a dataset moved or copied as a whole keeps its fingerprint,
and a changed, added or removed frame, pose or point cloud changes it.

What training does not read is left out: the ground truths, and of ``transforms.json`` the frames' ground-truth and
depth paths and our block's ground-truth settings and provenance (:data:`NOT_TRAINING_INPUT`). A dataset rendered
again with another ground truth, or copied by a tool that rewrites the JSON's layout, keeps its fingerprint;
``transforms.json`` is hashed as its content (canonical JSON), the other files as their bytes.
"""

from __future__ import annotations

import hashlib
import json
import os
from pathlib import Path

from spotlessgs.io.colmap_text import model_files
from spotlessgs.io.errors import InputError
from spotlessgs.io.exposure import exposure_sidecar
from spotlessgs.io.transforms import DatasetDescription

#: What a fingerprint starts with (the hash that makes it), so that another hash can follow without confusion.
FINGERPRINT_PREFIX = "sha256:"
#: The entries of a ``transforms.json`` that training does not read: of each frame, and of our ``spotless`` block and
#: its ``renderer`` record.
NOT_TRAINING_INPUT = {"frame": ("gt_file_path", "exr_file_path", "depth_file_path"),
                      "spotless": ("provenance",), "renderer": ("ground_truths", "ground_truth_lighting")}


def training_input_files(dataset: DatasetDescription) -> list[Path]:
    """The files training reads from ``dataset``, each once, in a fixed order: its description (``transforms.json``,
    or the COLMAP model's files its reader reads), each frame's image and its exposure sidecar (``<image>.json``,
    where there is one: :mod:`spotlessgs.io.exposure`), and its initial point cloud (where there is one)."""
    source = Path(dataset.source)
    frames: list[Path] = []
    for image in dataset.image_paths:
        sidecar = exposure_sidecar(image)
        frames += [Path(image), sidecar] if sidecar.is_file() else [Path(image)]
    points = [Path(dataset.ply_path)] if dataset.ply_path is not None else []
    described = [p for p in model_files(source) if p.is_file()] if source.is_dir() else [source]
    return list(dict.fromkeys(described + frames + points))


def _training_content(record: object) -> object:
    """A ``transforms.json`` record without :data:`NOT_TRAINING_INPUT`."""
    if not isinstance(record, dict):
        return record
    kept = dict(record)
    if isinstance(kept.get("frames"), list):
        kept["frames"] = [{k: v for k, v in frame.items() if k not in NOT_TRAINING_INPUT["frame"]}
                          if isinstance(frame, dict) else frame for frame in kept["frames"]]
    if isinstance(kept.get("spotless"), dict):
        ours = {k: v for k, v in kept["spotless"].items() if k not in NOT_TRAINING_INPUT["spotless"]}
        if isinstance(ours.get("renderer"), dict):
            ours["renderer"] = {k: v for k, v in ours["renderer"].items() if k not in NOT_TRAINING_INPUT["renderer"]}
        kept["spotless"] = ours
    return kept


def _file_digests(path: Path, description: Path) -> tuple[str, str]:
    """SHA-256 (hex) of what training reads of ``path``, whole and without a start point cloud's name: for
    ``description`` (the dataset's ``transforms.json``) its training content in canonical JSON, and the same without
    its top-level ``ply_file_path``; for any other file its bytes, twice."""
    if path == description and path.suffix == ".json":
        try:
            record = json.loads(path.read_text(encoding="utf-8"))
        except (UnicodeDecodeError, json.JSONDecodeError) as exc:
            raise InputError(f"{path}: not a readable dataset description ({exc})") from None
        content = _training_content(record)
        without_cloud = {k: v for k, v in content.items() if k != "ply_file_path"} if isinstance(content, dict) \
            else content
        return _json_digest(content), _json_digest(without_cloud)
    with open(path, "rb") as f:
        digest = hashlib.file_digest(f, "sha256").hexdigest()
    return digest, digest


def _json_digest(content: object) -> str:
    """SHA-256 (hex) of ``content`` as canonical JSON (sorted keys, no spaces)."""
    return hashlib.sha256(json.dumps(content, sort_keys=True, separators=(",", ":")).encode()).hexdigest()


def dataset_fingerprint(dataset: DatasetDescription) -> str:
    """``sha256:<hex>`` over each of :func:`training_input_files`, in that order: its path relative to
    ``dataset.root`` (POSIX separators) and the SHA-256 of its content (``transforms.json`` without what training
    does not read, as canonical JSON; any other file, its bytes).

    Raises:
        InputError: a file cannot be read (names it).
    """
    return dataset_fingerprints(dataset)[0]


def dataset_fingerprints(dataset: DatasetDescription) -> tuple[str, str]:
    """(:func:`dataset_fingerprint`, the views' fingerprint), reading each file once. The views' fingerprint leaves
    out the start point cloud (the PLY file and ``transforms.json``'s ``ply_file_path``, or a COLMAP model's
    ``points3D`` file): what a finished run's relighting, rendering and evaluation read of the dataset, so that its
    dataset moved with another start cloud is still its own.

    Raises:
        InputError: a file cannot be read (names it).
    """
    root, description = Path(dataset.root), Path(dataset.source)
    cloud = {Path(dataset.ply_path)} if dataset.ply_path is not None else set()
    if description.is_dir():
        cloud.add(model_files(description)[2])
    whole, views = hashlib.sha256(), hashlib.sha256()
    for path in training_input_files(dataset):
        try:
            digest, digest_without_cloud = _file_digests(path, description)
        except OSError as exc:
            raise InputError(f"{path}: cannot read the dataset file ({exc.strerror or exc})") from None
        name = Path(os.path.relpath(path, root)).as_posix()
        whole.update(f"{name}\0{digest}\n".encode())
        if path not in cloud:
            views.update(f"{name}\0{digest_without_cloud}\n".encode())
    return FINGERPRINT_PREFIX + whole.hexdigest(), FINGERPRINT_PREFIX + views.hexdigest()


def other_dataset(recorded: object, fingerprint: str) -> bool:
    """Whether a run whose ``run.json`` records the fingerprint ``recorded`` was trained on other files than those
    whose fingerprint is ``fingerprint``; False for a run saved before fingerprints (``recorded`` None), which has
    nothing to compare."""
    return recorded is not None and recorded != fingerprint
