"""The direct light of a rendered dataset's true lamp at known geometry (the analyses of docs/results.md that split
an input into the lamp's direct light and the rest)."""

from __future__ import annotations

import math

import numpy as np
import torch

from spotlessgs.models.light import cone_profile


def true_direct_light(points: np.ndarray, normals: np.ndarray, diffuse: np.ndarray, light) -> np.ndarray:
    """(H, W) the lamp's direct light up to a gain: diffuse × profile(θ) × max(cos, 0) / d² (a Lambertian surface,
    the lamp's shadows ignored).

    Args:
        points: (H, W, 3) camera-frame points (OpenCV axes, metres); normals: (H, W, 3) unit normals, camera frame;
        diffuse: (H, W) diffuse colour; light: the dataset's ``LightTruth`` (position and rotation in the camera,
            cone angle and blend).
    """
    to_point = points - np.asarray(light.position_in_camera, dtype=np.float64)
    distance = np.linalg.norm(to_point, axis=-1)
    in_light = to_point @ np.asarray(light.rotation_in_camera, dtype=np.float64)  # light frame: R^T d
    theta = np.arctan2(np.hypot(in_light[..., 0], in_light[..., 1]), in_light[..., 2])
    profile = cone_profile(torch.from_numpy(theta), math.radians(light.cone_angle_deg / 2), light.blend).numpy()
    cosine = np.clip(-(normals * to_point).sum(-1) / np.maximum(distance, 1e-9), 0.0, None)
    return diffuse * profile * cosine / np.maximum(distance, 1e-9) ** 2
