"""Spotlight frames, RID angle and fall-off at the hard points, cone initialisation, SH light, ambient, prior."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch
from scipy.spatial.transform import Rotation

from spotlessgs.models.geometry import so3_exp, so3_log, viewmat_to_c2w
from spotlessgs.models.light import (
    ConstantAmbient, LowFrequencyLight, SpotLight, cone_profile, light_prior_loss,
)
from spotlessgs.models.sh import SH_C0



def _scalar(x) -> float:
    """A Python float of a number or a one-element tensor (detached)."""
    return float(x.detach()) if isinstance(x, torch.Tensor) else float(x)


def _camera(dtype=torch.float32) -> torch.Tensor:
    """A camera at C = (1, 2, 0.5) rotated by a generic rotation."""
    c2w = torch.eye(4, dtype=dtype)
    c2w[:3, :3] = torch.as_tensor(Rotation.from_rotvec([0.3, -0.5, 1.1]).as_matrix(), dtype=dtype)
    c2w[:3, 3] = torch.tensor([1.0, 2.0, 0.5], dtype=dtype)
    return c2w


def _world_from_light(light: SpotLight, c2w: torch.Tensor, x_l: torch.Tensor) -> torch.Tensor:
    """Inverse of the documented chain: x_cam = R x_l + t, x = R_cw x_cam + C."""
    with torch.no_grad():
        x_cam = x_l @ light.rotation().T + light.translation
        return x_cam @ c2w[:3, :3].T + c2w[:3, 3]


def _all_grads_finite(module: torch.nn.Module, *extra: torch.Tensor) -> bool:
    tensors = [p.grad for p in module.parameters() if p.grad is not None] + [e.grad for e in extra]
    return all(t is not None and torch.isfinite(t).all() for t in tensors)


# ---- so(3) -------------------------------------------------------------------------------------------------------
def test_so3_exp_matches_scipy_and_is_smooth_at_zero():
    for w in ([0.3, -0.5, 1.1], [1e-5, 2e-5, -1e-5], [0.0, 0.0, math.pi - 1e-3]):
        got = so3_exp(torch.tensor(w, dtype=torch.float64)).numpy()
        np.testing.assert_allclose(got, Rotation.from_rotvec(w).as_matrix(), atol=1e-12)
    w = torch.zeros(3, dtype=torch.float64, requires_grad=True)
    m = torch.arange(9, dtype=torch.float64).reshape(3, 3) ** 2
    (so3_exp(w) * m).sum().backward()
    # At w = 0, dR/dw_i is the generator [e_i]×, so d/dw Σ M⊙R = (M21 - M12, M02 - M20, M10 - M01).
    expected = [m[2, 1] - m[1, 2], m[0, 2] - m[2, 0], m[1, 0] - m[0, 1]]
    np.testing.assert_allclose(w.grad.numpy(), expected, atol=1e-12)


def test_so3_log_roundtrip_and_errors():
    r = Rotation.from_rotvec([0.2, 0.1, -0.4]).as_matrix()
    np.testing.assert_allclose(so3_log(r), [0.2, 0.1, -0.4], atol=1e-12)
    with pytest.raises(ValueError, match="not a proper rotation"):
        so3_log(np.diag([1.0, 1.0, -1.0]))
    with pytest.raises(ValueError, match=r"\(3, 3\) rotation matrix, got shape \(2, 2\)"):
        so3_log(np.eye(2))
    with pytest.raises(ValueError, match=r"\(3,\) axis-angle vector, got shape \(4,\)"):
        so3_exp(torch.zeros(4))


def test_viewmat_to_c2w_inverts():
    c2w = _camera(torch.float64)
    viewmat = torch.linalg.inv(c2w)
    torch.testing.assert_close(viewmat_to_c2w(viewmat), c2w)


# ---- frames ------------------------------------------------------------------------------------------------------
def test_light_frame_and_origin_follow_the_documented_chain():
    r_lc = Rotation.from_rotvec([0.0, 0.4, 0.1]).as_matrix()
    light = SpotLight(rotation=r_lc, translation=[0.1, -0.05, 0.02]).double()
    np.testing.assert_allclose(light.rotation().detach().numpy(), r_lc, atol=1e-12)
    c2w = _camera(torch.float64)
    x = torch.tensor([[0.3, 2.5, 4.0], [-1.0, 0.0, 1.0]], dtype=torch.float64)
    rcw, c = c2w[:3, :3].numpy(), c2w[:3, 3].numpy()
    t = np.array([0.1, -0.05, 0.02])
    x_cam = (rcw.T @ (x.numpy() - c).T).T
    x_l = (r_lc.T @ (x_cam - t).T).T
    np.testing.assert_allclose(light.to_light_frame(x, c2w).detach().numpy(), x_l, atol=1e-12)
    o = c + rcw @ t
    np.testing.assert_allclose(light.origin_world(c2w).detach().numpy(), o, atol=1e-12)
    np.testing.assert_allclose(light.axis_world(c2w).detach().numpy(), rcw @ r_lc[:, 2], atol=1e-12)
    _, l_hat = light.incident(x, c2w)
    expected = (o - x.numpy()) / np.linalg.norm(o - x.numpy(), axis=1, keepdims=True)
    np.testing.assert_allclose(l_hat.detach().numpy(), expected, atol=1e-12)


@pytest.mark.parametrize(
    "x_l, theta",
    [
        ([0.0, 0.0, 2.0], 0.0),                 # on the axis
        ([1.0, 0.0, 0.0], math.pi / 2),         # beside the light (x_l.z = 0)
        ([0.0, 0.0, -1.0], math.pi),            # straight behind
        ([1.0, 0.0, -1.0], 3 * math.pi / 4),    # behind, off axis
        ([0.0, 0.0, 0.0], math.pi / 2),         # at the light origin (d → 0)
    ],
)
def test_incident_is_finite_with_finite_gradients_at_hard_points(x_l, theta):
    light = SpotLight(rotation=[0.1, -0.2, 0.05], translation=[0.1, 0.0, 0.05]).double()
    c2w = _camera(torch.float64)
    x = _world_from_light(light, c2w, torch.tensor([x_l], dtype=torch.float64)).requires_grad_(True)
    x_light = light.to_light_frame(x, c2w)
    assert _scalar(SpotLight.angle_off_axis(x_light).detach()) == pytest.approx(theta, abs=1e-5)
    radiance, l_hat = light.incident(x, c2w)
    d_sq = _scalar((torch.tensor(x_l) ** 2).sum())
    expected = (0.3 + d_sq) ** -1.0 * _scalar(light.rid_curve([theta])[0])
    assert _scalar(radiance.detach()) == pytest.approx(expected, rel=1e-5)
    assert torch.isfinite(l_hat).all() and _scalar(l_hat.detach().norm()) == pytest.approx(1.0)
    (radiance.sum() + l_hat.sum()).backward()
    assert _all_grads_finite(light, x)
    assert light.translation.grad.abs().sum() > 0 and light.log_tau.grad.abs() > 0


def test_direction_at_light_origin_falls_back_to_minus_axis():
    light = SpotLight(rotation=[0.0, 0.5, 0.0], translation=[0.2, 0.0, 0.0]).double()
    c2w = _camera(torch.float64)
    x = light.origin_world(c2w).detach().reshape(1, 3)
    _, l_hat = light.incident(x, c2w)
    torch.testing.assert_close(l_hat[0], -light.axis_world(c2w).detach())


def test_falloff_hand_values():
    light = SpotLight(gamma=2.0, tau=0.5).double()
    x_l = torch.tensor([[0.0, 0.0, 2.0], [1.0, 1.0, 1.0]], dtype=torch.float64)
    np.testing.assert_allclose(light.falloff(x_l).detach().numpy()[:, 0], [4.5**-2, 3.5**-2], rtol=1e-7)
    assert light.gamma.item() == pytest.approx(2.0) and light.tau.item() == pytest.approx(0.5)


def test_pose_can_be_frozen():
    light = SpotLight()
    light.set_pose_trainable(False)
    radiance, _ = light.incident(torch.tensor([[0.0, 0.0, 2.0]]), torch.eye(4))
    radiance.sum().backward()
    assert light.translation.grad is None and light.rotvec.grad is None
    assert light.log_gamma.grad is not None


def test_rid_is_positive_deterministic_and_seeded():
    thetas = np.linspace(0, math.pi, 50)
    a, b, c = SpotLight(seed=3).rid_curve(thetas), SpotLight(seed=3).rid_curve(thetas), SpotLight(seed=4).rid_curve(thetas)
    assert a.shape == (50,) and (a > 0).all()
    torch.testing.assert_close(a, b, rtol=0, atol=0)
    assert not torch.equal(a, c)


# ---- cone ----------------------------------------------------------------------------------------------------------
def test_cone_profile_hand_values_and_errors():
    half, blend = math.radians(30), 0.4
    cos_c = math.cos(half)
    mid = math.acos(cos_c + 0.5 * blend * (1 - cos_c))  # s = 0.5 → smoothstep 0.5
    quarter = math.acos(cos_c + 0.25 * blend * (1 - cos_c))  # s = 0.25 → 0.25²(3 - 0.5) = 0.15625
    got = cone_profile(torch.tensor([0.0, mid, quarter, half, 2.0, math.pi], dtype=torch.float64), half, blend)
    np.testing.assert_allclose(got.numpy(), [1.0, 0.5, 0.15625, 0.0, 0.0, 0.0], atol=1e-12)
    with pytest.raises(ValueError, match="half_angle must be in"):
        cone_profile(torch.zeros(1), 2.0, 0.5)
    with pytest.raises(ValueError, match="blend must be in"):
        cone_profile(torch.zeros(1), 0.5, 0.0)


@pytest.mark.parametrize("half_deg, blend, intensity, tol", [(30.0, 0.3, 1.0, 0.02), (22.5, 0.15, 2.0, 0.15)])
def test_rid_fitted_to_cone_reproduces_the_profile(half_deg, blend, intensity, tol):
    light = SpotLight(seed=0)
    max_err = light.fit_rid_to_cone(math.radians(half_deg), blend, intensity=intensity)
    thetas = torch.linspace(0, math.pi, 1001)
    target = intensity * cone_profile(thetas, math.radians(half_deg), blend)
    err = (light.rid_curve(thetas) - target).abs()
    assert max_err < tol and _scalar(err.max()) < tol
    assert _scalar(err.pow(2).mean().sqrt()) < tol / 5  # good on average, the worst error sits on the edge
    again = SpotLight(seed=0)
    again.fit_rid_to_cone(math.radians(half_deg), blend, intensity=intensity)
    torch.testing.assert_close(again.rid_curve(thetas), light.rid_curve(thetas), rtol=0, atol=0)


def test_fit_rid_errors():
    with pytest.raises(ValueError, match="intensity must be > 0"):
        SpotLight().fit_rid_to_cone(0.5, 0.5, intensity=0.0)
    with pytest.raises(ValueError, match="n_samples >= 2"):
        SpotLight().fit_rid_to_cone(0.5, 0.5, n_samples=1)


# ---- prior -------------------------------------------------------------------------------------------------------
def test_prior_loss_zero_at_prior_and_real_gradient_elsewhere():
    light = SpotLight(translation=[0.1, 0.2, 0.3]).double()
    at_prior = light.light_prior_loss([0.1, 0.2, 0.3], weight=2.0)
    assert at_prior.item() == pytest.approx(0.0, abs=1e-9)
    loss = light_prior_loss(light, torch.tensor([0.4, 0.6, 0.3]), weight=2.0)
    diff = np.array([-0.3, -0.4, 0.0])
    assert loss.item() == pytest.approx(2.0 * (math.sqrt(0.25 + 1e-6) - 1e-3), rel=1e-6)
    loss.backward()
    np.testing.assert_allclose(light.translation.grad.numpy(), 2.0 * diff / math.sqrt(0.25 + 1e-6), rtol=1e-6)
    assert _scalar(light.translation.grad.norm()) > 1.9  # ≈ weight: a real pull, not a dead term


def test_prior_loss_errors():
    light = SpotLight()
    with pytest.raises(ValueError, match="weight must be >= 0"):
        light.light_prior_loss([0, 0, 0], -1.0)
    with pytest.raises(ValueError, match=r"t_prior must have shape \(3,\), got \(2,\)"):
        light.light_prior_loss([0, 0], 1.0)


def test_spotlight_constructor_errors():
    with pytest.raises(ValueError, match="gamma and tau must be > 0"):
        SpotLight(tau=0.0)
    with pytest.raises(ValueError, match=r"translation must have shape \(3,\), got \(2,\)"):
        SpotLight(translation=[0.0, 1.0])
    with pytest.raises(ValueError, match=r"rotation must be a \(3, 3\) matrix or a \(3,\) axis-angle vector"):
        SpotLight(rotation=np.eye(4))
    with pytest.raises(ValueError, match=r"c2w must be a \(4, 4\)"):
        SpotLight().incident(torch.zeros(1, 3), torch.eye(3))
    with pytest.raises(ValueError, match=r"x_world must be an \(N, 3\) tensor, got \(3,\)"):
        SpotLight().incident(torch.zeros(3), torch.eye(4))


# ---- low-frequency light -----------------------------------------------------------------------------------------
def test_sh_light_starts_dark_but_learns():
    lf = LowFrequencyLight(3)
    n = torch.nn.functional.normalize(torch.randn(20, 3, generator=torch.Generator().manual_seed(0)), dim=-1)
    out = lf(n)
    assert out.shape == (20, 3) and out.detach().abs().max().item() == 0.0
    out.sum().backward()
    assert _scalar(lf.coeffs.grad[0].abs().min()) > 0  # gradient passes the clamp at exactly 0


def test_dead_sh_light_comes_back_when_the_loss_wants_light():
    # every normal below 0: the plain clamp would give no gradient at all and the light would stay off for good
    lf = LowFrequencyLight(1).double()
    with torch.no_grad():
        lf.coeffs[0] = -0.2
    n = torch.nn.functional.normalize(torch.randn(50, 3, dtype=torch.float64,
                                                  generator=torch.Generator().manual_seed(4)), dim=-1)
    target = torch.full((50, 3), 0.3, dtype=torch.float64)
    out = lf(n)
    assert out.detach().abs().max().item() == 0.0
    ((out - target) ** 2).sum().backward()  # wants more light: d loss / d out = -0.6 < 0 everywhere
    # the gradient an unclamped light would get: sum over the normals of -0.6 * Y_0^0
    np.testing.assert_allclose(lf.coeffs.grad[0].numpy(), [-0.6 * SH_C0 * 50] * 3, rtol=1e-12)
    opt = torch.optim.Adam(lf.parameters(), lr=0.02)
    for _ in range(300):
        opt.zero_grad()
        ((lf(n) - target) ** 2).mean().backward()
        opt.step()
    assert lf(n).detach().mean().item() == pytest.approx(0.3, abs=0.02)  # revived and fitted
    # a gradient asking for less light where the light is already off does not reach c
    lf.zero_grad()
    with torch.no_grad():
        lf.coeffs.zero_()
        lf.coeffs[0] = -0.2
    lf(n).sum().backward()
    assert lf.coeffs.grad.abs().max().item() == 0.0


def test_sh_light_is_non_negative_with_finite_gradient():
    lf = LowFrequencyLight(1).double()
    with torch.no_grad():
        lf.coeffs[2] = torch.tensor([1.0, 2.0, -1.0], dtype=torch.float64)  # y_1^0 ∝ z
    n = torch.tensor([[0.0, 0.0, 1.0], [0.0, 0.0, -1.0]], dtype=torch.float64)
    out = lf(n)
    c1 = math.sqrt(3 / (4 * math.pi))
    np.testing.assert_allclose(out.detach().numpy(), [[c1, 2 * c1, 0.0], [0.0, 0.0, c1]], atol=1e-12)
    out.sum().backward()
    assert torch.isfinite(lf.coeffs.grad).all()


def test_sh_degree_zero_is_a_constant_ambient():
    lf, amb = LowFrequencyLight(0).double(), ConstantAmbient(0.37).double()
    with torch.no_grad():
        lf.coeffs.fill_(0.37 / SH_C0)
    n = torch.nn.functional.normalize(torch.randn(30, 3, dtype=torch.float64, generator=torch.Generator().manual_seed(2)), dim=-1)
    torch.testing.assert_close(lf(n), amb(n))
    torch.testing.assert_close(amb(n), torch.full((30, 3), 0.37, dtype=torch.float64))


def test_low_frequency_errors():
    with pytest.raises(ValueError, match="SH degree must be an integer"):
        LowFrequencyLight(4)
    with pytest.raises(ValueError, match="ConstantAmbient init must be > 0"):
        ConstantAmbient(0.0)
    with pytest.raises(ValueError, match=r"normals must be an \(N, 3\) tensor"):
        LowFrequencyLight(1)(torch.zeros(3, 2))
