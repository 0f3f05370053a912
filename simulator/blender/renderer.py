"""Cycles set-up and the paired render of one pose: spotlight-only (uneven) and lamps-on (ground truth), and on
request a third, the uniform ground truth (even, shadow-free environment light: see :func:`_uniform_light`)."""

from __future__ import annotations

import contextlib
import logging
import tempfile
from dataclasses import dataclass
from pathlib import Path

import bpy
import numpy as np
from mathutils import Matrix

from simulator.blender.scene_builder import BuiltScene
from spotlessgs.io.exr import blender_depth_to_planar, read_exr

log = logging.getLogger(__name__)

@dataclass(frozen=True)
class CyclesSettings:
    """Renderer settings.

    Attributes:
        width, height: image size in pixels.
        samples: Cycles samples per pixel.
        denoise: run OpenImageDenoise on the result.
        max_bounces: total light bounces (0 = direct light only, no bounce light).
        threads: CPU threads (Cycles ``threads_mode='FIXED'``).
        device: ``auto`` (GPU when Blender finds one), ``cpu`` or ``gpu``.
        ambient: world (environment) strength of the spotlight-only render; 0 = darkness besides the spotlight.
        residual_light: the room's own lights (the ground truth's lamps and their glowing surfaces) left on in the
            spotlight-only render at this fraction of their power (a dimmed ceiling light); 0 = off.
        motion_blur: Cycles camera motion blur in the spotlight-only render, on when :func:`render_pair` is given
            the poses at shutter open and close (the ground truth stays sharp).
        uniform_gt: also render the uniform ground truth (:func:`_uniform_light`).
    """

    width: int = 320
    height: int = 240
    samples: int = 32
    denoise: bool = True
    max_bounces: int = 4
    threads: int = 2
    device: str = "auto"
    ambient: float = 0.0
    residual_light: float = 0.0
    motion_blur: bool = False
    uniform_gt: bool = False


def _select_device(settings: CyclesSettings) -> str:
    if settings.device == "cpu":
        return "CPU"
    prefs = bpy.context.preferences.addons["cycles"].preferences
    for kind in ("OPTIX", "CUDA", "HIP", "METAL", "ONEAPI"):
        try:
            prefs.compute_device_type = kind
            prefs.get_devices()
        except (TypeError, ValueError):
            continue
        gpus = [d for d in prefs.devices if d.type == kind]
        if gpus:
            for d in prefs.devices:
                d.use = d.type == kind
            log.info("Cycles renders on %s (%s)", kind, ", ".join(d.name for d in gpus))
            return "GPU"
    if settings.device == "gpu":
        raise RuntimeError("--device gpu was requested but Blender found no GPU")
    prefs.compute_device_type = "NONE"
    return "CPU"


def configure(settings: CyclesSettings) -> str:
    """Set up Cycles, colour management ('Standard': PNG = sRGB of the clipped linear render) and render passes.

    Returns the device used (``CPU`` or ``GPU``).
    """
    scene = bpy.context.scene
    scene.render.engine = "CYCLES"
    device = _select_device(settings)
    scene.cycles.device = device
    scene.cycles.samples = int(settings.samples)
    scene.cycles.use_adaptive_sampling = False
    scene.cycles.use_denoising = bool(settings.denoise)
    if settings.denoise:
        scene.cycles.denoiser = "OPENIMAGEDENOISE"
    scene.cycles.max_bounces = int(settings.max_bounces)
    for attr in ("diffuse_bounces", "glossy_bounces", "transmission_bounces", "volume_bounces"):
        setattr(scene.cycles, attr, min(int(settings.max_bounces), 4))
    scene.cycles.transparent_max_bounces = 8
    scene.cycles.caustics_reflective = False
    scene.cycles.caustics_refractive = False
    scene.render.resolution_x = int(settings.width)
    scene.render.resolution_y = int(settings.height)
    scene.render.resolution_percentage = 100
    scene.render.threads_mode = "FIXED"
    scene.render.threads = int(settings.threads)
    scene.render.film_transparent = False
    scene.render.dither_intensity = 0.0
    scene.view_settings.view_transform = "Standard"
    scene.view_settings.look = "None"
    scene.view_settings.exposure = 0.0
    scene.view_settings.gamma = 1.0
    scene.display_settings.display_device = "sRGB"
    if scene.world is None:
        scene.world = bpy.data.worlds.new("world")
    layer = scene.view_layers[0]
    layer.use_pass_z = True
    layer.use_pass_normal = True
    layer.use_pass_diffuse_color = True  # the albedo (diffuse colour) of what each pixel sees
    layer.use_pass_glossy_color = True  # its specular reflectance (a metal's colour; a dielectric's Fresnel share)
    layer.use_pass_emit = True  # the light that visible surfaces emit (the glowing lamps of the ground truth)
    img = scene.render.image_settings
    img.media_type = "MULTI_LAYER_IMAGE"
    img.file_format = "OPEN_EXR_MULTILAYER"
    img.color_depth = "32"
    img.exr_codec = "ZIP"
    return device


def set_world_strength(value: float) -> None:
    """Make the world (environment) a white background of strength ``value``; 0 leaves only the scene's lights."""
    bg = bpy.context.scene.world.node_tree.nodes.get("Background")
    if bg is not None:
        bg.inputs["Strength"].default_value = float(value)
        bg.inputs["Color"].default_value = (1.0, 1.0, 1.0, 1.0)


def _set_mode(built: BuiltScene, mode: str, settings: CyclesSettings) -> None:
    """Light the scene for the spotlight-only render (``uneven``: the spotlight, the world at ``ambient`` and the
    room's lights at ``residual_light`` of their power) or the lamps-on ground truth (``gt``)."""
    spot = mode == "uneven"
    dimmed = settings.residual_light if spot else 1.0
    built.spotlight.hide_render = not spot
    for fixture in built.fixtures:
        power = fixture.get(_FULL_POWER)
        if power is None:  # the built power, kept on the object so that dimming never compounds
            power = fixture[_FULL_POWER] = float(fixture.data.energy)
        fixture.data.energy = power * dimmed
        fixture.hide_render = dimmed <= 0.0
    for socket, strength in built.emission_inputs:
        socket.default_value = strength * dimmed
    set_world_strength(settings.ambient if spot else 0.0)


#: Custom property on each ground-truth light: its full power (W) as built.
_FULL_POWER = "spotless_full_power_w"


#: Ray visibilities a mesh loses in the uniform ground truth: it is seen by camera rays only.
_INDIRECT_VISIBILITY = ("visible_diffuse", "visible_glossy", "visible_transmission", "visible_volume_scatter",
                        "visible_shadow")


@contextlib.contextmanager
def _uniform_light(built: BuiltScene):
    """The room under even, shadow-free environment light of radiance 1 (white): the relighting equation's constant
    L0. The spotlight and the lamps' lights are off and no surface glows (the lamps are present, unlit); every mesh
    is visible to camera rays only, so every ray leaving a surface reaches the environment: each surface point sees
    it, unoccluded, over its whole hemisphere and returns its directional albedo (a Lambertian surface: exactly its
    albedo), with no shadow and no interreflection. On exit the meshes' ray visibility and the world are restored; the
    lights stay off until the next :func:`_set_mode` sets them for its render."""
    built.spotlight.hide_render = True
    for fixture in built.fixtures:
        fixture.hide_render = True
    for socket, _strength in built.emission_inputs:
        socket.default_value = 0.0
    saved = [(ob, name, getattr(ob, name)) for ob in built.meshes for name in _INDIRECT_VISIBILITY]
    for ob, name, _value in saved:
        setattr(ob, name, False)
    set_world_strength(1.0)
    try:
        yield
    finally:
        for ob, name, value in saved:
            setattr(ob, name, value)
        set_world_strength(0.0)


@dataclass
class RenderedPair:
    """Both renders of one pose, linear float32.

    Attributes:
        uneven: (H, W, 3) spotlight-only render, linear RGB.
        gt: (H, W, 3) lamps-on render, linear RGB.
        depth: (H, W) planar depth along the optical axis (metres), inf where nothing was hit.
        normal: (H, W, 3) world-space normals.
        albedo: (H, W, 3) diffuse colour of the visible surfaces (Cycles' Diffuse Color pass: the Principled BSDF's base
            colour scaled by its diffuse share, so a metal's is dark), linear.
        emission: (H, W, 3) linear radiance emitted by the visible surfaces in the ground truth (Cycles' Emission pass).
        gt_uniform: (H, W, 3) the uniform ground truth (:func:`_uniform_light`), linear RGB, or None when not asked.
        glossy: (H, W, 3) glossy colour of the visible surfaces (Cycles' Glossy Color pass: the specular layer's
            directional albedo towards the camera), linear; diffuse + glossy colour is what a surface reflects of an
            even, unoccluded light.
    """

    uneven: np.ndarray
    gt: np.ndarray
    depth: np.ndarray
    normal: np.ndarray
    albedo: np.ndarray
    emission: np.ndarray
    gt_uniform: np.ndarray | None = None
    glossy: np.ndarray | None = None


def exr_channels(chans: dict[str, np.ndarray], suffixes: tuple[str, ...], path: Path) -> np.ndarray:
    """The channels of ``chans`` (from :func:`render_exr`) whose names end with ``suffixes``, stacked (H, W, C), or
    (H, W) for one suffix; a missing channel raises RuntimeError naming ``path``."""
    out = []
    for suffix in suffixes:
        hits = [k for k in chans if k.endswith(suffix)]
        if not hits:
            raise RuntimeError(f"{path}: Blender EXR has no channel *{suffix} (channels: {sorted(chans)})")
        out.append(chans[hits[0]])
    return np.stack(out, axis=-1) if len(out) > 1 else out[0]


def render_exr(workdir: Path, name: str) -> dict[str, np.ndarray]:
    """Render the scene as it stands and return every channel of the multilayer EXR (read back from a temporary
    file ``workdir/name.exr``, removed afterwards)."""
    bpy.ops.render.render(write_still=False)
    path = workdir / f"{name}.exr"
    try:
        bpy.data.images["Render Result"].save_render(str(path), scene=bpy.context.scene)
        return read_exr(path)
    finally:
        path.unlink(missing_ok=True)


def _place(built: BuiltScene, c2w: np.ndarray) -> None:
    """Camera at ``c2w`` (4, 4), Blender axes, and the camera-mounted spotlight with it."""
    built.camera.matrix_world = Matrix(c2w.tolist())
    built.spotlight.matrix_world = Matrix((c2w @ built.spot_local).tolist())


@contextlib.contextmanager
def _camera_motion(built: BuiltScene, shutter: tuple[np.ndarray, np.ndarray, np.ndarray]):
    """Key the camera and the spotlight at shutter open, mid-exposure and close (frames 0, 1, 2; linear
    interpolation), with the scene at frame 1 and Cycles' motion blur over frames 0-2; everything undone after."""
    scene = bpy.context.scene
    objects = (built.camera, built.spotlight)
    old_modes = [obj.rotation_mode for obj in objects]
    old_frame = scene.frame_current
    try:
        for obj in objects:
            obj.rotation_mode = "QUATERNION"
        previous = [None] * len(objects)
        for frame, c2w in enumerate(shutter):
            scene.frame_set(frame)
            _place(built, np.asarray(c2w, dtype=np.float64))
            for k, obj in enumerate(objects):
                if previous[k] is not None and previous[k].dot(obj.rotation_quaternion) < 0:
                    obj.rotation_quaternion.negate()  # the same rotation: interpolate along the short way
                previous[k] = obj.rotation_quaternion.copy()
                obj.keyframe_insert("location", frame=frame)
                obj.keyframe_insert("rotation_quaternion", frame=frame)
        for obj in objects:
            for curve in _fcurves(obj):
                for key in curve.keyframe_points:
                    key.interpolation = "LINEAR"
        scene.frame_set(1)
        scene.render.use_motion_blur = True
        scene.render.motion_blur_shutter = 2.0  # frames 0..2: open .. close
        yield
    finally:
        scene.render.use_motion_blur = False
        for obj, mode in zip(objects, old_modes):
            obj.animation_data_clear()
            obj.rotation_mode = mode
        scene.frame_set(old_frame)


def _fcurves(obj) -> list:
    """The F-curves of ``obj``'s action (Blender 5 keeps them in the action's layered channelbags)."""
    action = obj.animation_data.action
    curves = list(getattr(action, "fcurves", []) or [])
    if not curves:
        for layer in getattr(action, "layers", []):
            for strip in layer.strips:
                for bag in strip.channelbags:
                    curves.extend(bag.fcurves)
    return curves


def render_pair(built: BuiltScene, c2w_blender: np.ndarray, settings: CyclesSettings, seed: int,
                workdir: Path | None = None,
                shutter: tuple[np.ndarray, np.ndarray] | None = None) -> RenderedPair:
    """Render one camera pose in both lighting modes.

    Args:
        built: the scene built by :func:`simulator.blender.scene_builder.build_scene`.
        c2w_blender: (4, 4) camera-to-world, OpenGL/Blender camera convention.
        settings: renderer settings (already applied by :func:`configure`).
        seed: Cycles noise seed for this frame.
        workdir: an existing folder for Blender's EXR of each render (read back and deleted at once). The dataset
            renderer passes a scratch folder inside the dataset, which the next run removes if this process is
            killed; None: a temporary folder in the system's temporary directory.
        shutter: (4, 4) camera-to-world poses at shutter open and close (Blender axes): the spotlight-only render
            is motion-blurred along open → ``c2w_blender`` → close when ``settings.motion_blur``; the ground truth,
            depth, normals, albedo and emission are the sharp render's at ``c2w_blender``.
    """
    scene = bpy.context.scene
    c2w = np.asarray(c2w_blender, dtype=np.float64)
    _place(built, c2w)
    scene.cycles.seed = int(seed) % (2**31 - 1)
    blurred = settings.motion_blur and shutter is not None
    with contextlib.ExitStack() as stack:
        if workdir is None:
            work = Path(stack.enter_context(tempfile.TemporaryDirectory(prefix="spotless-render-")))
        else:
            work = Path(workdir)
        _set_mode(built, "uneven", settings)
        if blurred:
            with _camera_motion(built, (shutter[0], c2w, shutter[1])):
                spot = render_exr(work, "uneven")
            _place(built, c2w)
        else:
            spot = render_exr(work, "uneven")
        _set_mode(built, "gt", settings)
        gt = render_exr(work, "gt")
        uniform = None
        if settings.uniform_gt:
            with _uniform_light(built):
                uniform = render_exr(work, "gt_uniform")
    combined = (".Combined.R", ".Combined.G", ".Combined.B")
    sharp = gt if blurred else spot  # the geometry passes of a sharp render (identical in both when nothing moves)
    depth = blender_depth_to_planar(exr_channels(sharp, (".Depth.Z",), work))
    return RenderedPair(
        uneven=exr_channels(spot, combined, work).astype(np.float32),
        gt=exr_channels(gt, combined, work).astype(np.float32),
        depth=depth,
        normal=exr_channels(sharp, (".Normal.X", ".Normal.Y", ".Normal.Z"), work).astype(np.float32),
        albedo=exr_channels(gt, (".Diffuse Color.R", ".Diffuse Color.G", ".Diffuse Color.B"), work).astype(np.float32),
        emission=exr_channels(gt, (".Emission.R", ".Emission.G", ".Emission.B"), work).astype(np.float32),
        gt_uniform=None if uniform is None else exr_channels(uniform, combined, work).astype(np.float32),
        glossy=exr_channels(gt, (".Glossy Color.R", ".Glossy Color.G", ".Glossy Color.B"), work).astype(np.float32),
    )


def blender_version() -> str:
    """The running Blender's version string."""
    return bpy.app.version_string
