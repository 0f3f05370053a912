"""OpenEXR files: atomic writing of named float channels, reading of single- and multi-part files, and the per-frame
EXR of the dataset contract.

Channel names: a single-part file keeps its channel names as stored (e.g. ``uneven.R``). In a multi-part file (Blender
writes one part per render pass, e.g. part ``ViewLayer.Depth`` holding channel ``ViewLayer.Depth.Z``) a channel name
that does not already start with ``"<part name>."`` is prefixed with it, so every channel is reported as
``"<part/layer>.<channel>"`` whichever way the writer laid the file out.

The dataset's per-frame EXR holds linear renders and geometry of one view (see ``docs/dataset.md``):
``uneven.R/G/B`` (linear spotlight-only render), ``gt.R/G/B`` (linear ground truth), ``depth.Z`` (planar depth along the
optical axis in metres, inf for background) and ``normal.X/Y/Z`` (world-space unit normals); datasets rendered from
2026-11-24 on also ``albedo.R/G/B`` (the diffuse colour of the visible surfaces) and ``emission.R/G/B`` (the radiance
that visible surfaces emit in the ground truth: its glowing lamps); datasets rendered from 2026-11-26 on also
``glossy.R/G/B`` (the glossy colour of the visible surfaces: their specular reflectance, a metal's colour); datasets
rendered with ``--gt uniform`` also
``gt_uniform.R/G/B`` (the uniform ground truth: even, shadow-free environment light, lamps unlit).
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from spotlessgs.io.atomic import atomic_path

_COMPRESSIONS = {
    "none": "NO_COMPRESSION",
    "zip": "ZIP_COMPRESSION",
    "zips": "ZIPS_COMPRESSION",
    "piz": "PIZ_COMPRESSION",
    "rle": "RLE_COMPRESSION",
}

# Channel names of the dataset's per-frame EXR.
UNEVEN_CHANNELS = ("uneven.R", "uneven.G", "uneven.B")
GT_CHANNELS = ("gt.R", "gt.G", "gt.B")
DEPTH_CHANNEL = "depth.Z"
NORMAL_CHANNELS = ("normal.X", "normal.Y", "normal.Z")
ALBEDO_CHANNELS = ("albedo.R", "albedo.G", "albedo.B")
EMISSION_CHANNELS = ("emission.R", "emission.G", "emission.B")
GLOSSY_CHANNELS = ("glossy.R", "glossy.G", "glossy.B")
UNIFORM_GT_CHANNELS = ("gt_uniform.R", "gt_uniform.G", "gt_uniform.B")
# A pixel shows an emitter when the emitted radiance is at least this share of its ground-truth radiance (the lamp
# surfaces; anti-aliased edge pixels that are mostly lamp count too).
EMITTER_SHARE = 0.5
# Blender's Cycles depth pass stores 1e10 where a ray hit nothing (measured with bpy 5.0.1); the dataset stores inf.
BLENDER_BACKGROUND_DEPTH = 1.0e10


def blender_depth_to_planar(depth: np.ndarray, background_threshold: float = 1.0e9) -> np.ndarray:
    """Blender's depth pass (H, W) -> the dataset's depth: float32, values >= ``background_threshold`` become inf."""
    depth = np.array(depth, dtype=np.float32, copy=True)
    depth[depth >= background_threshold] = np.inf
    return depth


def write_exr(
    path: str | os.PathLike,
    channels: dict[str, np.ndarray],
    compression: str = "zip",
    half: bool = False,
) -> None:
    """Write named (H, W) channels to a single-part scanline EXR, atomically.

    Args:
        path: output ``.exr`` file (parent folders are created).
        channels: channel name -> (H, W) array, all the same shape (cast to float32; inf and NaN are kept).
        compression: one of ``none``, ``zip`` (lossless, default), ``zips``, ``piz``, ``rle`` (all lossless).
        half: store 16-bit half floats instead of 32-bit floats (lossy: about 3 significant digits).
    """
    import OpenEXR

    if not channels:
        raise ValueError(f"{path}: write_exr needs at least one channel")
    if compression not in _COMPRESSIONS:
        raise ValueError(f"{path}: unknown EXR compression {compression!r} (choose from {sorted(_COMPRESSIONS)})")
    shape = None
    data = {}
    for name, array in channels.items():
        if not isinstance(name, str) or not name:
            raise ValueError(f"{path}: EXR channel names must be non-empty strings, got {name!r}")
        array = np.asarray(array)
        if array.ndim != 2 or array.shape[0] == 0 or array.shape[1] == 0:
            raise ValueError(f"{path}: EXR channel {name!r} must be a non-empty (H, W) array, got shape {array.shape}")
        if shape is None:
            shape = array.shape
        elif array.shape != shape:
            raise ValueError(f"{path}: EXR channel {name!r} has shape {array.shape}, other channels have {shape}")
        if not (np.issubdtype(array.dtype, np.floating) or np.issubdtype(array.dtype, np.integer)):
            raise ValueError(f"{path}: EXR channel {name!r} has unsupported dtype {array.dtype}")
        data[name] = np.ascontiguousarray(array, dtype=np.float16 if half else np.float32)
    header = {"compression": getattr(OpenEXR, _COMPRESSIONS[compression]), "type": OpenEXR.scanlineimage}
    with atomic_path(path, suffix=".exr") as tmp:
        OpenEXR.File(header, data).write(str(tmp))


def read_exr(path: str | os.PathLike) -> dict[str, np.ndarray]:
    """Read every channel of every part of an EXR file.

    Returns:
        ``{"<part/layer>.<channel>": (H, W) float32}`` (half and uint channels are converted to float32); see the
        module docstring for the naming rule. Raises ValueError naming the file for unreadable files and for two
        channels that end up with the same name.
    """
    import OpenEXR

    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"{path}: EXR file not found")
    if not OpenEXR.isOpenExrFile(str(path)):
        raise ValueError(f"{path}: not an OpenEXR file")
    result: dict[str, np.ndarray] = {}
    try:
        with OpenEXR.File(str(path), separate_channels=True) as exr:
            multi_part = len(exr.parts) > 1
            for part in exr.parts:
                part_name = part.name() if multi_part else ""
                for channel_name, channel in part.channels.items():
                    if part_name and not channel_name.startswith(part_name + "."):
                        full_name = f"{part_name}.{channel_name}"
                    else:
                        full_name = channel_name
                    if full_name in result:
                        raise ValueError(f"{path}: channel name {full_name!r} occurs twice")
                    # Copy inside the block: the library empties the arrays when the file closes.
                    result[full_name] = np.array(channel.pixels, dtype=np.float32, copy=True)
    except (RuntimeError, OSError) as exc:
        raise ValueError(f"{path}: cannot read EXR file ({exc})") from exc
    return result


@dataclass(frozen=True)
class FrameEXR:
    """The linear renders and geometry of one dataset frame.

    Attributes:
        uneven: (H, W, 3) float32 linear spotlight-only render.
        gt: (H, W, 3) float32 linear evenly lit ground truth.
        depth: (H, W) float32 planar depth along the optical axis, metres; inf where no surface was hit.
        normal: (H, W, 3) float32 world-space unit normals (zero where no surface was hit).
        albedo: (H, W, 3) float32 linear diffuse colour of the visible surfaces, or None (datasets rendered before
            2026-11-24).
        emission: (H, W, 3) float32 linear radiance emitted by the visible surfaces in the ground truth, or None.
        gt_uniform: (H, W, 3) float32 linear uniform ground truth (even, shadow-free environment light of radiance 1,
            no glowing lamps), or None (rendered only with ``spotless-sim render --gt uniform``).
        glossy: (H, W, 3) float32 linear glossy colour of the visible surfaces (Cycles' Glossy Color pass: the
            specular layer's directional albedo towards the camera, Fresnel included), or None (datasets rendered
            before 2026-11-26).
    """

    uneven: np.ndarray
    gt: np.ndarray
    depth: np.ndarray
    normal: np.ndarray
    albedo: np.ndarray | None = None
    emission: np.ndarray | None = None
    gt_uniform: np.ndarray | None = None
    glossy: np.ndarray | None = None

    def __post_init__(self) -> None:
        if self.depth.ndim != 2:
            raise ValueError(f"FrameEXR: depth must be (H, W), got shape {self.depth.shape}")
        expected = self.depth.shape + (3,)
        for name in ("uneven", "gt", "normal", "albedo", "emission", "gt_uniform", "glossy"):
            value = getattr(self, name)
            if value is not None and value.shape != expected:
                raise ValueError(f"FrameEXR: {name} must have shape {expected} (from depth), got {value.shape}")

    def emitters(self) -> np.ndarray | None:
        """(H, W) bool: pixels whose ground-truth radiance is at least EMITTER_SHARE emitted light (the lamps), or
        None when the frame has no emission pass."""
        return None if self.emission is None else emitter_mask(self.emission, self.gt)

    def reflectance(self) -> np.ndarray | None:
        """(H, W, 3) what the visible surfaces reflect of an even, unoccluded light of radiance 1: the diffuse colour
        plus the glossy colour (the diffuse colour alone for a frame without the glossy pass); None without an albedo
        pass. Under the uniform ground truth's light it is that ground truth, up to the renderer's noise."""
        if self.albedo is None:
            return None
        return self.albedo if self.glossy is None else self.albedo + self.glossy


def emitter_mask(emission: np.ndarray, gt: np.ndarray) -> np.ndarray:
    """(H, W) bool from (H, W, 3) emission and ground truth: pixels that are at least EMITTER_SHARE emitted light."""
    emitted, total = emission.sum(-1), gt.sum(-1)
    return (emitted > 0) & (emitted >= EMITTER_SHARE * total)


def read_emitters(path: str | os.PathLike) -> np.ndarray | None:
    """The lamps (:func:`emitter_mask`) of an EXR holding the ground truth and its emission pass; None for any other
    EXR (one from before the pass, a depth-only file)."""
    channels = read_exr(path)
    if not all(name in channels for name in (*EMISSION_CHANNELS, *GT_CHANNELS)):
        return None
    return emitter_mask(np.stack([channels[n] for n in EMISSION_CHANNELS], -1),
                        np.stack([channels[n] for n in GT_CHANNELS], -1))


def write_frame_exr(path: str | os.PathLike, frame: FrameEXR, compression: str = "zip") -> None:
    """Write a :class:`FrameEXR` with the dataset's channel names, 32-bit float, atomically."""
    channels: dict[str, np.ndarray] = {}
    for names, image in ((UNEVEN_CHANNELS, frame.uneven), (GT_CHANNELS, frame.gt), (NORMAL_CHANNELS, frame.normal),
                         (ALBEDO_CHANNELS, frame.albedo), (EMISSION_CHANNELS, frame.emission),
                         (UNIFORM_GT_CHANNELS, frame.gt_uniform), (GLOSSY_CHANNELS, frame.glossy)):
        if image is None:
            continue
        for k, name in enumerate(names):
            channels[name] = image[:, :, k]
    channels[DEPTH_CHANNEL] = frame.depth
    write_exr(path, channels, compression=compression)


def read_frame_exr(path: str | os.PathLike) -> FrameEXR:
    """Read a dataset frame EXR; raises ValueError naming the file and the missing channels if any are absent."""
    channels = read_exr(path)
    wanted = (*UNEVEN_CHANNELS, *GT_CHANNELS, DEPTH_CHANNEL, *NORMAL_CHANNELS)
    missing = [name for name in wanted if name not in channels]
    if missing:
        raise ValueError(f"{path}: frame EXR lacks channels {missing} (has {sorted(channels)})")

    def stack(names: tuple[str, ...]) -> np.ndarray:
        return np.stack([channels[n] for n in names], axis=-1)

    def optional(names: tuple[str, ...]) -> np.ndarray | None:
        return stack(names) if all(n in channels for n in names) else None

    return FrameEXR(
        uneven=stack(UNEVEN_CHANNELS),
        gt=stack(GT_CHANNELS),
        depth=channels[DEPTH_CHANNEL],
        normal=stack(NORMAL_CHANNELS),
        albedo=optional(ALBEDO_CHANNELS),
        emission=optional(EMISSION_CHANNELS),
        gt_uniform=optional(UNIFORM_GT_CHANNELS),
        glossy=optional(GLOSSY_CHANNELS),
    )
