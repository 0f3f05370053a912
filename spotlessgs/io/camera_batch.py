"""The one camera type from the dataset readers to the rasterizer's caller: poses, intrinsics and size of views.

A :class:`Cameras` holds a batch of V views that share one :class:`~spotlessgs.io.cameras.Intrinsics` or have one
each (a rig, or COLMAP's camera per image; as nerfstudio's ``Cameras`` and gsplat's ``viewmats`` / ``Ks``); indexing
it gives one view, still a ``Cameras``::

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
    """One view or a batch of views with one shared camera or one camera per view.

    Attributes:
        c2w: (4, 4) or (V, 4, 4) float camera-to-world matrices, OpenCV axes.
        intrinsics: the camera (focal lengths, principal point, image size in pixels, lens); for a batch, either one
            camera that every view shares or a tuple of V cameras, one per view (a tuple of one camera becomes it).
        viewmat: (4, 4) or (V, 4, 4) world-to-camera matrices; derived from ``c2w`` when not given.
    """

    c2w: torch.Tensor
    intrinsics: Intrinsics | tuple[Intrinsics, ...]
    viewmat: torch.Tensor = field(default=None)  # type: ignore[assignment]

    def __post_init__(self) -> None:
        if self.c2w.ndim not in (2, 3) or tuple(self.c2w.shape[-2:]) != (4, 4):
            raise ValueError(f"Cameras: c2w must be (4, 4) or (V, 4, 4), got {tuple(self.c2w.shape)}")
        if isinstance(self.intrinsics, tuple):
            if self.c2w.ndim != 3 or len(self.intrinsics) != self.c2w.shape[0]:
                raise ValueError(f"Cameras: {len(self.intrinsics)} cameras for c2w {tuple(self.c2w.shape)}; a "
                                 "tuple of cameras needs one per view of a batch")
            if len(set(self.intrinsics)) == 1:
                object.__setattr__(self, "intrinsics", self.intrinsics[0])
        if self.viewmat is None:
            object.__setattr__(self, "viewmat", torch.linalg.inv(self.c2w))
        elif self.viewmat.shape != self.c2w.shape:
            raise ValueError(f"Cameras: viewmat {tuple(self.viewmat.shape)} does not match c2w "
                             f"{tuple(self.c2w.shape)}")

    @classmethod
    def from_dataset(cls, dataset: DatasetDescription,
                     intrinsics: Intrinsics | tuple[Intrinsics, ...] | None = None) -> "Cameras":
        """All V views of a dataset as float32, relative to its :attr:`~DatasetDescription.working_origin`
        (``intrinsics``: other cameras for its views, e.g. at the training size; default: the dataset's own, one per
        frame)."""
        c2w = dataset.c2w_opencv.copy()
        c2w[:, :3, 3] -= dataset.working_origin
        c2w = torch.as_tensor(c2w, dtype=torch.float32)
        return cls(c2w, tuple(dataset.cameras) if intrinsics is None else intrinsics)

    @property
    def per_view(self) -> bool:
        """True for a batch whose views have different cameras (``intrinsics`` is a tuple)."""
        return isinstance(self.intrinsics, tuple)

    def camera(self, index: int) -> Intrinsics:
        """The camera of view ``index`` of a batch."""
        return self.intrinsics[index] if isinstance(self.intrinsics, tuple) else self.intrinsics

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
        return Cameras(self.c2w[index], self.camera(index), self.viewmat[index])

    def _shared(self, what: str) -> Intrinsics:
        if isinstance(self.intrinsics, tuple):
            raise ValueError(f"Cameras: the views have different cameras; take {what} of one view (cameras[k])")
        return self.intrinsics

    @property
    def K(self) -> torch.Tensor:
        """(3, 3) pinhole matrix of the shared camera, float32, on the cameras' device."""
        return torch.as_tensor(self._shared("K").K(), dtype=torch.float32, device=self.c2w.device)

    @property
    def width(self) -> int:
        """Image width (pixels) of the shared camera, or of every view's camera when they differ but have one size."""
        return self._size()[0]

    @property
    def height(self) -> int:
        """Image height (pixels), as :attr:`width`."""
        return self._size()[1]

    def _size(self) -> tuple[int, int]:
        cams = self.intrinsics if isinstance(self.intrinsics, tuple) else (self.intrinsics,)
        sizes = {(c.width, c.height) for c in cams}
        if len(sizes) > 1:
            raise ValueError(f"Cameras: the views have images of {len(sizes)} different sizes; take the size of one "
                             "view (cameras[k])")
        return next(iter(sizes))

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

    def with_intrinsics(self, intrinsics: Intrinsics | tuple[Intrinsics, ...]) -> "Cameras":
        """The same poses seen through other cameras (e.g. the native size instead of the training size)."""
        return Cameras(self.c2w, intrinsics, self.viewmat)
