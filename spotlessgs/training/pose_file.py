"""The run folder's camera poses after pose refinement: ``RUN/poses.json`` (written atomically at the end of a run with
``refine_poses``; docs/run.md).

Every view of the dataset has one entry, in the dataset's order::

    {"name": "frame_00003.png", "file_path": "images/frame_00003.png", "split": "train" | "test",
     "source": "refined" | "aligned",
     "transform_matrix": 4x4 camera-to-world after refinement or alignment,
     "dataset_transform_matrix": 4x4 camera-to-world as the dataset gave it,
     "correction_translation_m": ..., "correction_rotation_deg": ...}

The matrices are in the dataset's world frame (metres) and in the nerfstudio / Blender (OpenGL) camera axes of
``transforms.json`` (x right, y up, looking along −z), so that a frame's ``transform_matrix`` can replace the one in
the dataset's file. ``refined``: a training view's pose, learned beside the scene; ``aligned``: a view that training
never fitted (a test view), fitted to its own spotlit input with the model frozen
(:mod:`spotlessgs.training.pose_alignment`).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from spotlessgs.io.atomic import write_json
from spotlessgs.io.cameras import opencv_to_opengl_c2w
from spotlessgs.io.errors import InputError
from spotlessgs.io.json_files import read_json
from spotlessgs.models.pose import PoseCorrection, correction_matrix, correction_size
from spotlessgs.training.checkpoint import RUN_SCHEMA_VERSION, check_schema_version
from spotlessgs.training.data import TrainingViews
from spotlessgs.training.pose_alignment import AlignedView

#: The file's name in the run folder.
POSES_FILE = "poses.json"
#: What the file says about its matrices.
CONVENTION = ("transform_matrix: camera-to-world 4x4 in the dataset's world frame (metres), nerfstudio/OpenGL camera "
              "axes as in transforms.json (x right, y up, looking along -z); refined = dataset pose @ correction, "
              "the correction a rigid transform in the camera's own axes")


@dataclass(frozen=True)
class RefinedPoses:
    """``RUN/poses.json`` as read back.

    Attributes:
        names: V image file names.
        c2w_opengl: (V, 4, 4) refined (or aligned) camera-to-world, OpenGL axes.
        dataset_c2w_opengl: (V, 4, 4) the dataset's poses, OpenGL axes.
        sources: V of ``refined`` / ``aligned``.
        step: the training step the corrections are from.
    """

    names: list[str]
    c2w_opengl: np.ndarray
    dataset_c2w_opengl: np.ndarray
    sources: list[str]
    step: int

    def pose(self, name: str) -> np.ndarray:
        """(4, 4) the refined camera-to-world (OpenGL axes) of the view named ``name``."""
        return self.c2w_opengl[self.names.index(name)]


def refined_c2w_opencv(views: TrainingViews, deltas: torch.Tensor) -> np.ndarray:
    """(V, 4, 4) float64 the dataset's poses (OpenCV axes) corrected by ``deltas`` (V, 9) on the right."""
    return views.dataset.c2w_opencv @ correction_matrix(deltas.detach().cpu().double()).numpy()


def write_refined_poses(run_dir: Path, views: TrainingViews, poses: PoseCorrection,
                        aligned: dict[int, AlignedView], step: int) -> Path:
    """Write ``RUN/poses.json`` (atomically): the training views' refined poses and the ``aligned`` views' poses."""
    deltas = poses.delta.detach().cpu().clone()
    for k, a in aligned.items():
        deltas[k] = a.delta
    c2w = refined_c2w_opencv(views, deltas)
    translation, rotation = correction_size(deltas.double())
    test = set(views.dataset.split.test)
    frames = []
    for k, name in enumerate(views.names):
        frames.append({
            "name": name, "file_path": views.dataset.file_paths[k], "split": "test" if k in test else "train",
            "source": "aligned" if k in aligned else "refined",
            "transform_matrix": opencv_to_opengl_c2w(c2w[k]).tolist(),
            "dataset_transform_matrix": views.dataset.c2w_opengl[k].tolist(),
            "correction_translation_m": float(translation[k]), "correction_rotation_deg": float(rotation[k]),
        })
    path = Path(run_dir) / POSES_FILE
    write_json(path, {"schema_version": RUN_SCHEMA_VERSION, "convention": CONVENTION, "step": step,
                      "frames": frames})
    return path


def read_refined_poses(run_dir: str | Path) -> RefinedPoses | None:
    """``RUN/poses.json``, or None when the run has none (it did not refine its poses, or is unfinished).

    Raises:
        InputError: the file is damaged (names it).
    """
    path = Path(run_dir) / POSES_FILE
    if not path.is_file():
        return None
    record = read_json(path, "refined poses", ("frames", "step"))
    check_schema_version(path, record)
    try:
        frames = record["frames"]
        c2w = np.array([f["transform_matrix"] for f in frames], dtype=np.float64).reshape(-1, 4, 4)
        given = np.array([f["dataset_transform_matrix"] for f in frames], dtype=np.float64).reshape(-1, 4, 4)
        return RefinedPoses([str(f["name"]) for f in frames], c2w, given, [str(f["source"]) for f in frames],
                            int(record["step"]))
    except (KeyError, TypeError, ValueError) as exc:
        raise InputError(f"{path}: damaged refined poses ({exc})") from None
