"""What a robot's camera does to a rendered dataset: sensor noise at the high gain of a dark scene, auto-exposure and
vignetting.

Cycles renders are clean (denoised), while a real camera in a dark tunnel runs at high gain: its images are noisy,
most of all in the dark corners the spotlight does not reach. This module adds the standard heteroscedastic model of
shot and read noise in linear intensity (Foi et al. 2008, "Practical Poissonian-Gaussian noise modeling"; the
parametrisation of Brooks et al. 2019, "Unprocessing images for learned raw denoising")::

    y = x + n,   n ~ N(0, shot · x + read²),   then clipped to [0, 1], sRGB-encoded and quantised to 8 bits

to the spotlight-only images of a dataset. :func:`add_sensor_noise_to_dataset` derives a noisy copy of a finished
dataset from its linear renders (``exr/``), so the same renders can be used clean and noisy: the copy's ``images/`` are
noisy, everything else (ground truth, EXRs, poses, point cloud, transforms.json) is copied unchanged, and
``sensor_noise.json`` records the parameters (a copy through a lens resamples the ground truth and the EXRs through it:
the renders and the ground truth bilinearly, depth and normals by nearest sample). Noise of frame k comes from its own
generator (seed, frame index), so a rerun writes the same bytes and an interrupted run resumes frame by frame; the
temporary files a killed run left (``.<name>.partial-*``) are removed when the next run starts.

With :class:`CameraEffects` the copy also gets a robot camera's photometric effects, applied to the linear render
before the noise: a sensitivity (the scene is darker than the render) and an auto-exposure gain per frame (the camera scales each frame so that its mean linear brightness
approaches ``target_level``, within [1, ``max_gain``], converging over frames like a real controller) and vignetting
``V(r) = 1 - vignetting · r²`` (r = 1 at the image corner farthest from the principal point). The truth (every
frame's gain, the vignetting) goes to ``camera_effects.json`` and the dataset's ``"spotless"`` block gets
``camera_effects``, so that the trainer's photometric camera turns on by itself (``TrainConfig.photometric``).
"""

from __future__ import annotations

import json
import math
import shutil
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np

from spotlessgs.io.atomic import atomic_path, remove_partial_files, write_json
from spotlessgs.io.cameras import Intrinsics
from spotlessgs.io.colorspace import linear_to_srgb
from spotlessgs.io.dataset import UNIFORM_GT_DIR
from spotlessgs.io.dataset_fingerprint import dataset_fingerprint
from spotlessgs.io.depth_images import DEFAULT_DEPTH_SCALE, MAX_DEPTH_UNITS, write_depth_image
from spotlessgs.io.exr import FrameEXR, read_frame_exr, write_frame_exr
from spotlessgs.io.folder_lock import folder_lock
from spotlessgs.io.images import write_png
from spotlessgs.io.json_files import read_json
from spotlessgs.io.lens import check_invertible, distort_maps, remap, remap_nearest, undistort
from spotlessgs.io.paths import refuse_foreign_folder, refuse_overlap
from spotlessgs.io.seeding import numpy_rng
from spotlessgs.io.transforms import nerfstudio_camera, read_transforms

NOISE_RECORD = "sensor_noise.json"
EFFECTS_RECORD = "camera_effects.json"
#: The folder of a depth camera's images in the copy (same file names as images/).
DEPTH_DIR = "depth"
# Everything of a dataset folder that the noisy copy takes over unchanged (images/ is written anew; transforms.json,
# rewritten for the copy's camera where it changes, is written last: it marks the copy as finished).
COPIED = ("gt", UNIFORM_GT_DIR, "exr", "sparse", "points3d.ply", "plan.json")


#: The largest shot variance per unit signal and read-noise deviation accepted: noise of the image's whole range
#: (far beyond any camera's, 0.012 at high gain); 1e300 overflowed and left a record that blocked the folder.
MAX_NOISE = 1.0


@dataclass(frozen=True)
class SensorNoise:
    """Shot and read noise in linear intensity (image values in [0, 1]).

    Attributes:
        shot: variance of the signal-dependent (Poisson) part per unit of signal; Brooks et al. sample it between
            1e-4 (low gain) and 0.012 (high gain).
        read: standard deviation of the signal-independent (read / quantisation) part.
    """

    shot: float = 0.01
    read: float = 0.012

    def __post_init__(self) -> None:
        for name in ("shot", "read"):
            value = getattr(self, name)
            if not (math.isfinite(value) and 0 <= value <= MAX_NOISE):
                raise ValueError(f"SensorNoise: {name} must be in [0, {MAX_NOISE:g}], got {value}")

    def std(self, linear: np.ndarray) -> np.ndarray:
        """Noise standard deviation at each linear intensity (same shape)."""
        return np.sqrt(self.shot * np.clip(linear, 0.0, None) + self.read ** 2)


@dataclass(frozen=True)
class CameraEffects:
    """A robot camera's auto-exposure and vignetting.

    Attributes:
        sensitivity: what the sensor records of the rendered radiance at gain 1 (0.25: a dark scene that needs a
            gain of about 4 to reach the target).
        auto_exposure: scale each frame towards ``target_level`` (False: gain 1 for every frame).
        target_level: the mean linear brightness auto-exposure aims at.
        max_gain: the largest gain (the smallest is 1: the render's own exposure).
        adaptation: share of the way (in log gain) to its target the gain moves each frame (1: at once).
        vignetting: darkening at the farthest image corner, ``V(1) = 1 - vignetting``, in [0, 1).
        lens, distortion: a lens model of :data:`spotlessgs.io.cameras.LENS_MODELS` and its coefficients: the copy's
            images (and ground truth) are the renders resampled through this lens, into a camera of the same size
            whose focal length is raised just enough that every pixel's ray lies inside the render
            (:meth:`camera`); "pinhole": the render's own geometry.
    """

    sensitivity: float = 1.0
    auto_exposure: bool = True
    target_level: float = 0.18
    max_gain: float = 4.0
    adaptation: float = 0.5
    vignetting: float = 0.35
    lens: str = "pinhole"
    distortion: tuple[float, ...] = ()

    def __post_init__(self) -> None:
        object.__setattr__(self, "distortion", tuple(float(v) for v in self.distortion))
        Intrinsics(1.0, 1.0, 1.0, 1.0, 2, 2, self.lens, self.distortion)  # checks the lens
        if self.lens == "opencv" and len(self.distortion) > 5:
            raise ValueError("CameraEffects: the dataset's transforms.json holds at most 5 opencv coefficients "
                             "(k1, k2, p1, p2, k3)")
        checks = {"sensitivity": self.sensitivity > 0, "target_level": self.target_level > 0, "max_gain": self.max_gain >= 1,
                  "adaptation": 0 < self.adaptation <= 1, "vignetting": 0 <= self.vignetting < 1}
        for name, ok in checks.items():
            value = getattr(self, name)
            if not (math.isfinite(value) and ok):
                raise ValueError(f"CameraEffects: {name} out of range: {value}")

    def gains(self, brightness: np.ndarray) -> np.ndarray:
        """(N,) exposure gains of N frames in order, from their rendered mean linear brightness (N,) (recorded at
        gain 1 as ``sensitivity`` times that)."""
        gains, log_gain = [], 0.0
        for level in np.asarray(brightness, dtype=np.float64):
            wanted = self.target_level / max(self.sensitivity * level, 1e-6) if self.auto_exposure else 1.0
            target = math.log(min(max(wanted, 1.0), self.max_gain))
            log_gain = target if not gains else log_gain + self.adaptation * (target - log_gain)
            gains.append(math.exp(log_gain))
        return np.asarray(gains)

    def camera(self, render: Intrinsics) -> Intrinsics:
        """The copy's camera: ``render``'s size and principal point with this lens, its focal lengths scaled up (the
        least scale, found by bisection) so that every pixel's ray, the image edges' included, falls inside the
        pinhole ``render``."""
        base = Intrinsics(render.fx, render.fy, render.cx, render.cy, render.width, render.height, self.lens,
                          self.distortion)
        if base.is_pinhole:
            return base
        check_invertible(base, "CameraEffects")
        edges = np.concatenate([np.stack([np.linspace(0, render.width, 65), np.full(65, y)], 1)
                                for y in (0.0, render.height)]
                               + [np.stack([np.full(49, x), np.linspace(0, render.height, 49)], 1)
                                  for x in (0.0, render.width)])

        def with_scale(scale: float) -> Intrinsics:
            return Intrinsics(render.fx * scale, render.fy * scale, render.cx, render.cy, render.width,
                              render.height, self.lens, self.distortion)

        def inside(scale: float) -> bool:  # every edge ray lands inside the pinhole render
            xy = undistort(with_scale(scale), edges)
            u, v = render.fx * xy[:, 0] + render.cx, render.fy * xy[:, 1] + render.cy
            return bool((u >= 0).all() and (u <= render.width).all() and (v >= 0).all() and (v <= render.height).all())

        low, high = 1.0, 1.0
        while not inside(high):  # a longer focal length narrows the view: find one that fits, then bisect
            low, high = high, 2.0 * high
        for _ in range(40):
            middle = 0.5 * (low + high)
            low, high = (low, middle) if inside(middle) else (middle, high)
        return with_scale(high)

    def falloff(self, height: int, width: int, cx: float, cy: float) -> np.ndarray:
        """(H, W) vignetting of each pixel centre, principal point (cx, cy) in pixels (corner at 0)."""
        u, v = np.meshgrid(np.arange(width) + 0.5, np.arange(height) + 0.5)
        corner = max(math.hypot(x - cx, y - cy) for x in (0, width) for y in (0, height))
        return 1.0 - self.vignetting * (np.hypot(u - cx, v - cy) / corner) ** 2


@dataclass(frozen=True)
class DepthCamera:
    """An RGB-D camera's depth images, registered to the colour frames (RealSense's ``aligned_depth_to_color``).

    The depth of a structured-light or stereo camera is noisy along the ray, its standard deviation growing with the
    square of the depth (Khoshelham and Elberink 2012, "Accuracy and resolution of Kinect depth data")::

        z' = z + N(0, (noise · z²)²),   then rounded to units of ``scale`` metres; 0 beyond ``max_range`` or no hit

    Attributes:
        noise: σ of the depth at 1 m, metres (σ = noise · z², z in metres); 0.0025: 2.5 mm at 1 m, 1 cm at 2 m.
        max_range: the farthest depth measured, metres (farther pixels hold 0: no measurement).
        scale: metres per depth unit of the 16-bit images (nerfstudio's ``depth_unit_scale_factor``).
    """

    noise: float = 0.0025
    max_range: float = 6.0
    scale: float = DEFAULT_DEPTH_SCALE

    def __post_init__(self) -> None:
        checks = {"noise": self.noise >= 0, "max_range": self.max_range > 0,
                  "scale": self.scale > 0 and self.max_range / self.scale <= MAX_DEPTH_UNITS}
        for name, ok in checks.items():
            value = getattr(self, name)
            if not (math.isfinite(value) and ok):
                raise ValueError(f"DepthCamera: {name} out of range: {value} (max_range / scale must fit 16 bits)")

    def measure(self, depth: np.ndarray, rng: np.random.Generator) -> np.ndarray:
        """(H, W) the depth (m) this camera records of a true planar depth map (H, W) (inf: no surface): noisy, NaN
        where nothing is measured."""
        depth = np.asarray(depth, dtype=np.float64)
        seen = np.isfinite(depth) & (depth > 0) & (depth <= self.max_range)
        noisy = depth + self.noise * np.where(seen, depth, 0.0) ** 2 * rng.standard_normal(depth.shape)
        return np.where(seen & (noisy > 0), noisy, np.nan)


def add_sensor_noise(linear: np.ndarray, noise: SensorNoise, rng: np.random.Generator) -> np.ndarray:
    """A noisy copy of a linear image.

    Args:
        linear: (H, W, 3) linear intensities (finite; values above 1 are clipped by the sensor).
        noise: the noise model; rng: the generator (one per frame for reproducible datasets).
    Returns:
        (H, W, 3) float32 in [0, 1].
    """
    x = np.asarray(linear, dtype=np.float64)
    if x.ndim != 3 or x.shape[2] != 3:
        raise ValueError(f"add_sensor_noise: expected an (H, W, 3) image, got shape {x.shape}")
    if not np.isfinite(x).all():
        raise ValueError("add_sensor_noise: the image has non-finite values")
    noisy = x + noise.std(x) * rng.standard_normal(x.shape)
    return np.clip(noisy, 0.0, 1.0).astype(np.float32)


def add_sensor_noise_to_dataset(data: str | Path, out: str | Path, noise: SensorNoise | None, seed: int = 0,
                                effects: CameraEffects | None = None, point_cloud: bool = True,
                                depth_camera: DepthCamera | None = None) -> int:
    """Write a copy of the finished dataset ``data`` to ``out`` whose spotlight-only images carry sensor noise
    (``noise``; None: none) and, with ``effects``, a robot camera's auto-exposure and vignetting. Without
    ``point_cloud`` the copy has no depth-derived point cloud (a robot has none: ``spotless prepare --points``
    triangulates one from the images, or back-projects the depth images). With ``depth_camera`` every frame also
    gets that camera's depth image (``depth/<frame>.png``, the frame's ``depth_file_path``), through the lens of
    ``effects`` when it has one.

    Returns the number of images written now (frames already written by an earlier run with the same settings are
    kept; temporary files of a killed run are removed first). Raises ValueError naming the folder when ``data`` is not
    a finished dataset with linear renders, or when ``out`` holds a noisy copy made with other settings, and
    :class:`~spotlessgs.io.errors.OutputOverlapError` (a ValueError) when ``out`` is ``data``, lies inside it or
    contains it, before anything is written.
    """
    data, out = Path(data), Path(out)
    refuse_overlap(out, {"--data": data}, "--out")
    if not (data / "transforms.json").is_file():
        raise ValueError(f"{data}: not a finished dataset (no transforms.json)")
    meta = read_transforms(data / "transforms.json")
    record: dict = {"source": str(data.resolve()), "seed": int(seed),
                    **(asdict(noise) if noise is not None else {"shot": 0.0, "read": 0.0}),
                    "model": "y = x + N(0, shot*x + read^2) in linear intensity, clipped to [0, 1], 8-bit sRGB"}
    if effects is not None:
        record["camera_effects"] = asdict(effects)
    if not point_cloud:
        record["point_cloud"] = False
    if depth_camera is not None:
        record["depth_camera"] = asdict(depth_camera)
    # which dataset, by its content: `source` (the path) may change with a moved folder and is not compared
    record["source_fingerprint"] = dataset_fingerprint(meta)
    record = json.loads(json.dumps(record))  # as the file holds it (a lens's distortion tuple reads back as a list)
    record_path = out / NOISE_RECORD
    if record_path.is_file():
        old = read_json(record_path, "a noisy copy's record")
        compared = (set(old) | set(record)) - {"source"} - ({"source_fingerprint"} - set(old))  # older records
        differ = sorted(k for k in compared if old.get(k) != record.get(k))
        if differ:
            shown = "; ".join(f"{k}: {old.get(k)!r} then, {record.get(k)!r} now" for k in differ)
            raise ValueError(f"{out}: holds a noisy copy made with other settings or of another dataset ({shown}); "
                             "use a new folder, or delete this one to make it again")
    refuse_foreign_folder(out, [NOISE_RECORD], "--out", "a noisy copy this command began")
    frames = []
    for index, frame in enumerate(meta.frames()):
        if frame.exr_file_path is None:
            raise ValueError(f"{data}: frame {frame.file_path} has no linear render (exr_file_path)")
        frames.append((index, frame))
    with folder_lock(out, "spotless-sim add-noise"):  # one writer: a second run would remove its partial files
        remove_partial_files(out)
        write_json(record_path, record)
        gains, lens_maps = None, None
        camera = meta.intrinsics
        if effects is not None:  # the exposure of each frame follows the brightness of the frames before it
            gains = effects.gains(np.array([float(np.mean(read_frame_exr(data / frame.exr_file_path).uneven))
                                            for _, frame in frames]))
            camera = effects.camera(meta.intrinsics)
            if not camera.is_pinhole:
                map_x, map_y, valid = distort_maps(camera, meta.intrinsics)
                if not valid.all():  # CameraEffects.camera keeps every ray inside the render: a bug if not
                    raise RuntimeError(f"{out}: {int((~valid).sum())} pixels of the lens camera fall outside the render")
                lens_maps = (map_x, map_y)
            falloff = effects.falloff(camera.height, camera.width, camera.cx, camera.cy)[..., None]
            write_json(out / EFFECTS_RECORD, {
                "gains": {Path(frame.file_path).name: float(g) for (_, frame), g in zip(frames, gains)},
                **asdict(effects), "camera": asdict(camera)})
        for name in COPIED:
            src, dst = data / name, out / name
            if name in ("points3d.ply", "sparse") and not point_cloud:  # the COLMAP model holds the depth points too
                continue
            if lens_maps is not None and name in ("gt", UNIFORM_GT_DIR, "exr", "sparse"):  # resampled below
                continue
            if not src.exists() or dst.exists():
                continue
            if src.is_dir():  # copied into a hidden folder that a killed run's successor completes, then renamed
                partial = dst.with_name(f".{dst.name}.partial-copy")
                shutil.copytree(src, partial, dirs_exist_ok=True)
                partial.rename(dst)
            else:
                with atomic_path(dst) as tmp:
                    shutil.copy2(src, tmp)
        written = 0
        for index, frame in frames:
            target = out / frame.file_path
            if target.is_file():
                continue
            rendered = read_frame_exr(data / frame.exr_file_path)
            linear = rendered.uneven
            if depth_camera is not None:  # written before the image, which marks the frame as done
                true_depth = rendered.depth if lens_maps is None else remap_nearest(rendered.depth, *lens_maps)
                write_depth_image(out / DEPTH_DIR / f"{Path(frame.file_path).stem}.png",
                                  depth_camera.measure(true_depth, numpy_rng(seed, f"depth-noise/{index}")),
                                  depth_camera.scale)
            if lens_maps is not None:  # the render seen through the lens; the ground truth and the geometry too
                linear = remap(linear, *lens_maps)
                gt = remap(rendered.gt, *lens_maps)
                uniform = None if rendered.gt_uniform is None else remap(rendered.gt_uniform, *lens_maps)
                # depth and normals: nearest samples (an interpolated depth at an edge is a surface nobody sees)
                write_frame_exr(out / frame.exr_file_path, FrameEXR(
                    uneven=linear, gt=gt, depth=remap_nearest(rendered.depth, *lens_maps),
                    normal=remap_nearest(rendered.normal, *lens_maps),
                    albedo=None if rendered.albedo is None else remap(rendered.albedo, *lens_maps),
                    emission=None if rendered.emission is None else remap(rendered.emission, *lens_maps),
                    gt_uniform=uniform, glossy=None if rendered.glossy is None else remap(rendered.glossy, *lens_maps)))
                if frame.gt_file_path is not None:
                    write_png(out / frame.gt_file_path, linear_to_srgb(np.clip(gt, 0, 1)))
                if uniform is not None and frame.gt_file_path is not None:
                    write_png(out / UNIFORM_GT_DIR / Path(frame.gt_file_path).name,
                              linear_to_srgb(np.clip(uniform, 0, 1)))
            if gains is not None:
                linear = linear * (effects.sensitivity * gains[index] * falloff)
            recorded = np.clip(linear, 0.0, 1.0) if noise is None else add_sensor_noise(
                linear, noise, numpy_rng(seed, f"sensor-noise/{index}"))
            write_png(target, linear_to_srgb(recorded))
            written += 1
        src, dst = data / "transforms.json", out / "transforms.json"
        if effects is not None or not point_cloud or depth_camera is not None:
            _write_transforms(src, dst, effects, camera, point_cloud, depth_camera)
        else:
            with atomic_path(dst) as tmp:
                shutil.copy2(src, tmp)
        return written


def _write_transforms(src: Path, dst: Path, effects: CameraEffects | None, camera: Intrinsics,
                      point_cloud: bool, depth_camera: DepthCamera | None = None) -> None:
    """``src``'s transforms.json, written atomically to ``dst``, with ``camera_effects`` in its "spotless" block (a
    plain nerfstudio file, which has no block, keeps none: the trainer treats it as a real camera's anyway), for a
    lens its camera (the EXRs are the renders resampled through it), without ``point_cloud`` no
    ``ply_file_path``, and with ``depth_camera`` each frame's ``depth_file_path`` and the images'
    ``depth_unit_scale_factor``."""
    data = json.loads(src.read_text(encoding="utf-8"))
    if not point_cloud:
        data.pop("ply_file_path", None)
    if depth_camera is not None:
        data["depth_unit_scale_factor"] = depth_camera.scale
        for frame in data["frames"]:
            frame["depth_file_path"] = f"{DEPTH_DIR}/{Path(frame['file_path']).stem}.png"
    if effects is not None and isinstance(data.get("spotless"), dict):
        data["spotless"]["camera_effects"] = {"exposure": "auto" if effects.auto_exposure else "fixed",
                                              "vignetting": effects.vignetting, "lens": effects.lens,
                                              "record": EFFECTS_RECORD}
    if not camera.is_pinhole:
        for key in ("k1", "k2", "k3", "k4", "p1", "p2"):
            data.pop(key, None)
        data.update(nerfstudio_camera(camera, dst))
    write_json(dst, data)
