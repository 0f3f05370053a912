"""Cycle-GAN networks: a ResNet-style generator and a PatchGAN discriminator (instance norm, reflection padding).

Images are (B, 3, H, W) tensors with values in [-1, 1]. Weights are initialised from an explicit torch.Generator.
"""

from __future__ import annotations

import torch
from torch import nn

from spotlessgs.baselines2d.cyclegan.config import CycleGANConfig


def _norm(channels: int) -> nn.InstanceNorm2d:
    return nn.InstanceNorm2d(channels, affine=False, track_running_stats=False)


class ResidualBlock(nn.Module):
    """x + [reflect-pad, conv3x3, IN, ReLU, reflect-pad, conv3x3, IN](x); (B, C, H, W) -> (B, C, H, W)."""

    def __init__(self, channels: int) -> None:
        super().__init__()
        self.body = nn.Sequential(
            nn.ReflectionPad2d(1), nn.Conv2d(channels, channels, 3), _norm(channels), nn.ReLU(inplace=True),
            nn.ReflectionPad2d(1), nn.Conv2d(channels, channels, 3), _norm(channels),
        )  # fmt: skip

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return x + self.body(x)


class ResnetGenerator(nn.Module):
    """(B, 3, H, W) in [-1, 1] -> (B, 3, H, W) in [-1, 1]; H and W must be multiples of 2**n_down and >= 2**(n_down+1).

    c7s1-ngf, n_down stride-2 convolutions, n_res_blocks residual blocks, n_down transposed convolutions, c7s1-3, tanh.
    """

    def __init__(self, ngf: int, n_down: int, n_res_blocks: int) -> None:
        super().__init__()
        self.n_down = n_down
        layers: list[nn.Module] = [nn.ReflectionPad2d(3), nn.Conv2d(3, ngf, 7), _norm(ngf), nn.ReLU(inplace=True)]
        channels = ngf
        for _ in range(n_down):
            layers += [nn.Conv2d(channels, 2 * channels, 3, stride=2, padding=1), _norm(2 * channels), nn.ReLU(True)]
            channels *= 2
        layers += [ResidualBlock(channels) for _ in range(n_res_blocks)]
        for _ in range(n_down):
            layers += [
                nn.ConvTranspose2d(channels, channels // 2, 3, stride=2, padding=1, output_padding=1),
                _norm(channels // 2),
                nn.ReLU(True),
            ]
            channels //= 2
        layers += [nn.ReflectionPad2d(3), nn.Conv2d(channels, 3, 7), nn.Tanh()]
        self.model = nn.Sequential(*layers)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.model(x)


class PatchDiscriminator(nn.Module):
    """(B, 3, H, W) -> (B, 1, h, w) real/fake scores of overlapping patches (PatchGAN, no output activation)."""

    def __init__(self, ndf: int, n_layers: int) -> None:
        super().__init__()
        layers: list[nn.Module] = [nn.Conv2d(3, ndf, 4, stride=2, padding=1), nn.LeakyReLU(0.2, True)]
        mult = 1
        for n in range(1, n_layers + 1):
            prev, mult = mult, min(2**n, 8)
            stride = 2 if n < n_layers else 1
            layers += [
                nn.Conv2d(ndf * prev, ndf * mult, 4, stride=stride, padding=1),
                _norm(ndf * mult),
                nn.LeakyReLU(0.2, True),
            ]
        layers += [nn.Conv2d(ndf * mult, 1, 4, stride=1, padding=1)]
        self.model = nn.Sequential(*layers)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.model(x)


def init_weights(module: nn.Module, std: float, generator: torch.Generator) -> None:
    """Convolution weights ~ N(0, std), biases 0, drawn from ``generator`` in module order (deterministic).

    Every parameter of the networks here is a convolution weight or bias (instance norm has no affine part), so
    after this call no parameter is left uninitialised.
    """
    initialised = set()
    with torch.no_grad():
        for sub in module.modules():
            if isinstance(sub, (nn.Conv2d, nn.ConvTranspose2d)):
                nn.init.normal_(sub.weight, 0.0, std, generator=generator)
                initialised.add(id(sub.weight))
                if sub.bias is not None:
                    nn.init.zeros_(sub.bias)
                    initialised.add(id(sub.bias))
    left = [name for name, p in module.named_parameters() if id(p) not in initialised]
    if left:
        raise RuntimeError(f"init_weights: parameters {left} of {type(module).__name__} were not initialised")


def _allocate(factory) -> nn.Module:
    """Build a module on the meta device and allocate (uninitialised) CPU storage: torch's default initialisers,
    which draw from the global random generator, never run."""
    with torch.device("meta"):
        module = factory()
    return module.to_empty(device="cpu")


def build_generator(config: CycleGANConfig) -> ResnetGenerator:
    """A generator with the configured size and UNINITIALISED weights (call init_weights or load a state dict)."""
    return _allocate(lambda: ResnetGenerator(config.ngf, config.n_down, config.n_res_blocks))


def build_discriminator(config: CycleGANConfig) -> PatchDiscriminator:
    """A discriminator with the configured size and UNINITIALISED weights (call init_weights or load a state dict)."""
    return _allocate(lambda: PatchDiscriminator(config.ndf, config.disc_layers))
