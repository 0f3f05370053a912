"""Configuration of the Cycle-GAN baseline (Zhu et al. 2017) with named presets."""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import Any


@dataclass(frozen=True)
class CycleGANConfig:
    # Generator channels after the first 7x7 convolution (doubled at each down-sampling stage).
    ngf: int = 24
    # Down-sampling (stride-2) stages in the generator; inputs are padded to a multiple of 2**n_down.
    n_down: int = 2
    # Residual blocks at the generator's bottleneck.
    n_res_blocks: int = 4
    # Discriminator channels of its first convolution (doubled per stride-2 layer, capped at 8x).
    ndf: int = 32
    # Stride-2 layers in the PatchGAN discriminator (3 gives the classic 70x70 patches).
    disc_layers: int = 3
    # Height of the random training crops, pixels.
    crop_height: int = 96
    # Width of the random training crops, pixels.
    crop_width: int = 128
    # Crops per domain per step (the paper uses 1).
    batch_size: int = 1
    # Randomly mirror crops left-right.
    flip: bool = True
    # Optimisation steps in total.
    steps: int = 3000
    # Fraction of the steps after which the learning rate decays linearly to zero (paper: 0.5).
    decay_start: float = 0.5
    # Adam learning rate for generators and discriminators.
    lr: float = 2e-4
    # Adam beta1.
    beta1: float = 0.5
    # Adam beta2.
    beta2: float = 0.999
    # Weight of the cycle-consistency L1 losses (lambda).
    lambda_cycle: float = 10.0
    # Weight of the identity L1 losses relative to lambda_cycle (paper: 0.5, i.e. 0.5 * lambda).
    lambda_identity: float = 0.5
    # Size of each image pool of generated images shown to the discriminators (0 disables the pool).
    pool_size: int = 50
    # Standard deviation of the normal weight initialisation.
    init_std: float = 0.02
    # Write a checkpoint every this many steps (and always at the end).
    checkpoint_every: int = 500
    # Record the running mean of the losses every this many steps.
    log_every: int = 50
    # torch intra-op threads while training/translating (None: leave torch's setting alone).
    num_threads: int | None = 2

    def __post_init__(self) -> None:
        positive_ints = (
            "ngf", "n_down", "ndf", "disc_layers", "crop_height", "crop_width", "batch_size", "steps",
            "checkpoint_every", "log_every",
        )  # fmt: skip
        for name in positive_ints:
            value = getattr(self, name)
            if not isinstance(value, int) or isinstance(value, bool) or value < 1:
                raise ValueError(f"CycleGANConfig.{name} must be a positive integer, got {value!r}")
        for name in ("n_res_blocks", "pool_size"):
            value = getattr(self, name)
            if not isinstance(value, int) or isinstance(value, bool) or value < 0:
                raise ValueError(f"CycleGANConfig.{name} must be a non-negative integer, got {value!r}")
        for name in ("lr", "init_std", "lambda_cycle"):
            if not getattr(self, name) > 0:
                raise ValueError(f"CycleGANConfig.{name} must be positive, got {getattr(self, name)}")
        if not self.lambda_identity >= 0:
            raise ValueError(f"CycleGANConfig.lambda_identity must be >= 0, got {self.lambda_identity}")
        if not 0.0 <= self.decay_start <= 1.0:
            raise ValueError(f"CycleGANConfig.decay_start must be in [0, 1], got {self.decay_start}")
        if not (0.0 <= self.beta1 < 1.0 and 0.0 <= self.beta2 < 1.0):
            raise ValueError(f"CycleGANConfig betas must be in [0, 1), got {self.beta1}, {self.beta2}")
        if self.num_threads is not None and (not isinstance(self.num_threads, int) or self.num_threads < 1):
            raise ValueError(f"CycleGANConfig.num_threads must be None or a positive integer, got {self.num_threads!r}")
        multiple = 2**self.n_down
        if self.crop_height % multiple or self.crop_width % multiple:
            raise ValueError(
                f"CycleGANConfig crop {self.crop_height}x{self.crop_width} must be a multiple of 2**n_down = {multiple}"
            )
        smallest = min(self.crop_height, self.crop_width)
        for layer in range(self.disc_layers + 1):  # normalised discriminator layers need > 1 spatial element
            smallest = smallest // 2 if layer < self.disc_layers else smallest - 1
            if layer >= 1 and smallest < 2:
                raise ValueError(
                    f"CycleGANConfig crop {self.crop_height}x{self.crop_width} is too small for a discriminator with "
                    f"{self.disc_layers} stride-2 layers (its layer {layer + 1} would be {smallest} pixels wide)"
                )

    def to_dict(self) -> dict[str, Any]:
        """Plain-JSON form (stored in checkpoints and provenance)."""
        return dataclasses.asdict(self)

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> CycleGANConfig:
        """Inverse of ``to_dict``; unknown keys raise ValueError naming them."""
        known = {f.name for f in dataclasses.fields(cls)}
        unknown = sorted(set(data) - known)
        if unknown:
            raise ValueError(f"CycleGANConfig: unknown fields {unknown}")
        return cls(**data)


PRESETS: dict[str, CycleGANConfig] = {
    # Unit tests: seconds on one CPU core.
    "tiny": CycleGANConfig(
        ngf=8, n_res_blocks=2, ndf=8, disc_layers=2, crop_height=32, crop_width=32, batch_size=2, steps=60,
        pool_size=10, checkpoint_every=20, log_every=5, num_threads=1,
    ),  # fmt: skip
    # CPU reproduction: about 5-10 minutes (0.2-0.4 s per step measured with 1 thread on a busy 2-core machine;
    # 2 threads took 4-6 s per step there because the OpenMP threads fought other processes for the cores).
    "quick": CycleGANConfig(
        ngf=16, n_res_blocks=3, ndf=16, crop_height=72, crop_width=96, steps=1500, checkpoint_every=100, log_every=20,
        num_threads=1,
    ),  # fmt: skip
    # The paper's scale (GPU): ngf 64, 9 residual blocks, 256x256 crops, ~200 epochs of 300 images.
    "paper": CycleGANConfig(
        ngf=64, n_res_blocks=9, ndf=64, crop_height=256, crop_width=256, steps=60000, checkpoint_every=2000,
        log_every=100, num_threads=None,
    ),  # fmt: skip
}


def preset(name: str, **overrides: Any) -> CycleGANConfig:
    """A named preset (``tiny``, ``quick``, ``paper``) with optional field overrides."""
    if name not in PRESETS:
        raise ValueError(f"unknown CycleGAN preset {name!r}; choose one of {sorted(PRESETS)}")
    return dataclasses.replace(PRESETS[name], **overrides)
