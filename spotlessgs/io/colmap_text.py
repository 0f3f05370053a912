"""COLMAP sparse models: write the text format, read the text and binary formats.

Poses in a COLMAP model are world-to-camera (``cam_from_world``) in the OpenCV camera convention (x right, y down,
z forward), with the rotation stored as a unit quaternion ``QW QX QY QZ`` (scalar first). Only the three files of the
classic layout are written (``cameras.txt``, ``images.txt``, ``points3D.txt``); COLMAP >= 3.12 and pycolmap 4 read
them and create one trivial rig and frame per camera/image themselves. Reading ignores ``rigs``/``frames`` files.

Text format: https://colmap.github.io/format.html (one line per camera; two lines per image: the pose line and the
``X Y POINT3D_ID`` observations; one line per 3D point with its track of ``IMAGE_ID POINT2D_IDX`` pairs).
"""

from __future__ import annotations

import io
import os
import struct
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from spotlessgs.io.atomic import write_text
from spotlessgs.io.cameras import (
    Intrinsics,
    matrix_to_quaternion_wxyz,
    opengl_to_opencv_c2w,
    quaternion_wxyz_to_matrix,
    world_to_camera,
)

# COLMAP camera models: name -> (model id, number of parameters), as in colmap/src/colmap/sensor/models.h.
CAMERA_MODELS: dict[str, tuple[int, int]] = {
    "SIMPLE_PINHOLE": (0, 3),
    "PINHOLE": (1, 4),
    "SIMPLE_RADIAL": (2, 4),
    "RADIAL": (3, 5),
    "OPENCV": (4, 8),
    "OPENCV_FISHEYE": (5, 8),
    "FULL_OPENCV": (6, 12),
    "FOV": (7, 5),
    "SIMPLE_RADIAL_FISHEYE": (8, 4),
    "RADIAL_FISHEYE": (9, 5),
    "THIN_PRISM_FISHEYE": (10, 12),
    "RAD_TAN_THIN_PRISM_FISHEYE": (11, 16),
}
_MODEL_BY_ID = {model_id: (name, n) for name, (model_id, n) in CAMERA_MODELS.items()}
# The COLMAP models we read -> our lens model (spotlessgs.io.cameras.LENS_MODELS); see ColmapCamera.to_intrinsics.
SUPPORTED_MODELS = {"SIMPLE_PINHOLE": "pinhole", "PINHOLE": "pinhole", "SIMPLE_RADIAL": "opencv", "RADIAL": "opencv",
                    "OPENCV": "opencv", "FULL_OPENCV": "opencv", "OPENCV_FISHEYE": "fisheye"}


@dataclass(frozen=True)
class ColmapCamera:
    """One COLMAP camera.

    Attributes:
        camera_id: COLMAP camera id (>= 1).
        model: camera model name (a key of :data:`CAMERA_MODELS`).
        width: image width, pixels.
        height: image height, pixels.
        params: the model's parameters in COLMAP order (PINHOLE: fx, fy, cx, cy).
    """

    camera_id: int
    model: str
    width: int
    height: int
    params: tuple[float, ...]

    def to_intrinsics(self) -> Intrinsics:
        """The camera as :class:`Intrinsics` with OpenCV's lens model of the same projection (:data:`SUPPORTED_MODELS`:
        SIMPLE_RADIAL f, cx, cy, k and RADIAL f, cx, cy, k1, k2 are OpenCV's k1[, k2]; OPENCV k1, k2, p1, p2;
        FULL_OPENCV k1, k2, p1, p2, k3, k4, k5, k6; OPENCV_FISHEYE k1..k4, cv2.fisheye's)."""
        p = self.params
        if self.model not in SUPPORTED_MODELS:
            raise ValueError(f"COLMAP camera {self.camera_id}: model {self.model} is not supported (supported: "
                             f"{', '.join(SUPPORTED_MODELS)})")
        lens = SUPPORTED_MODELS[self.model]
        if self.model in ("SIMPLE_PINHOLE", "SIMPLE_RADIAL", "RADIAL"):
            fx = fy = p[0]
            cx, cy, rest = p[1], p[2], tuple(p[3:])
        else:
            fx, fy, cx, cy, rest = p[0], p[1], p[2], p[3], tuple(p[4:])
        if self.model in ("SIMPLE_RADIAL", "RADIAL"):
            rest = (rest + (0.0,))[:2] + (0.0, 0.0)  # k1, k2, p1 = p2 = 0
        return Intrinsics(fx, fy, cx, cy, self.width, self.height, lens, rest)

    @classmethod
    def from_intrinsics(cls, camera_id: int, intr: Intrinsics) -> "ColmapCamera":
        """The COLMAP camera of ``intr``: PINHOLE, OPENCV (4 coefficients), FULL_OPENCV (5 or 8) or
        OPENCV_FISHEYE."""
        pinhole = (intr.fx, intr.fy, intr.cx, intr.cy)
        if intr.is_pinhole:
            return cls(camera_id, "PINHOLE", intr.width, intr.height, pinhole)
        if intr.lens == "fisheye":
            model = "OPENCV_FISHEYE"
        else:
            model = "OPENCV" if len(intr.distortion) == 4 else "FULL_OPENCV"
        coeffs = intr.distortion + (0.0,) * (CAMERA_MODELS[model][1] - 4 - len(intr.distortion))
        return cls(camera_id, model, intr.width, intr.height, pinhole + coeffs)


@dataclass(frozen=True)
class ColmapImage:
    """One registered COLMAP image.

    Attributes:
        image_id: COLMAP image id (>= 1).
        qvec: (4,) float64 world-to-camera rotation quaternion (w, x, y, z).
        tvec: (3,) float64 world-to-camera translation.
        camera_id: id of its :class:`ColmapCamera`.
        name: image file name relative to the image folder.
        xys: (M, 2) float64 keypoint positions in pixels.
        point3d_ids: (M,) int64 id of the 3D point each keypoint observes, -1 for none.
    """

    image_id: int
    qvec: np.ndarray
    tvec: np.ndarray
    camera_id: int
    name: str
    xys: np.ndarray = field(default_factory=lambda: np.zeros((0, 2)))
    point3d_ids: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=np.int64))

    def cam_from_world(self) -> np.ndarray:
        """(4, 4) world-to-camera matrix, OpenCV camera axes."""
        mat = np.eye(4)
        mat[:3, :3] = quaternion_wxyz_to_matrix(self.qvec)
        mat[:3, 3] = self.tvec
        return mat

    def c2w_opencv(self) -> np.ndarray:
        """(4, 4) camera-to-world matrix, OpenCV camera axes."""
        return world_to_camera(self.cam_from_world())


@dataclass(frozen=True)
class ColmapPoints:
    """The 3D points of a model.

    Attributes:
        ids: (P,) int64 point ids.
        xyz: (P, 3) float64 positions.
        rgb: (P, 3) uint8 colours.
        errors: (P,) float64 mean reprojection errors (-1 when unknown).
        tracks: P arrays (L, 2) int64 of (image_id, point2D_idx) observations.
    """

    ids: np.ndarray
    xyz: np.ndarray
    rgb: np.ndarray
    errors: np.ndarray
    tracks: tuple[np.ndarray, ...]

    @staticmethod
    def empty() -> "ColmapPoints":
        """A model without 3D points."""
        return ColmapPoints(np.zeros(0, np.int64), np.zeros((0, 3)), np.zeros((0, 3), np.uint8), np.zeros(0), ())


@dataclass(frozen=True)
class ColmapModel:
    """A COLMAP sparse model: cameras and images by id, and the 3D points."""

    cameras: dict[int, ColmapCamera]
    images: dict[int, ColmapImage]
    points: ColmapPoints


def model_from_poses(
    intrinsics: Intrinsics,
    names: list[str],
    c2w_opengl: np.ndarray,
    xyz: np.ndarray | None = None,
    rgb: np.ndarray | None = None,
) -> ColmapModel:
    """A model with one camera (id 1; its COLMAP model from ``intrinsics``' lens), images 1..N and (optionally) 3D
    points without observations.

    Args:
        intrinsics: the shared camera.
        names: N image names (relative to the image folder, e.g. ``frame_00000.png``).
        c2w_opengl: (N, 4, 4) camera-to-world poses, OpenGL camera axes (as in ``transforms.json``).
        xyz: (P, 3) point positions, or None.
        rgb: (P, 3) uint8 point colours (required with ``xyz``).
    """
    c2w_opengl = np.asarray(c2w_opengl, dtype=np.float64)
    if c2w_opengl.ndim != 3 or c2w_opengl.shape[1:] != (4, 4) or c2w_opengl.shape[0] != len(names):
        raise ValueError(f"model_from_poses: expected ({len(names)}, 4, 4) poses, got shape {c2w_opengl.shape}")
    camera = ColmapCamera.from_intrinsics(1, intrinsics)
    w2c = world_to_camera(opengl_to_opencv_c2w(c2w_opengl))
    quats = matrix_to_quaternion_wxyz(w2c[:, :3, :3])
    images = {
        i + 1: ColmapImage(i + 1, quats[i], w2c[i, :3, 3].copy(), 1, name) for i, name in enumerate(names)
    }
    if xyz is None:
        points = ColmapPoints.empty()
    else:
        xyz = np.asarray(xyz, dtype=np.float64)
        if rgb is None or np.asarray(rgb).shape != xyz.shape or xyz.ndim != 2 or xyz.shape[1] != 3:
            raise ValueError("model_from_poses: xyz must be (P, 3) with an rgb array of the same shape")
        n = xyz.shape[0]
        empty_track = np.zeros((0, 2), np.int64)
        points = ColmapPoints(
            np.arange(1, n + 1, dtype=np.int64), xyz, np.asarray(rgb, np.uint8), -np.ones(n), (empty_track,) * n
        )
    return ColmapModel({1: camera}, images, points)


def _fmt(value: float) -> str:
    """Shortest repr that round-trips a float64 exactly."""
    return repr(float(value))


def write_colmap_text(folder: str | os.PathLike, model: ColmapModel) -> None:
    """Write ``cameras.txt``, ``images.txt`` and ``points3D.txt`` into ``folder`` (created), each atomically.

    Floats are written with Python's shortest round-trip representation, so reading back gives identical values.
    """
    folder = Path(folder)
    for image in model.images.values():
        if image.camera_id not in model.cameras:
            raise ValueError(f"{folder}: image {image.image_id} refers to unknown camera {image.camera_id}")
        if not image.name or any(c.isspace() for c in image.name):
            raise ValueError(f"{folder}: image {image.image_id} name {image.name!r} is empty or contains whitespace")
    lines = [
        "# Camera list with one line of data per camera:",
        "#   CAMERA_ID, MODEL, WIDTH, HEIGHT, PARAMS[]",
        f"# Number of cameras: {len(model.cameras)}",
    ]
    for cam in model.cameras.values():
        if cam.model not in CAMERA_MODELS or len(cam.params) != CAMERA_MODELS[cam.model][1]:
            raise ValueError(f"{folder}: camera {cam.camera_id} has model {cam.model!r} with {len(cam.params)} params")
        lines.append(" ".join([str(cam.camera_id), cam.model, str(cam.width), str(cam.height), *map(_fmt, cam.params)]))
    write_text(folder / "cameras.txt", "\n".join(lines) + "\n")

    lines = [
        "# Image list with two lines of data per image:",
        "#   IMAGE_ID, QW, QX, QY, QZ, TX, TY, TZ, CAMERA_ID, NAME",
        "#   POINTS2D[] as (X, Y, POINT3D_ID)",
        f"# Number of images: {len(model.images)}",
    ]
    for img in model.images.values():
        pose = [*map(_fmt, img.qvec), *map(_fmt, img.tvec)]
        lines.append(" ".join([str(img.image_id), *pose, str(img.camera_id), img.name]))
        lines.append(" ".join(f"{_fmt(x)} {_fmt(y)} {int(p)}" for (x, y), p in zip(img.xys, img.point3d_ids)))
    write_text(folder / "images.txt", "\n".join(lines) + "\n")

    pts = model.points
    lines = [
        "# 3D point list with one line of data per point:",
        "#   POINT3D_ID, X, Y, Z, R, G, B, ERROR, TRACK[] as (IMAGE_ID, POINT2D_IDX)",
        f"# Number of points: {len(pts.ids)}",
    ]
    for k in range(len(pts.ids)):
        track = " ".join(f"{int(i)} {int(j)}" for i, j in pts.tracks[k])
        fields = [str(int(pts.ids[k])), *map(_fmt, pts.xyz[k]), *map(str, pts.rgb[k].tolist()), _fmt(pts.errors[k])]
        lines.append(" ".join(fields + ([track] if track else [])))
    write_text(folder / "points3D.txt", "\n".join(lines) + "\n")


def _data_lines(path: Path) -> list[tuple[int, str]]:
    if not path.is_file():
        raise FileNotFoundError(f"{path}: COLMAP model file not found")
    data = path.read_bytes()
    try:
        text = data.decode("utf-8")
    except UnicodeDecodeError as exc:
        line = data[: exc.start].count(b"\n") + 1
        raise ValueError(f"{path}:{line}: not UTF-8 text ({exc.reason})") from None
    out = []
    for number, line in enumerate(io.StringIO(text, newline=None), start=1):  # lines as a text file's, \r\n included
        stripped = line.strip()
        if stripped.startswith("#"):
            continue
        out.append((number, stripped))
    return out


def read_colmap_text(folder: str | os.PathLike) -> ColmapModel:
    """Read ``cameras.txt``, ``images.txt`` and ``points3D.txt`` from ``folder``.

    Raises ValueError naming the file and line for malformed entries.
    """
    folder = Path(folder)
    cameras: dict[int, ColmapCamera] = {}
    path = folder / "cameras.txt"
    for number, line in _data_lines(path):
        if not line:
            continue
        try:
            parts = line.split()
            model = parts[1]
            if model not in CAMERA_MODELS:
                raise ValueError(f"unknown camera model {model!r}")
            params = tuple(float(v) for v in parts[4:])
            if len(params) != CAMERA_MODELS[model][1]:
                raise ValueError(f"model {model} needs {CAMERA_MODELS[model][1]} params, got {len(params)}")
            cam = ColmapCamera(int(parts[0]), model, int(parts[2]), int(parts[3]), params)
        except (ValueError, IndexError) as exc:
            raise ValueError(f"{path}:{number}: bad camera line ({exc})") from exc
        cameras[cam.camera_id] = cam

    images: dict[int, ColmapImage] = {}
    path = folder / "images.txt"
    lines = _data_lines(path)
    k = 0
    while k < len(lines):
        number, line = lines[k]
        if not line:  # a stray blank line between entries or at the end
            k += 1
            continue
        try:
            parts = line.split()
            if len(parts) < 10:
                raise ValueError(f"expected 10 fields, got {len(parts)}")
            obs = lines[k + 1][1].split() if k + 1 < len(lines) else []
            if len(obs) % 3:
                raise ValueError("observation line must hold (X, Y, POINT3D_ID) triples")
            obs_arr = np.array(obs, dtype=np.float64).reshape(-1, 3)
            img = ColmapImage(
                image_id=int(parts[0]),
                qvec=np.array(parts[1:5], dtype=np.float64),
                tvec=np.array(parts[5:8], dtype=np.float64),
                camera_id=int(parts[8]),
                name=" ".join(parts[9:]),
                xys=obs_arr[:, :2].copy(),
                point3d_ids=obs_arr[:, 2].astype(np.int64),
            )
        except (ValueError, IndexError) as exc:
            raise ValueError(f"{path}:{number}: bad image entry ({exc})") from exc
        if img.camera_id not in cameras:
            raise ValueError(f"{path}:{number}: image {img.image_id} refers to unknown camera {img.camera_id}")
        _check_image(img, images, f"{path}:{number}")
        images[img.image_id] = img
        k += 2

    path = folder / "points3D.txt"
    ids, xyz, rgb, errors, tracks = [], [], [], [], []
    for number, line in _data_lines(path):
        if not line:
            continue
        try:
            parts = line.split()
            if len(parts) < 8 or (len(parts) - 8) % 2:
                raise ValueError(f"expected 8 fields plus (IMAGE_ID, POINT2D_IDX) pairs, got {len(parts)} fields")
            ids.append(int(parts[0]))
            xyz.append([float(v) for v in parts[1:4]])
            colour = [int(v) for v in parts[4:7]]
            if not all(0 <= v <= 255 for v in colour):
                raise ValueError(f"colour {colour} outside 0..255")
            rgb.append(colour)
            errors.append(float(parts[7]))
            tracks.append(np.array(parts[8:], dtype=np.int64).reshape(-1, 2))
        except (ValueError, IndexError) as exc:
            raise ValueError(f"{path}:{number}: bad point line ({exc})") from exc
    points = ColmapPoints(
        np.array(ids, dtype=np.int64),
        np.array(xyz, dtype=np.float64).reshape(-1, 3),
        np.array(rgb, dtype=np.uint8).reshape(-1, 3),
        np.array(errors, dtype=np.float64),
        tuple(tracks),
    )
    return ColmapModel(cameras, images, points)


def _check_image(image: ColmapImage, images: dict[int, ColmapImage], where: str) -> None:
    """ValueError naming ``where`` (the file, and line) for an image that repeats an id already in ``images`` or whose
    pose is not finite or has a zero quaternion."""
    if image.image_id in images:
        raise ValueError(f"{where}: image id {image.image_id} appears twice")
    norm = float(np.linalg.norm(image.qvec))
    if not (np.isfinite(image.qvec).all() and np.isfinite(image.tvec).all() and norm > 1e-12):
        raise ValueError(f"{where}: image {image.image_id} has an unusable pose (quaternion {image.qvec.tolist()}, "
                         f"translation {image.tvec.tolist()}: not finite, or a zero quaternion)")


class _Reader:
    """Little-endian binary reader that names the file on truncation."""

    def __init__(self, path: Path):
        if not path.is_file():
            raise FileNotFoundError(f"{path}: COLMAP model file not found")
        self.path = path
        self.data = path.read_bytes()
        self.pos = 0

    def read(self, fmt: str) -> tuple:
        size = struct.calcsize("<" + fmt)
        if self.pos + size > len(self.data):
            raise ValueError(f"{self.path}: truncated file (needed {size} bytes at offset {self.pos})")
        values = struct.unpack_from("<" + fmt, self.data, self.pos)
        self.pos += size
        return values

    def array(self, dtype: np.dtype, count: int) -> np.ndarray:
        dtype = np.dtype(dtype)
        size = dtype.itemsize * count
        if self.pos + size > len(self.data):
            raise ValueError(f"{self.path}: truncated file (needed {size} bytes at offset {self.pos})")
        out = np.frombuffer(self.data, dtype=dtype, count=count, offset=self.pos).copy()
        self.pos += size
        return out

    def string(self) -> str:
        end = self.data.find(b"\x00", self.pos)
        if end < 0:
            raise ValueError(f"{self.path}: unterminated image name at offset {self.pos}")
        try:
            text = self.data[self.pos : end].decode("utf-8")
        except UnicodeDecodeError as exc:
            raise ValueError(f"{self.path}: image name at offset {self.pos} is not UTF-8 ({exc.reason})") from None
        self.pos = end + 1
        return text

    def finish(self) -> None:
        if self.pos != len(self.data):
            raise ValueError(f"{self.path}: {len(self.data) - self.pos} unexpected trailing bytes")


def read_colmap_binary(folder: str | os.PathLike) -> ColmapModel:
    """Read ``cameras.bin``, ``images.bin`` and ``points3D.bin`` from ``folder`` (COLMAP's binary layout)."""
    folder = Path(folder)
    reader = _Reader(folder / "cameras.bin")
    cameras: dict[int, ColmapCamera] = {}
    for _ in range(reader.read("Q")[0]):
        camera_id, model_id, width, height = reader.read("iiQQ")
        if model_id not in _MODEL_BY_ID:
            raise ValueError(f"{reader.path}: camera {camera_id} has unknown model id {model_id}")
        name, n_params = _MODEL_BY_ID[model_id]
        params = tuple(float(v) for v in reader.read("d" * n_params))
        cameras[camera_id] = ColmapCamera(camera_id, name, width, height, params)
    reader.finish()

    reader = _Reader(folder / "images.bin")
    images: dict[int, ColmapImage] = {}
    obs_dtype = np.dtype([("x", "<f8"), ("y", "<f8"), ("id", "<i8")])
    for _ in range(reader.read("Q")[0]):
        image_id, qw, qx, qy, qz, tx, ty, tz, camera_id = reader.read("I7dI")
        name = reader.string()
        obs = reader.array(obs_dtype, reader.read("Q")[0])
        if camera_id not in cameras:
            raise ValueError(f"{reader.path}: image {image_id} refers to unknown camera {camera_id}")
        image = ColmapImage(
            image_id,
            np.array([qw, qx, qy, qz]),
            np.array([tx, ty, tz]),
            camera_id,
            name,
            np.stack([obs["x"], obs["y"]], axis=1),
            obs["id"].astype(np.int64),
        )
        _check_image(image, images, str(reader.path))
        images[image_id] = image
    reader.finish()

    reader = _Reader(folder / "points3D.bin")
    n_points = reader.read("Q")[0]
    ids = np.zeros(n_points, np.int64)
    xyz = np.zeros((n_points, 3))
    rgb = np.zeros((n_points, 3), np.uint8)
    errors = np.zeros(n_points)
    tracks = []
    for k in range(n_points):
        values = reader.read("Q3d3Bd")
        ids[k], xyz[k], rgb[k], errors[k] = values[0], values[1:4], values[4:7], values[7]
        length = reader.read("Q")[0]
        tracks.append(reader.array(np.dtype("<u4"), 2 * length).reshape(-1, 2).astype(np.int64))
    reader.finish()
    return ColmapModel(cameras, images, ColmapPoints(ids, xyz, rgb, errors, tuple(tracks)))


def model_files(folder: str | os.PathLike) -> tuple[Path, Path, Path]:
    """The files of the COLMAP model in ``folder`` that :func:`read_colmap_model` reads, cameras, images and points:
    the binary model (``.bin``) when ``cameras.bin`` exists, else the text one (``.txt``); they need not exist."""
    suffix = ".bin" if (Path(folder) / "cameras.bin").is_file() else ".txt"
    return tuple(Path(folder) / f"{name}{suffix}" for name in ("cameras", "images", "points3D"))


def read_colmap_model(folder: str | os.PathLike) -> ColmapModel:
    """Read a COLMAP model folder, binary (``cameras.bin``) if present, else text (``cameras.txt``)."""
    cameras = model_files(folder)[0]
    if not cameras.is_file():
        raise FileNotFoundError(f"{folder}: no COLMAP model (neither cameras.bin nor cameras.txt)")
    return read_colmap_binary(folder) if cameras.suffix == ".bin" else read_colmap_text(folder)
