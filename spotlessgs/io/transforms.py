"""The dataset contract: a nerfstudio-compatible ``transforms.json`` with a versioned ``"spotless"`` block.

See ``docs/dataset.md`` for the full description and an example. In short:

* top level (nerfstudio): ``camera_model`` ("OPENCV", distortion k1=k2=p1=p2=0), ``fl_x fl_y cx cy w h``,
  ``ply_file_path`` (optional), ``frames[]`` with ``file_path`` and ``transform_matrix`` (4x4 camera-to-world, OpenGL
  camera axes: x right, y up, looking along -z), plus our optional per-frame ``gt_file_path`` and ``exr_file_path``;
  nerfstudio's optional per-frame ``depth_file_path`` (an RGB-D camera's registered depth image:
  :mod:`spotlessgs.io.depth_images`) with the top-level ``depth_unit_scale_factor`` (metres per unit, default 0.001);
* ``"spotless"``: ``schema_version`` (1), ``scene_id``, ``room``, ``seed``, ``preset``, ``split``, ``color_space``
  ("srgb"), ``light`` (:class:`LightTruth` or null), ``renderer`` and ``provenance`` (free dicts).

The reader also accepts plain nerfstudio files (no ``"spotless"`` block) with per-frame intrinsics: frames may use
different cameras (sizes, lenses), as nerfstudio allows.
"""

from __future__ import annotations

import json
import math
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from spotlessgs.io.atomic import write_json
from spotlessgs.io.cameras import Intrinsics, opengl_to_opencv_c2w, working_origin, world_to_camera
from spotlessgs.io.depth_images import DEFAULT_DEPTH_SCALE
from spotlessgs.io.errors import InputError
from spotlessgs.io.lens import check_invertible

SCHEMA_VERSION = 1
DEFAULT_TEST_EVERY = 11
_INTRINSIC_KEYS = ("fl_x", "fl_y", "cx", "cy", "w", "h")
_DISTORTION_KEYS = ("k1", "k2", "k3", "k4", "p1", "p2")
# nerfstudio camera models -> (our lens model, the keys of its distortion coefficients in OpenCV's order).
_CAMERA_MODELS = {"OPENCV": ("opencv", ("k1", "k2", "p1", "p2", "k3")), "OPENCV_FISHEYE": ("fisheye", ("k1", "k2", "k3", "k4")),
                  "PINHOLE": ("pinhole", ()), "SIMPLE_PINHOLE": ("pinhole", ())}
_ROTATION_TOL = 1e-3  # max |R^T R - I| accepted in a transform_matrix
_LIGHT_ROTATION_TOL = 1e-6  # max |R^T R - I| accepted in a light rotation


class DatasetError(InputError):
    """A dataset file is malformed; the message names the file, the entry and the problem."""


def split_indices(n: int, test_every: int = DEFAULT_TEST_EVERY) -> tuple[list[int], list[int]]:
    """The paper's split of ``n`` frames: test = indices i with ``i % test_every == 0``, train = the rest."""
    if n < 0 or test_every < 1:
        raise ValueError(f"split_indices: need n >= 0 and test_every >= 1, got n={n}, test_every={test_every}")
    test = list(range(0, n, test_every))
    train = [i for i in range(n) if i % test_every]
    return train, test


def split_rule_name(test_every: int) -> str:
    """The rule label stored in the split block, e.g. ``every_11th``."""
    return f"every_{test_every}th"


def _vec(value: Any, shape: tuple[int, ...], where: str) -> np.ndarray:
    try:
        arr = np.array(value, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise DatasetError(f"{where}: expected numbers of shape {shape} ({exc})") from exc
    if arr.shape != shape:
        raise DatasetError(f"{where}: expected shape {shape}, got {arr.shape}")
    if not np.isfinite(arr).all():
        raise DatasetError(f"{where}: contains NaN or inf")
    arr.setflags(write=False)
    return arr


def _finite_number(value: Any, where: str) -> float:
    try:  # an integer beyond float's range overflows
        number = float(value) if isinstance(value, (int, float)) and not isinstance(value, bool) else math.nan
    except OverflowError:
        number = math.nan
    if not math.isfinite(number):
        raise DatasetError(f"{where}: expected a finite number, got {_short_repr(value)}")
    return number


def _short_repr(value: Any, limit: int = 60) -> str:
    """repr(value), cut to ``limit`` characters (a damaged file's value may be huge)."""
    text = repr(value)
    return text if len(text) <= limit else f"{text[:limit]}... ({len(text)} characters)"


def _view_angle(value: Any, where: str) -> float:
    """A field of view (radians) in (0, π): nerfstudio's ``camera_angle_x`` / ``camera_angle_y``."""
    angle = _finite_number(value, where)
    if not 0.0 < angle < math.pi:
        raise DatasetError(f"{where}: a field of view must lie between 0 and pi radians, got {angle!r}")
    return angle


@dataclass(frozen=True, eq=False)
class LightTruth:
    """The true spotlight, rigidly mounted on the camera (known in simulation).

    Attributes:
        position_in_camera: (3,) light origin in the OpenCV camera frame (x right, y down, z forward), metres.
        rotation_in_camera: (3, 3) rotation whose columns are the light frame's axes in the OpenCV camera frame; the
            spotlight shines along the light frame's +z (so ``x_light = R^T (x_cam - t)``).
        cone_angle_deg: full cone angle in degrees, in (0, 180].
        blend: softness of the cone edge in [0, 1] (Blender's ``spot_blend``).
        power_w: radiant power in watts (Blender's light power), > 0.
        color: (3,) linear RGB colour of the light, each >= 0.
        radius_m: radius of the emitting sphere in metres (soft shadows), >= 0.
    """

    position_in_camera: np.ndarray
    rotation_in_camera: np.ndarray
    cone_angle_deg: float
    blend: float
    power_w: float
    color: np.ndarray = field(default_factory=lambda: np.ones(3))
    radius_m: float = 0.0

    def __post_init__(self) -> None:
        where = "LightTruth"
        position = _vec(self.position_in_camera, (3,), f"{where}.position_in_camera")
        object.__setattr__(self, "position_in_camera", position)
        rot = _vec(self.rotation_in_camera, (3, 3), f"{where}.rotation_in_camera")
        if np.abs(rot.T @ rot - np.eye(3)).max() > _LIGHT_ROTATION_TOL or np.linalg.det(rot) <= 0:
            raise DatasetError(f"{where}.rotation_in_camera: not a rotation matrix: {rot.tolist()}")
        object.__setattr__(self, "rotation_in_camera", rot)
        object.__setattr__(self, "color", _vec(self.color, (3,), f"{where}.color"))
        if (self.color < 0).any():
            raise DatasetError(f"{where}.color: must be non-negative, got {self.color.tolist()}")
        for name in ("cone_angle_deg", "blend", "power_w", "radius_m"):
            object.__setattr__(self, name, _finite_number(getattr(self, name), f"{where}.{name}"))
        if not 0.0 < self.cone_angle_deg <= 180.0:
            raise DatasetError(f"{where}.cone_angle_deg: must be in (0, 180], got {self.cone_angle_deg}")
        if not 0.0 <= self.blend <= 1.0:
            raise DatasetError(f"{where}.blend: must be in [0, 1], got {self.blend}")
        if self.power_w <= 0.0:
            raise DatasetError(f"{where}.power_w: must be positive, got {self.power_w}")
        if self.radius_m < 0.0:
            raise DatasetError(f"{where}.radius_m: must be non-negative, got {self.radius_m}")

    @property
    def direction_in_camera(self) -> np.ndarray:
        """(3,) unit vector of the beam axis (the light frame's +z) in the OpenCV camera frame."""
        return self.rotation_in_camera[:, 2].copy()

    def to_json(self) -> dict[str, Any]:
        """A JSON-ready dict (exact float round trip)."""
        return {
            "position_in_camera": self.position_in_camera.tolist(),
            "rotation_in_camera": self.rotation_in_camera.tolist(),
            "cone_angle_deg": self.cone_angle_deg,
            "blend": self.blend,
            "power_w": self.power_w,
            "color": self.color.tolist(),
            "radius_m": self.radius_m,
        }

    @classmethod
    def from_json(cls, data: Any, where: str = "light") -> "LightTruth":
        """Parse :meth:`to_json` output; errors are prefixed with ``where``."""
        if not isinstance(data, dict):
            raise DatasetError(f"{where}: expected an object, got {type(data).__name__}")
        keys = ("position_in_camera", "rotation_in_camera", "cone_angle_deg", "blend", "power_w", "color", "radius_m")
        missing = [k for k in keys if k not in data]
        if missing:
            raise DatasetError(f"{where}: missing keys {missing}")
        try:
            return cls(**{k: data[k] for k in keys})
        except DatasetError as exc:
            raise DatasetError(f"{where}: {exc}") from exc

    def __eq__(self, other: object) -> bool:
        return isinstance(other, LightTruth) and self.to_json() == other.to_json()

    __hash__ = None  # type: ignore[assignment]


@dataclass(frozen=True)
class Split:
    """Train/test split of the frames.

    Attributes:
        rule: how it was made (``every_11th`` for the paper's rule).
        test_every: the period of the rule.
        train: sorted frame indices for training.
        test: sorted frame indices for testing.
    """

    rule: str
    test_every: int
    train: tuple[int, ...]
    test: tuple[int, ...]

    @classmethod
    def every_nth(cls, n: int, test_every: int = DEFAULT_TEST_EVERY) -> "Split":
        """The paper's rule: every ``test_every``-th frame (starting with frame 0) is a test frame."""
        train, test = split_indices(n, test_every)
        return cls(split_rule_name(test_every), test_every, tuple(train), tuple(test))

    def to_json(self) -> dict[str, Any]:
        """A JSON-ready dict."""
        return {"rule": self.rule, "test_every": self.test_every, "train": list(self.train), "test": list(self.test)}


@dataclass(frozen=True, eq=False)
class FrameRecord:
    """One frame as written to ``transforms.json``.

    Attributes:
        file_path: the uneven (spotlight-only) image, relative to the dataset folder, e.g. ``images/frame_00000.png``.
        c2w_opengl: (4, 4) camera-to-world matrix, OpenGL camera axes.
        gt_file_path: the evenly lit ground-truth image (relative), or None.
        exr_file_path: the linear EXR with renders, depth and normals (relative), or None.
        depth_file_path: an RGB-D camera's depth image registered to ``file_path`` (relative), or None.
    """

    file_path: str
    c2w_opengl: np.ndarray
    gt_file_path: str | None = None
    exr_file_path: str | None = None
    depth_file_path: str | None = None

    def __eq__(self, other: object) -> bool:
        return (
            isinstance(other, FrameRecord)
            and (self.file_path, self.gt_file_path, self.exr_file_path, self.depth_file_path)
            == (other.file_path, other.gt_file_path, other.exr_file_path, other.depth_file_path)
            and np.array_equal(self.c2w_opengl, other.c2w_opengl)
        )

    __hash__ = None  # type: ignore[assignment]


@dataclass(frozen=True)
class DatasetMeta:
    """Our ``"spotless"`` block, minus the split (derived from the number of frames) and the schema version.

    Attributes:
        scene_id: id of the rendered scene (3D-FRONT house uid or generator id).
        room: the room instance id the camera path is in, or None.
        seed: the command seed, or None.
        preset: the named render preset (``tiny``, ``quick``, ``paper``, ...), or None.
        light: the true spotlight, or None when unknown (real data).
        renderer: free JSON dict of renderer settings (engine, samples, Blender version, ...).
        provenance: free JSON dict from :func:`spotlessgs.io.provenance.provenance`.
        color_space: colour space of the PNG images; only ``srgb`` is defined.
        test_every: period of the train/test split rule.
    """

    scene_id: str
    room: str | None = None
    seed: int | None = None
    preset: str | None = None
    light: LightTruth | None = None
    renderer: dict[str, Any] = field(default_factory=dict)
    provenance: dict[str, Any] = field(default_factory=dict)
    color_space: str = "srgb"
    test_every: int = DEFAULT_TEST_EVERY


def _check_relative(path_str: str, where: str) -> None:
    if not isinstance(path_str, str) or not path_str:
        raise DatasetError(f"{where}: expected a non-empty relative path string, got {path_str!r}")
    if Path(path_str).is_absolute() or "\\" in path_str:
        raise DatasetError(f"{where}: must be a relative POSIX path, got {path_str!r}")
    if ".." in Path(path_str).parts:
        raise DatasetError(f"{where}: must stay inside the dataset folder (no '..'), got {path_str!r}")


def nerfstudio_camera(intrinsics: Intrinsics, path: str | os.PathLike) -> dict[str, Any]:
    """The top-level camera keys of a ``transforms.json`` for ``intrinsics``: ``camera_model`` (``OPENCV``, also for
    a pinhole, or ``OPENCV_FISHEYE``), ``fl_x fl_y cx cy w h`` and the distortion keys (``k1 k2 p1 p2`` and ``k3``
    when the lens has one, or ``k1..k4``). DatasetError naming ``path`` for a lens nerfstudio cannot hold."""
    model = {"pinhole": "OPENCV", "opencv": "OPENCV", "fisheye": "OPENCV_FISHEYE"}[intrinsics.lens]
    keys = _CAMERA_MODELS[model][1]
    if len(intrinsics.distortion) > len(keys):
        raise DatasetError(f"{path}: nerfstudio's camera models cannot hold the {len(intrinsics.distortion)}-coefficient "
                           f"(rational) {intrinsics.lens} lens {list(intrinsics.distortion)}; keep it as a COLMAP model")
    coeffs = dict(zip(keys, intrinsics.distortion))
    written = keys if model == "OPENCV_FISHEYE" else ("k1", "k2", "p1", "p2") + (("k3",) if "k3" in coeffs else ())
    return {"camera_model": model, "fl_x": intrinsics.fx, "fl_y": intrinsics.fy, "cx": intrinsics.cx,
            "cy": intrinsics.cy, "w": intrinsics.width, "h": intrinsics.height,
            **{k: coeffs.get(k, 0.0) for k in written}}


def write_transforms(
    path: str | os.PathLike,
    intrinsics: Intrinsics,
    frames: list[FrameRecord],
    meta: DatasetMeta | None,
    ply_file_path: str | None = None,
    depth_unit_scale_factor: float | None = None,
) -> None:
    """Write ``transforms.json`` atomically (``meta=None`` writes a plain nerfstudio file without our block);
    ``depth_unit_scale_factor``: the metres per unit of the frames' depth images (written when given).

    Raises DatasetError for empty frame lists, absolute paths, bad or non-finite matrices, unknown colour spaces.
    """
    path = Path(path)
    if not frames:
        raise DatasetError(f"{path}: no frames to write")
    out: dict[str, Any] = nerfstudio_camera(intrinsics, path)
    if ply_file_path is not None:
        _check_relative(ply_file_path, f"{path}: ply_file_path")
        out["ply_file_path"] = ply_file_path
    if depth_unit_scale_factor is not None:
        out["depth_unit_scale_factor"] = _depth_scale(depth_unit_scale_factor, f"{path}: depth_unit_scale_factor")
    frame_list = []
    for i, frame in enumerate(frames):
        where = f"{path}: frames[{i}]"
        _check_relative(frame.file_path, f"{where}.file_path")
        matrix = _check_pose(frame.c2w_opengl, f"{where}.transform_matrix")
        entry: dict[str, Any] = {"file_path": frame.file_path, "transform_matrix": matrix.tolist()}
        if frame.gt_file_path is not None:
            _check_relative(frame.gt_file_path, f"{where}.gt_file_path")
            entry["gt_file_path"] = frame.gt_file_path
        if frame.exr_file_path is not None:
            _check_relative(frame.exr_file_path, f"{where}.exr_file_path")
            entry["exr_file_path"] = frame.exr_file_path
        if frame.depth_file_path is not None:
            _check_relative(frame.depth_file_path, f"{where}.depth_file_path")
            entry["depth_file_path"] = frame.depth_file_path
        frame_list.append(entry)
    out["frames"] = frame_list
    if meta is not None:
        if meta.color_space != "srgb":
            raise DatasetError(f"{path}: color_space must be 'srgb', got {meta.color_space!r}")
        split = Split.every_nth(len(frames), meta.test_every)
        out["spotless"] = {
            "schema_version": SCHEMA_VERSION,
            "scene_id": meta.scene_id,
            "room": meta.room,
            "seed": None if meta.seed is None else int(meta.seed),
            "preset": meta.preset,
            "split": split.to_json(),
            "color_space": meta.color_space,
            "light": None if meta.light is None else meta.light.to_json(),
            "renderer": meta.renderer,
            "provenance": meta.provenance,
        }
    try:
        write_json(path, out)
    except (TypeError, ValueError) as exc:
        raise DatasetError(f"{path}: metadata is not JSON-serialisable ({exc})") from exc


def _depth_scale(value: Any, where: str) -> float:
    """A depth image's metres per unit: a finite number > 0 (DatasetError naming ``where`` otherwise)."""
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value) or value <= 0:
        raise DatasetError(f"{where}: must be a positive number of metres per depth unit, got {value!r}")
    return float(value)


def _check_pose(value: Any, where: str) -> np.ndarray:
    """Validate a 4x4 rigid camera-to-world matrix; returns it as float64 (4, 4)."""
    try:
        arr = np.array(value, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise DatasetError(f"{where}: not a numeric 4x4 matrix ({exc})") from exc
    if arr.shape != (4, 4):
        raise DatasetError(f"{where}: must be 4x4, got shape {arr.shape}")
    if not np.isfinite(arr).all():
        raise DatasetError(f"{where}: contains NaN or inf")
    if np.abs(arr[3] - [0.0, 0.0, 0.0, 1.0]).max() > 1e-6:
        raise DatasetError(f"{where}: last row must be [0, 0, 0, 1], got {arr[3].tolist()}")
    rot = arr[:3, :3]
    if np.abs(rot.T @ rot - np.eye(3)).max() > _ROTATION_TOL or np.linalg.det(rot) <= 0:
        raise DatasetError(f"{where}: the 3x3 block is not a rotation (scaled or mirrored pose)")
    return arr


@dataclass(frozen=True, eq=False)
class DatasetDescription:
    """A dataset as the trainer sees it.

    Attributes:
        root: the dataset folder (relative paths are resolved against it).
        source: the file it was read from.
        cameras: N cameras, one per frame (the same object for frames that share one); see :attr:`intrinsics` for
            the camera of a single-camera dataset.
        c2w_opengl: (N, 4, 4) float64 camera-to-world, OpenGL camera axes (as stored).
        c2w_opencv: (N, 4, 4) float64 camera-to-world, OpenCV camera axes (for the trainer).
        file_paths: N image paths as stored (relative).
        image_paths: N resolved uneven-image paths.
        gt_paths: N resolved ground-truth paths (None where absent).
        exr_paths: N resolved EXR paths (None where absent).
        depth_paths: N resolved depth-image paths (None where absent; :mod:`spotlessgs.io.depth_images`), or None
            when no frame has one.
        depth_scale: metres per unit of the depth images (``depth_unit_scale_factor``).
        split: the train/test split (from our block, else every 11th frame).
        light: the true spotlight, or None.
        ply_path: resolved initial point cloud, or None.
        meta: our ``"spotless"`` block as parsed ({} for plain nerfstudio files).
    """

    root: Path
    source: Path
    cameras: tuple[Intrinsics, ...]
    c2w_opengl: np.ndarray
    c2w_opencv: np.ndarray
    file_paths: tuple[str, ...]
    image_paths: tuple[Path, ...]
    gt_paths: tuple[Path | None, ...]
    exr_paths: tuple[Path | None, ...]
    split: Split
    light: LightTruth | None
    ply_path: Path | None
    meta: dict[str, Any]
    depth_paths: tuple[Path | None, ...] | None = None
    depth_scale: float = DEFAULT_DEPTH_SCALE

    def __post_init__(self) -> None:
        if len(self.cameras) != len(self.image_paths):
            raise ValueError(f"DatasetDescription: {len(self.cameras)} cameras for {len(self.image_paths)} frames")

    @property
    def n_frames(self) -> int:
        """Number of frames N."""
        return len(self.image_paths)

    def distinct_cameras(self) -> list[Intrinsics]:
        """The different cameras of the frames, in the order they first appear."""
        return list(dict.fromkeys(self.cameras))

    @property
    def has_one_camera(self) -> bool:
        """True when every frame has the same camera."""
        return len(self.distinct_cameras()) == 1

    @property
    def intrinsics(self) -> Intrinsics:
        """The camera every frame shares; DatasetError naming the dataset when its frames use several (steps that
        take one camera for the whole sequence, e.g. SfM with known intrinsics, call this)."""
        distinct = self.distinct_cameras()
        if len(distinct) > 1:
            raise DatasetError(f"{self.source}: the frames use {len(distinct)} different cameras; this step needs "
                               "one camera for every frame")
        return distinct[0]

    @property
    def working_origin(self) -> np.ndarray:
        """(3,) float64 world point that training, relighting and rendering take coordinates relative to (the cameras,
        the start point cloud, the model): zeros unless the poses lie far from the origin
        (:func:`~spotlessgs.io.cameras.working_origin`)."""
        return working_origin(self.c2w_opencv)

    def view_matrices(self) -> np.ndarray:
        """(N, 4, 4) world-to-camera matrices, OpenCV camera axes."""
        return world_to_camera(self.c2w_opencv)

    def frames(self) -> list[FrameRecord]:
        """The frames as :class:`FrameRecord` s, with paths relative to ``root`` (for rewriting the file)."""

        def rel(p: Path | None) -> str | None:
            return None if p is None else p.relative_to(self.root).as_posix()

        depths = self.depth_paths or (None,) * self.n_frames
        return [
            FrameRecord(self.file_paths[i], self.c2w_opengl[i], rel(self.gt_paths[i]), rel(self.exr_paths[i]),
                        rel(depths[i]))
            for i in range(self.n_frames)
        ]


def _resolve_image(root: Path, rel: str) -> Path:
    """Resolve a frame path; like nerfstudio, a path without suffix (NeRF-synthetic files) means ``.png``."""
    path = root / rel
    if not path.suffix:
        path = path.with_suffix(".png")
    return path


def _checked_camera(values: tuple, where: str) -> Intrinsics:
    """The camera of the (fx, fy, cx, cy, w, h, lens, distortion) ``values``, checked to be invertible."""
    camera = Intrinsics(*values)
    check_invertible(camera, where)
    return camera


def _frame_intrinsics(data: dict[str, Any], frame: dict[str, Any], where: str, root: Path, image: Path) -> tuple:
    """The (fx, fy, cx, cy, w, h, lens, distortion) of one frame: the frame's own keys override the top-level ones."""

    def get(key: str) -> Any:
        return frame.get(key, data.get(key))

    model = get("camera_model") or "OPENCV"
    if model not in _CAMERA_MODELS:
        raise DatasetError(f"{where}: camera_model {model!r} is not supported (only {', '.join(_CAMERA_MODELS)})")
    lens, keys = _CAMERA_MODELS[model]
    for key in _DISTORTION_KEYS:
        value = get(key)
        if key not in keys and value is not None and _finite_number(value, f"{where}.{key}") != 0.0:
            raise DatasetError(f"{where}: camera_model {model} has no distortion coefficient {key}, got {key}={value}")
    distortion = tuple(0.0 if get(k) is None else _finite_number(get(k), f"{where}.{k}") for k in keys)
    w, h = get("w"), get("h")
    if w is None or h is None:
        if not image.is_file():
            raise DatasetError(f"{where}: missing 'w'/'h' and image {image} is not there to measure")
        from PIL import Image, UnidentifiedImageError

        try:
            with Image.open(image) as im:
                w, h = im.size
        except (UnidentifiedImageError, OSError) as exc:
            raise DatasetError(f"{where}: missing 'w'/'h' and image {image} cannot be read to measure it ({exc})"
                               ) from None
    w = _finite_number(w, f"{where}.w")
    h = _finite_number(h, f"{where}.h")
    if w != int(w) or h != int(h) or w <= 0 or h <= 0:
        raise DatasetError(f"{where}: w and h must be positive integers, got {w}x{h}")
    fl_x = get("fl_x")
    if fl_x is None:
        angle = get("camera_angle_x")
        if angle is None:
            raise DatasetError(f"{where}: missing key 'fl_x' (and no 'camera_angle_x')")
        fl_x = 0.5 * w / math.tan(0.5 * _view_angle(angle, f"{where}.camera_angle_x"))
    fl_y = get("fl_y")
    if fl_y is None:
        angle_y = get("camera_angle_y")
        fl_y = fl_x if angle_y is None else 0.5 * h / math.tan(0.5 * _view_angle(angle_y, f"{where}.camera_angle_y"))
    cx = get("cx")
    cy = get("cy")
    values = (
        _finite_number(fl_x, f"{where}.fl_x"),
        _finite_number(fl_y, f"{where}.fl_y"),
        w / 2.0 if cx is None else _finite_number(cx, f"{where}.cx"),
        h / 2.0 if cy is None else _finite_number(cy, f"{where}.cy"),
        int(w),
        int(h),
        lens,
        distortion,
    )
    if values[0] <= 0 or values[1] <= 0:
        raise DatasetError(f"{where}: focal lengths must be positive, got fl_x={values[0]}, fl_y={values[1]}")
    return values


def _parse_split(block: dict[str, Any], n: int, where: str) -> Split:
    data = block.get("split")
    if not isinstance(data, dict):
        raise DatasetError(f"{where}: missing or invalid 'split' object")
    missing = [k for k in ("rule", "test_every", "train", "test") if k not in data]
    if missing:
        raise DatasetError(f"{where}.split: missing keys {missing}")
    test_every = data["test_every"]
    if isinstance(test_every, bool) or not isinstance(test_every, int) or test_every < 1:
        raise DatasetError(f"{where}.split.test_every: must be a positive integer, got {test_every!r}")
    lists = {}
    for key in ("train", "test"):
        values = data[key]
        if not isinstance(values, list) or not all(isinstance(v, int) and not isinstance(v, bool) for v in values):
            raise DatasetError(f"{where}.split.{key}: must be a list of integers")
        bad = [v for v in values if not 0 <= v < n]
        if bad:
            raise DatasetError(f"{where}.split.{key}: indices {bad[:5]} out of range for {n} frames")
        if values != sorted(set(values)):
            raise DatasetError(f"{where}.split.{key}: indices must be sorted and unique")
        lists[key] = values
    overlap = sorted(set(lists["train"]) & set(lists["test"]))
    if overlap:
        raise DatasetError(f"{where}.split: frames {overlap[:5]} are in both train and test")
    if len(lists["train"]) + len(lists["test"]) != n:
        covered = len(lists["train"]) + len(lists["test"])
        raise DatasetError(f"{where}.split: train and test cover {covered} of {n} frames")
    if data["rule"] == split_rule_name(test_every):
        expected_train, expected_test = split_indices(n, test_every)
        if lists["test"] != expected_test:
            raise DatasetError(f"{where}.split: test indices do not follow rule {data['rule']!r}")
    return Split(str(data["rule"]), test_every, tuple(lists["train"]), tuple(lists["test"]))


def read_transforms(path: str | os.PathLike, check_files: bool = False) -> DatasetDescription:
    """Read and validate a ``transforms.json`` (ours or plain nerfstudio).

    Args:
        path: the ``transforms.json`` file, or the dataset folder holding it.
        check_files: also require every referenced image, ground-truth, EXR and PLY file to exist.

    Raises:
        FileNotFoundError: no such file (or, with ``check_files``, a referenced file is missing).
        DatasetError: malformed content; the message names the file, the frame/key and the problem.
    """
    path = Path(path)
    if path.is_dir():
        path = path / "transforms.json"
    if not path.is_file():
        raise FileNotFoundError(f"{path}: transforms file not found")
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise DatasetError(f"{path}: not valid JSON ({exc})") from exc
    except RecursionError:
        raise DatasetError(f"{path}: not valid JSON (nested too deeply)") from None
    if not isinstance(data, dict):
        raise DatasetError(f"{path}: top level must be an object")
    root = path.parent
    frames = data.get("frames")
    if not isinstance(frames, list) or not frames:
        raise DatasetError(f"{path}: missing or empty 'frames' list")

    poses, file_paths, images, gts, exrs, depths = [], [], [], [], [], []
    cameras: list[tuple] = []
    for i, frame in enumerate(frames):
        where = f"{path}: frames[{i}]"
        if not isinstance(frame, dict):
            raise DatasetError(f"{where}: expected an object")
        for key in ("file_path", "transform_matrix"):
            if key not in frame:
                raise DatasetError(f"{where}: missing key {key!r}")
        _check_relative(frame["file_path"], f"{where}.file_path")
        poses.append(_check_pose(frame["transform_matrix"], f"{where}.transform_matrix"))
        file_paths.append(frame["file_path"])
        images.append(_resolve_image(root, frame["file_path"]))
        for key, store in (("gt_file_path", gts), ("exr_file_path", exrs), ("depth_file_path", depths)):
            value = frame.get(key)
            if value is None:
                store.append(None)
            else:
                _check_relative(value, f"{where}.{key}")
                store.append(root / value)
        cameras.append(_frame_intrinsics(data, frame, where, root, images[-1]))
    distinct: dict[tuple, Intrinsics] = {}  # one Intrinsics per different camera, checked once
    for i, values in enumerate(cameras):
        if values not in distinct:
            distinct[values] = _checked_camera(values, str(path) if i == 0 else f"{path}: frames[{i}]")

    ply_path = None
    if data.get("ply_file_path") is not None:
        _check_relative(data["ply_file_path"], f"{path}: ply_file_path")
        ply_path = root / data["ply_file_path"]
    depth_scale = DEFAULT_DEPTH_SCALE
    if data.get("depth_unit_scale_factor") is not None:
        depth_scale = _depth_scale(data["depth_unit_scale_factor"], f"{path}: depth_unit_scale_factor")

    n = len(frames)
    block = data.get("spotless")
    if block is None:
        meta: dict[str, Any] = {}
        split = Split.every_nth(n)
        light = None
    else:
        where = f"{path}: spotless"
        if not isinstance(block, dict):
            raise DatasetError(f"{where}: must be an object")
        version = block.get("schema_version")
        if version != SCHEMA_VERSION:
            raise DatasetError(
                f"{where}.schema_version: unsupported version {version!r} (this reader knows {SCHEMA_VERSION})"
            )
        missing = [k for k in ("scene_id", "split", "color_space", "light") if k not in block]
        if missing:
            raise DatasetError(f"{where}: missing keys {missing}")
        if block["color_space"] != "srgb":
            raise DatasetError(f"{where}.color_space: unsupported {block['color_space']!r} (only 'srgb')")
        split = _parse_split(block, n, where)
        light = None if block["light"] is None else LightTruth.from_json(block["light"], f"{where}.light")
        meta = block

    if check_files:
        for i in range(n):
            for label, p in (("image", images[i]), ("gt image", gts[i]), ("EXR", exrs[i]), ("depth image", depths[i])):
                if p is not None and not p.is_file():
                    raise FileNotFoundError(f"{path}: frames[{i}]: {label} file {p} does not exist")
        if ply_path is not None and not ply_path.is_file():
            raise FileNotFoundError(f"{path}: ply_file_path {ply_path} does not exist")

    c2w_opengl = np.stack(poses)
    return DatasetDescription(
        root=root,
        source=path,
        cameras=tuple(distinct[values] for values in cameras),
        c2w_opengl=c2w_opengl,
        c2w_opencv=opengl_to_opencv_c2w(c2w_opengl),
        file_paths=tuple(file_paths),
        image_paths=tuple(images),
        gt_paths=tuple(gts),
        exr_paths=tuple(exrs),
        split=split,
        light=light,
        ply_path=ply_path,
        meta=meta,
        depth_paths=tuple(depths) if any(p is not None for p in depths) else None,
        depth_scale=depth_scale,
    )
