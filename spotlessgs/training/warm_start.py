"""Warm start: a new model that begins from the Gaussians and the spotlight of another run's checkpoint.

Model selection (:mod:`spotlessgs.training.selection`) fits one shared base model, then every candidate starts from
its geometry and light, so that the candidates differ only in what is being compared (the low-frequency light and the
reflectance) and not in how far their geometry and spotlight got in a short run.
"""

from __future__ import annotations

from typing import Any

import torch

from spotlessgs.models.gaussians import GaussianParams
from spotlessgs.models.relightable import RelightableScene


def warm_start_scene(scene: RelightableScene, checkpoint: dict[str, Any], source: str = "checkpoint") -> RelightableScene:
    """``scene``'s model with the checkpoint's per-Gaussian parameters, spotlight and low-frequency light.

    The spotlight state is copied whole. SH light coefficients (K_src, 3), of the low-frequency light and of the
    bounce light, are copied into the first rows of the new light's (K, 3) (a lower degree is the leading block of a
    higher one; extra rows stay 0, missing rows are dropped).
    A learned BRDF network is copied when the checkpoint has one of the same shape (model selection's second phase
    continues the first phase's winner); a constant ambient, or a BRDF of another kind, is not copied (the
    candidate's own initial values are used).

    Raises:
        ValueError: the checkpoint has no Gaussians, or the spotlight of one side is missing (names ``source``).
    """
    if "gaussians" not in checkpoint or "appearance" not in checkpoint:
        raise ValueError(f"{source}: not a training checkpoint (no 'gaussians'/'appearance')")
    app = scene.appearance
    state = checkpoint["appearance"]
    light_state = {k[len("light."):]: v for k, v in state.items() if k.startswith("light.")}
    if app.light is None or not light_state:
        raise ValueError(f"{source}: warm start needs a spotlight model on both sides")
    new = RelightableScene(scene.config, GaussianParams({k: v.clone() for k, v in checkpoint["gaussians"].items()}),
                           app)
    app.light.load_state_dict(light_state)
    for name in ("lf_light", "bounce_light"):
        coeffs, own = state.get(f"{name}.coeffs"), getattr(getattr(app, name), "coeffs", None)
        if coeffs is not None and own is not None:
            rows = min(coeffs.shape[0], own.shape[0])
            with torch.no_grad():
                own.zero_()
                own[:rows] = coeffs[:rows]
    brdf_state = {k[len("brdf."):]: v for k, v in state.items() if k.startswith("brdf.")}
    if brdf_state and app.brdf is not None:
        own = app.brdf.state_dict()
        if own.keys() == brdf_state.keys() and all(own[k].shape == brdf_state[k].shape for k in own):
            app.brdf.load_state_dict(brdf_state)
    return new
