"""The image pool of Shrivastava et al. 2017 used by Cycle-GAN: discriminators also see older generated images."""

from __future__ import annotations

import numpy as np
import torch


class ImagePool:
    """Holds up to ``size`` generated images (each (3, H, W)); ``query`` returns a batch mixing new and stored ones.

    Once full, each new image is returned with probability 1/2; otherwise a random stored image is returned and the
    new one takes its place. Randomness comes from the numpy Generator passed to ``query``.
    """

    def __init__(self, size: int) -> None:
        self.size = size
        self.images: list[torch.Tensor] = []

    def query(self, batch: torch.Tensor, rng: np.random.Generator) -> torch.Tensor:
        """(B, 3, H, W) detached generated images -> (B, 3, H, W) images for the discriminator."""
        if self.size == 0:
            return batch
        out = []
        for image in batch:
            image = image.detach().clone()
            if len(self.images) < self.size:
                self.images.append(image)
                out.append(image)
            elif rng.random() < 0.5:
                slot = int(rng.integers(self.size))
                out.append(self.images[slot])
                self.images[slot] = image
            else:
                out.append(image)
        return torch.stack(out)

    def state(self) -> list[torch.Tensor]:
        """The stored images (for checkpoints)."""
        return list(self.images)

    def load_state(self, images: list[torch.Tensor]) -> None:
        """Restore from ``state()``; raises ValueError when there are more images than the pool holds."""
        if len(images) > self.size:
            raise ValueError(f"image pool state has {len(images)} images, more than the pool size {self.size}")
        self.images = [img.clone() for img in images]
