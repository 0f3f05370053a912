"""Cycle-GAN baseline: unpaired uneven -> even image translation (Zhu et al. 2017), small enough for a CPU."""

from spotlessgs.baselines2d.cyclegan.config import PRESETS, CycleGANConfig, preset
from spotlessgs.baselines2d.cyclegan.train import train_cyclegan
from spotlessgs.baselines2d.cyclegan.translate import load_generator, translate_folder, translate_image

__all__ = [
    "PRESETS",
    "CycleGANConfig",
    "load_generator",
    "preset",
    "train_cyclegan",
    "translate_folder",
    "translate_image",
]
