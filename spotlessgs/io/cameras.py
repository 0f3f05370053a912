"""Camera intrinsics (pinhole projection, size, lens model), camera-convention changes and small rotation helpers
(numpy only; the lens itself is computed by spotlessgs.io.lens through OpenCV).

Conventions used across the project:

* World frame: metres, z up.
* ``c2w`` is a (4, 4) camera-to-world matrix ``[[R, C], [0, 0, 0, 1]]``: its columns are the camera axes and the
  camera centre in world coordinates.
* OpenGL/Blender camera axes: x right, y up, the camera looks along -z (the simulator and ``transforms.json``).
* OpenCV/COLMAP camera axes: x right, y down, the camera looks along +z (the trainer and COLMAP models).
* Pixel coordinates are continuous with the image's top-left *corner* at (0, 0): pixel (row i, column j) has its centre
  at (u, v) = (j + 0.5, i + 0.5). This is COLMAP's and nerfstudio's convention; ``cx = width / 2`` is the image centre.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

# Diagonal flipping y and z: converts camera axes between the OpenGL and OpenCV conventions (its own inverse).
_GL_CV_FLIP = np.diag([1.0, -1.0, -1.0, 1.0])

#: Lens models -> the numbers of distortion coefficients they accept, in OpenCV's order: ``opencv``
#: (k1, k2, p1, p2[, k3[, k4, k5, k6]]: cv2.projectPoints), ``fisheye`` (k1, k2, k3, k4: cv2.fisheye).
LENS_MODELS: dict[str, tuple[int, ...]] = {"pinhole": (0,), "opencv": (4, 5, 8), "fisheye": (4,)}


@dataclass(frozen=True)
class Intrinsics:
    """A camera: pinhole projection, image size and lens distortion.

    Attributes:
        fx: focal length along x, pixels.
        fy: focal length along y, pixels.
        cx: principal point x, pixels (continuous coordinates, image corner at 0).
        cy: principal point y, pixels.
        width: image width, pixels.
        height: image height, pixels.
        lens: a key of :data:`LENS_MODELS`; an ``opencv`` lens whose coefficients are all 0 becomes ``pinhole``.
        distortion: the lens's coefficients in OpenCV's order (empty for ``pinhole``); they act on normalised
            image coordinates, so resizing the image keeps them.
    """

    fx: float
    fy: float
    cx: float
    cy: float
    width: int
    height: int
    lens: str = "pinhole"
    distortion: tuple[float, ...] = ()

    def __post_init__(self) -> None:
        self._check_lens()
        for name in ("fx", "fy", "cx", "cy"):
            value = getattr(self, name)
            if not math.isfinite(value):
                raise ValueError(f"Intrinsics: {name} must be finite, got {value!r}")
        if self.fx <= 0 or self.fy <= 0:
            raise ValueError(f"Intrinsics: focal lengths must be positive, got fx={self.fx!r}, fy={self.fy!r}")
        if int(self.width) != self.width or int(self.height) != self.height or self.width <= 0 or self.height <= 0:
            raise ValueError(
                f"Intrinsics: width and height must be positive integers, got {self.width!r}x{self.height!r}"
            )
        object.__setattr__(self, "width", int(self.width))
        object.__setattr__(self, "height", int(self.height))
        for name in ("fx", "fy", "cx", "cy"):
            object.__setattr__(self, name, float(getattr(self, name)))

    def _check_lens(self) -> None:
        if self.lens not in LENS_MODELS:
            raise ValueError(f"Intrinsics: unknown lens model {self.lens!r}; choose one of {list(LENS_MODELS)}")
        coeffs = tuple(float(v) for v in self.distortion)
        if len(coeffs) not in LENS_MODELS[self.lens]:
            raise ValueError(f"Intrinsics: a {self.lens} lens takes {' or '.join(map(str, LENS_MODELS[self.lens]))} "
                             f"distortion coefficients, got {len(coeffs)}")
        if not all(math.isfinite(v) for v in coeffs):
            raise ValueError(f"Intrinsics: distortion coefficients must be finite, got {coeffs}")
        if self.lens == "opencv":  # the shortest equivalent form: k4..k6 = 0 -> 5 coefficients, k3 = 0 -> 4, none -> 0
            if len(coeffs) == 8 and not any(coeffs[5:]):
                coeffs = coeffs[:5]
            if len(coeffs) == 5 and coeffs[4] == 0.0:
                coeffs = coeffs[:4]
            if not any(coeffs):
                object.__setattr__(self, "lens", "pinhole")
                coeffs = ()
        object.__setattr__(self, "distortion", coeffs)

    @property
    def is_pinhole(self) -> bool:
        """True without lens distortion."""
        return self.lens == "pinhole"

    @classmethod
    def from_fov(cls, h_fov_deg: float, width: int, height: int) -> "Intrinsics":
        """Square pixels, principal point at the image centre, horizontal field of view ``h_fov_deg`` (0, 180)."""
        if not 0.0 < h_fov_deg < 180.0:
            raise ValueError(
                f"Intrinsics.from_fov: horizontal field of view must be in (0, 180) degrees, got {h_fov_deg!r}"
            )
        f = 0.5 * width / math.tan(math.radians(h_fov_deg) / 2.0)
        return cls(fx=f, fy=f, cx=width / 2.0, cy=height / 2.0, width=width, height=height)

    @property
    def h_fov_deg(self) -> float:
        """Horizontal field of view in degrees (for a centred principal point)."""
        return math.degrees(2.0 * math.atan(0.5 * self.width / self.fx))

    def K(self) -> np.ndarray:
        """The (3, 3) float64 calibration matrix."""
        return np.array([[self.fx, 0.0, self.cx], [0.0, self.fy, self.cy], [0.0, 0.0, 1.0]])

    def scaled(self, factor: float) -> "Intrinsics":
        """Intrinsics of the image resized by ``factor`` (e.g. 0.5 halves it).

        The new size is ``round(width * factor) x round(height * factor)``; focal lengths and principal point are scaled
        by the exact per-axis ratios new_size / old_size, so that image corners map to image corners.
        """
        if not (math.isfinite(factor) and factor > 0):
            raise ValueError(f"Intrinsics.scaled: factor must be positive and finite, got {factor!r}")
        width = max(1, round(self.width * factor))
        height = max(1, round(self.height * factor))
        sx, sy = width / self.width, height / self.height
        return Intrinsics(self.fx * sx, self.fy * sy, self.cx * sx, self.cy * sy, width, height, self.lens,
                          self.distortion)


def _check_poses(c2w: np.ndarray, name: str) -> np.ndarray:
    c2w = np.asarray(c2w, dtype=np.float64)
    if c2w.shape[-2:] != (4, 4) or c2w.ndim not in (2, 3):
        raise ValueError(f"{name}: expected a (4, 4) or (N, 4, 4) array, got shape {c2w.shape}")
    return c2w


#: World coordinates become float32 tensors for training, whose rounding is about 6e-8 of a coordinate. When the
#: camera centres lie farther from the world origin than this many times their spread (the largest distance of a
#: centre from their mean, at least 1 mm), that rounding would exceed 1e-5 of the scene (e.g. UTM coordinates,
#: ~5e6 m: camera centres ~0.25 m off); such poses are trained about their mean instead (:func:`working_origin`).
FAR_FROM_ORIGIN_RATIO = 168.0


def working_origin(c2w: np.ndarray) -> np.ndarray:
    """(3,) float64 point that world coordinates are taken relative to before they become float32: zeros for poses
    near the origin (every shipped and simulated dataset: their numbers stay as they were), else the mean camera
    centre (:data:`FAR_FROM_ORIGIN_RATIO`).

    Args:
        c2w: (N, 4, 4) camera-to-world matrices (either camera-axes convention), float64.
    """
    centres = np.asarray(c2w, dtype=np.float64)[:, :3, 3]
    mean = centres.mean(axis=0)
    spread = max(float(np.linalg.norm(centres - mean, axis=1).max()), 1e-3)
    far = float(np.linalg.norm(centres, axis=1).max())
    return mean if far > FAR_FROM_ORIGIN_RATIO * spread else np.zeros(3)


def opengl_to_opencv_c2w(c2w: np.ndarray) -> np.ndarray:
    """Camera-to-world (4, 4) or (N, 4, 4) with OpenGL camera axes -> the same poses with OpenCV camera axes."""
    return _check_poses(c2w, "opengl_to_opencv_c2w") @ _GL_CV_FLIP


def opencv_to_opengl_c2w(c2w: np.ndarray) -> np.ndarray:
    """Camera-to-world (4, 4) or (N, 4, 4) with OpenCV camera axes -> the same poses with OpenGL camera axes."""
    return _check_poses(c2w, "opencv_to_opengl_c2w") @ _GL_CV_FLIP


def world_to_camera(c2w: np.ndarray) -> np.ndarray:
    """The view matrix (world-to-camera), (4, 4) or (N, 4, 4), of rigid camera-to-world poses (same camera axes).

    Uses the rigid inverse ``[R^T, -R^T C]`` (exact for rotations, no general matrix inversion).
    """
    c2w = _check_poses(c2w, "world_to_camera")
    rot = c2w[..., :3, :3]
    centre = c2w[..., :3, 3]
    w2c = np.zeros_like(c2w)
    rot_t = np.swapaxes(rot, -1, -2)
    w2c[..., :3, :3] = rot_t
    w2c[..., :3, 3] = -np.einsum("...ij,...j->...i", rot_t, centre)
    w2c[..., 3, 3] = 1.0
    return w2c


def axis_angle_to_matrix(rotvec: np.ndarray) -> np.ndarray:
    """Rodrigues' formula: axis-angle vectors (..., 3) (radians) -> rotation matrices (..., 3, 3).

    Uses a Taylor expansion below 1e-4 rad, so small and zero angles are exact to float64 precision.
    """
    rotvec = np.asarray(rotvec, dtype=np.float64)
    if rotvec.shape[-1:] != (3,):
        raise ValueError(f"axis_angle_to_matrix: expected (..., 3), got shape {rotvec.shape}")
    theta = np.linalg.norm(rotvec, axis=-1)[..., None, None]
    small = theta < 1e-4
    theta_safe = np.where(small, 1.0, theta)
    theta2 = theta * theta
    a = np.where(small, 1.0 - theta2 / 6.0, np.sin(theta_safe) / theta_safe)
    b = np.where(small, 0.5 - theta2 / 24.0, (1.0 - np.cos(theta_safe)) / (theta_safe * theta_safe))
    x, y, z = rotvec[..., 0], rotvec[..., 1], rotvec[..., 2]
    zero = np.zeros_like(x)
    skew = np.stack([zero, -z, y, z, zero, -x, -y, x, zero], axis=-1).reshape(rotvec.shape[:-1] + (3, 3))
    eye = np.broadcast_to(np.eye(3), skew.shape)
    return eye + a * skew + b * (skew @ skew)


def matrix_to_quaternion_wxyz(rot: np.ndarray) -> np.ndarray:
    """Rotation matrices (..., 3, 3) -> unit quaternions (..., 4) ordered (w, x, y, z) with w >= 0.

    Shepperd's method: picks the numerically largest of the four candidate components, so it is stable for every
    rotation, including 180 degrees.
    """
    rot = np.asarray(rot, dtype=np.float64)
    if rot.shape[-2:] != (3, 3):
        raise ValueError(f"matrix_to_quaternion_wxyz: expected (..., 3, 3), got shape {rot.shape}")
    m = rot.reshape(-1, 3, 3)
    out = np.empty((m.shape[0], 4))
    trace = np.trace(m, axis1=1, axis2=2)
    diag = np.stack([trace, m[:, 0, 0], m[:, 1, 1], m[:, 2, 2]], axis=1)
    choice = np.argmax(diag, axis=1)
    for k in range(m.shape[0]):
        r = m[k]
        c = choice[k]
        if c == 0:
            s = 2.0 * math.sqrt(max(1.0 + trace[k], 0.0))
            q = [0.25 * s, (r[2, 1] - r[1, 2]) / s, (r[0, 2] - r[2, 0]) / s, (r[1, 0] - r[0, 1]) / s]
        elif c == 1:
            s = 2.0 * math.sqrt(max(1.0 + r[0, 0] - r[1, 1] - r[2, 2], 0.0))
            q = [(r[2, 1] - r[1, 2]) / s, 0.25 * s, (r[0, 1] + r[1, 0]) / s, (r[0, 2] + r[2, 0]) / s]
        elif c == 2:
            s = 2.0 * math.sqrt(max(1.0 + r[1, 1] - r[0, 0] - r[2, 2], 0.0))
            q = [(r[0, 2] - r[2, 0]) / s, (r[0, 1] + r[1, 0]) / s, 0.25 * s, (r[1, 2] + r[2, 1]) / s]
        else:
            s = 2.0 * math.sqrt(max(1.0 + r[2, 2] - r[0, 0] - r[1, 1], 0.0))
            q = [(r[1, 0] - r[0, 1]) / s, (r[0, 2] + r[2, 0]) / s, (r[1, 2] + r[2, 1]) / s, 0.25 * s]
        out[k] = q
    out /= np.linalg.norm(out, axis=1, keepdims=True)
    out[out[:, 0] < 0] *= -1.0
    return out.reshape(rot.shape[:-2] + (4,))


def quaternion_wxyz_to_matrix(quat: np.ndarray) -> np.ndarray:
    """Quaternions (..., 4) ordered (w, x, y, z) (normalised here, must be non-zero) -> rotations (..., 3, 3)."""
    quat = np.asarray(quat, dtype=np.float64)
    if quat.shape[-1:] != (4,):
        raise ValueError(f"quaternion_wxyz_to_matrix: expected (..., 4), got shape {quat.shape}")
    norm = np.linalg.norm(quat, axis=-1, keepdims=True)
    if not np.all(np.isfinite(norm)) or np.any(norm < 1e-12):
        raise ValueError("quaternion_wxyz_to_matrix: quaternions must be finite and non-zero")
    w, x, y, z = np.moveaxis(quat / norm, -1, 0)
    return np.stack(
        [
            1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y),
            2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x),
            2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y),
        ],
        axis=-1,
    ).reshape(quat.shape[:-1] + (3, 3))


def interpolate_pose(a: np.ndarray, b: np.ndarray, t: float) -> np.ndarray:
    """The (4, 4) rigid pose a fraction ``t`` in [0, 1] of the way from ``a`` to ``b`` (camera-to-world, any axis
    convention shared by both): the centre moves on the straight line, the rotation on the shortest arc (slerp)."""
    from scipy.spatial.transform import Rotation, Slerp

    out = np.eye(4)
    out[:3, :3] = Slerp([0.0, 1.0], Rotation.from_matrix(np.stack([a[:3, :3], b[:3, :3]])))([t]).as_matrix()[0]
    out[:3, 3] = (1.0 - t) * a[:3, 3] + t * b[:3, 3]
    return out
