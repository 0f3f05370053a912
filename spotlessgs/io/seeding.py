"""Per-stage random generators derived from (seed, stage name): adding a stage never changes the others.

No code in this project touches global random state; every stage asks for its own generator here.
"""

from __future__ import annotations

import hashlib

import numpy as np


def stage_seed(seed: int, stage: str) -> int:
    """A 63-bit integer seed derived deterministically from the command seed and a stage name."""
    digest = hashlib.sha256(f"{int(seed)}:{stage}".encode()).digest()
    return int.from_bytes(digest[:8], "little") & ((1 << 63) - 1)


def numpy_rng(seed: int, stage: str) -> np.random.Generator:
    """A ``numpy.random.Generator`` for one stage."""
    return np.random.default_rng(stage_seed(seed, stage))


def torch_generator(seed: int, stage: str, device: str = "cpu"):
    """A ``torch.Generator`` for one stage (torch is imported lazily)."""
    import torch

    gen = torch.Generator(device=device)
    gen.manual_seed(stage_seed(seed, stage))
    return gen


def restore_generator(gen, state) -> None:
    """Set the ``torch.Generator`` ``gen`` to a saved ``state`` (a uint8 tensor from ``get_state``). A state saved by a
    generator of another device type (a CPU run resumed on CUDA, or the reverse: their states differ in form and size)
    seeds ``gen`` from the state's SHA-256 instead: the draws that follow are another stream, the same on every
    resume from that state."""
    if state.numel() == gen.get_state().numel():
        gen.set_state(state)
        return
    digest = hashlib.sha256(state.cpu().contiguous().numpy().tobytes()).digest()
    gen.manual_seed(int.from_bytes(digest[:8], "little") & ((1 << 63) - 1))
