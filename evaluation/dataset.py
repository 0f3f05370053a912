"""The dataset fields the evaluation needs, taken from the shared reader.

A dataset folder is read by :func:`spotlessgs.io.dataset.read_dataset`, the project's only reader of dataset folders:
our ``transforms.json`` (see ``docs/dataset.md``), a plain nerfstudio ``transforms.json`` or a COLMAP folder. The
evaluation uses its intrinsics, per-frame input / ground-truth / EXR paths, camera-to-world poses (OpenGL axes) and the
test split (``split.test``; every 11th frame when the file has no split). Relit images are matched to views by the input
image's file name, so those names must be unique.
A run's dataset folder is found from its ``run.json`` by :func:`spotlessgs.training.checkpoint.resolve_data_dir` (the
one place that reads those paths); its ``relit/`` folder holds one relit PNG per view, named like the inputs.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from spotlessgs.io.cameras import Intrinsics
from spotlessgs.io.dataset import ground_truth_paths, true_exposure_gains
from spotlessgs.io.dataset import read_dataset as read_dataset_description
from spotlessgs.io.exr import DEPTH_CHANNEL, read_exr
from spotlessgs.io.transforms import DatasetDescription, DatasetError


@dataclass(frozen=True)
class DatasetFrame:
    """One view of a dataset folder."""

    name: str  # file name of the input image, e.g. "frame_00000.png" (relit images use the same name)
    input_path: Path  # uneven (spotlight-lit) input image
    gt_path: Path | None  # evenly lit ground truth, when known
    depth_path: Path | None  # EXR with planar depth, when known
    c2w_opengl: np.ndarray  # (4, 4) camera-to-world, OpenGL axes


@dataclass(frozen=True)
class DatasetViews:
    """What the evaluation needs from a dataset folder (a view of the shared :class:`DatasetDescription`)."""

    root: Path  # the dataset folder
    intrinsics: Intrinsics | None  # the camera every frame shares; None for frames of several cameras
    frames: tuple[DatasetFrame, ...]  # all views in time order
    test_indices: tuple[int, ...]  # indices into ``frames`` of the test views
    # each frame's true exposure gain (a simulated robot camera's copy, spotlessgs.io.dataset.true_exposure_gains),
    # else None
    exposure_gains: tuple[float, ...] | None = None

    @property
    def test_frames(self) -> list[DatasetFrame]:
        """The test views, in order."""
        return [self.frames[i] for i in self.test_indices]


def read_dataset(data_dir: str | os.PathLike, ground_truth: str = "lamps") -> DatasetViews:
    """Read a dataset folder with the shared reader (see the module docstring) and keep what the evaluation needs;
    ``ground_truth``: which of the dataset's ground truths the frames' ``gt_path`` are
    (:data:`spotlessgs.io.dataset.GROUND_TRUTHS`).

    Raises:
        FileNotFoundError: the folder has neither ``transforms.json`` nor a COLMAP ``sparse/`` model.
        spotlessgs.io.transforms.DatasetError: malformed content (a ValueError naming the file, frame and field), or
            the dataset has no such ground truth.
        ValueError: two views share an input image file name.
    """
    return dataset_views(read_dataset_description(data_dir), ground_truth)


def dataset_views(desc: DatasetDescription, ground_truth: str = "lamps") -> DatasetViews:
    """The evaluation's view of a shared dataset description: one :class:`DatasetFrame` per frame (its ground truth
    of the kind ``ground_truth``), the test split."""
    gt_paths = ground_truth_paths(desc, ground_truth)
    frames = tuple(
        DatasetFrame(
            name=desc.image_paths[i].name,
            input_path=desc.image_paths[i],
            gt_path=gt_paths[i],
            depth_path=desc.exr_paths[i],
            c2w_opengl=desc.c2w_opengl[i],
        )
        for i in range(desc.n_frames)
    )
    seen: dict[str, int] = {}
    for i, frame in enumerate(frames):
        if frame.name in seen:
            raise DatasetError(
                f"{desc.source}: input image file names are not unique: frames[{seen[frame.name]}] and frames[{i}] "
                f"are both {frame.name!r} (relit images are matched to views by this name)"
            )
        seen[frame.name] = i
    return DatasetViews(desc.root, desc.intrinsics if desc.has_one_camera else None, frames, tuple(desc.split.test),
                        true_exposure_gains(desc))


def read_depth_exr(path: str | os.PathLike) -> np.ndarray:
    """Planar depth from an EXR file read with :func:`spotlessgs.io.exr.read_exr`: the dataset's channel ``depth.Z``,
    else a channel ending in ``depth.z`` (any case, e.g. Blender's ``ViewLayer.Depth.Z``), else ``Z``.

    Returns:
        (H, W) float32 depth in metres (inf where there is no surface).

    Raises:
        FileNotFoundError: the file is missing.
        ValueError: not an EXR file, or no depth channel (the channels present are listed).
    """
    channels = read_exr(path)
    candidates = (DEPTH_CHANNEL, *sorted(k for k in channels if k.lower().endswith("depth.z")), "Z")
    for key in candidates:
        if key in channels:
            return channels[key]
    raise ValueError(f"{path}: no depth channel ('depth.Z' or 'Z'); channels are {sorted(channels)}")
