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
