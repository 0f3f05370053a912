"""Unpaired training data: all images of each domain held in memory, random crops drawn per step.

Every step draws its crops from its own numpy Generator derived from (seed, step), so a resumed run sees exactly
the crops that an uninterrupted run would.
"""

from __future__ import annotations

import hashlib
import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from spotlessgs.io.colorspace import to_uint8
from spotlessgs.io.images import list_image_files, read_image


@dataclass(frozen=True)
class ImageDomain:
    """The images of one domain. ``images``: list of (H_i, W_i, 3) uint8 arrays; ``files``: their paths."""

    name: str
    files: tuple[Path, ...]
    images: tuple[np.ndarray, ...]


def load_domain(name: str, folders: list[str | os.PathLike], min_height: int, min_width: int) -> ImageDomain:
    """Read every image of ``folders`` (sorted per folder, folders in the given order) as 8-bit RGB.

    Raises ValueError naming the file when an image is smaller than the training crop, and when no folder is given.
    """
    if not folders:
        raise ValueError(f"no {name} image folders were given")
    files: list[Path] = []
    for folder in folders:
        files.extend(list_image_files(folder))
    images = []
    for path in files:
        img = read_image(path)
        if img.shape[0] < min_height or img.shape[1] < min_width:
            raise ValueError(
                f"{path}: {name} image is {img.shape[0]}x{img.shape[1]} pixels, smaller than the training crop "
                f"{min_height}x{min_width}; use larger images, or a preset with a smaller crop (--preset tiny: 32x32; "
                "crop_height/crop_width in CycleGANConfig)"
            )
        images.append(to_uint8(img))
    return ImageDomain(name, tuple(files), tuple(images))


def domain_fingerprint(domain: ImageDomain) -> str:
    """sha256 over file names, sizes and pixel contents: resuming with different data is refused."""
    digest = hashlib.sha256()
    for path, img in zip(domain.files, domain.images):
        digest.update(path.name.encode())
        digest.update(str(img.shape).encode())
        digest.update(img.tobytes())
    return digest.hexdigest()


def sample_crops(
    domain: ImageDomain, rng: np.random.Generator, batch: int, height: int, width: int, flip: bool
) -> torch.Tensor:
    """A (batch, 3, height, width) float32 tensor in [-1, 1] of random crops (optionally mirrored) of random images."""
    crops = []
    for _ in range(batch):
        img = domain.images[int(rng.integers(len(domain.images)))]
        top = int(rng.integers(img.shape[0] - height + 1))
        left = int(rng.integers(img.shape[1] - width + 1))
        crop = img[top : top + height, left : left + width]
        if flip and rng.random() < 0.5:
            crop = crop[:, ::-1]
        crops.append(np.ascontiguousarray(crop.transpose(2, 0, 1)))
    stacked = torch.from_numpy(np.stack(crops)).to(torch.float32)
    return stacked / 127.5 - 1.0
