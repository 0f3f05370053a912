"""Cycle-GAN checkpoints: one file holding config, step, networks, optimisers and image pools.

A checkpoint is a safetensors file whose metadata holds the plain data as JSON (:mod:`spotlessgs.io.tensor_file`),
written atomically: loading one from a shared folder cannot run code. Runs of older versions have ``checkpoint.pt`` (a
torch pickle), read with ``torch.load(weights_only=True)`` (tensors and plain containers only); a resumed run replaces
it with ``checkpoint.safetensors``.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any, Callable

import torch

from spotlessgs.baselines2d.cyclegan.config import CycleGANConfig
from spotlessgs.io.errors import InputError
from spotlessgs.io.tensor_file import load_plain_torch_file, load_tree, save_tree

CHECKPOINT_FORMAT = "spotlessgs-cyclegan-v1"
CHECKPOINT_NAME = "checkpoint.safetensors"
#: The checkpoint file of runs written by older versions (a torch pickle).
LEGACY_CHECKPOINT_NAME = "checkpoint.pt"
# Networks in a checkpoint: G_ab maps uneven (a) to even (b), G_ba back; D_a/D_b judge domain a/b.
NETWORK_KEYS = ("G_ab", "G_ba", "D_a", "D_b")


def existing_checkpoint(run_dir: str | os.PathLike) -> Path | None:
    """The checkpoint of the Cycle-GAN run folder ``run_dir``: ``checkpoint.safetensors``, else an older version's
    ``checkpoint.pt``, else None."""
    for name in (CHECKPOINT_NAME, LEGACY_CHECKPOINT_NAME):
        if (Path(run_dir) / name).is_file():
            return Path(run_dir) / name
    return None


def save_checkpoint(run_dir: str | os.PathLike, state: dict[str, Any]) -> Path:
    """Write ``state`` (must hold 'format', 'config', 'step', ...) atomically as ``run_dir/checkpoint.safetensors``
    (an older version's ``checkpoint.pt`` there is superseded and removed); returns its path."""
    path = save_tree(Path(run_dir) / CHECKPOINT_NAME, state, CHECKPOINT_FORMAT)
    (Path(run_dir) / LEGACY_CHECKPOINT_NAME).unlink(missing_ok=True)
    return path


def checkpoint_file(path: str | os.PathLike) -> Path:
    """The checkpoint file ``path`` names: the file itself, or the checkpoint inside a Cycle-GAN run folder
    (:func:`existing_checkpoint`); FileNotFoundError naming ``path`` when there is none."""
    path = Path(path)
    if path.is_dir():
        found = existing_checkpoint(path)
        if found is None:
            raise FileNotFoundError(f"{path}: holds no Cycle-GAN checkpoint ({CHECKPOINT_NAME} or "
                                    f"{LEGACY_CHECKPOINT_NAME}); train one with `spotless baseline2d train-cyclegan`")
        return found
    if not path.is_file():
        raise FileNotFoundError(f"{path}: Cycle-GAN checkpoint not found")
    return path


def load_checkpoint(path: str | os.PathLike) -> dict[str, Any]:
    """Read and check a checkpoint (:func:`check_checkpoint`): a safetensors file, an older version's ``.pt`` file,
    or a run folder holding either (:func:`checkpoint_file`); raises FileNotFoundError / InputError naming the file
    and the problem."""
    path = checkpoint_file(path)
    if path.suffix.lower() in (".pt", ".pth"):
        state = load_plain_torch_file(path, "Cycle-GAN checkpoint")
    else:
        try:
            state = load_tree(path, CHECKPOINT_FORMAT)
        except InputError as exc:
            raise InputError(f"{exc} (not a Cycle-GAN checkpoint)") from None
    if not isinstance(state, dict) or state.get("format") != CHECKPOINT_FORMAT:
        found = state.get("format") if isinstance(state, dict) else type(state).__name__
        raise InputError(f"{path}: not a Cycle-GAN checkpoint (format {found!r}, expected {CHECKPOINT_FORMAT!r})")
    missing = [k for k in ("config", "step", "seed", "networks") if k not in state]
    if missing:
        raise InputError(f"{path}: Cycle-GAN checkpoint lacks entries {missing}")
    if not isinstance(state["config"], dict):
        raise InputError(f"{path}: damaged Cycle-GAN checkpoint: config is not a table of settings")
    try:
        state["config"] = CycleGANConfig.from_dict(state["config"])
    except (TypeError, ValueError) as exc:
        raise InputError(f"{path}: damaged Cycle-GAN checkpoint: {exc}") from None
    check_checkpoint(state, path)
    return state


def check_checkpoint(state: dict[str, Any], path: Path) -> None:
    """InputError naming ``path`` unless ``state`` holds whole numbers ``step`` (0..the config's steps) and ``seed``,
    and the four networks (:data:`NETWORK_KEYS`) as tables of finite tensors; optimiser and pool state, when present,
    as tables. (Each network's names and shapes are checked when it is loaded: :func:`restore`.)"""
    for key in ("step", "seed"):
        if isinstance(state[key], bool) or not isinstance(state[key], int):
            raise InputError(f"{path}: damaged Cycle-GAN checkpoint: {key} {state[key]!r} is not a whole number")
    steps = state["config"].steps
    if not 0 <= state["step"] <= steps:
        raise InputError(f"{path}: damaged Cycle-GAN checkpoint: step {state['step']} is outside the run's 0..{steps}")
    networks = state["networks"]
    absent = [k for k in NETWORK_KEYS if not isinstance(networks, dict) or not isinstance(networks.get(k), dict)]
    if absent:
        raise InputError(f"{path}: damaged Cycle-GAN checkpoint: it lacks the network(s) {absent}")
    for name in NETWORK_KEYS:
        for key, tensor in networks[name].items():
            if not isinstance(tensor, torch.Tensor):
                raise InputError(f"{path}: damaged Cycle-GAN checkpoint: {name}.{key} is not a tensor")
            if tensor.is_floating_point() and not torch.isfinite(tensor).all():
                raise InputError(f"{path}: damaged Cycle-GAN checkpoint: {name}.{key} holds values that are not "
                                 "finite")
    for key in ("optimizers", "pools"):
        if key in state and not isinstance(state[key], dict):
            raise InputError(f"{path}: damaged Cycle-GAN checkpoint: {key} is not a table")


def restore(path: Path, what: str, load: Callable[[], None]) -> None:
    """Run ``load`` (``load_state_dict`` of a network, optimiser or pool from a checkpoint read from ``path``); its
    failures (names or shapes that do not fit, missing entries) become one InputError naming the file and ``what``."""
    try:
        load()
    except (KeyError, TypeError, ValueError, RuntimeError, IndexError, AttributeError) as exc:
        first = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
        raise InputError(f"{path}: damaged Cycle-GAN checkpoint: its {what} does not fit this model "
                         f"({first[:200]})") from None
