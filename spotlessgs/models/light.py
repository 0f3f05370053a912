"""Light models: the camera-mounted spotlight (pose, neural RID, distance fall-off), the low-frequency SH light, the
DarkGS constant ambient, and the light-translation prior.

Frames. The light pose relative to the camera is T = (R, t): R (3, 3) maps light-frame vectors to camera-frame vectors
(learned as an so(3) axis-angle vector), t (3,) is the light origin in camera coordinates (metres, OpenCV axes). For a
camera `c2w` = [R_cw | C]:
    light origin in world     o   = C + R_cw t
    camera coordinates        x_c = R_cwᵀ (x - C)
    light coordinates         x_l = Rᵀ (x_c - t)
and the spotlight shines along +z of the light frame.

Spotlight radiance reaching a point: L_spot(x) = Ψ(x_l) · Φ(θ(x_l)), with
    θ = atan2(sqrt(x_l.x² + x_l.y² + ε²), x_l.z)                     angle off the light axis, ε = 1e-6 m
    Φ(θ) = softplus(MLP([θ, cos θ, cos 2θ, cos 4θ, cos 8θ]))           RID, MLP 5→20→20→20→1, softplus activations
           or a non-increasing piecewise-linear profile on 48 knots (rid_model "monotone", models.angular_profile)
    Ψ(x_l) = (τ + |x_l|²)^(-γ),  τ = exp(log τ), γ = exp(log γ)         fall-off (init γ = 1, τ = 0.3)
Unlike the research code's tan θ input (singular at x_l.z = 0, sign-blind behind the light), θ is defined and smooth
(finite value and gradient) everywhere: beside the light θ = π/2, behind it θ → π, at the origin θ = π/2.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np
import torch
import torch.nn.functional as F
from torch import nn

from spotlessgs.io.seeding import torch_generator
from spotlessgs.models.angular_profile import MonotoneProfile
from spotlessgs.models.geometry import check_c2w, safe_normalize, so3_exp, so3_log, world_to_camera
from spotlessgs.models.nets import seeded_linear
from spotlessgs.models.sh import check_sh_degree, eval_sh, num_sh_bases

# Regulariser of the off-axis radius in θ (metres): keeps θ and its gradient finite on the axis and at the origin.
THETA_EPS = 1e-6
# Smoothing length of the translation prior (metres): the loss is quadratic below ~1 mm and linear above.
PRIOR_EPS = 1e-3
# RID network: frequencies of the cosine features of θ (input is [θ, cos(kθ) for k in RID_FREQUENCIES]).
RID_FREQUENCIES = (1.0, 2.0, 4.0, 8.0)
# Forms of the RID: the paper's MLP, or a non-increasing piecewise-linear profile (models.angular_profile).
RID_MODELS = ("mlp", "monotone")


def cone_profile(theta: torch.Tensor, half_angle: float, blend: float) -> torch.Tensor:
    """Smooth cone of a Blender (Cycles ≥ 4) spot lamp: smoothstep((cos θ - cos θ_c) / (blend · (1 - cos θ_c))).

    Args:
        theta: (...) angle from the axis, radians.
        half_angle: θ_c = spot_size / 2, radians in (0, π/2].
        blend: spot_blend in (0, 1]: the fraction of the cone (in cos θ) over which the edge fades.
    Returns:
        (...) profile in [0, 1]: 1 on the axis, 0 outside the cone.
    """
    if not 0.0 < half_angle <= math.pi / 2:
        raise ValueError(f"cone half_angle must be in (0, pi/2] radians, got {half_angle}")
    if not 0.0 < blend <= 1.0:
        raise ValueError(f"cone blend must be in (0, 1], got {blend}")
    cos_c = math.cos(half_angle)
    s = ((torch.cos(theta) - cos_c) / (blend * (1.0 - cos_c))).clamp(0.0, 1.0)
    return s * s * (3.0 - 2.0 * s)


class SpotLight(nn.Module):
    """Camera-mounted spotlight with learnable pose, neural RID and distance fall-off.

    Args:
        rotation: light→camera rotation R, as a (3, 3) matrix or a (3,) axis-angle vector; default identity.
        translation: t (3,), light origin in camera coordinates, metres; default 0 (co-located with the camera).
        gamma: initial fall-off exponent γ > 0.
        tau: initial fall-off offset τ > 0 (m²).
        hidden: RID hidden width (the MLP's).
        seed: seed of the RID initialisation (stage "spotlight_rid"; the monotone profile's start is fixed).
        rid_model: "mlp" (the paper's RID) or "monotone" (MonotoneProfile).
        radiance_scale: a fixed factor s > 0 on the radiance, s Ψ Φ: the unit the learned radiance is counted in
            (1: the research code's). The albedo is capped at 1, so the unit decides where the albedo/light
            scale, which the images cannot tell, starts (training.light_unit).
    Parameters: `rotvec` (3,), `translation` (3,), `log_gamma` (), `log_tau` (), `rid` (nn.Sequential, or a
    MonotoneProfile). Buffer: `radiance_scale` () (saved with the state; a state saved before it has none and
    loads as 1).
    """

    def __init__(
        self,
        rotation: Sequence | np.ndarray | torch.Tensor | None = None,
        translation: Sequence | np.ndarray | torch.Tensor | None = None,
        gamma: float = 1.0,
        tau: float = 0.3,
        hidden: int = 20,
        seed: int = 0,
        rid_model: str = "mlp",
        radiance_scale: float = 1.0,
    ) -> None:
        super().__init__()
        if gamma <= 0 or tau <= 0:
            raise ValueError(f"SpotLight: gamma and tau must be > 0, got gamma={gamma}, tau={tau}")
        if not (math.isfinite(radiance_scale) and radiance_scale > 0):
            raise ValueError(f"SpotLight: radiance_scale must be finite and > 0, got {radiance_scale}")
        self.register_buffer("radiance_scale", torch.tensor(float(radiance_scale)))
        if rid_model not in RID_MODELS:
            raise ValueError(f"SpotLight: rid_model must be one of {RID_MODELS}, got {rid_model!r}")
        self.rotvec = nn.Parameter(torch.tensor(np.array(_rotvec_from(rotation)), dtype=torch.float32))
        if translation is None:
            t = torch.zeros(3)
        else:
            raw = translation.detach().cpu() if isinstance(translation, torch.Tensor) else translation
            t = torch.tensor(np.array(raw, dtype=np.float64), dtype=torch.float32)  # a copy: inputs may be read-only
        if t.shape != (3,):
            raise ValueError(f"SpotLight: translation must have shape (3,), got {tuple(t.shape)}")
        self.translation = nn.Parameter(t.clone())
        self.log_gamma = nn.Parameter(torch.tensor(math.log(gamma)))
        self.log_tau = nn.Parameter(torch.tensor(math.log(tau)))
        if rid_model == "monotone":
            self.rid: nn.Module = MonotoneProfile()
            return
        gen = torch_generator(seed, "spotlight_rid")
        n_in = 1 + len(RID_FREQUENCIES)
        self.rid = nn.Sequential(
            seeded_linear(n_in, hidden, gen), nn.Softplus(),
            seeded_linear(hidden, hidden, gen), nn.Softplus(),
            seeded_linear(hidden, hidden, gen), nn.Softplus(),
            seeded_linear(hidden, 1, gen), nn.Softplus(),
        )

    # ---- pose ----------------------------------------------------------------------------------------------------
    def rotation(self) -> torch.Tensor:
        """R (3, 3): light frame → camera frame."""
        return so3_exp(self.rotvec)

    def set_pose_trainable(self, trainable: bool) -> None:
        """Freeze (False) or unfreeze (True) the pose parameters `rotvec` and `translation`."""
        self.rotvec.requires_grad_(trainable)
        self.translation.requires_grad_(trainable)

    def set_falloff_trainable(self, trainable: bool) -> None:
        """Freeze (False) or unfreeze (True) the fall-off parameters `log_gamma` and `log_tau`."""
        self.log_gamma.requires_grad_(trainable)
        self.log_tau.requires_grad_(trainable)

    def _load_from_state_dict(self, state_dict, prefix, *args, **kwargs) -> None:
        """A state saved before `radiance_scale` existed loads with the unit it trained in, 1 (as BatchNorm's
        `num_batches_tracked` is filled in for older states)."""
        state_dict.setdefault(prefix + "radiance_scale", torch.tensor(1.0))
        super()._load_from_state_dict(state_dict, prefix, *args, **kwargs)

    def origin_world(self, c2w: torch.Tensor) -> torch.Tensor:
        """Light origin o = C + R_cw t in world coordinates, (3,)."""
        check_c2w(c2w)
        return c2w[:3, 3] + c2w[:3, :3] @ self.translation

    def axis_world(self, c2w: torch.Tensor) -> torch.Tensor:
        """Unit light axis (+z of the light frame) in world coordinates, (3,)."""
        check_c2w(c2w)
        return c2w[:3, :3] @ self.rotation()[:, 2]

    def to_light_frame(self, x_world: torch.Tensor, c2w: torch.Tensor) -> torch.Tensor:
        """Points (N, 3) in world → light coordinates x_l = Rᵀ (x_cam - t), (N, 3)."""
        check_c2w(c2w)
        _check_points(x_world, "x_world")
        x_cam = world_to_camera(x_world, c2w)
        return (x_cam - self.translation) @ self.rotation()

    # ---- radiance --------------------------------------------------------------------------------------------------
    @property
    def gamma(self) -> torch.Tensor:
        """Fall-off exponent γ = exp(log γ), ()."""
        return torch.exp(self.log_gamma)

    @property
    def tau(self) -> torch.Tensor:
        """Fall-off offset τ = exp(log τ) (m²), ()."""
        return torch.exp(self.log_tau)

    @staticmethod
    def angle_off_axis(x_l: torch.Tensor) -> torch.Tensor:
        """θ = atan2(sqrt(x² + y² + ε²), z) for light-frame points (N, 3) → (N, 1), radians in (0, π)."""
        radial = torch.sqrt(x_l[:, 0:1] ** 2 + x_l[:, 1:2] ** 2 + THETA_EPS**2)
        return torch.atan2(radial, x_l[:, 2:3])

    def rid_of_angle(self, theta: torch.Tensor) -> torch.Tensor:
        """RID Φ(θ) for angles (N, 1) → (N, 1), > 0."""
        if isinstance(self.rid, MonotoneProfile):
            return self.rid(theta)
        feats = [theta] + [torch.cos(k * theta) for k in RID_FREQUENCIES]
        return self.rid(torch.cat(feats, dim=-1))

    def falloff(self, x_l: torch.Tensor) -> torch.Tensor:
        """Ψ = (τ + |x_l|²)^(-γ) for light-frame points (N, 3) → (N, 1), computed as exp(-γ log(τ + d²))."""
        d_sq = (x_l * x_l).sum(dim=-1, keepdim=True)
        return torch.exp(-self.gamma * torch.log(self.tau + d_sq))

    def incident(self, x_world: torch.Tensor, c2w: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """Spotlight radiance at world points and the unit direction from each point to the light.

        Args:
            x_world: (N, 3) points, world frame.
            c2w: (4, 4) camera-to-world (OpenCV axes) of the camera carrying the light.
        Returns:
            radiance (N, 1) = s Ψ Φ ≥ 0 (s: `radiance_scale`), and l̂ (N, 3) unit vectors point → light origin
            (world frame); at the origin itself l̂ falls back to minus the light axis (as for a point just in front of
            the lamp).
        """
        x_l = self.to_light_frame(x_world, c2w)
        radiance = self.radiance_scale * self.falloff(x_l) * self.rid_of_angle(self.angle_off_axis(x_l))
        to_light = self.origin_world(c2w) - x_world
        l_hat = safe_normalize(to_light, fallback=-self.axis_world(c2w))
        return radiance, l_hat

    @torch.no_grad()
    def rid_curve(self, thetas: torch.Tensor | np.ndarray | Sequence[float]) -> torch.Tensor:
        """Φ(θ) at the given angles (K,) radians → (K,), detached; for plots."""
        th = torch.as_tensor(np.asarray(thetas, dtype=np.float64)).reshape(-1, 1)
        th = th.to(device=self.log_tau.device, dtype=self.log_tau.dtype)
        return self.rid_of_angle(th).reshape(-1).cpu()

    def fit_rid_to_cone(
        self,
        half_angle: float,
        blend: float,
        intensity: float = 1.0,
        adam_steps: int = 200,
        lbfgs_iters: int = 300,
        n_samples: int = 512,
    ) -> float:
        """Fit the RID MLP to intensity · cone_profile(θ) on θ ∈ [0, π] (calibrated DarkGS mode).

        Full-batch Adam (lr 1e-2) to get near the profile, then L-BFGS (strong Wolfe line search) to sharpen the cone
        edge, on a fixed grid of `n_samples` angles: deterministic given the seed, ~0.5 s on one CPU thread. Adam alone
        leaves ~0.1-0.2 maximum error at sharp edges (blend 0.15); with L-BFGS it is ~0.005-0.06. Only the RID weights
        change. Returns the final maximum absolute error on the grid (units of `intensity`).
        """
        if intensity <= 0:
            raise ValueError(f"fit_rid_to_cone: intensity must be > 0, got {intensity}")
        if adam_steps < 0 or lbfgs_iters < 0 or n_samples < 2:
            raise ValueError(
                f"fit_rid_to_cone: need adam_steps >= 0, lbfgs_iters >= 0, n_samples >= 2, "
                f"got {adam_steps}, {lbfgs_iters}, {n_samples}"
            )
        theta = torch.linspace(0.0, math.pi, n_samples, device=self.log_tau.device, dtype=self.log_tau.dtype)
        theta = theta.reshape(-1, 1)
        target = cone_profile(theta, half_angle, blend)  # (n_samples, 1), peak 1

        def loss_fn() -> torch.Tensor:  # relative error, so the schedule does not depend on `intensity`
            return F.mse_loss(self.rid_of_angle(theta) / intensity, target)

        with torch.enable_grad():  # callers may be inside no_grad (e.g. loading a calibrated run for export)
            self._fit_rid(loss_fn, adam_steps, lbfgs_iters)
        with torch.no_grad():
            return float((self.rid_of_angle(theta) - intensity * target).abs().max())

    def _fit_rid(self, loss_fn, adam_steps: int, lbfgs_iters: int) -> None:
        """Adam then L-BFGS on ``loss_fn`` over the RID weights (see fit_rid_to_cone)."""
        adam = torch.optim.Adam(self.rid.parameters(), lr=1e-2)
        for _ in range(adam_steps):
            adam.zero_grad(set_to_none=True)
            loss_fn().backward()
            adam.step()
        if lbfgs_iters > 0:
            lbfgs = torch.optim.LBFGS(
                self.rid.parameters(), lr=1.0, max_iter=lbfgs_iters, history_size=50,
                tolerance_grad=1e-12, tolerance_change=1e-15, line_search_fn="strong_wolfe",
            )

            def closure() -> torch.Tensor:
                lbfgs.zero_grad(set_to_none=True)
                loss = loss_fn()
                loss.backward()
                return loss

            lbfgs.step(closure)

    # ---- prior ----------------------------------------------------------------------------------------------------
    def light_prior_loss(self, t_prior: torch.Tensor | Sequence[float], weight: float) -> torch.Tensor:
        """Translation prior weight · (sqrt(|t - t_prior|² + ε²) - ε), ε = 1 mm; scalar tensor.

        A smooth version of weight · |t - t_prior|₂ (the paper's term): 0 at the prior, gradient weight · unit vector
        away from it beyond a few mm, and a finite (zero) gradient exactly at the prior instead of the norm's kink.
        """
        if weight < 0:
            raise ValueError(f"light prior weight must be >= 0, got {weight}")
        prior = torch.as_tensor(t_prior, dtype=self.translation.dtype, device=self.translation.device)
        if prior.shape != (3,):
            raise ValueError(f"light prior t_prior must have shape (3,), got {tuple(prior.shape)}")
        diff = self.translation - prior
        return weight * (torch.sqrt((diff * diff).sum() + PRIOR_EPS**2) - PRIOR_EPS)


def light_prior_loss(light: SpotLight, t_prior: torch.Tensor | Sequence[float], weight: float) -> torch.Tensor:
    """Functional form of `SpotLight.light_prior_loss`: weight · (sqrt(|t - t_prior|² + ε²) - ε), scalar."""
    return light.light_prior_loss(t_prior, weight)


class _ReviveClamp(torch.autograd.Function):
    """max(0, x) whose backward also passes, where x < 0, the gradient components that would raise x.

    A plain clamp gives no gradient where x < 0: once every normal's cᵀY is negative (measured: the constant term of
    a selection proxy's light went below 0 in its first steps, while the spotlight model was still too bright), the
    low-frequency light is zero everywhere and stays so for good, and higher SH degrees added later never learn. Here,
    where the light is off, a gradient asking for more light (∂loss/∂out < 0) still reaches c; one asking for less
    does not (the light is already 0 there). The forward value is the plain clamp.
    """

    @staticmethod
    def forward(ctx, x: torch.Tensor) -> torch.Tensor:
        ctx.save_for_backward(x)
        return torch.where(x >= 0, x, torch.zeros_like(x))

    @staticmethod
    def backward(ctx, grad: torch.Tensor) -> torch.Tensor:
        (x,) = ctx.saved_tensors
        return torch.where(x >= 0, grad, grad.clamp_max(0.0))


class LowFrequencyLight(nn.Module):
    """Low-frequency incident light L_lf(n̂) = max(0, cᵀ Y(n̂)) with real SH of degree 0..3, evaluated at the normal.

    c (K, 3), K = (degree+1)², is initialised at 0. The clamp's gradient passes where cᵀY ≥ 0 (so the all-zero
    initialisation learns) and, where cᵀY < 0, only when the loss asks for more light (:class:`_ReviveClamp`): a light
    pushed below 0 everywhere early on can come back. The research code multiplies L_lf by
    max(0, n̂·l̂) with l̂ the spotlight direction: `shading` keeps that choice by applying the cosine to the sum
    (L_spot + L_lf), see `spotlessgs.models.shading`.
    """

    def __init__(self, degree: int = 3) -> None:
        super().__init__()
        check_sh_degree(degree)
        self.degree = degree
        self.coeffs = nn.Parameter(torch.zeros(num_sh_bases(degree), 3))

    def radiance(self, normals: torch.Tensor) -> torch.Tensor:
        """Unit normals (N, 3), world frame → non-negative RGB radiance (N, 3)."""
        _check_points(normals, "normals")
        return _ReviveClamp.apply(eval_sh(self.coeffs, normals, self.degree))

    def forward(self, normals: torch.Tensor) -> torch.Tensor:
        """Same as `radiance`."""
        return self.radiance(normals)


class ConstantAmbient(nn.Module):
    """DarkGS ambient: one learned grey radiance A = exp(log A) > 0, the same for every point.

    Args:
        init: initial A (> 0), linear radiance units of the spotlight model.
    """

    def __init__(self, init: float = 0.05) -> None:
        super().__init__()
        if init <= 0:
            raise ValueError(f"ConstantAmbient init must be > 0, got {init}")
        self.log_value = nn.Parameter(torch.tensor(math.log(init)))

    @property
    def value(self) -> torch.Tensor:
        """A, ()."""
        return torch.exp(self.log_value)

    def radiance(self, normals: torch.Tensor) -> torch.Tensor:
        """Unit normals (N, 3) → (N, 3) filled with A (the normals only set N, device and dtype)."""
        _check_points(normals, "normals")
        return self.value.to(normals.dtype).expand(normals.shape[0], 3)

    def forward(self, normals: torch.Tensor) -> torch.Tensor:
        """Same as `radiance`."""
        return self.radiance(normals)


def _rotvec_from(rotation) -> np.ndarray:
    """(3, 3) matrix, (3,) axis-angle or None → (3,) axis-angle."""
    if rotation is None:
        return np.zeros(3)
    r = np.asarray(rotation.detach().cpu() if isinstance(rotation, torch.Tensor) else rotation, dtype=np.float64)
    if r.shape == (3,):
        return r
    if r.shape == (3, 3):
        return so3_log(r)
    raise ValueError(f"SpotLight: rotation must be a (3, 3) matrix or a (3,) axis-angle vector, got shape {r.shape}")


def _check_points(x: torch.Tensor, name: str) -> None:
    if not isinstance(x, torch.Tensor) or x.ndim != 2 or x.shape[1] != 3:
        shape = tuple(x.shape) if hasattr(x, "shape") else type(x).__name__
        raise ValueError(f"{name} must be an (N, 3) tensor, got {shape}")
