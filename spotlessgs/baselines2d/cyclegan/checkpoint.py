"""Cycle-GAN checkpoints: one torch file holding config, step, networks, optimisers and image pools.

Written atomically (temporary file + rename), loaded with ``weights_only=True`` (plain data and tensors only).
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

import torch

from spotlessgs.baselines2d.cyclegan.config import CycleGANConfig
from spotlessgs.io.atomic import atomic_path
from spotlessgs.io.tensor_file import load_plain_torch_file

CHECKPOINT_FORMAT = "spotlessgs-cyclegan-v1"
CHECKPOINT_NAME = "checkpoint.pt"
# Networks in a checkpoint: G_ab maps uneven (a) to even (b), G_ba back; D_a/D_b judge domain a/b.
NETWORK_KEYS = ("G_ab", "G_ba", "D_a", "D_b")


def save_checkpoint(path: str | os.PathLike, state: dict[str, Any]) -> None:
    """Write ``state`` (must hold 'format', 'config', 'step', ...) atomically to ``path``."""
    with atomic_path(path, suffix=".pt") as tmp:
        torch.save(state, tmp)


def load_checkpoint(path: str | os.PathLike) -> dict[str, Any]:
    """Read and check a checkpoint; raises FileNotFoundError / ValueError naming the file and the problem."""
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"{path}: Cycle-GAN checkpoint not found")
    state = load_plain_torch_file(path, "Cycle-GAN checkpoint")
    if not isinstance(state, dict) or state.get("format") != CHECKPOINT_FORMAT:
        found = state.get("format") if isinstance(state, dict) else type(state).__name__
        raise ValueError(f"{path}: not a Cycle-GAN checkpoint (format {found!r}, expected {CHECKPOINT_FORMAT!r})")
    missing = [k for k in ("config", "step", "seed", "networks") if k not in state]
    if missing:
        raise ValueError(f"{path}: Cycle-GAN checkpoint lacks entries {missing}")
    state["config"] = CycleGANConfig.from_dict(state["config"])
    return state
