"""Light settings of the two renders (bpy-free).

* The **spotlight** (uneven image): a cone-shaped lamp rigidly mounted on the camera, a few centimetres off the lens.
  Its pose is given in the OpenCV camera frame (x right, y down, z forward); it shines along its own +z.
* The **ground truth** (evenly lit image): the spotlight is off; lamps and ceiling lights (furniture whose category says
  lamp, ``LightBand`` meshes) glow and carry Blender lights so that the room is evenly and realistically lit.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np

from simulator.scene_model import LightFixture, MeshObject, Scene


@dataclass(frozen=True)
class SpotlightConfig:
    """The camera-mounted spotlight.

    Attributes:
        cone_angle_deg: full opening angle of the cone (Blender ``spot_size``).
        blend: softness of the cone edge in [0, 1] (Blender ``spot_blend``).
        power_w: radiant power in watts (Blender light power).
        color: linear RGB colour.
        radius_m: emitter radius (soft shadow size).
        position_in_camera: light origin in the OpenCV camera frame, metres (right, down, forward).
        rotation_in_camera_deg: XYZ Euler angles (degrees) of the light frame relative to the camera frame; zero means
            the beam is parallel to the optical axis.
    """

    cone_angle_deg: float = 65.0
    blend: float = 0.35
    power_w: float = 300.0
    color: tuple[float, float, float] = (1.0, 1.0, 1.0)
    radius_m: float = 0.02
    position_in_camera: tuple[float, float, float] = (0.06, -0.04, 0.0)
    rotation_in_camera_deg: tuple[float, float, float] = (3.0, -2.0, 0.0)

    def rotation_matrix(self) -> np.ndarray:
        """(3, 3) rotation light frame -> OpenCV camera frame, R = Rz Ry Rx of ``rotation_in_camera_deg``."""
        rx, ry, rz = np.deg2rad(self.rotation_in_camera_deg)
        cx, sx, cy, sy, cz, sz = np.cos(rx), np.sin(rx), np.cos(ry), np.sin(ry), np.cos(rz), np.sin(rz)
        mx = np.array([[1, 0, 0], [0, cx, -sx], [0, sx, cx]])
        my = np.array([[cy, 0, sy], [0, 1, 0], [-sy, 0, cy]])
        mz = np.array([[cz, -sz, 0], [sz, cz, 0], [0, 0, 1]])
        return mz @ my @ mx


#: Named spotlight presets: ``uneven`` (hot spot, dark corners, few clipped pixels) and ``saturated`` (clips).
SPOTLIGHT_PRESETS: dict[str, SpotlightConfig] = {
    "uneven": SpotlightConfig(),
    "saturated": SpotlightConfig(power_w=700.0),
}


@dataclass(frozen=True)
class GroundTruthLighting:
    """Lamps and ceiling lights of the evenly lit render.

    Attributes:
        ceiling_lamp_w: power of the Blender light inside each ceiling / pendant lamp.
        other_lamp_w: power of the light inside every other lamp (floor, desk, wall lamps).
        lightband_w_per_m2: power of the area light under a LightBand strip, per m^2 of strip.
        lamp_emission: emission strength of lamp surfaces (what the camera sees of the lamp itself).
        ceiling_glow: emission of ceiling meshes seen only by indirect rays (camera rays see the plain surface), a
            standard trick that mimics many recessed lights; 0 disables it.
        color: linear RGB colour of all fixtures (warm white).
    """

    ceiling_lamp_w: float = 9.0
    other_lamp_w: float = 3.6
    lightband_w_per_m2: float = 7.2
    lamp_emission: float = 3.0
    ceiling_glow: float = 0.036
    color: tuple[float, float, float] = (1.0, 0.94, 0.86)


def _is_ceiling_lamp(obj: MeshObject) -> bool:
    text = obj.category.lower()
    return "ceiling" in text or "pendant" in text or "chandelier" in text


def ground_truth_fixtures(scene: Scene, objects: list[MeshObject], config: GroundTruthLighting) -> list[LightFixture]:
    """One Blender light per lamp / light strip among ``objects``.

    Ceiling and pendant lamps get a point light 5 cm below their lowest point; other lamps a point light at their
    bounding-box centre (inside the shade); LightBand strips a downward area light of their footprint.
    """
    lights: list[LightFixture] = []
    for obj in objects:
        if not obj.is_light:
            continue
        lo, hi = obj.bounds()
        centre = 0.5 * (lo + hi)
        if obj.source == "mesh":
            footprint = max((hi[0] - lo[0]) * (hi[1] - lo[1]), 0.01)
            pos = (centre[0], centre[1], lo[2] - 0.02)
            lights.append(
                LightFixture(f"light/{obj.name}", "area", pos, config.lightband_w_per_m2 * footprint, config.color,
                             float(np.sqrt(footprint)))
            )
        elif _is_ceiling_lamp(obj):
            pos = (centre[0], centre[1], lo[2] - 0.05)
            lights.append(LightFixture(f"light/{obj.name}", "point", pos, config.ceiling_lamp_w, config.color, 0.08))
        else:
            size = float(min(hi - lo) * 0.3)
            lights.append(
                LightFixture(f"light/{obj.name}", "point", tuple(centre), config.other_lamp_w, config.color, size)
            )
    return lights


def with_ground_truth_lighting(scene: Scene, objects: list[MeshObject], config: GroundTruthLighting) -> Scene:
    """The scene with lamp emission set on its lamp materials and its ``lights`` filled in."""
    lit_objects = []
    for obj in scene.objects:
        if obj.is_light:
            obj = replace(obj, material=replace(obj.material, emission=config.lamp_emission,
                                                emission_color=config.color))
        lit_objects.append(obj)
    lights = ground_truth_fixtures(scene, objects, config)
    return replace(scene, objects=lit_objects, lights=lights)


@dataclass(frozen=True)
class LightingSetup:
    """Both renders' light settings, as recorded in the dataset."""

    spotlight: SpotlightConfig = field(default_factory=SpotlightConfig)
    ground_truth: GroundTruthLighting = field(default_factory=GroundTruthLighting)
