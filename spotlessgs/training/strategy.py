"""Densification and pruning as a strategy object, separate from the trainer (in the style of gsplat's strategies).

The trainer calls :meth:`DensifyStrategy.step_post_backward` after every backward pass. The strategy accumulates each
Gaussian's screen-space gradient, and every ``densify_every`` steps within [densify_from, densify_until) it clones small
Gaussians and splits large ones whose average gradient is high, prunes transparent (and, after an opacity reset,
oversized) ones, and periodically resets opacities. Every change edits the parameter tensors *and* their Adam state
together (:func:`edit_parameters`), so optimisation continues smoothly.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Callable

import torch
from torch import nn

from spotlessgs.io.seeding import restore_generator
from spotlessgs.models.gaussians import GaussianParams
from spotlessgs.rasterizer import quat_to_rotmat
from spotlessgs.training.config import TrainConfig


@dataclass(frozen=True)
class DensifyConfig:
    """Densification settings (see TrainConfig for the meaning of each; the defaults are TrainConfig's)."""

    densify_from: int = TrainConfig.densify_from
    densify_until: int = TrainConfig.densify_until
    densify_every: int = TrainConfig.densify_every
    grad_threshold: float = TrainConfig.densify_grad_threshold
    percent_dense: float = TrainConfig.percent_dense
    prune_opacity: float = TrainConfig.prune_opacity
    opacity_reset_every: int = TrainConfig.opacity_reset_every
    reset_opacity_value: float = TrainConfig.reset_opacity_value
    max_gaussians: int = TrainConfig.max_gaussians
    # After an opacity reset, Gaussians larger than this fraction of the scene extent are pruned too.
    prune_scale: float = 0.1


def edit_parameters(
    gaussians: GaussianParams,
    optimizers: dict[str, torch.optim.Optimizer],
    edit: Callable[[str, torch.Tensor], torch.Tensor],
    edit_state: Callable[[str, torch.Tensor], torch.Tensor],
) -> None:
    """Replace every per-Gaussian parameter p by ``edit(name, p)`` and its Adam moments m by ``edit_state(name, m)``.

    Both callables must return tensors with the same new leading size. The optimizer keeps its step counts.
    """
    for name in list(gaussians.params.keys()):
        old = gaussians.params[name]
        new = nn.Parameter(edit(name, old.detach()), requires_grad=old.requires_grad)
        opt = optimizers.get(name)
        if opt is not None:
            state = opt.state.pop(old, None)
            for group in opt.param_groups:
                group["params"] = [new if p is old else p for p in group["params"]]
            if state is not None:
                for key in ("exp_avg", "exp_avg_sq"):
                    if key in state:
                        state[key] = edit_state(name, state[key])
                opt.state[new] = state
        gaussians.params[name] = new


class DensifyStrategy:
    """Adaptive density control of 3DGS with a Gaussian cap.

    Args:
        config: densification settings.
        scene_extent: scene radius in metres (clone/split and oversize thresholds scale with it).
        generator: torch generator for the positions of split children (no global random state).
    """

    def __init__(self, config: DensifyConfig, scene_extent: float, generator: torch.Generator) -> None:
        self.config = config
        self.scene_extent = float(scene_extent)
        self.generator = generator
        self.grad_accum: torch.Tensor | None = None  # (N,) summed NDC gradient norms
        self.count: torch.Tensor | None = None  # (N,) number of steps each Gaussian was visible
        self.last_reset_step = -1

    # ---- state (for checkpoints) -----------------------------------------------------------------------------------
    def state_dict(self) -> dict:
        return {"grad_accum": self.grad_accum, "count": self.count, "last_reset_step": self.last_reset_step,
                "generator": self.generator.get_state()}

    def load_state_dict(self, state: dict) -> None:
        self.grad_accum, self.count = state["grad_accum"], state["count"]
        self.last_reset_step = state["last_reset_step"]
        restore_generator(self.generator, state["generator"])

    # ---- hooks -----------------------------------------------------------------------------------------------------
    def step_post_backward(
        self,
        step: int,
        gaussians: GaussianParams,
        optimizers: dict[str, torch.optim.Optimizer],
        means2d_grad: torch.Tensor | None,
        radii: torch.Tensor,
        width: int,
        height: int,
    ) -> dict[str, int]:
        """Accumulate gradient statistics; densify, prune and reset opacities on schedule.

        Args:
            step: the step just taken (0-based).
            gaussians: the parameters (edited in place).
            optimizers: one optimizer per parameter name (their state is edited with the parameters).
            means2d_grad: (N, 2) gradient of the loss w.r.t. the projected centres in pixels, or None.
            radii: (N,) screen radii of this step's view (0 = not visible).
            width, height: image size in pixels.

        Returns:
            counts of what changed at this step (``cloned``, ``split``, ``pruned``, ``reset``), zeros if nothing.
        """
        cfg = self.config
        n = len(gaussians)
        changes = {"cloned": 0, "split": 0, "pruned": 0, "reset": 0}
        if step >= cfg.densify_until:
            return changes
        if self.grad_accum is None or self.grad_accum.shape[0] != n:
            self.grad_accum = torch.zeros(n, device=gaussians.means.device)
            self.count = torch.zeros(n, device=gaussians.means.device)
        elif self.grad_accum.device != gaussians.means.device:  # restored from a checkpoint (CPU tensors)
            self.grad_accum = self.grad_accum.to(gaussians.means.device)
            self.count = self.count.to(gaussians.means.device)
        if means2d_grad is not None:
            visible = radii > 0
            # pixels -> normalised device coordinates: d/d(ndc) = d/d(px) * (size / 2)
            g = means2d_grad.detach().clone()
            g[:, 0] *= width / 2.0
            g[:, 1] *= height / 2.0
            self.grad_accum += torch.where(visible, torch.linalg.norm(g, dim=1), torch.zeros_like(self.grad_accum))
            self.count += visible.float()
        s = step + 1
        if s >= cfg.densify_from and s % cfg.densify_every == 0:
            changes.update(self._densify_and_prune(gaussians, optimizers, s))
        if cfg.opacity_reset_every > 0 and s % cfg.opacity_reset_every == 0:
            self._reset_opacity(gaussians, optimizers)
            self.last_reset_step = s
            changes["reset"] = 1
        return changes

    # ---- operations ------------------------------------------------------------------------------------------------
    def _densify_and_prune(self, gaussians: GaussianParams, optimizers, step: int) -> dict[str, int]:
        cfg = self.config
        avg = self.grad_accum / self.count.clamp(min=1.0)
        high = avg > cfg.grad_threshold
        max_scale = gaussians.scales.detach().max(dim=1).values
        small = max_scale <= cfg.percent_dense * self.scene_extent
        budget = max(cfg.max_gaussians - len(gaussians), 0)
        clone_mask = high & small
        split_mask = high & ~small
        # respect the cap: a split adds one Gaussian (two children replace the parent), a clone adds one
        wanted = int(clone_mask.sum() + split_mask.sum())
        if wanted > budget:
            keep = torch.zeros_like(high)
            if budget > 0:
                score = torch.where(high, avg, torch.full_like(avg, -1.0))
                keep[torch.topk(score, budget).indices] = True
            clone_mask &= keep
            split_mask &= keep
        n_clone, n_split = int(clone_mask.sum()), int(split_mask.sum())
        if n_clone:
            self._clone(gaussians, optimizers, clone_mask)
            split_mask = torch.cat([split_mask, torch.zeros(n_clone, dtype=torch.bool, device=split_mask.device)])
        if n_split:
            self._split(gaussians, optimizers, split_mask)
        # prune: transparent, and oversized after an opacity reset
        prune = gaussians.opacities.detach() < cfg.prune_opacity
        if self.last_reset_step > 0 and step > self.last_reset_step:
            prune |= gaussians.scales.detach().max(dim=1).values > cfg.prune_scale * self.scene_extent
        if prune.all():  # never prune everything: keep the most opaque Gaussian
            prune[torch.argmax(gaussians.opacities.detach())] = False
        n_prune = int(prune.sum())
        if n_prune:
            self._keep(gaussians, optimizers, ~prune)
        n = len(gaussians)
        self.grad_accum = torch.zeros(n, device=gaussians.means.device)
        self.count = torch.zeros(n, device=gaussians.means.device)
        return {"cloned": n_clone, "split": n_split, "pruned": n_prune}

    def _clone(self, gaussians: GaussianParams, optimizers, mask: torch.Tensor) -> None:
        idx = torch.nonzero(mask).squeeze(1)
        edit_parameters(
            gaussians, optimizers,
            lambda _n, p: torch.cat([p, p[idx]]),
            lambda _n, m: torch.cat([m, torch.zeros_like(m[idx])]),
        )

    def _split(self, gaussians: GaussianParams, optimizers, mask: torch.Tensor) -> None:
        """Replace each masked Gaussian by two children sampled from it, with scales / 1.6 (as in 3DGS)."""
        idx = torch.nonzero(mask).squeeze(1)
        rest = torch.nonzero(~mask).squeeze(1)
        scales = gaussians.scales.detach()[idx]
        rot = quat_to_rotmat(gaussians.quats.detach()[idx])
        noise = torch.randn((2, len(idx), 3), generator=self.generator, device=scales.device, dtype=scales.dtype)
        offsets = torch.einsum("kij,nkj->nki", rot, noise * scales[None])  # (2, M, 3)
        means = gaussians.means.detach()[idx]
        children_means = (means[None] + offsets).reshape(-1, 3)

        def edit(name: str, p: torch.Tensor) -> torch.Tensor:
            if name == "means":
                child = children_means
            elif name == "log_scales":
                child = (p[idx] - math.log(1.6)).repeat(2, *([1] * (p.dim() - 1)))
            else:
                child = p[idx].repeat(2, *([1] * (p.dim() - 1)))
            return torch.cat([p[rest], child])

        edit_parameters(
            gaussians, optimizers, edit,
            lambda _n, m: torch.cat([m[rest], torch.zeros_like(m[idx]).repeat(2, *([1] * (m.dim() - 1)))]),
        )

    def _keep(self, gaussians: GaussianParams, optimizers, keep: torch.Tensor) -> None:
        edit_parameters(gaussians, optimizers, lambda _n, p: p[keep], lambda _n, m: m[keep])

    def _reset_opacity(self, gaussians: GaussianParams, optimizers) -> None:
        limit = math.log(self.config.reset_opacity_value / (1.0 - self.config.reset_opacity_value))

        def edit(name: str, p: torch.Tensor) -> torch.Tensor:
            return p.clamp(max=limit) if name == "opacity_logits" else p

        def edit_state(name: str, m: torch.Tensor) -> torch.Tensor:
            return torch.zeros_like(m) if name == "opacity_logits" else m

        edit_parameters(gaussians, optimizers, edit, edit_state)

