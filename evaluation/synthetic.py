"""A small posed synthetic sequence rendered by ray casting (no Blender): the interior of a textured box room.

For self-tests and benchmarks of the evaluation package: images with exact depth, intrinsics and camera poses, under
even light and under a camera-mounted spotlight. Every wall, the floor and the ceiling carry their own non-repetitive
multi-scale random texture, so SIFT finds distinctive features and every view registers.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from spotlessgs.io.cameras import Intrinsics, opencv_to_opengl_c2w
from spotlessgs.io.lens import undistort
from spotlessgs.io.colorspace import linear_to_srgb
from spotlessgs.io.exr import DEPTH_CHANNEL, write_exr
from spotlessgs.io.images import write_png
from spotlessgs.io.seeding import numpy_rng
from spotlessgs.io.transforms import DatasetMeta, FrameRecord, write_transforms

#: Room extent in metres: x in [-ROOM_X, ROOM_X], y in [-ROOM_Y, ROOM_Y], z in [0, ROOM_Z] (z up).
ROOM_X, ROOM_Y, ROOM_Z = 2.5, 2.0, 2.6


@dataclass(frozen=True)
class SyntheticSequence:
    """A rendered posed sequence."""

    even: np.ndarray  # (N, H, W, 3) float32 sRGB in [0, 1], evenly lit
    spot: np.ndarray  # (N, H, W, 3) float32 sRGB in [0, 1], lit only by a camera-mounted spotlight
    depth: np.ndarray  # (N, H, W) float32 planar depth in metres (the room is closed: always finite)
    c2w_opengl: np.ndarray  # (N, 4, 4) camera-to-world, OpenGL axes (x right, y up, looking along −z)
    intrinsics: Intrinsics  # shared pinhole intrinsics


def _face_textures(seed: int, size: int = 1024) -> np.ndarray:
    """(6, size, size) albedo textures in [0.1, 0.9]: sums of bilinearly upsampled noise at several octaves."""
    rng = numpy_rng(seed, "synthetic-textures")
    out = np.zeros((6, size, size))
    for f in range(6):
        tex = np.zeros((size, size))
        for cells, amp in ((4, 1.0), (16, 0.8), (64, 0.7), (256, 0.5)):
            coarse = rng.random((cells + 1, cells + 1))
            tex += amp * _bilinear(coarse, np.linspace(0, cells, size), np.linspace(0, cells, size))
        tex = (tex - tex.min()) / (tex.max() - tex.min())
        out[f] = 0.05 + 0.9 * tex
    return out


def _bilinear(grid: np.ndarray, rows: np.ndarray, cols: np.ndarray) -> np.ndarray:
    """Sample a 2-D ``grid`` at the outer product of fractional ``rows`` × ``cols`` → (len(rows), len(cols))."""
    r0 = np.clip(np.floor(rows).astype(int), 0, grid.shape[0] - 2)
    c0 = np.clip(np.floor(cols).astype(int), 0, grid.shape[1] - 2)
    fr, fc = (rows - r0)[:, None], (cols - c0)[None, :]
    g00, g01 = grid[np.ix_(r0, c0)], grid[np.ix_(r0, c0 + 1)]
    g10, g11 = grid[np.ix_(r0 + 1, c0)], grid[np.ix_(r0 + 1, c0 + 1)]
    return (1 - fr) * ((1 - fc) * g00 + fc * g01) + fr * ((1 - fc) * g10 + fc * g11)


def _sample(tex: np.ndarray, u: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Bilinear lookup of (S, S) ``tex`` at texture coordinates u, v in [0, 1] (any equal shapes) → same shape."""
    s = tex.shape[0] - 1
    x, y = np.clip(u, 0, 1) * s, np.clip(v, 0, 1) * s
    x0, y0 = np.clip(np.floor(x).astype(int), 0, s - 1), np.clip(np.floor(y).astype(int), 0, s - 1)
    fx, fy = x - x0, y - y0
    return ((1 - fy) * ((1 - fx) * tex[y0, x0] + fx * tex[y0, x0 + 1])
            + fy * ((1 - fx) * tex[y0 + 1, x0] + fx * tex[y0 + 1, x0 + 1]))


def _look_at_opencv(eye: np.ndarray, target: np.ndarray) -> np.ndarray:
    """(4, 4) camera-to-world, OpenCV axes, camera at ``eye`` looking at ``target`` with world z up."""
    fwd = target - eye
    fwd /= np.linalg.norm(fwd)
    right = np.cross(fwd, [0.0, 0.0, 1.0])
    right /= np.linalg.norm(right)
    down = np.cross(fwd, right)
    c2w = np.eye(4)
    c2w[:3, 0], c2w[:3, 1], c2w[:3, 2], c2w[:3, 3] = right, down, fwd, eye
    return c2w


def render_room_sequence(
    num_frames: int = 16, width: int = 240, height: int = 180, seed: int = 0, spot_power: float = 2.5,
    lens: str = "pinhole", distortion: tuple[float, ...] = (),
) -> SyntheticSequence:
    """Render a camera moving on a smooth arc inside the textured room.

    Args:
        num_frames: frames along the path.
        width, height: image size in pixels.
        seed: seed of the textures (same seed, same images).
        spot_power: radiant intensity of the spotlight image (arbitrary units).
        lens, distortion: the camera's lens (:class:`~spotlessgs.io.cameras.Intrinsics`): each pixel's ray goes
            through the lens (the ground truth too), as a real distorted camera sees the room.
    """
    if num_frames < 2 or width < 16 or height < 16:
        raise ValueError("need at least 2 frames of at least 16x16 pixels")
    textures = _face_textures(seed)
    f = 0.9 * width
    intr = Intrinsics(f, f, width / 2.0, height / 2.0, width, height, lens, distortion)
    lo, hi = np.array([-ROOM_X, -ROOM_Y, 0.0]), np.array([ROOM_X, ROOM_Y, ROOM_Z])
    jj, ii = np.meshgrid(np.arange(height) + 0.5, np.arange(width) + 0.5, indexing="ij")
    xy = undistort(intr, np.stack([ii.ravel(), jj.ravel()], axis=1))  # (P, 2) normalised, through the lens
    rays_cam = np.concatenate([xy, np.ones((len(xy), 1))], axis=1)
    even, spot, depth, poses = [], [], [], []
    for k in range(num_frames):
        s = k / (num_frames - 1)
        eye = np.array([-0.9 + 1.6 * s, -0.6 + 0.35 * np.sin(np.pi * s), 1.3 + 0.1 * np.sin(2 * np.pi * s)])
        yaw = np.radians(60.0 - 75.0 * s)
        target = eye + np.array([np.cos(yaw), np.sin(yaw), -0.25])
        c2w = _look_at_opencv(eye, target)
        d = rays_cam @ c2w[:3, :3].T  # (P, 3) world directions with unit forward component
        with np.errstate(divide="ignore", invalid="ignore"):
            t_axes = np.where(d > 0, (hi - eye) / d, np.where(d < 0, (lo - eye) / d, np.inf))
        axis = np.argmin(t_axes, axis=1)
        t = t_axes[np.arange(len(d)), axis]  # planar depth: the ray's forward component is 1
        p = eye + t[:, None] * d
        face = 2 * axis + (d[np.arange(len(d)), axis] > 0)
        span = hi - lo
        rel = (p - lo) / span
        uv_axes = np.array([[1, 2], [0, 2], [0, 1]])[axis]
        u = rel[np.arange(len(d)), uv_axes[:, 0]]
        v = rel[np.arange(len(d)), uv_axes[:, 1]]
        albedo = np.zeros(len(d))
        for fi in range(6):
            m = face == fi
            albedo[m] = _sample(textures[fi], u[m], v[m])
        tint = np.array([[1.0, 0.92, 0.85], [0.85, 0.95, 1.0], [0.95, 1.0, 0.9],
                         [1.0, 0.95, 0.95], [0.9, 0.9, 1.0], [1.0, 1.0, 0.95]])[face]
        colour = albedo[:, None] * tint
        normal = np.zeros_like(d)
        normal[np.arange(len(d)), axis] = np.where(d[np.arange(len(d)), axis] > 0, -1.0, 1.0)
        dist = np.linalg.norm(p - eye, axis=1)
        to_cam = (eye - p) / dist[:, None]
        cos_cam = np.clip((normal * to_cam).sum(1), 0, 1)
        cos_axis = (d / np.linalg.norm(d, axis=1, keepdims=True)) @ c2w[:3, 2]
        cone = 1.0 / (1.0 + np.exp(-(cos_axis - np.cos(np.radians(22))) * 40.0))
        spot_light = spot_power * cone * cos_cam / dist**2
        even_lin = np.clip(colour * 0.9, 0, 1)
        spot_lin = np.clip(colour * spot_light[:, None], 0, 1)
        even.append(linear_to_srgb(even_lin).reshape(height, width, 3))
        spot.append(linear_to_srgb(spot_lin).reshape(height, width, 3))
        depth.append(t.reshape(height, width))
        poses.append(opencv_to_opengl_c2w(c2w))
    return SyntheticSequence(
        even=np.stack(even).astype(np.float32),
        spot=np.stack(spot).astype(np.float32),
        depth=np.stack(depth).astype(np.float32),
        c2w_opengl=np.stack(poses),
        intrinsics=intr,
    )


def write_dataset_folder(seq: SyntheticSequence, root, with_depth: bool = True, test_every: int = 11) -> list[str]:
    """Write ``seq`` as a dataset folder with the shared writers: ``transforms.json`` (our contract, split every
    ``test_every``-th frame, no light truth), images/ = spotlight, gt/ = even, depth/*.exr (channel ``depth.Z``).

    Returns the image names.
    """
    from pathlib import Path

    root = Path(root)
    frames, names = [], []
    for k in range(len(seq.even)):
        name = f"frame_{k:05d}.png"
        names.append(name)
        write_png(root / "images" / name, seq.spot[k])
        write_png(root / "gt" / name, seq.even[k])
        exr = None
        if with_depth:
            exr = f"depth/frame_{k:05d}.exr"
            write_exr(root / exr, {DEPTH_CHANNEL: seq.depth[k]})
        frames.append(FrameRecord(f"images/{name}", seq.c2w_opengl[k], gt_file_path=f"gt/{name}", exr_file_path=exr))
    meta = DatasetMeta(scene_id="synthetic-box-room", renderer={"engine": "evaluation.synthetic ray casting"},
                       test_every=test_every)
    write_transforms(root / "transforms.json", seq.intrinsics, frames, meta)
    return names
