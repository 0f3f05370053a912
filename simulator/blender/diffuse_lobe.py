"""Measure the renderer's diffuse lobe under a lamp at the camera: Lambertian, or with Burley's retro-reflection?

The learned BRDF of SpotlessGS starts from the Disney model, whose diffuse lobe has Burley's factor
(1 + (F_D90 - 1)(1 - n·l)⁵)(1 + (F_D90 - 1)(1 - n·v)⁵), F_D90 = ½ + 2ρ (l·h)² (spotlessgs.models.brdf). Lit and seen
from one direction, as by a robot's lamp beside its camera, that factor brightens a rough surface towards grazing
(1.78x at 75° for ρ = 1). This check renders what the simulator's materials do there.

Set-up: a 0.2 m square of the simulator's own material (`scene_builder.build_material` with its specular layer off,
metalness 0, base colour 0.5) faces a camera 2 m away, turned by θ about a horizontal axis through its centre; a point
light sits at the camera; direct light only, no denoiser. The centre pixels see the square at n·l = n·v = cos θ and at
the same distance for every θ, so their linear radiance over cos θ, divided by its value at θ = 0, is the lobe's
retro-reflection factor: exactly 1 for a Lambertian lobe.

    python -m simulator.blender.diffuse_lobe [--samples 256] [--threads 2]

prints, per roughness and angle, the measured factor beside the Lambertian (1) and Burley predictions.
"""

from __future__ import annotations

import argparse
import math
import tempfile
from pathlib import Path

import bpy
import numpy as np
import torch

from simulator.blender.renderer import CyclesSettings, configure, exr_channels, render_exr, set_world_strength
from simulator.blender.scene_builder import BuiltScene, build_material, reset_blender
from simulator.scene_model import Material
from spotlessgs.models.brdf import disney_brdf

ANGLES_DEG = (0.0, 30.0, 50.0, 65.0, 75.0)
ROUGHNESS = (0.1, 0.5, 1.0)
# Distance (m) of the square from the camera and the light, its side (m), and the camera's field of view (deg).
DISTANCE = 2.0
SIDE = 0.2
FIELD_OF_VIEW_DEG = 4.0
IMAGE_SIZE = 24
CENTRE = 2  # half-width in pixels of the centre block that is averaged


def burley_factor(roughness: float, angle_deg: float) -> float:
    """The Disney diffuse lobe over the Lambertian one at n·l = n·v = cos θ, l = v (from `disney_brdf`)."""
    cos = math.cos(math.radians(angle_deg))
    direction = torch.tensor([[math.sqrt(1.0 - cos * cos), 0.0, cos]], dtype=torch.float64)
    normal = torch.tensor([[0.0, 0.0, 1.0]], dtype=torch.float64)
    albedo = torch.full((1, 3), 0.5, dtype=torch.float64)
    rough, metal = torch.full((1, 1), roughness, dtype=torch.float64), torch.zeros(1, 1, dtype=torch.float64)
    with_factor = disney_brdf(albedo, rough, metal, normal, direction, direction)
    lambertian = disney_brdf(albedo, rough, metal, normal, direction, direction, burley=False)
    diffuse = 0.5 / math.pi
    return float(((with_factor - lambertian)[0, 0] + diffuse) / diffuse)


def _scene(roughness: float) -> bpy.types.Object:
    """Camera at the origin looking down -Z, a point light on it, and the square 2 m ahead (returned)."""
    reset_blender()
    scene = bpy.context.scene
    cam_data = bpy.data.cameras.new("camera")
    cam_data.angle = math.radians(FIELD_OF_VIEW_DEG)
    camera = bpy.data.objects.new("camera", cam_data)
    scene.collection.objects.link(camera)
    scene.camera = camera
    light_data = bpy.data.lights.new("lamp", type="POINT")
    light_data.energy = 100.0
    light_data.shadow_soft_size = 0.0
    scene.collection.objects.link(bpy.data.objects.new("lamp", light_data))
    bpy.ops.mesh.primitive_plane_add(size=SIDE, location=(0.0, 0.0, -DISTANCE))
    square = bpy.context.active_object
    material = build_material(Material("square", base_color=(0.5, 0.5, 0.5), roughness=roughness),
                              BuiltScene(camera=camera, spotlight=camera, spot_local=np.eye(4)), lambertian=True)
    square.data.materials.append(material)
    return square


def measure(samples: int, threads: int) -> list[tuple[float, float, float]]:
    """(roughness, θ in degrees, measured factor) for every roughness in ROUGHNESS and angle in ANGLES_DEG."""
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for roughness in ROUGHNESS:
            square = _scene(roughness)
            configure(CyclesSettings(width=IMAGE_SIZE, height=IMAGE_SIZE, samples=samples, denoise=False,
                                     max_bounces=0, threads=threads, device="cpu"))
            set_world_strength(0.0)  # the lamp alone: a new world's grey background would light the square evenly
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


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--samples", type=int, default=256, help="Cycles samples per pixel")
    parser.add_argument("--threads", type=int, default=2, help="Cycles CPU threads")
    args = parser.parse_args()
    print(f"Blender {bpy.app.version_string}; factor = radiance / cos θ, relative to θ = 0")
    print("| roughness | θ | measured | Lambertian | Burley |")
    print("|---|---|---|---|---|")
    for roughness, angle, factor in measure(args.samples, args.threads):
        print(f"| {roughness:.1f} | {angle:.0f}° | {factor:.3f} | 1.000 | {burley_factor(roughness, angle):.3f} |")


if __name__ == "__main__":
    main()
