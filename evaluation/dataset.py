"""The few dataset-folder and run-folder fields the evaluation needs, read in one place.

A dataset folder holds ``transforms.json`` (nerfstudio style, extended by the simulator): intrinsics ``fl_x fl_y cx cy
w h``; ``frames[i]`` with ``file_path`` (uneven input), optional ``gt_file_path`` (ground truth), ``transform_matrix``
(4×4 camera-to-world, OpenGL axes) and optional ``exr_file_path`` (channel ``depth.Z``: planar depth, metres, inf for
background); and ``spotless.split.test`` (test frame indices; default every 11th frame, i % 11 == 0).
A run folder holds ``run.json`` (key ``data_dir``) and ``relit/`` with one relit PNG per view, named like the inputs.

:func:`_read_transforms` is the only code that parses ``transforms.json``; it can be swapped for the shared reader
(``spotlessgs.io.transforms``) without touching the rest of the package.
"""

from __future__ import annotations

import json
import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from spotlessgs.io.cameras import Intrinsics

#: Default test split: every TEST_EVERY-th frame (METHOD §7).
TEST_EVERY = 11


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
    """What the evaluation needs from a dataset folder."""

    root: Path  # the dataset folder
    intrinsics: Intrinsics  # shared pinhole intrinsics
    frames: tuple[DatasetFrame, ...]  # all views in time order
    test_indices: tuple[int, ...]  # indices into ``frames`` of the test views

    @property
    def test_frames(self) -> list[DatasetFrame]:
        """The test views, in order."""
        return [self.frames[i] for i in self.test_indices]


def read_dataset(data_dir: str | os.PathLike) -> DatasetViews:
    """Read a dataset folder's ``transforms.json`` (see the module docstring).

    Raises:
        FileNotFoundError: the folder or its transforms.json is missing.
        ValueError: a required field is missing or malformed (the field and frame are named).
    """
    return _read_transforms(Path(data_dir))


def _read_transforms(root: Path) -> DatasetViews:
    """Parse ``root/transforms.json`` into :class:`DatasetViews` (the single place that knows its layout)."""
    path = root / "transforms.json"
    if not path.is_file():
        raise FileNotFoundError(f"{path}: dataset transforms.json not found")
    try:
        meta = json.loads(path.read_text(encoding="utf-8"))
    except json.JSONDecodeError as exc:
        raise ValueError(f"{path}: not valid JSON ({exc})") from exc
    try:
        intr = Intrinsics(
            float(meta["fl_x"]), float(meta["fl_y"]), float(meta["cx"]), float(meta["cy"]), int(meta["w"]), int(meta["h"])
        )
    except KeyError as exc:
        raise ValueError(f"{path}: missing intrinsics field {exc.args[0]!r} (need fl_x, fl_y, cx, cy, w, h)") from exc
    raw_frames = meta.get("frames")
    if not isinstance(raw_frames, list) or not raw_frames:
        raise ValueError(f"{path}: 'frames' must be a non-empty list")
    frames = []
    for i, fr in enumerate(raw_frames):
        if "file_path" not in fr or "transform_matrix" not in fr:
            raise ValueError(f"{path}: frames[{i}] needs 'file_path' and 'transform_matrix'")
        c2w = np.asarray(fr["transform_matrix"], dtype=np.float64)
        if c2w.shape != (4, 4) or not np.isfinite(c2w).all():
            raise ValueError(f"{path}: frames[{i}].transform_matrix must be a finite 4x4 matrix")
        gt = fr.get("gt_file_path")
        exr = fr.get("exr_file_path")
        frames.append(DatasetFrame(
            name=Path(fr["file_path"]).name,
            input_path=root / fr["file_path"],
            gt_path=None if gt is None else root / gt,
            depth_path=None if exr is None else root / exr,
            c2w_opengl=c2w,
        ))
    names = [f.name for f in frames]
    if len(set(names)) != len(names):
        raise ValueError(f"{path}: input image file names are not unique")
    split = (meta.get("spotless") or {}).get("split") or {}
    test = split.get("test")
    if test is None:
        test = [i for i in range(len(frames)) if i % TEST_EVERY == 0]
    test = [int(i) for i in test]
    bad = [i for i in test if not 0 <= i < len(frames)]
    if bad:
        raise ValueError(f"{path}: spotless.split.test has indices outside 0..{len(frames) - 1}: {bad[:5]}")
    return DatasetViews(root, intr, tuple(frames), tuple(test))


def read_run_data_dir(run_dir: str | os.PathLike) -> Path:
    """The dataset folder a training run was made from (``run.json`` key ``data_dir``; relative paths are taken
    relative to the run folder).

    Raises:
        FileNotFoundError: run.json or the relit folder is missing.
        ValueError: run.json has no ``data_dir``.
    """
    run = Path(run_dir)
    path = run / "run.json"
    if not path.is_file():
        raise FileNotFoundError(f"{path}: not a training run folder (run.json missing)")
    try:
        meta = json.loads(path.read_text(encoding="utf-8"))
    except json.JSONDecodeError as exc:
        raise ValueError(f"{path}: not valid JSON ({exc})") from exc
    if not isinstance(meta, dict) or "data_dir" not in meta:
        raise ValueError(f"{path}: missing key 'data_dir'")
    data = Path(meta["data_dir"])
    if not data.is_absolute():
        data = (run / data).resolve()
    if not (run / "relit").is_dir():
        raise FileNotFoundError(f"{run / 'relit'}: the run has no relit images")
    return data


def read_depth_exr(path: str | os.PathLike) -> np.ndarray:
    """Planar depth from an EXR file: the channel ``depth.Z`` (any part), else one ending in ``depth.z``, else ``Z``.

    Returns:
        (H, W) float32 depth in metres (inf where there is no surface).

    Raises:
        FileNotFoundError: the file is missing.
        ValueError: no depth channel (the channels present are listed).
    """
    import OpenEXR

    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"{path}: depth EXR not found")
    found: dict[str, np.ndarray] = {}
    with OpenEXR.File(str(path)) as fh:
        for part in fh.parts:
            for name, ch in part.channels.items():
                if name.lower().endswith("depth.z") or name == "Z":
                    found[name] = np.array(ch.pixels, dtype=np.float32, copy=True)
            all_names = [n for p in fh.parts for n in p.channels]
    for key in ("depth.Z", *sorted(k for k in found if k != "Z"), "Z"):
        if key in found:
            depth = found[key]
            if depth.ndim != 2:
                raise ValueError(f"{path}: depth channel {key!r} has shape {depth.shape}, expected (H, W)")
            return depth
    raise ValueError(f"{path}: no depth channel ('depth.Z' or 'Z'); channels are {all_names}")
