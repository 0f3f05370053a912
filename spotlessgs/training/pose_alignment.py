"""Test-view alignment: a view that training never fitted (a test view) gets its pose corrected against its own
spotlit input, with the model frozen, before it is rendered and scored.

A run that refined its training views' poses (``TrainConfig.refine_poses``) has moved its scene to agree with the
corrected poses; a test view at its dataset pose would then be scored partly on the pose error that refinement
removed elsewhere. So each such view gets a correction of its own (:mod:`spotlessgs.models.pose`), fitted to the
view's INPUT image (never its ground truth) by Adam from the identity.

The spotlight is mounted on the camera, so every pose hypothesis carries its own light: a plain photometric loss can
prefer a wrong pose whose hot spot happens to match the input's brightness better. The default ``texture`` loss
compares local contrast (:func:`spotlessgs.training.losses.texture_loss`), in which a slowly varying light cancels;
``photometric`` is the training loss, for comparison (docs/results.md, "Camera pose refinement").
"""

from __future__ import annotations

import contextlib
from dataclasses import dataclass
from typing import Iterator, Sequence

import torch
from torch import nn

from spotlessgs.io.camera_batch import Cameras
from spotlessgs.models.photometric import PhotometricCamera
from spotlessgs.models.pose import PoseCorrection, correction_size
from spotlessgs.models.relightable import RelightableScene
from spotlessgs.training.config import TrainConfig
from spotlessgs.training.data import TrainingViews
from spotlessgs.training.losses import photometric_loss, texture_loss

#: ``TrainConfig.pose_align_loss`` values.
ALIGN_LOSSES = ("texture", "photometric")


@dataclass(frozen=True)
class AlignedView:
    """One view's alignment.

    Attributes:
        view: the view's index in the dataset.
        delta: (9,) its correction's parameters (:class:`spotlessgs.models.pose.PoseCorrection` row), CPU.
        loss_before, loss_after: the alignment loss at the dataset pose and at the aligned pose.
        translation_m, rotation_deg: the size of the correction.
    """

    view: int
    delta: torch.Tensor
    loss_before: float
    loss_after: float
    translation_m: float
    rotation_deg: float


@contextlib.contextmanager
def frozen(*modules: nn.Module | None) -> Iterator[None]:
    """No parameter of ``modules`` requires a gradient inside the block (restored after)."""
    params = [p for m in modules if m is not None for p in m.parameters() if p.requires_grad]
    for p in params:
        p.requires_grad_(False)
    try:
        yield
    finally:
        for p in params:
            p.requires_grad_(True)


def alignment_loss(kind: str, recorded: torch.Tensor, target: torch.Tensor, saturated: torch.Tensor,
                   unseen: torch.Tensor | None, ssim_lambda: float) -> torch.Tensor:
    """The alignment loss ``kind`` between a spotlit render (through the photometric camera) and the input (both
    (H, W, 3) linear); saturated, unseen: (H, W) bool."""
    if kind == "texture":
        valid = ~saturated if unseen is None else ~(saturated | unseen)
        return texture_loss(recorded, target, valid.to(recorded.dtype))
    if kind == "photometric":
        if unseen is not None:
            target = torch.where(unseen[..., None], recorded.detach().clamp(0.0, 1.0), target)
            saturated = saturated | unseen
        return photometric_loss(recorded, target, saturated, ssim_lambda)[0]
    raise ValueError(f"unknown pose alignment loss {kind!r}; choose one of {ALIGN_LOSSES}")


def align_view(scene: RelightableScene, camera: Cameras, view: int, target: torch.Tensor, saturated: torch.Tensor,
               config: TrainConfig, unseen: torch.Tensor | None = None,
               photometric: PhotometricCamera | None = None) -> AlignedView:
    """Fit the pose correction of one view (``camera``, index ``view``) to its input ``target`` (H, W, 3) linear, with
    ``saturated`` / ``unseen`` (H, W) bool, the model frozen: ``config.pose_align_steps`` Adam steps at
    ``config.pose_align_lr`` on ``config.pose_align_loss``. Deterministic (no random state). (An exponentially
    decaying step size stopped short of the minimum that a constant one reaches from 3 cm / 0.3 deg away.)"""
    pose = PoseCorrection(1, sparse=False).to(camera.device)
    opt = torch.optim.Adam(pose.parameters(), lr=config.pose_align_lr)

    def loss_at() -> torch.Tensor:
        out = scene.render(pose(camera, 0), backend=config.raster_backend, num_threads=config.num_threads)
        # the texture loss does not see the frame's exposure and hardly the vignetting: it compares the render itself,
        # so that an alignment with and without the photometric camera (training, relighting) is the same
        use_camera = photometric is not None and config.pose_align_loss == "photometric"
        recorded = photometric(out.image, view) if use_camera else out.image
        return alignment_loss(config.pose_align_loss, recorded, target, saturated, unseen, config.ssim_lambda)

    with frozen(scene, photometric):
        before = None
        for _ in range(config.pose_align_steps):
            loss = loss_at()
            before = float(loss.detach()) if before is None else before
            opt.zero_grad(set_to_none=True)
            loss.backward()
            opt.step()
        with torch.no_grad():
            after = float(loss_at())
    if before is None:
        before = after
    delta = pose.delta.detach()[0].cpu()
    translation, rotation = correction_size(delta)
    return AlignedView(view, delta, before, after, float(translation), float(rotation))


def align_views(scene: RelightableScene, views: TrainingViews, indices: Sequence[int], config: TrainConfig,
                photometric: PhotometricCamera | None = None) -> dict[int, AlignedView]:
    """:func:`align_view` for each of ``indices`` (dataset view indices) at the training resolution."""
    device = scene.gaussians.means.device
    cameras = views.cameras.to(device)
    was_training = scene.training
    scene.eval()
    try:
        with torch.enable_grad():  # also from a caller under no_grad (rendering)
            return {k: align_view(scene, cameras[k], k, views.images[k].to(device), views.saturated[k].to(device),
                                  config, None if views.unseen is None else views.unseen[k].to(device), photometric)
                    for k in indices}
    finally:
        scene.train(was_training)
