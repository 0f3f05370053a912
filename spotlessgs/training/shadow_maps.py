"""The training views' shadow maps, kept between the steps that fit a view (``TrainConfig.shadow_map_every``).

A view's pair of maps (the lamp's and the camera's) costs about a quarter of a training step (two forward
rasterizations at half the camera's focal length); reused for a few visits of its view it costs that much less. A
reused map gives the shadows of the geometry and lamp pose it was rendered from; the gradient still reaches the
lamp's current position (:func:`spotlessgs.models.shadow.spot_visibility`). The maps go into the checkpoints, so that
a resumed run reuses the maps an uninterrupted one would.
"""

from __future__ import annotations

import dataclasses
from typing import Any

import torch

from spotlessgs.io.camera_batch import Cameras
from spotlessgs.models.relightable import RelightableScene
from spotlessgs.models.shadow import ShadowMap
from spotlessgs.training.config import TrainConfig


class ShadowMapCache:
    """Each training view's shadow maps, re-rendered when ``config.shadow_map_every`` steps old (models.shadow)."""

    def __init__(self, config: TrainConfig) -> None:
        self.config = config
        self.maps: dict[int, tuple[int, ShadowMap]] = {}

    def get(self, scene: RelightableScene, view: int, step: int, camera: Cameras) -> ShadowMap | None:
        """The map of ``view`` for ``step`` (None when the model has no spotlight shadows: nothing to cache)."""
        if not scene.has_spot_shadows:
            return None
        cached = self.maps.get(view)
        if cached is None or step - cached[0] >= self.config.shadow_map_every:
            cached = (step, scene.shadow_map(camera, self.config.raster_backend, self.config.num_threads))
            self.maps[view] = cached
        return cached[1]

    def state_dict(self) -> dict[int, dict[str, Any]]:
        """The cached maps by view: the step each was rendered at and its tensors (for a checkpoint)."""
        return {view: {"step": step, **{f.name: getattr(m, f.name) for f in dataclasses.fields(ShadowMap)}}
                for view, (step, m) in self.maps.items()}

    def load_state_dict(self, state: dict[int, dict[str, Any]], device: torch.device | str) -> None:
        """Restore the maps of :meth:`state_dict` onto ``device``. A map that lacks a field (a checkpoint from before
        the camera's own map) is left out: its view renders a new one when next fitted."""
        names = [f.name for f in dataclasses.fields(ShadowMap)]
        self.maps = {int(view): (int(entry["step"]), ShadowMap(**{name: entry[name].to(device) for name in names}))
                     for view, entry in state.items() if all(name in entry for name in names)}
