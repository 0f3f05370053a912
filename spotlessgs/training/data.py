"""Training views as tensors: linear images at the training resolution, clipped-pixel masks, cameras, split.

Reads any dataset folder that :func:`spotlessgs.io.dataset.read_dataset` reads (ours, nerfstudio, COLMAP). Images of
a camera with lens distortion are resampled into its pinhole working camera (:func:`spotlessgs.io.lens.working_camera`);
the working pixels without an input sample are marked ``unseen`` and take no part in the loss or the scores.
"""

from __future__ import annotations

import functools
import logging
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch
import torch.nn.functional as F

from spotlessgs.io.camera_batch import Cameras
from spotlessgs.io.cameras import Intrinsics
from spotlessgs.io.colorspace import srgb_to_linear
from spotlessgs.io.dataset import load_initial_points, read_dataset
from spotlessgs.io.frame_quality import FrameStats, frame_stats, usable_frames, warn_unusable_test_frames
from spotlessgs.io.exposure import frame_exposures
from spotlessgs.io.images import read_image_with_alpha
from spotlessgs.io.lens import remap, undistort_maps, working_camera
from spotlessgs.io.ply import PointCloud
from spotlessgs.io.pose_layout import warn_pose_layout, warn_unseen_points
from spotlessgs.io.transforms import DatasetDescription, LightTruth

log = logging.getLogger(__name__)


@dataclass
class TrainingViews:
    """All views of a dataset at the training resolution (N views, H x W pixels).

    Attributes:
        dataset: the parsed dataset description.
        names: N image file names (``frame_00000.png``), used to name rendered outputs.
        images: (N, H, W, 3) float32 linear RGB inputs.
        saturated: (N, H, W) bool, True where an input pixel was clipped (any channel >= the threshold).
        cameras: the N views' poses (float32, OpenCV axes) and (pinhole) cameras at the training resolution: the
            dataset's own, or for a distorted lens its working camera; one shared camera, or one per view when the
            frames come from several cameras (all of the canvas size H × W).
        unseen: (N, H, W) bool, True where a working-camera pixel has no sample of the input image (outside the
            distorted image's edges, or outside a smaller camera's image on the canvas) or samples a transparent
            pixel of the frame's alpha mask (alpha below 1); None when there is none.
        radius: (N, H, W) float32 distance of each pixel's sample from the principal point in the input image, 1 at
            the farthest corner (what vignetting depends on). With one camera both are views of one (H, W) tensor
            (``unseen`` unless a frame has an alpha mask).
        exposures: the frames' known exposures (shutter time × gain, ``spotlessgs.io.exposure``), or None.
        train: indices of training views; test: indices of held-out views.
        light: the true spotlight (simulated data) or None.
    """

    dataset: DatasetDescription
    names: list[str]
    images: torch.Tensor
    saturated: torch.Tensor
    cameras: Cameras
    train: list[int]
    test: list[int]
    light: LightTruth | None
    unseen: torch.Tensor | None = None
    radius: torch.Tensor | None = None
    exposures: list[float] | None = None

    @functools.cached_property
    def start_points(self) -> PointCloud | None:
        """The dataset's initial point cloud (:func:`~spotlessgs.io.dataset.load_initial_points`), read once; None
        when it has none; a warning when most of its points lie outside every camera's image
        (:func:`~spotlessgs.io.pose_layout.warn_unseen_points`). Treat it as read-only: the start-up decisions and
        the initial Gaussians share it."""
        points = load_initial_points(self.dataset)
        if points is not None:
            warn_unseen_points(self.dataset, points, str(self.dataset.ply_path or self.dataset.source))
        return points

    def scene_extent(self) -> float:
        """Radius of the camera centres around their mean × 1.1 (3DGS's 'cameras extent'); at least 0.1 m."""
        centres = self.cameras.centres
        radius = torch.linalg.norm(centres - centres.mean(0), dim=1).max().item()
        return max(1.1 * radius, 0.1)


def _load_linear(path: Path, linear_input: bool,
                 threshold: float) -> tuple[np.ndarray, np.ndarray, np.ndarray | None, FrameStats]:
    """(H, W, 3) linear image, (H, W) clipped mask, (H, W) transparent mask (alpha below 1; None for a file without
    alpha) and the quality statistics of one file."""
    img, alpha = read_image_with_alpha(path)
    saturated = img.max(axis=2) >= threshold
    transparent = None if alpha is None else alpha < 1.0
    linear = img if linear_input else srgb_to_linear(img).astype(np.float32)
    stats = frame_stats(img, saturated, linear=linear_input, opaque=None if transparent is None else ~transparent)
    return linear.astype(np.float32), saturated, transparent, stats


def _downscale(images: torch.Tensor, masks: torch.Tensor, size: tuple[int, int]) -> tuple[torch.Tensor, torch.Tensor]:
    """Area-average linear images (N,H,W,3) to ``size`` (h, w); a pixel is clipped if any source pixel was."""
    h, w = size
    if images.shape[1:3] == (h, w):
        return images, masks
    scaled = F.interpolate(images.permute(0, 3, 1, 2), size=(h, w), mode="area").permute(0, 2, 3, 1)
    clipped = F.adaptive_max_pool2d(masks[:, None].float(), (h, w))[:, 0] > 0
    return scaled.contiguous(), clipped


@dataclass(frozen=True)
class _CameraSampling:
    """How the images of one input camera become training images.

    Attributes:
        working: its pinhole working camera at the training size, drawn on the shared canvas (its own size may be
            smaller: the rest of the canvas is unseen).
        size: (h, w) of its working image at the training size, at the top-left of the canvas.
        maps: (map_x, map_y) where each working pixel samples the input image (native working size), or None for a
            pinhole camera.
        unseen: (H, W) bool canvas pixels without an input sample of this camera.
        radius: (H, W) float32 distance of each canvas pixel's sample from the principal point, 1 at the farthest
            corner (1 outside the camera's own image).
    """

    working: Intrinsics
    size: tuple[int, int]
    maps: tuple[np.ndarray, np.ndarray] | None
    unseen: torch.Tensor
    radius: torch.Tensor


def _camera_sampling(native: Intrinsics, factor: float, canvas: tuple[int, int]) -> _CameraSampling:
    """The sampling of camera ``native`` at ``factor`` × its working size, on a canvas of ``canvas`` (H, W)."""
    working = working_camera(native)  # the camera itself when it is a pinhole
    intr = working if factor == 1.0 else working.scaled(factor)
    size = (int(intr.height), int(intr.width))
    unseen = torch.ones(canvas, dtype=torch.bool)
    unseen[: size[0], : size[1]] = False
    maps = None
    if native.is_pinhole:
        u, v = np.meshgrid(np.arange(native.width) + 0.5, np.arange(native.height) + 0.5)
    else:
        map_x, map_y, valid = undistort_maps(native, working)
        maps = (map_x, map_y)
        unseen[: size[0], : size[1]] = F.adaptive_max_pool2d(torch.from_numpy(~valid)[None, None].float(), size)[0, 0] > 0
        u, v = map_x + 0.5, map_y + 0.5  # where each working pixel samples the input image
    corner = max(math.hypot(x - native.cx, y - native.cy) for x in (0, native.width) for y in (0, native.height))
    radius = np.hypot(u - native.cx, v - native.cy).astype(np.float32) / corner
    on_canvas = torch.ones(canvas, dtype=torch.float32)
    on_canvas[: size[0], : size[1]] = F.interpolate(torch.from_numpy(radius)[None, None], size=size, mode="area")[0, 0]
    drawn = Intrinsics(intr.fx, intr.fy, intr.cx, intr.cy, canvas[1], canvas[0])
    return _CameraSampling(drawn, size, maps, unseen, on_canvas)


def _training_scale(cameras: list[Intrinsics], image_width: int | None) -> float:
    """The factor from each camera's working size to its training size: ``image_width`` over the widest input
    camera's width (1 for ``None`` or a width at least that)."""
    widest = max(c.width for c in cameras)
    if image_width is not None and image_width > widest:
        log.info("training at the images' own width, %d px: --width %d is wider (images are never upsampled)",
                 widest, image_width)
    return 1.0 if image_width is None or image_width >= widest else image_width / widest


def _canvas(cameras: list[Intrinsics], factor: float) -> tuple[int, int]:
    """(H, W) of the shared training image: the largest working image at the training size."""
    sizes = [(w.height, w.width) for w in (working_camera(c) if factor == 1.0 else working_camera(c).scaled(factor)
                                           for c in cameras)]
    return max(h for h, _ in sizes), max(w for _, w in sizes)


def _per_view(per_camera: dict[Intrinsics, torch.Tensor], cameras: tuple[Intrinsics, ...]) -> torch.Tensor:
    """(N, H, W): each view's camera's (H, W) tensor; a view of the one tensor when every view has one camera."""
    if len(per_camera) == 1:
        return next(iter(per_camera.values())).expand(len(cameras), -1, -1)
    return torch.stack([per_camera[c] for c in cameras])


def load_training_views(
    data: str | Path | DatasetDescription, image_width: int | None = None, linear_input: bool = False,
    saturation_threshold: float = 250.0 / 255.0,
) -> TrainingViews:
    """Read a dataset folder and prepare its views for training.

    Black, fully saturated and fully transparent frames are left out of ``train`` with a warning naming them
    (:mod:`spotlessgs.io.frame_quality`); a dataset with no usable training frame, or whose frames are all one image,
    raises InputError. Frames of several cameras (sizes, lenses) share one training image size, the largest working
    image; each is drawn at its top-left, and the rest is unseen. A frame's alpha channel is a mask: its transparent
    pixels (alpha below 1, e.g. the robot's own body) are unseen too, whatever colour they store.

    Args:
        data: our dataset folder, a nerfstudio folder or a COLMAP folder, or its description as
            ``read_dataset(folder, check_files=True)`` read it (not read a second time).
        image_width: training width in pixels of the widest camera (every camera is scaled by the same factor,
            heights keep the aspect ratio); None = native size.
        linear_input: the files are linear already (default: sRGB, linearised here).
        saturation_threshold: value (in the file's encoding, [0, 1]) at or above which a pixel counts as clipped.
    """
    dataset = data if isinstance(data, DatasetDescription) else read_dataset(data, check_files=True)
    linear_input = linear_input or bool(dataset.meta.get("linear_images"))  # e.g. DarkGS's raw/ frames
    natives = dataset.distinct_cameras()
    factor = _training_scale(natives, image_width)
    canvas = _canvas(natives, factor)
    sampling = {native: _camera_sampling(native, factor, canvas) for native in natives}
    imgs, masks, stats, transparent = [], [], [], {}
    for k, (path, native) in enumerate(zip(dataset.image_paths, dataset.cameras)):
        img, sat, clear, quality = _load_linear(path, linear_input, saturation_threshold)
        stats.append(quality)
        if img.shape[:2] != (native.height, native.width):
            raise ValueError(f"{path}: image is {img.shape[1]}x{img.shape[0]}, the camera says "
                             f"{native.width}x{native.height}")
        camera = sampling[native]
        pad = (0, canvas[1] - camera.size[1], 0, canvas[0] - camera.size[0])
        if camera.maps is not None:  # a working pixel is clipped when any input pixel it samples is
            img, sat = remap(img, *camera.maps), remap(sat.astype(np.float32), *camera.maps) > 0
        t_img, t_sat = _downscale(torch.from_numpy(img)[None], torch.from_numpy(sat)[None], camera.size)
        imgs.append(F.pad(t_img[0], (0, 0, *pad)))
        masks.append(F.pad(t_sat[0], pad))
        if clear is not None and clear.any():  # likewise transparent, where any input pixel it samples is
            if camera.maps is not None:
                clear = remap(clear.astype(np.float32), *camera.maps) > 0
            t_clear = F.adaptive_max_pool2d(torch.from_numpy(clear)[None, None].float(), camera.size)[0, 0] > 0
            transparent[k] = F.pad(t_clear, pad)
    names = [p.name for p in dataset.image_paths]
    warn_pose_layout(dataset)
    train = usable_frames(str(dataset.root), names, stats, list(dataset.split.train))
    warn_unusable_test_frames(str(dataset.root), names, stats, list(dataset.split.test))
    unseen = _per_view({c: s.unseen for c, s in sampling.items()}, dataset.cameras)
    if transparent:  # alpha masks: each frame's own unseen pixels
        log.info("%s: %d frame(s) carry an alpha mask; their transparent pixels are left out of the fit and the "
                 "scores", dataset.root, len(transparent))
        unseen = unseen.clone(memory_format=torch.contiguous_format)
        for k, clear in transparent.items():
            unseen[k] |= clear
    return TrainingViews(
        dataset=dataset,
        names=names,
        images=torch.stack(imgs),
        saturated=torch.stack(masks),
        cameras=Cameras.from_dataset(dataset, tuple(sampling[c].working for c in dataset.cameras)),
        train=train,
        test=list(dataset.split.test),
        light=dataset.light,
        unseen=unseen if bool(unseen.any()) else None,
        radius=_per_view({c: s.radius for c, s in sampling.items()}, dataset.cameras),
        exposures=frame_exposures(dataset.image_paths),
    )


def estimate_normals(xyz: np.ndarray, viewpoints: np.ndarray, neighbours: int = 12) -> np.ndarray:
    """(N, 3) unit normals of a point cloud without them (an SfM cloud): the direction of least spread of each point's
    ``neighbours`` nearest points (the smallest eigenvector of their covariance), turned towards the nearest of the
    ``viewpoints`` (V, 3) (the cameras that saw the surface). Fewer than 3 points: zero normals (facing the camera)."""
    from scipy.spatial import cKDTree

    n = len(xyz)
    if n < 3:
        return np.zeros((n, 3))
    _, idx = cKDTree(xyz).query(xyz, k=min(neighbours, n))
    patches = xyz[idx] - xyz[idx].mean(axis=1, keepdims=True)  # (N, k, 3)
    _, vectors = np.linalg.eigh(np.einsum("nki,nkj->nij", patches, patches))
    normals = vectors[:, :, 0]  # eigenvalues ascending: the first vector is the normal
    _, nearest = cKDTree(viewpoints).query(xyz)
    facing = np.einsum("ni,ni->n", normals, viewpoints[nearest] - xyz)
    return normals * np.where(facing < 0, -1.0, 1.0)[:, None]


def initial_point_cloud(views: TrainingViews, rng: np.random.Generator, n_random: int = 20_000,
                        estimate: bool = True) -> PointCloud:
    """The dataset's point cloud (PLY or COLMAP points3D), else random points in the camera frusta (with a warning).

    A dataset cloud without normals (SfM points) gets :func:`estimate_normals` facing the training cameras (unless
    ``estimate`` is False: then it keeps none, and the Gaussians start facing the camera). Random
    points are drawn per training view at uniform pixels and depths in [0.3, 2 × scene extent] m, grey, without
    normals.
    """
    cloud = views.start_points
    if cloud is not None and len(cloud.xyz) > 0:
        if estimate and (cloud.normals is None or not np.any(cloud.normals)):  # none in the file, or zeros
            centres = views.cameras.centres[views.train].double().numpy()
            return PointCloud(cloud.xyz, cloud.rgb, estimate_normals(np.asarray(cloud.xyz, np.float64), centres))
        return cloud
    log.warning("%s has no point cloud: initialising %d Gaussians at random in the camera frusta",
                views.dataset.root, n_random)
    per_view = max(n_random // max(len(views.train), 1), 1)
    far = 2.0 * views.scene_extent()
    pts = []
    for k in views.train:
        intr = views.cameras.camera(k)
        u = rng.uniform(0, intr.width, per_view)
        v = rng.uniform(0, intr.height, per_view)
        z = rng.uniform(0.3, max(far, 0.6), per_view)
        cam = np.stack([(u - intr.cx) / intr.fx * z, (v - intr.cy) / intr.fy * z, z], axis=1)
        c2w = views.cameras.c2w[k].double().numpy()
        pts.append(cam @ c2w[:3, :3].T + c2w[:3, 3])
    xyz = np.concatenate(pts).astype(np.float32)
    rgb = np.full((len(xyz), 3), 128, dtype=np.uint8)
    return PointCloud(xyz, rgb, None)
