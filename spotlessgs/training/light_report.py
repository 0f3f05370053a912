"""The estimated light of a run: pose relative to the camera, fall-off, ambient/SH, RID curve plot, the lamp's learned
position over the training steps, and its error against the dataset's light truth when known. Written to
``RUN/light.json``, ``RUN/light_rid.png`` and ``RUN/light_path.png``."""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

import numpy as np
import torch

from spotlessgs.io.atomic import write_json
from spotlessgs.io.figures import pyplot, save_figure
from spotlessgs.io.transforms import LightTruth
from spotlessgs.models.light import ConstantAmbient, LowFrequencyLight, cone_profile
from spotlessgs.training.checkpoint import RUN_SCHEMA_VERSION


def axis_angle_error_deg(rotation_a: np.ndarray, rotation_b: np.ndarray) -> float:
    """Angle (degrees) between the light axes (+z columns) of two light→camera rotations (3, 3)."""
    a, b = rotation_a[:, 2], rotation_b[:, 2]
    cos = float(np.dot(a, b) / (np.linalg.norm(a) * np.linalg.norm(b)))
    return math.degrees(math.acos(max(-1.0, min(1.0, cos))))


@torch.no_grad()
def light_estimate(scene) -> dict[str, Any] | None:
    """The learned light as plain data, or None for models without a light (3dgs)."""
    app = scene.appearance
    if app.light is None:
        return None
    light = app.light
    rot = light.rotation().double().cpu().numpy()
    est: dict[str, Any] = {
        "rotation_in_camera": rot.tolist(),
        "axis_in_camera": rot[:, 2].tolist(),
        "position_in_camera_m": light.translation.double().cpu().numpy().tolist(),
        "falloff_gamma": float(light.gamma),
        "falloff_tau_m2": float(light.tau),
        "radiance_scale": float(light.radiance_scale),
        "pose_trainable": bool(light.translation.requires_grad),
    }
    if isinstance(app.lf_light, ConstantAmbient):
        est["ambient"] = float(app.lf_light.value)
    elif isinstance(app.lf_light, LowFrequencyLight):
        est["sh_degree"] = app.lf_light.degree
        est["sh_coefficients"] = app.lf_light.coeffs.double().cpu().numpy().tolist()
    if app.bounce_light is not None:
        est["bounce_sh_degree"] = app.bounce_light.degree
        est["bounce_sh_coefficients_camera_frame"] = app.bounce_light.coeffs.double().cpu().numpy().tolist()
    return est


def light_errors(estimate: dict[str, Any], truth: LightTruth) -> dict[str, float]:
    """Translation error (m) and light-axis angle error (degrees) of an estimate against the truth."""
    t_err = float(np.linalg.norm(np.asarray(estimate["position_in_camera_m"]) - truth.position_in_camera))
    axis = axis_angle_error_deg(np.asarray(estimate["rotation_in_camera"]), truth.rotation_in_camera)
    return {"translation_error_m": t_err, "axis_error_deg": axis}


@torch.no_grad()
def write_light_report(scene, views, run_dir: Path) -> dict[str, Any]:
    """Write ``light.json`` and the RID plot; returns the JSON content."""
    est = light_estimate(scene)
    report: dict[str, Any] = {"model": scene.config.name, "estimate": est, "truth": None, "errors": None}
    if views.light is not None:
        report["truth"] = views.light.to_json()
        if est is not None:
            report["errors"] = light_errors(est, views.light)
    write_json(Path(run_dir) / "light.json", {"schema_version": RUN_SCHEMA_VERSION, **report})
    if est is not None:
        plot_rid(scene, views.light, Path(run_dir) / "light_rid.png")
        steps, positions = lamp_path(Path(run_dir) / "metrics.jsonl")
        if len(steps) >= 2:
            plot_lamp_path(steps, positions, views.light, Path(run_dir) / "light_path.png")
    return report


def lamp_path(metrics_path: Path) -> tuple[np.ndarray, np.ndarray]:
    """The learned lamp position logged in ``metrics.jsonl``: steps (K,) and positions (K, 3) in metres, camera frame
    (empty when the file or the field is missing; unreadable lines are skipped: the plot is a report, not a check)."""
    steps, positions = [], []
    try:
        lines = metrics_path.read_text(encoding="utf-8").splitlines()
    except OSError:
        lines = []
    for line in lines:
        try:
            row = json.loads(line)
            position = [float(v) for v in row["light_translation_m"]]
            step = int(row["step"])
        except (ValueError, KeyError, TypeError):
            continue
        if len(position) == 3:
            steps.append(step)
            positions.append(position)
    return np.asarray(steps, dtype=np.int64), np.asarray(positions, dtype=np.float64).reshape(-1, 3)


def plot_lamp_path(steps: np.ndarray, positions: np.ndarray, truth: LightTruth | None, path: Path) -> None:
    """The lamp's learned position (camera frame, cm) against the training step, with the true one when known."""
    plt = pyplot()
    fig, ax = plt.subplots(figsize=(5, 3.4))
    for axis, (name, colour) in enumerate(zip("xyz", ("tab:red", "tab:green", "tab:blue"))):
        ax.plot(steps, 100.0 * positions[:, axis], color=colour, label=f"learned {name}")
        if truth is not None:
            ax.axhline(100.0 * float(truth.position_in_camera[axis]), color=colour, linestyle="--", linewidth=1,
                       label=f"true {name}")
    ax.set_xlabel("training step")
    ax.set_ylabel("lamp position in the camera frame (cm)")
    ax.grid(True, alpha=0.3)
    ax.legend(fontsize=7, ncol=2)
    save_figure(fig, path)


@torch.no_grad()
def plot_rid(scene, truth: LightTruth | None, path: Path) -> None:
    """The learned radiant intensity against the angle off the light axis (normalised to its peak), with the true
    cone profile when known."""
    plt = pyplot()
    theta = torch.linspace(0.0, math.radians(80.0), 200)
    rid = scene.appearance.light.rid_curve(theta).reshape(-1).double().cpu().numpy()
    fig, ax = plt.subplots(figsize=(5, 3.4))
    ax.plot(np.degrees(theta.numpy()), rid / max(rid.max(), 1e-12), label="learned RID (normalised)")
    if truth is not None:
        half = math.radians(truth.cone_angle_deg) / 2.0
        ax.plot(np.degrees(theta.numpy()), cone_profile(theta.double(), half, truth.blend).numpy(), "--",
                label=f"true cone ({truth.cone_angle_deg:.0f} deg, blend {truth.blend:.2f})")
    ax.set_xlabel("angle off the light axis (degrees)")
    ax.set_ylabel("relative intensity")
    ax.grid(True, alpha=0.3)
    ax.legend(fontsize=8)
    save_figure(fig, path)
