"""Camera pose corrections: one small rigid correction per view, learned beside the scene (as gsplat's ``pose_opt``).

A view's dataset pose (camera-to-world ``c2w``, OpenCV axes) is corrected on the right, in the camera's own frame:

    c2w' = c2w · Δ_k,    Δ_k = [[R(r_k), t_k], [0, 1]],    viewmat' = Δ_k⁻¹ · viewmat

so ``t_k`` (metres) moves the camera along its own axes (x right, y down, z forward) and ``R(r_k)`` turns it about its
centre. ``R`` is the 6D rotation of Zhou et al. (2019): the first two rows come from ``(1, 0, 0, 0, 1, 0) + r_k`` by
Gram–Schmidt, the third is their cross product. Every correction starts at zero (the identity), and its parameters
δ_k = (t_k, r_k) (V, 9) are what a penalty pulls back towards zero. The spotlight is mounted on the camera (its pose
is relative to the camera), so correcting a camera moves its light with it: the shading takes the corrected ``c2w``.

The rows are looked up with a sparse gradient, so that a lazy optimiser (``torch.optim.SparseAdam``) moves only the
views that were rendered in a step: a dense Adam keeps moving every row on momentum from its last visit.
"""

from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import Tensor, nn

from spotlessgs.io.camera_batch import Cameras

#: The 6D rotation parameters of the identity (its first two rows).
ROT6D_IDENTITY = (1.0, 0.0, 0.0, 0.0, 1.0, 0.0)


def rotation_6d_to_matrix(r6: Tensor) -> Tensor:
    """(..., 6) → (..., 3, 3) rotation: Gram–Schmidt on the two 3-vectors, which become the matrix's first two rows.

    The vectors must not be (near) parallel or zero; a correction near the identity is far from that.
    """
    a1, a2 = r6[..., :3], r6[..., 3:]
    b1 = F.normalize(a1, dim=-1)
    b2 = F.normalize(a2 - (b1 * a2).sum(-1, keepdim=True) * b1, dim=-1)
    return torch.stack([b1, b2, torch.linalg.cross(b1, b2, dim=-1)], dim=-2)


def correction_matrix(delta: Tensor) -> Tensor:
    """(..., 9) correction parameters (translation t (3,), 6D rotation offset r (6,)) → (..., 4, 4) rigid Δ."""
    base = delta.new_tensor(ROT6D_IDENTITY)
    rot = rotation_6d_to_matrix(base + delta[..., 3:])
    out = torch.zeros(delta.shape[:-1] + (4, 4), dtype=delta.dtype, device=delta.device)
    out[..., :3, :3] = rot
    out[..., :3, 3] = delta[..., :3]
    out[..., 3, 3] = 1.0
    return out


def rigid_inverse(m: Tensor) -> Tensor:
    """(..., 4, 4) rigid transforms → their inverses [Rᵀ, −Rᵀ t] (differentiable, exact for a rotation block)."""
    rot_t = m[..., :3, :3].transpose(-1, -2)
    out = torch.zeros_like(m)
    out[..., :3, :3] = rot_t
    out[..., :3, 3] = -(rot_t @ m[..., :3, 3:4])[..., 0]
    out[..., 3, 3] = 1.0
    return out


def corrected_camera(camera: Cameras, delta: Tensor) -> Cameras:
    """One view (``camera``) with its pose corrected by the parameters ``delta`` (9,): c2w · Δ and Δ⁻¹ · viewmat
    (differentiable in ``delta``)."""
    if camera.is_batch:
        raise ValueError("corrected_camera: expected one view, got a batch of cameras")
    m = correction_matrix(delta.to(camera.c2w.dtype))
    return Cameras(camera.c2w @ m, camera.intrinsics, rigid_inverse(m) @ camera.viewmat)


def corrected_cameras(cameras: Cameras, deltas: Tensor) -> Cameras:
    """A batch of V views (``cameras``) with their poses corrected by the parameters ``deltas`` (V, 9)."""
    if not cameras.is_batch or len(cameras) != deltas.shape[0]:
        raise ValueError(f"corrected_cameras: {tuple(deltas.shape)} corrections for cameras of shape "
                         f"{tuple(cameras.c2w.shape)}")
    m = correction_matrix(deltas.to(device=cameras.device, dtype=cameras.c2w.dtype))
    return Cameras(cameras.c2w @ m, cameras.intrinsics, rigid_inverse(m) @ cameras.viewmat)


def correction_size(delta: Tensor) -> tuple[Tensor, Tensor]:
    """(..., 9) correction parameters → ((...,) translation in metres, (...,) rotation angle in degrees)."""
    return delta[..., :3].norm(dim=-1), rotation_angle_deg(correction_matrix(delta)[..., :3, :3])


class PoseCorrection(nn.Module):
    """Rigid corrections of V views' poses, all zero (the identity) at the start.

    Args:
        num_views: V, the dataset's views (every view has a row; only the rendered ones learn).
        sparse: the rows' gradients are sparse (for ``torch.optim.SparseAdam``); False for a dense optimiser.
    """

    def __init__(self, num_views: int, sparse: bool = True) -> None:
        super().__init__()
        if num_views < 1:
            raise ValueError(f"PoseCorrection: need at least one view, got {num_views}")
        self.delta = nn.Parameter(torch.zeros(num_views, 9))  # (V, 9): translation (m), 6D rotation offset
        self.sparse = sparse

    def __len__(self) -> int:
        return int(self.delta.shape[0])

    def row(self, view: int) -> Tensor:
        """(9,) the parameters of view ``view`` (a sparse gradient of that row alone when ``sparse``)."""
        index = torch.tensor([view], device=self.delta.device)
        return F.embedding(index, self.delta, sparse=self.sparse)[0]

    def forward(self, camera: Cameras, view: int) -> Cameras:
        """View ``view``'s camera (one view) with its pose corrected (differentiable in the row's parameters)."""
        return corrected_camera(camera, self.row(view))

    def penalty(self, view: int) -> Tensor:
        """‖δ_k‖² of view ``view`` (translation in m², rotation offset ≈ rad²): the pull towards the identity."""
        return self.row(view).square().sum()

    @torch.no_grad()
    def matrices(self) -> Tensor:
        """(V, 4, 4) the corrections Δ (no gradient)."""
        return correction_matrix(self.delta.detach())

    @torch.no_grad()
    def sizes(self) -> tuple[Tensor, Tensor]:
        """((V,) translation in m, (V,) rotation in degrees) of each correction."""
        return correction_size(self.delta.detach())


def rotation_angle_deg(rot: Tensor) -> Tensor:
    """(...,) rotation angle in degrees of (..., 3, 3) rotations (atan2 of the skew and trace parts: precise near 0)."""
    trace = rot.diagonal(dim1=-2, dim2=-1).sum(-1)
    skew = torch.stack([rot[..., 2, 1] - rot[..., 1, 2], rot[..., 0, 2] - rot[..., 2, 0],
                        rot[..., 1, 0] - rot[..., 0, 1]], dim=-1)
    return torch.rad2deg(torch.atan2(skew.norm(dim=-1) / 2.0, (trace - 1.0) / 2.0))


__all__ = ["PoseCorrection", "ROT6D_IDENTITY", "corrected_camera", "corrected_cameras", "correction_matrix",
           "correction_size", "rigid_inverse", "rotation_6d_to_matrix", "rotation_angle_deg"]
