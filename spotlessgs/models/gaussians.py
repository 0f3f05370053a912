"""Per-Gaussian parameters (raw, unconstrained tensors) and their activations.

`GaussianParams.params` is an `nn.ParameterDict` of (N, ...) tensors — the layout that densification strategies index
and concatenate together with their optimizer state (gsplat-style `params: Dict[str, Parameter]`):

    name             shape      activation (accessor)                        init (`from_point_cloud`)
    means            (N, 3)     identity (`means`)                           point positions, metres, world frame
    quats            (N, 4)     unit quaternion wxyz (`quats`)               identity (1, 0, 0, 0)
    log_scales       (N, 3)     exp (`scales`)                               log of mean distance to 3 nearest neighbours
    opacity_logits   (N,)       sigmoid (`opacities`)                        logit(0.1)
    albedo_raw       (N, 3)     sigmoid (`albedo`) → (0, 1)                  logit of the linearised point colour
    normals_raw      (N, 3)     normalised, see `normals`                    point normals, or 0 (= face the camera)
    roughness_raw    (N,)       0.09 + 0.9 sigmoid (`roughness`) → (0.09, 0.99)   0.5 (paper)
    metalness_raw    (N,)       sigmoid (`metalness`) → (0, 1)               0.01 (paper: 0; a sigmoid cannot reach 0)
    sh0              (N, 1, 3)  `sh_colour_coeffs` = cat(sh0, shN)           (linear colour - 0.5) / C0
    shN              (N, 15, 3)  (vanilla 3DGS colour, degree 3)             0

Albedo uses a sigmoid (not softplus): it is a reflectance, so (0, 1) is its physical range, which keeps the Lambertian
f̃ = a within the learned BRDF's [0, 1] bound; the brightness scale lives in the light. sh0/shN are split as in gsplat
because 3DGS trains the higher bands at 1/20 of the learning rate.
"""

from __future__ import annotations

import math

import numpy as np
import torch
from torch import nn

from spotlessgs.io.colorspace import srgb_to_linear
from spotlessgs.models.geometry import safe_normalize
from spotlessgs.models.sh import SH_C0
from spotlessgs.rasterizer.projection import quat_to_rotmat

ROUGHNESS_MIN = 0.09  # roughness = ROUGHNESS_MIN + ROUGHNESS_SPAN · sigmoid(raw)
ROUGHNESS_SPAN = 0.9
ROUGHNESS_INIT = 0.5
METALNESS_INIT = 0.01
OPACITY_INIT = 0.1
ALBEDO_INIT_RANGE = (0.01, 0.99)  # linear albedo is clamped here before the logit
# Normals: n̂ = normalize(raw + δ exp(-|raw|²/δ²) f̂), f̂ the unit direction to the camera, δ = NORMAL_FALLBACK_SCALE.
# A zero raw normal faces the camera with a finite gradient ((I - f fᵀ)/δ); for |raw| > 6δ the added term is below
# 1e-18 and vanishes in float arithmetic, so ordinary normals are used as they are (no camera dependence).
NORMAL_FALLBACK_SCALE = 1e-3
SCALE_NEIGHBOURS = 3
# Duplicate points have zero neighbour distance: distances are floored at this fraction of the median positive one.
SCALE_FLOOR_FRACTION = 0.1
# Scale used when no positive neighbour distance exists (a single point, or all points identical), metres.
SCALE_FALLBACK = 0.01
PARAM_NAMES = (
    "means", "quats", "log_scales", "opacity_logits", "albedo_raw", "normals_raw",
    "roughness_raw", "metalness_raw", "sh0", "shN",
)


def _logit(p: np.ndarray) -> np.ndarray:
    return np.log(p) - np.log1p(-p)


#: The largest log-scale :attr:`GaussianParams.scales` uses: e^30 ≈ 1e13 m, far beyond any scene, far below float32's
#: overflow at e^88.7.
MAX_LOG_SCALE = 30.0


class GaussianParams(nn.Module):
    """Container of the per-Gaussian parameters (see module docstring for names, shapes and activations).

    Args:
        params: mapping name → tensor with the names of `PARAM_NAMES` and consistent N.
    """

    def __init__(self, params: dict[str, torch.Tensor]) -> None:
        super().__init__()
        missing = [k for k in PARAM_NAMES if k not in params]
        extra = [k for k in params if k not in PARAM_NAMES]
        if missing or extra:
            raise ValueError(f"GaussianParams: missing parameters {missing}, unknown parameters {extra}")
        n = params["means"].shape[0]
        expected = {
            "means": (n, 3), "quats": (n, 4), "log_scales": (n, 3), "opacity_logits": (n,), "albedo_raw": (n, 3),
            "normals_raw": (n, 3), "roughness_raw": (n,), "metalness_raw": (n,), "sh0": (n, 1, 3), "shN": (n, 15, 3),
        }
        for name, shape in expected.items():
            if tuple(params[name].shape) != shape:
                raise ValueError(f"GaussianParams: '{name}' must have shape {shape}, got {tuple(params[name].shape)}")
        self.params = nn.ParameterDict(
            {k: v if isinstance(v, nn.Parameter) else nn.Parameter(v.detach().clone()) for k, v in params.items()}
        )

    def __len__(self) -> int:
        return self.params["means"].shape[0]

    def subset(self, idx: torch.Tensor) -> "GaussianParams":
        """A differentiable view of rows ``idx`` (M,): its tensors are indexed from these parameters, not copied into
        new leaves, so gradients of anything computed from the view reach the full parameters."""
        view = GaussianParams.__new__(GaussianParams)
        nn.Module.__init__(view)
        view.params = _RowView(self.params, idx)
        return view

    # ---- construction ----------------------------------------------------------------------------------------------
    @classmethod
    def from_point_cloud(
        cls,
        xyz: np.ndarray,
        rgb: np.ndarray,
        normals: np.ndarray | None = None,
        rgb_is_srgb: bool = True,
        dtype: torch.dtype = torch.float32,
    ) -> "GaussianParams":
        """Initialise one Gaussian per point.

        Args:
            xyz: (N, 3) positions, metres, world frame; N ≥ 1, finite.
            rgb: (N, 3) colours, uint8 in [0, 255] or float in [0, 1].
            normals: (N, 3) normals (need not be unit; zero rows allowed) or None (Gaussians face the camera).
            rgb_is_srgb: the colours are sRGB-encoded (True: linearised here) or already linear.
            dtype: parameter dtype.
        """
        xyz = np.asarray(xyz, dtype=np.float64)
        if xyz.ndim != 2 or xyz.shape[1] != 3 or xyz.shape[0] == 0:
            raise ValueError(f"from_point_cloud: xyz must be a non-empty (N, 3) array, got shape {xyz.shape}")
        if not np.isfinite(xyz).all():
            raise ValueError(f"from_point_cloud: xyz has {int((~np.isfinite(xyz)).any(1).sum())} non-finite rows")
        n = xyz.shape[0]
        rgb_arr = np.asarray(rgb)
        if rgb_arr.shape != (n, 3):
            raise ValueError(f"from_point_cloud: rgb must have shape ({n}, 3), got {rgb_arr.shape}")
        colour = rgb_arr.astype(np.float64) / 255.0 if rgb_arr.dtype == np.uint8 else rgb_arr.astype(np.float64)
        if not np.isfinite(colour).all() or colour.min() < 0.0 or colour.max() > 1.0:
            raise ValueError("from_point_cloud: float rgb must be finite and in [0, 1] (pass uint8 for 0-255 colours)")
        linear = srgb_to_linear(colour) if rgb_is_srgb else colour
        if normals is None:
            nrm = np.zeros((n, 3))
        else:
            nrm = np.asarray(normals, dtype=np.float64)
            if nrm.shape != (n, 3) or not np.isfinite(nrm).all():
                raise ValueError(f"from_point_cloud: normals must be a finite ({n}, 3) array, got shape {nrm.shape}")
            length = np.linalg.norm(nrm, axis=1, keepdims=True)
            nrm = np.where(length > 1e-12, nrm / np.maximum(length, 1e-12), 0.0)

        rough_p = (ROUGHNESS_INIT - ROUGHNESS_MIN) / ROUGHNESS_SPAN

        def t(a: np.ndarray) -> torch.Tensor:
            return torch.as_tensor(np.asarray(a, dtype=np.float64), dtype=dtype)

        params = {
            "means": t(xyz),
            "quats": t(np.tile([1.0, 0.0, 0.0, 0.0], (n, 1))),
            "log_scales": t(np.repeat(np.log(initial_scales(xyz))[:, None], 3, axis=1)),
            "opacity_logits": t(np.full(n, _logit(OPACITY_INIT))),
            "albedo_raw": t(_logit(np.clip(linear, *ALBEDO_INIT_RANGE))),
            "normals_raw": t(nrm),
            "roughness_raw": t(np.full(n, _logit(rough_p))),
            "metalness_raw": t(np.full(n, _logit(METALNESS_INIT))),
            "sh0": t(((linear - 0.5) / SH_C0).reshape(n, 1, 3)),
            "shN": t(np.zeros((n, 15, 3))),
        }
        return cls(params)

    # ---- activated views -------------------------------------------------------------------------------------------
    @property
    def means(self) -> torch.Tensor:
        """(N, 3) positions."""
        return self.params["means"]

    @property
    def quats(self) -> torch.Tensor:
        """(N, 4) unit quaternions wxyz (a zero quaternion maps to the identity)."""
        q = self.params["quats"]
        identity = torch.zeros_like(q)
        identity[:, 0] = 1.0
        sq = (q * q).sum(-1, keepdim=True)
        ok = sq > 1e-24
        return torch.where(ok, q * torch.rsqrt(torch.where(ok, sq, torch.ones_like(sq))), identity)

    @property
    def scales(self) -> torch.Tensor:
        """(N, 3) standard deviations, metres; log-scales above :data:`MAX_LOG_SCALE` count as that (e^88.7
        overflows float32: the rasterizer's R·S would be NaN, and so every gradient of that Gaussian)."""
        return torch.exp(self.params["log_scales"].clamp(max=MAX_LOG_SCALE))

    @property
    def opacities(self) -> torch.Tensor:
        """(N,) in (0, 1)."""
        return torch.sigmoid(self.params["opacity_logits"])

    @property
    def albedo(self) -> torch.Tensor:
        """(N, 3) linear albedo in (0, 1)."""
        return torch.sigmoid(self.params["albedo_raw"])

    @property
    def roughness(self) -> torch.Tensor:
        """(N, 1) in (0.09, 0.99)."""
        return (ROUGHNESS_MIN + ROUGHNESS_SPAN * torch.sigmoid(self.params["roughness_raw"])).unsqueeze(-1)

    @property
    def metalness(self) -> torch.Tensor:
        """(N, 1) in (0, 1)."""
        return torch.sigmoid(self.params["metalness_raw"]).unsqueeze(-1)

    def shortest_axes(self) -> torch.Tensor:
        """(N, 3) unit vectors along each Gaussian's shortest axis, world frame (sign arbitrary): a flat splat's
        surface normal. Differentiable in the rotation (the choice of axis is not)."""
        rotations = quat_to_rotmat(self.params["quats"])  # (N, 3, 3): columns are the local axes
        shortest = self.params["log_scales"].detach().argmin(dim=1)
        return rotations[torch.arange(len(shortest), device=shortest.device), :, shortest]

    def sh_colour_coeffs(self) -> torch.Tensor:
        """(N, 16, 3) SH colour coefficients of vanilla 3DGS."""
        return torch.cat([self.params["sh0"], self.params["shN"]], dim=1)

    def normals(self, camera_center: torch.Tensor) -> torch.Tensor:
        """Unit normals (N, 3), world frame.

        n̂ = normalize(raw + δ exp(-|raw|²/δ²) f̂) with f̂ the unit direction from the Gaussian to `camera_center` and
        δ = 1e-3: a zero raw normal faces the camera with a finite, nonzero gradient, while normals longer than ~6δ are
        used unchanged. If the sum is still zero (raw = -δ e⁻¹ f̂ exactly, or a Gaussian at the camera centre) the
        result is f̂, or +z.

        Held normals (``normals_raw`` without a gradient, as a trusted start holds them) whose fallback weight is
        exactly 0 for every row (every |raw| above about 10δ: the exponential underflows) carry no gradient at all:
        their only path, through f̂ to the means, is multiplied by 0, so it is cut instead, and every shading term that
        reads n̂ skips its backward pass to it (the values and the gradients to every parameter are unchanged).

        Args:
            camera_center: (3,) camera centre C, world frame.
        """
        if camera_center.shape != (3,):
            raise ValueError(f"camera_center must have shape (3,), got {tuple(camera_center.shape)}")
        raw = self.params["normals_raw"]
        weight = NORMAL_FALLBACK_SCALE * torch.exp(-(raw * raw).sum(-1, keepdim=True) / NORMAL_FALLBACK_SCALE**2)
        means = self.means.detach() if not raw.requires_grad and not bool(weight.any()) else self.means
        towards = safe_normalize(camera_center.to(means) - means)
        return safe_normalize(raw + weight * towards, fallback=towards)


class _RowView(dict):
    """Rows ``idx`` of a parameter dict, indexed on first access (shading reads only some parameters; indexing the
    others would cost a full-size scatter each in the backward pass)."""

    def __init__(self, params: nn.ParameterDict, idx: torch.Tensor) -> None:
        super().__init__()
        self._params, self._idx = params, idx

    def __missing__(self, name: str) -> torch.Tensor:
        rows = self._params[name][self._idx]
        self[name] = rows
        return rows


def initial_scales(xyz: np.ndarray) -> np.ndarray:
    """Isotropic initial scale per point (N,): mean distance to its 3 nearest neighbours (scipy cKDTree).

    Zero distances (duplicate points) are floored at 0.1 × the median positive distance; with no positive distance at
    all (one point, or all identical) every scale is 0.01 m. Always finite and > 0.
    """
    from scipy.spatial import cKDTree

    n = xyz.shape[0]
    if n == 1:
        return np.full(1, SCALE_FALLBACK)
    k = min(SCALE_NEIGHBOURS, n - 1)
    dist, _ = cKDTree(xyz).query(xyz, k=k + 1)  # column 0 is the point itself
    dist = np.asarray(dist).reshape(n, k + 1)[:, 1:]
    positive = dist[dist > 0]
    if positive.size == 0:
        return np.full(n, SCALE_FALLBACK)
    floor = SCALE_FLOOR_FRACTION * float(np.median(positive))
    return np.maximum(dist.mean(axis=1), floor)


def logit_roughness(roughness: float) -> float:
    """Raw value whose activation is `roughness` ∈ (0.09, 0.99)."""
    p = (roughness - ROUGHNESS_MIN) / ROUGHNESS_SPAN
    if not 0.0 < p < 1.0:
        raise ValueError(f"roughness must be in ({ROUGHNESS_MIN}, {ROUGHNESS_MIN + ROUGHNESS_SPAN}), got {roughness}")
    return math.log(p) - math.log1p(-p)
