"""What training renders per view and keeps for a few steps: the lamp's shadow maps (``TrainConfig.shadow_map_every``)
and the lamp's bounce light (``TrainConfig.lamp_bounce_every``).

A view's pair of shadow maps (the lamp's and the camera's) costs about a quarter of a training step (two forward
rasterizations at half the camera's focal length); reused for a few visits of its view it costs that much less. A
reused map gives the shadows of the geometry and lamp pose it was rendered from; the gradient still reaches the
lamp's current position (:func:`spotlessgs.models.shadow.spot_visibility`).

A view's one-bounce irradiance (models.lamp_bounce) is computed in the training step's own render, from six more
channels (the spotlight's part of the colour and the camera-frame normals) and the bounce's pair sums; it carries no
gradient, so a reused one changes only what the bounce light was computed from: the geometry, normals and spotlight
of a few steps ago. A step that reuses one composites the albedo only.

Both go into the checkpoints, so that a resumed run reuses what an uninterrupted one would.
"""

from __future__ import annotations

import abc
import dataclasses
from typing import Any, Generic, TypeVar

import torch

from spotlessgs.io.camera_batch import Cameras
from spotlessgs.models.relightable import RelightableScene
from spotlessgs.models.shadow import ShadowMap
from spotlessgs.training.config import TrainConfig

Kept = TypeVar("Kept")


class _ViewCache(abc.ABC, Generic[Kept]):
    """Something rendered per training view, re-rendered once ``every`` steps old; subclasses say how it is stored
    as named tensors."""

    def __init__(self, config: TrainConfig, every: int) -> None:
        self.config = config
        self.every = every
        self.kept: dict[int, tuple[int, Kept]] = {}

    @abc.abstractmethod
    def _tensors(self, kept: Kept) -> dict[str, torch.Tensor]:
        """``kept`` as named tensors (a checkpoint's)."""

    @abc.abstractmethod
    def _from_tensors(self, tensors: dict[str, Any], device: torch.device | str) -> Kept | None:
        """:meth:`_tensors`' inverse onto ``device``; None when a tensor is missing."""

    def fresh(self, view: int, step: int) -> Kept | None:
        """What ``view`` keeps, if it is less than ``every`` steps old at ``step``; else None."""
        cached = self.kept.get(view)
        return None if cached is None or step - cached[0] >= self.every else cached[1]

    def keep(self, view: int, step: int, kept: Kept) -> None:
        """Keep ``kept``, new at ``step``, for ``view`` (unless the view's kept one is still fresh)."""
        if self.fresh(view, step) is None:
            self.kept[view] = (step, kept)

    def state_dict(self) -> dict[int, dict[str, Any]]:
        """What is kept, by view: the step it was rendered at and its tensors (for a checkpoint)."""
        return {view: {"step": step, **self._tensors(kept)} for view, (step, kept) in self.kept.items()}

    def load_state_dict(self, state: dict[int, dict[str, Any]], device: torch.device | str) -> None:
        """Restore the views of :meth:`state_dict` onto ``device``. An entry that lacks a tensor (a checkpoint from
        an earlier version) is left out: its view renders a new one when next fitted."""
        self.kept = {}
        for view, entry in state.items():
            kept = self._from_tensors(entry, device)
            if kept is not None:
                self.kept[int(view)] = (int(entry["step"]), kept)


class ShadowMapCache(_ViewCache[ShadowMap]):
    """Each training view's shadow maps, re-rendered when ``config.shadow_map_every`` steps old (models.shadow)."""

    def __init__(self, config: TrainConfig) -> None:
        super().__init__(config, config.shadow_map_every)

    def get(self, scene: RelightableScene, view: int, step: int, camera: Cameras) -> ShadowMap | None:
        """The shadow map of ``view`` (``camera``: the view) for ``step``: the kept one, or a new one when it is
        ``shadow_map_every`` steps old; None for a model without spotlight shadows."""
        if not scene.has_spot_shadows:
            return None
        kept = self.fresh(view, step)
        if kept is None:
            kept = scene.shadow_map(camera, self.config.raster_backend, self.config.num_threads)
            self.keep(view, step, kept)
        return kept

    def _tensors(self, kept: ShadowMap) -> dict[str, torch.Tensor]:
        return {f.name: getattr(kept, f.name) for f in dataclasses.fields(ShadowMap)}

    def _from_tensors(self, tensors: dict[str, Any], device: torch.device | str) -> ShadowMap | None:
        names = [f.name for f in dataclasses.fields(ShadowMap)]
        if not all(name in tensors for name in names):  # a checkpoint from before the camera's own map
            return None
        return ShadowMap(**{name: tensors[name].to(device) for name in names})


class LampBounceCache(_ViewCache[torch.Tensor]):
    """Each training view's one-bounce irradiance (H, W, 3), recomputed when ``config.lamp_bounce_every`` steps old
    (models.lamp_bounce): :meth:`fresh` gives the render its ``lamp_irradiance`` (None: the render computes a new
    one in its own pass), :meth:`keep` takes the render's ``lamp_irradiance`` back."""

    def __init__(self, config: TrainConfig) -> None:
        super().__init__(config, config.lamp_bounce_every)

    def _tensors(self, kept: torch.Tensor) -> dict[str, torch.Tensor]:
        return {"irradiance": kept}

    def _from_tensors(self, tensors: dict[str, Any], device: torch.device | str) -> torch.Tensor | None:
        return tensors["irradiance"].to(device) if "irradiance" in tensors else None
