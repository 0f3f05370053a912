"""The one camera type from the dataset readers to the rasterizer's caller: poses, intrinsics and size of views.

A :class:`Cameras` holds a batch of V views that share one :class:`~spotlessgs.io.cameras.Intrinsics` (as
nerfstudio's ``Cameras`` and gsplat's ``viewmats`` / ``Ks``); indexing it gives one view, still a ``Cameras``::

    cams = Cameras.from_dataset(dataset)        # (V, 4, 4) poses, the dataset's camera
    cam = cams.to("cuda")[3]                    # view 3: cam.c2w (4, 4), cam.viewmat (4, 4), cam.K (3, 3)
    scene.render(cam)

Conventions as in :mod:`spotlessgs.io.cameras`: OpenCV camera axes (x right, y down, z forward), metres, pixel
corners at integers. The world-to-camera matrices are derived once, as the inverse of the camera-to-world ones.
Lens models other than the pinhole belong to the intrinsics, so they travel with the cameras.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import torch

from spotlessgs.io.cameras import Intrinsics
from spotlessgs.io.transforms import DatasetDescription


@dataclass(frozen=True)
class Cameras:
    """One view or a batch of views with one shared camera.

    Attributes:
        c2w: (4, 4) or (V, 4, 4) float camera-to-world matrices, OpenCV axes.
        intrinsics: the camera (focal lengths, principal point, image size in pixels).
        viewmat: (4, 4) or (V, 4, 4) world-to-camera matrices; derived from ``c2w`` when not given.
    """

    c2w: torch.Tensor
    intrinsics: Intrinsics
    viewmat: torch.Tensor = field(default=None)  # type: ignore[assignment]

    def __post_init__(self) -> None:
        if self.c2w.ndim not in (2, 3) or tuple(self.c2w.shape[-2:]) != (4, 4):
            raise ValueError(f"Cameras: c2w must be (4, 4) or (V, 4, 4), got {tuple(self.c2w.shape)}")
        if self.viewmat is None:
            object.__setattr__(self, "viewmat", torch.linalg.inv(self.c2w))
        elif self.viewmat.shape != self.c2w.shape:
            raise ValueError(f"Cameras: viewmat {tuple(self.viewmat.shape)} does not match c2w "
                             f"{tuple(self.c2w.shape)}")

    @classmethod
    def from_dataset(cls, dataset: DatasetDescription, intrinsics: Intrinsics | None = None) -> "Cameras":
        """All V views of a dataset as float32 (``intrinsics``: another size of its camera; default: its own)."""
        c2w = torch.as_tensor(dataset.c2w_opencv, dtype=torch.float32)
        return cls(c2w, dataset.intrinsics if intrinsics is None else intrinsics)

    @property
    def is_batch(self) -> bool:
        """True for a batch of views, False for one view."""
        return self.c2w.ndim == 3

    def __len__(self) -> int:
        if not self.is_batch:
            raise TypeError("Cameras: a single view has no length")
        return int(self.c2w.shape[0])

    def __getitem__(self, index: int) -> "Cameras":
        """View ``index`` of a batch."""
        if not self.is_batch:
            raise TypeError("Cameras: a single view cannot be indexed")
        return Cameras(self.c2w[index], self.intrinsics, self.viewmat[index])

    @property
    def K(self) -> torch.Tensor:
        """(3, 3) pinhole matrix, float32, on the cameras' device."""
        return torch.as_tensor(self.intrinsics.K(), dtype=torch.float32, device=self.c2w.device)

    @property
    def width(self) -> int:
        return self.intrinsics.width

    @property
    def height(self) -> int:
        return self.intrinsics.height

    @property
    def centres(self) -> torch.Tensor:
        """(3,) or (V, 3) camera centres in world coordinates (m)."""
        return self.c2w[..., :3, 3]

    @property
    def device(self) -> torch.device:
        return self.c2w.device

    def to(self, device: str | torch.device) -> "Cameras":
        """The same cameras with their matrices on ``device``."""
        return Cameras(self.c2w.to(device), self.intrinsics, self.viewmat.to(device))

    def with_intrinsics(self, intrinsics: Intrinsics) -> "Cameras":
        """The same poses seen through another camera (e.g. the native size instead of the training size)."""
        return Cameras(self.c2w, intrinsics, self.viewmat)
