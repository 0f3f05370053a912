"""``spotless prepare --points DATA`` on a dataset with depth images: a dense start from an RGB-D camera.

A robot with a depth camera (RealSense, Azure Kinect, a stereo pair) records a depth image registered to each colour
frame (the dataset's ``depth_file_path`` s: :mod:`spotlessgs.io.depth_images`). Back-projecting the training frames'
depth through the camera's lens with their poses gives a dense cloud. A depth camera is noisy along the ray (about
1 cm at 2 m), and a voxel grid finer than that noise does not average it out: each depth image is first averaged over
a small window, as RGB-D fusion smooths it (:func:`depth_surface`; pixels at a depth edge, where a depth camera's
flying pixels lie, give no point), and its normals are taken from the averaged depth. The points are then averaged on
a voxel grid, at most ``max_points`` kept, coloured from the frames, and each normal is averaged with its
neighbours' (:func:`neighbour_mean_normals`). The trainer trusts such a start's geometry
(``TrainConfig.trust_start_geometry``: dense, with normals): on the simulated robot camera it is what the lamp's
bounce light needs (docs/results.md, "An RGB-D start").

    DATA/depth_points.ply          the voxel-averaged points
    DATA/prepare.json              "points": how many, from how many frames and depth pixels, the voxel, the settings
    DATA/transforms.json           gets "ply_file_path": "depth_points.ply" (rewritten atomically, nothing else changes)
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import Any, NamedTuple

import numpy as np

from simulator.pointcloud import backproject_depth, merge_point_clouds
from spotlessgs.io.cameras import Intrinsics
from spotlessgs.io.colorspace import linear_to_srgb
from spotlessgs.io.dataset import read_dataset
from spotlessgs.io.depth_images import read_depth_image
from spotlessgs.io.errors import InputError
from spotlessgs.io.images import read_image
from spotlessgs.io.lens import camera_points
from spotlessgs.io.provenance import provenance
from spotlessgs.io.seeding import numpy_rng
from spotlessgs.io.transforms import DatasetDescription
from spotlessgs.prepare.points import adopt_start_cloud, training_frames

DEPTH_POINTS_FILE = "depth_points.ply"
#: The most points of the start (the simulator's dense clouds have as many).
MAX_DEPTH_POINTS = 60_000
#: The voxel's edge as a share of the median measured depth (1 cm at 2 m).
VOXEL_PER_METRE = 0.005
#: The fewest depth pixels of a frame kept before the voxel grid (a seeded subset of a larger frame).
MIN_FRAME_SAMPLES = 20_000
#: The window (pixels) over which a depth image is averaged before its normals are taken.
NORMAL_WINDOW = 5
#: Neighbouring depths further apart than this share of the nearer one are an edge: no point within the window. Well
#: above a depth camera's noise (σ = 0.0025 z² is 1.5 % at 6 m, the difference of two pixels √2 that): at 3 % the
#: noise itself made edges, and the simulated robot's start lost its far walls (49 % of the room's surface further
#: than 3 cm from any point, against 17 % at 10 %; docs/results.md, "An RGB-D start").
EDGE_JUMP = 0.1
#: The nearest points whose normals each point's normal is averaged with.
NORMAL_NEIGHBOURS = 16


def has_depth_images(dataset: DatasetDescription) -> bool:
    """Whether every training frame of ``dataset`` has a depth image."""
    return dataset.depth_paths is not None and all(dataset.depth_paths[k] is not None for k in dataset.split.train)


def add_depth_points(
    data: str | Path, max_points: int = MAX_DEPTH_POINTS, seed: int = 0,
    progress: Callable[[str], None] | None = None,
) -> dict[str, Any]:
    """Back-project the training frames' depth images of the posed dataset ``data`` into a dense point cloud and
    make it the dataset's initial point cloud (see the module docstring).

    Args:
        data: the dataset folder (a ``transforms.json`` with ``depth_file_path`` s and no ``ply_file_path``).
        max_points: the most points kept (a seeded uniform subset of the voxel points beyond it).
        seed: the subset's seed.
        progress: called with each step's name.
    Returns:
        the ``points`` summary also written into ``data/prepare.json``.
    Raises:
        InputError: ``data`` has no ``transforms.json``, already names a point cloud, a training frame has no depth
            image, a depth image is unreadable or of another size than its frame, or no pixel has a depth (the
            dataset is then left as it was).
    """
    data = Path(data)
    transforms = data / "transforms.json"
    if not transforms.is_file():
        raise InputError(f"{data}: --points needs a posed dataset with transforms.json")
    dataset = read_dataset(transforms, check_files=True)
    if dataset.ply_path is not None:
        raise InputError(f"{transforms}: already names a point cloud ({dataset.ply_path.name}); nothing to do")
    train = training_frames(dataset, transforms)
    missing = [k for k in train if dataset.depth_paths is None or dataset.depth_paths[k] is None]
    if missing:
        raise InputError(f"{transforms}: frames[{missing[0]}] ({dataset.file_paths[missing[0]]}) has no "
                         f"depth_file_path ({len(missing)} of {len(train)} training frames have none)")
    step = progress or (lambda _name: None)
    step(f"back-projecting the depth images of {len(train)} training frames")
    rng = numpy_rng(seed, "depth-points")
    per_frame = max(4 * max_points // len(train), MIN_FRAME_SAMPLES)  # bounds the memory of a long sequence
    clouds, measured, depths = [], 0, []
    for k in train:
        path, camera = dataset.depth_paths[k], dataset.cameras[k]
        depth = read_depth_image(path, dataset.depth_scale)
        if depth.shape != (camera.height, camera.width):
            raise InputError(f"{path}: the depth image is {depth.shape[1]}x{depth.shape[0]}, its frame "
                             f"{dataset.file_paths[k]} {camera.width}x{camera.height} (it must be registered to the "
                             "colour image)")
        valid = np.isfinite(depth)
        measured += int(valid.sum())
        depths.append(depth[valid][:: max(int(valid.sum()) // 1000, 1)])
        surface = depth_surface(depth, camera)
        normals = surface.normals @ dataset.c2w_opencv[k][:3, :3].T  # camera → world
        clouds.append(backproject_depth(surface.depth, _srgb_uint8(dataset, k), np.nan_to_num(normals), camera,
                                        dataset.c2w_opengl[k], max_points=per_frame, rng=rng))
    if measured == 0:
        raise InputError(f"{data}: no depth image of the {len(train)} training frames has a measured pixel")
    voxel = VOXEL_PER_METRE * float(np.median(np.concatenate(depths)))
    step(f"merging {measured} depth pixels on a {100 * voxel:.1f} cm voxel grid")
    cloud = merge_point_clouds(clouds, voxel_size=voxel, max_points=max_points, rng=rng)
    if len(cloud.xyz) == 0:
        raise InputError(f"{data}: the depth images of the {len(train)} training frames give no point with a normal "
                         "(every measured pixel lies at a depth edge)")
    summary = {"file": DEPTH_POINTS_FILE, "source": "depth images", "points": len(cloud.xyz), "frames": len(train),
               "depth_pixels": measured, "voxel_m": voxel, "depth_unit_scale_factor": dataset.depth_scale,
               "max_points": max_points, "provenance": provenance(seed=seed)}
    adopt_start_cloud(data, DEPTH_POINTS_FILE, cloud.xyz, cloud.rgb, neighbour_mean_normals(cloud.xyz, cloud.normals),
                      summary)
    return summary


class DepthSurface(NamedTuple):
    """A depth image smoothed for back-projection (:func:`depth_surface`).

    Attributes:
        depth: (H, W) metres, averaged over the window; NaN where unmeasured or at a depth edge.
        normals: (H, W, 3) unit camera-frame normals (OpenCV axes) facing the camera; NaN where ``depth`` is.
    """

    depth: np.ndarray
    normals: np.ndarray


def surface_normals(points: np.ndarray) -> np.ndarray:
    """(H, W, 3) unit normals, facing the camera, of the surface that camera-frame points (H, W, 3) trace (a depth map
    back-projected: io.lens.camera_points): the cross product of their central differences along the image's rows
    and columns. NaN on the image's border and next to a NaN point."""
    dx, dy = np.full_like(points, np.nan), np.full_like(points, np.nan)
    dx[:, 1:-1] = points[:, 2:] - points[:, :-2]
    dy[1:-1] = points[2:] - points[:-2]
    with np.errstate(invalid="ignore", divide="ignore"):
        normals = np.cross(dx, dy)
        normals /= np.linalg.norm(normals, axis=-1, keepdims=True)
    normals[(normals * points).sum(-1) > 0] *= -1.0  # towards the camera
    return normals


def depth_surface(depth: np.ndarray, camera: Intrinsics, window: int = NORMAL_WINDOW,
                  edge_jump: float = EDGE_JUMP) -> DepthSurface:
    """A depth image (H, W) in metres (NaN: no measurement) seen through ``camera``'s lens, averaged over ``window``
    × ``window`` pixels (a depth camera's noise along the ray drops by about the window's width on a flat surface),
    and its normals (:func:`surface_normals` of the averaged depth's camera-frame points). Both
    NaN where the window is not fully measured (the image's border, holes: a one-sided mean bends a slope), where a
    pixel of the window lies at a depth edge (neighbours further apart than ``edge_jump`` of the nearer depth, where
    averaging would join two surfaces), and where a difference is missing."""
    from scipy.ndimage import maximum_filter, uniform_filter

    measured = np.isfinite(depth)
    weight = uniform_filter(measured.astype(np.float64), window, mode="constant")
    total = uniform_filter(np.where(measured, depth, 0.0), window, mode="constant")
    with np.errstate(invalid="ignore", divide="ignore"):  # only full windows: a one-sided mean bends a slope
        smooth = np.where(weight > 1.0 - 1e-9, total / weight, np.nan)
    points = camera_points(camera, np.nan_to_num(smooth))
    points[np.isnan(smooth)] = np.nan
    normals = surface_normals(points)
    far = np.where(measured, depth, np.inf)  # a missing depth counts as an edge

    def apart(a: np.ndarray, b: np.ndarray) -> np.ndarray:
        return ~(np.abs(a - b) <= edge_jump * np.minimum(a, b))

    edge = np.zeros(depth.shape, dtype=bool)
    horizontal, vertical = apart(far[:, 1:], far[:, :-1]), apart(far[1:], far[:-1])
    edge[:, 1:] |= horizontal
    edge[:, :-1] |= horizontal
    edge[1:] |= vertical
    edge[:-1] |= vertical
    normals[maximum_filter(edge, size=window + 2)] = np.nan
    unknown = np.isnan(normals).any(-1)
    normals[unknown] = np.nan
    return DepthSurface(np.where(unknown, np.nan, smooth), normals)


def neighbour_mean_normals(xyz: np.ndarray, normals: np.ndarray, neighbours: int = NORMAL_NEIGHBOURS) -> np.ndarray:
    """(N, 3) each unit normal (N, 3) of the points ``xyz`` (N, 3) averaged with those of its ``neighbours`` nearest
    points (itself included), each turned to its side first (a surface's two faces do not cancel), normalised."""
    from scipy.spatial import cKDTree

    if len(xyz) < 2:
        return normals
    _, idx = cKDTree(xyz).query(xyz, k=min(neighbours, len(xyz)))
    around = normals[idx]  # (N, k, 3)
    side = np.where((around * normals[:, None]).sum(-1, keepdims=True) < 0, -1.0, 1.0)
    mean = (around * side).sum(1)
    return mean / np.linalg.norm(mean, axis=1, keepdims=True)


def _srgb_uint8(dataset: DatasetDescription, k: int) -> np.ndarray:
    """(H, W, 3) uint8 sRGB colours of frame ``k`` (linear frames encoded); InputError naming the frame where it is
    not of its camera's size."""
    image = read_image(dataset.image_paths[k])
    camera = dataset.cameras[k]
    if image.shape[:2] != (camera.height, camera.width):
        raise InputError(f"{dataset.image_paths[k]}: the frame is {image.shape[1]}x{image.shape[0]}, its camera "
                         f"{camera.width}x{camera.height}")
    if dataset.meta.get("linear_images"):
        image = linear_to_srgb(np.clip(image, 0.0, 1.0))
    return np.clip(np.rint(np.asarray(image) * 255.0), 0, 255).astype(np.uint8)
