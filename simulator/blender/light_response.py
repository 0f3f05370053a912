"""Measure how the renderer lights a surface, against what the light models assume: the diffuse lobe under a lamp
at the camera, and the spotlight's angular profile.

**Diffuse lobe.** The learned BRDF of SpotlessGS starts from the Disney model, whose diffuse lobe has Burley's factor
(1 + (F_D90 - 1)(1 - n·l)⁵)(1 + (F_D90 - 1)(1 - n·v)⁵), F_D90 = ½ + 2ρ (l·h)² (spotlessgs.models.brdf). Lit and seen
from one direction, as by a robot's lamp beside its camera, that factor brightens a rough surface towards grazing
(1.78x at 75° for ρ = 1). Set-up: a 0.2 m square of the simulator's own material (`scene_builder.build_material` with
its specular layer off, metalness 0, base colour 0.5) faces a camera 2 m away, turned by θ about a horizontal axis
through its centre; a point light sits at the camera; direct light only, no denoiser. The centre pixels see the square
at n·l = n·v = cos θ and at the same distance for every θ, so their linear radiance over cos θ, divided by its value at
θ = 0, is the lobe's retro-reflection factor: exactly 1 for a Lambertian lobe.

**Spotlight profile.** The calibrated DarkGS fits its RID to `spotlessgs.models.light.cone_profile`. Set-up: the
simulator's spotlight (`simulator.lighting.SPOTLIGHT_PRESETS["uneven"]`: cone, blend and emitter radius) at the camera,
pointing along the optical axis at a large plane of the same material 1 m ahead; the image row through the axis sees
the plane at angle θ from the axis, distance 1 / cos θ and incidence cos θ, so radiance / cos³ θ relative to the axis
is the profile I(θ) / I(0).

    python -m simulator.blender.light_response [--samples 256] [--threads 2] [--json]

prints both tables (or one JSON object).
"""

from __future__ import annotations

import argparse
import json
import math
import tempfile
from pathlib import Path

import bpy
import numpy as np
import torch

from simulator.blender.renderer import CyclesSettings, configure, exr_channels, render_exr, set_world_strength
from simulator.blender.scene_builder import BuiltScene, build_material, reset_blender, spotlight_data
from simulator.lighting import SPOTLIGHT_PRESETS
from simulator.scene_model import Material
from spotlessgs.models.brdf import disney_brdf
from spotlessgs.models.light import cone_profile

ANGLES_DEG = (0.0, 30.0, 50.0, 65.0, 75.0)
ROUGHNESS = (0.1, 0.5, 1.0)
# Distance (m) of the square from the camera and the light, its side (m), and the camera's field of view (deg).
DISTANCE = 2.0
SIDE = 0.2
FIELD_OF_VIEW_DEG = 4.0
IMAGE_SIZE = 24
CENTRE = 2  # half-width in pixels of the centre block that is averaged
# Spotlight profile: the plane's distance (m) and side (m), the camera's field of view (deg), the image width, and the
# samples of the printed profile (every PROFILE_STRIDE-th pixel from the axis outwards).
PLANE_DISTANCE = 1.0
PLANE_SIDE = 10.0
PROFILE_FIELD_OF_VIEW_DEG = 90.0
PROFILE_WIDTH = 201
PROFILE_HEIGHT = 5  # odd: the middle row's centre is on the axis
PROFILE_STRIDE = 5


def burley_factor(roughness: float, angle_deg: float) -> float:
    """The Disney diffuse lobe over the Lambertian one at n·l = n·v = cos θ, l = v (from `disney_brdf`)."""
    cos = math.cos(math.radians(angle_deg))
    direction = torch.tensor([[math.sqrt(1.0 - cos * cos), 0.0, cos]], dtype=torch.float64)
    normal = torch.tensor([[0.0, 0.0, 1.0]], dtype=torch.float64)
    albedo = torch.full((1, 3), 0.5, dtype=torch.float64)
    rough, metal = torch.full((1, 1), roughness, dtype=torch.float64), torch.zeros(1, 1, dtype=torch.float64)
    with_factor = disney_brdf(albedo, rough, metal, normal, direction, direction)
    lambertian = disney_brdf(albedo, rough, metal, normal, direction, direction, burley=False)
    diffuse = albedo[0, 0] / math.pi  # the Lambertian lobe; the specular lobe cancels in the difference
    return float(1.0 + (with_factor - lambertian)[0, 0] / diffuse)


def _camera_light_and_plane(light: bpy.types.Light, field_of_view_deg: float, side: float, distance: float,
                            roughness: float) -> bpy.types.Object:
    """Into a scene emptied by `reset_blender` (before ``light`` was made): a camera at the origin looking down -Z,
    ``light`` on it (pointing the same way), and a square of side ``side`` ``distance`` metres ahead facing the camera
    (returned), of the simulator's material with its specular layer off (base colour 0.5, ``roughness``)."""
    scene = bpy.context.scene
    cam_data = bpy.data.cameras.new("camera")
    cam_data.angle = math.radians(field_of_view_deg)
    camera = bpy.data.objects.new("camera", cam_data)
    scene.collection.objects.link(camera)
    scene.camera = camera
    scene.collection.objects.link(bpy.data.objects.new("lamp", light))
    bpy.ops.mesh.primitive_plane_add(size=side, location=(0.0, 0.0, -distance))
    square = bpy.context.active_object
    material = build_material(Material("square", base_color=(0.5, 0.5, 0.5), roughness=roughness),
                              BuiltScene(camera=camera, spotlight=camera, spot_local=np.eye(4)), lambertian=True)
    square.data.materials.append(material)
    return square


def _configure(width: int, height: int, samples: int, threads: int) -> None:
    """Cycles on the CPU, direct light only, no denoiser, and no light but the lamp (a new world's grey background
    would light the square evenly)."""
    configure(CyclesSettings(width=width, height=height, samples=samples, denoise=False, max_bounces=0,
                             threads=threads, device="cpu"))
    set_world_strength(0.0)


def diffuse_lobe(samples: int, threads: int) -> list[tuple[float, float, float]]:
    """(roughness, θ in degrees, measured factor) for every roughness in ROUGHNESS and angle in ANGLES_DEG."""
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for roughness in ROUGHNESS:
            reset_blender()
            lamp = bpy.data.lights.new("lamp", type="POINT")
            lamp.energy = 100.0
            lamp.shadow_soft_size = 0.0
            square = _camera_light_and_plane(lamp, FIELD_OF_VIEW_DEG, SIDE, DISTANCE, roughness)
            _configure(IMAGE_SIZE, IMAGE_SIZE, samples, threads)
            radiance = {}
            for angle in ANGLES_DEG:
                square.rotation_euler = (math.radians(angle), 0.0, 0.0)
                image = exr_channels(render_exr(Path(tmp), "lobe"), (".Combined.G",), Path(tmp))
                c = IMAGE_SIZE // 2
                radiance[angle] = float(image[c - CENTRE:c + CENTRE, c - CENTRE:c + CENTRE].mean())
            for angle in ANGLES_DEG:
                cos = math.cos(math.radians(angle))
                rows.append((roughness, angle, radiance[angle] / cos / radiance[ANGLES_DEG[0]]))
    return rows


def spot_profile(samples: int, threads: int) -> list[tuple[float, float, float]]:
    """(θ in degrees, measured I(θ) / I(0), cone_profile(θ)) along the image row through the spotlight's axis, every
    PROFILE_STRIDE-th pixel from the axis outwards."""
    spot = SPOTLIGHT_PRESETS["uneven"]
    reset_blender()
    _camera_light_and_plane(spotlight_data(spot), PROFILE_FIELD_OF_VIEW_DEG, PLANE_SIDE, PLANE_DISTANCE, 0.5)
    _configure(PROFILE_WIDTH, PROFILE_HEIGHT, samples, threads)
    with tempfile.TemporaryDirectory() as tmp:
        image = exr_channels(render_exr(Path(tmp), "profile"), (".Combined.G",), Path(tmp))
    if image.shape != (PROFILE_HEIGHT, PROFILE_WIDTH):
        raise RuntimeError(f"spot_profile: Blender rendered {image.shape}, not ({PROFILE_HEIGHT}, {PROFILE_WIDTH})")
    row = image[PROFILE_HEIGHT // 2].astype(np.float64)  # the middle row: through the axis
    tan_half = math.tan(math.radians(PROFILE_FIELD_OF_VIEW_DEG) / 2.0)
    theta = np.arctan(np.abs((np.arange(PROFILE_WIDTH) + 0.5) / PROFILE_WIDTH * 2.0 - 1.0) * tan_half)
    centre = PROFILE_WIDTH // 2
    profile = row / np.cos(theta) ** 3
    profile = profile / profile[centre]
    model = cone_profile(torch.from_numpy(theta), math.radians(spot.cone_angle_deg) / 2.0, spot.blend).numpy()
    return [(math.degrees(theta[i]), float(profile[i]), float(model[i]))
            for i in range(centre, PROFILE_WIDTH, PROFILE_STRIDE)]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--samples", type=int, default=256, help="Cycles samples per pixel")
    parser.add_argument("--threads", type=int, default=2, help="Cycles CPU threads")
    parser.add_argument("--json", action="store_true", help="print one JSON object instead of the tables")
    args = parser.parse_args()
    lobe = [(rough, angle, factor, burley_factor(rough, angle)) for rough, angle, factor in
            diffuse_lobe(args.samples, args.threads)]
    profile = spot_profile(args.samples, args.threads)
    if args.json:
        print(json.dumps({"blender": bpy.app.version_string,
                          "diffuse_lobe": [dict(zip(("roughness", "angle_deg", "measured", "burley"), r)) for r in lobe],
                          "spot_profile": [dict(zip(("angle_deg", "measured", "cone_profile"), r)) for r in profile]}))
        return
    print(f"Blender {bpy.app.version_string}. Diffuse lobe: radiance / cos θ, relative to θ = 0")
    print("| roughness | θ | measured | Lambertian | Burley |")
    print("|---|---|---|---|---|")
    for roughness, angle, factor, burley in lobe:
        print(f"| {roughness:.1f} | {angle:.0f}° | {factor:.3f} | 1.000 | {burley:.3f} |")
    print("\nSpotlight profile I(θ) / I(0)")
    print("| θ | measured | cone_profile |")
    print("|---|---|---|")
    for angle, measured, model in profile:
        print(f"| {angle:.1f}° | {measured:.3f} | {model:.3f} |")


if __name__ == "__main__":
    main()
