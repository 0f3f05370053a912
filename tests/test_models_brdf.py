"""Disney/GGX and learned BRDF: hand values, reciprocity, energy, stability at the bounds, initial equality."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from spotlessgs.models.brdf import LambertianBRDF, LearnedBRDF, disney_brdf
from spotlessgs.models.shading import hemisphere_directions



def _scalar(x) -> float:
    """A Python float of a number or a one-element tensor (detached)."""
    return float(x.detach()) if isinstance(x, torch.Tensor) else float(x)
F64 = torch.float64


def _unit(v) -> torch.Tensor:
    t = torch.as_tensor(v, dtype=F64)
    return t / t.norm(dim=-1, keepdim=True)


def _rows(n: int, *vals) -> list[torch.Tensor]:
    return [torch.as_tensor(v, dtype=F64).expand(n, *torch.as_tensor(v).shape).clone() for v in vals]


def _upper_hemisphere(n: int, seed: int) -> torch.Tensor:
    v = torch.randn(n, 3, dtype=F64, generator=torch.Generator().manual_seed(seed))
    v[:, 2] = v[:, 2].abs() + 0.05
    return v / v.norm(dim=-1, keepdim=True)


@pytest.mark.parametrize("rough, metal", [(0.5, 0.0), (0.3, 1.0), (0.8, 0.4)])
def test_normal_incidence_hand_value(rough, metal):
    # l = v = n: h = n, D = 1/(π α²), G1 = 1, F = F0, Burley factors 1 → f = (1-η) a/π + F0 / (4 π α²).
    a = torch.tensor([[0.2, 0.5, 0.9]], dtype=F64)
    n = torch.tensor([[0.0, 0.0, 1.0]], dtype=F64)
    f = disney_brdf(a, torch.tensor([rough], dtype=F64), torch.tensor([metal], dtype=F64), n, n, n)
    alpha = rough**2
    f0 = 0.04 * (1 - metal) + a.numpy() * metal
    expected = (1 - metal) * a.numpy() / math.pi + f0 / (4 * math.pi * alpha**2)
    np.testing.assert_allclose(f.numpy(), expected, rtol=1e-12)


def test_oblique_hand_value():
    # n = z, l at 60° in the xz plane, v = n: h at 30°, l·h = cos 30°, n·h = cos 30°.
    rough, a = 0.5, 0.6
    n, v = _unit([[0, 0, 1.0]]), _unit([[0, 0, 1.0]])
    l = _unit([[math.sin(math.pi / 3), 0, math.cos(math.pi / 3)]])
    f = disney_brdf(torch.full((1, 3), a, dtype=F64), torch.tensor([rough], dtype=F64), torch.zeros(1, dtype=F64), n, v, l)
    alpha2 = rough**4
    cos_h = math.cos(math.pi / 6)
    d = alpha2 / (math.pi * (cos_h**2 * (alpha2 - 1) + 1) ** 2)
    k = (rough + 1) ** 2 / 8
    vis = 1 / (4 * (0.5 * (1 - k) + k) * (1.0 * (1 - k) + k))
    fres = 0.04 + 0.96 * (1 - cos_h) ** 5
    fd90 = 0.5 + 2 * rough * cos_h**2
    diffuse = a / math.pi * (1 + (fd90 - 1) * 0.5**5)
    np.testing.assert_allclose(f.numpy(), np.full((1, 3), diffuse + d * vis * fres), rtol=1e-12)


def test_reciprocity():
    n_pts = 300
    n = _upper_hemisphere(n_pts, 0)
    l, v = _upper_hemisphere(n_pts, 1), _upper_hemisphere(n_pts, 2)
    g = torch.Generator().manual_seed(3)
    a = torch.rand(n_pts, 3, dtype=F64, generator=g)
    rough, metal = torch.rand(n_pts, dtype=F64, generator=g), torch.rand(n_pts, dtype=F64, generator=g)
    torch.testing.assert_close(disney_brdf(a, rough, metal, n, v, l), disney_brdf(a, rough, metal, n, l, v), rtol=1e-12, atol=0)


def _directional_albedo(rough: float, metal: float, cos_v: float, count: int = 20000) -> float:
    """(1/π)·∫ π f cos dω by cosine-weighted quadrature for a white base colour, n = +z."""
    dirs = hemisphere_directions(count, F64)
    n, v = _rows(count, [0.0, 0.0, 1.0], [math.sqrt(1 - cos_v**2), 0.0, cos_v])
    f = disney_brdf(torch.ones(count, 3, dtype=F64), torch.full((count,), rough, dtype=F64),
                    torch.full((count,), metal, dtype=F64), n, v, dirs)
    return _scalar((math.pi * f[:, 0]).mean())


@pytest.mark.parametrize("rough", [0.3, 0.5, 0.99])
def test_white_furnace_bounds(rough):
    # Metal (specular only): Smith shadowing keeps the reflected energy below 1 for every view.
    for cos_v in (1.0, 0.5, 0.1):
        assert 0.0 < _directional_albedo(rough, 1.0, cos_v) <= 1.0
    # Dielectric white: ≈ 1 (diffuse) + ~0.04 (specular) head-on; Burley's retro-reflection adds at most
    # (F_D90 - 1) ≤ 1.5 at grazing rough views, so the bound is 1 + 0.04 + small head-on and < 1.6 anywhere.
    head_on = _directional_albedo(rough, 0.0, 1.0)
    assert 0.95 < head_on < 1.06
    assert _directional_albedo(rough, 0.0, 0.05) < 1.6


@pytest.mark.parametrize("rough", [0.0, 0.09, 0.99, 1.0])
@pytest.mark.parametrize("metal", [0.0, 1.0])
def test_finite_values_and_gradients_at_bounds_and_grazing(rough, metal):
    n = _unit([[0, 0, 1.0]] * 5)
    l = _unit([[1, 0, 0.0], [0, 0, 1.0], [1, 0, 1e-9], [0.3, 0.2, 0.9], [0, 0, -1.0]])  # grazing, normal, ~grazing, generic, back
    v = _unit([[0, 1, 0.0], [0, 0, 1.0], [-1, 0, 0.0], [-1, 0, 1e-9], [0, 0, 1.0]])
    v[1] = -l[1]  # l = -v exactly → zero half vector
    a = torch.full((5, 3), 0.7, dtype=F64, requires_grad=True)
    r = torch.full((5,), rough, dtype=F64, requires_grad=True)
    m = torch.full((5,), metal, dtype=F64, requires_grad=True)
    nn_, ll, vv = (t.clone().requires_grad_(True) for t in (n, l, v))
    f = disney_brdf(a, r, m, nn_, vv, ll)
    assert torch.isfinite(f).all() and (f >= 0).all()
    f.sum().backward()
    for t in (a, r, m, nn_, ll, vv):
        assert torch.isfinite(t.grad).all()


def test_lambertian_returns_albedo():
    a = torch.rand(4, 3)
    n = torch.zeros(4, 3)
    assert LambertianBRDF()(a, None, None, n, n, n) is a


def test_learned_brdf_starts_as_clamped_analytic_and_stays_bounded():
    brdf = LearnedBRDF(seed=1).double()
    assert brdf.input_size == 117
    assert brdf.mlp[0].in_features == 117 and brdf.mlp[-1].out_features == 1
    n_pts = 64
    n, l, v = _upper_hemisphere(n_pts, 4), _upper_hemisphere(n_pts, 5), _upper_hemisphere(n_pts, 6)
    g = torch.Generator().manual_seed(7)
    a = torch.rand(n_pts, 3, dtype=F64, generator=g)
    rough = 0.09 + 0.9 * torch.rand(n_pts, 1, dtype=F64, generator=g)
    metal = torch.rand(n_pts, 1, dtype=F64, generator=g)
    analytic = (math.pi * disney_brdf(a, rough, metal, n, v, l)).clamp(0, 1)
    torch.testing.assert_close(brdf(a, rough, metal, n, v, l), analytic, rtol=0, atol=0)
    with torch.no_grad():
        brdf.mlp[-1].bias.fill_(50.0)  # tanh → 1: factor 1.2
    out = brdf(a, rough, metal, n, v, l)
    torch.testing.assert_close(out, (1.2 * math.pi * disney_brdf(a, rough, metal, n, v, l)).clamp(0, 1))
    assert _scalar(out.detach().max()) <= 1.0 and _scalar(out.detach().min()) >= 0.0


def test_learned_brdf_gradients_reach_the_mlp():
    brdf = LearnedBRDF(seed=0)
    n = torch.tensor([[0.0, 0.0, 1.0]] * 3)
    l = torch.nn.functional.normalize(torch.tensor([[0.3, 0.0, 1.0], [0.0, 0.5, 1.0], [1.0, 0.0, 0.0]]), dim=-1)
    v = torch.nn.functional.normalize(torch.tensor([[-0.2, 0.1, 1.0], [0.0, 0.0, 1.0], [0.0, 1.0, 0.0]]), dim=-1)
    out = brdf(torch.full((3, 3), 0.5), torch.full((3, 1), 0.5), torch.zeros(3, 1), n, v, l)
    out.sum().backward()
    assert _scalar(brdf.mlp[-1].weight.grad.abs().sum()) > 0
    assert all(torch.isfinite(p.grad).all() for p in brdf.parameters())


def test_learned_brdf_without_input_gradients_moves_its_inputs_by_the_analytic_factor_alone():
    """input_gradients=False: the same values and network gradients, and the directions' gradients are those of the
    Disney factor times the (constant) learned modulation; with the paper's setting the network adds its own."""
    n_pts = 32
    g = torch.Generator().manual_seed(3)
    a = torch.rand(n_pts, 3, dtype=F64, generator=g)
    rough = 0.09 + 0.9 * torch.rand(n_pts, 1, dtype=F64, generator=g)
    metal = torch.rand(n_pts, 1, dtype=F64, generator=g)
    grads = {}
    for setting in (True, False):
        brdf = LearnedBRDF(seed=2, upper_clamp=False, input_gradients=setting).double()
        with torch.no_grad():  # a trained-looking residual: the zero-initialised last layer made non-zero
            brdf.mlp[-1].weight.copy_(torch.randn(brdf.mlp[-1].weight.shape, dtype=F64, generator=g.manual_seed(9)))
        dirs = [_upper_hemisphere(n_pts, s).requires_grad_() for s in (4, 5, 6)]
        out = brdf(a, rough, metal, *dirs)
        out.sum().backward()
        grads[setting] = (out.detach(), [d.grad for d in dirs], [p.grad for p in brdf.parameters()])
        if not setting:  # independently: the Disney factor's gradient with the modulation held fixed
            ref_dirs = [d.detach().clone().requires_grad_() for d in dirs]
            fixed = brdf.modulation(*ref_dirs).detach()
            (math.pi * disney_brdf(a, rough, metal, *ref_dirs) * fixed).sum().backward()
            for got, want in zip(grads[False][1], ref_dirs):
                torch.testing.assert_close(got, want.grad, rtol=1e-12, atol=1e-12)
    torch.testing.assert_close(grads[False][0], grads[True][0], rtol=0, atol=0)
    for got, want in zip(grads[False][2], grads[True][2]):
        torch.testing.assert_close(got, want, rtol=1e-12, atol=1e-12)
    network_part = sum(float((t - f).abs().sum()) for t, f in zip(grads[True][1], grads[False][1]))
    assert network_part > 1e-3  # the paper's setting passes the network's gradient on to the directions


def test_brdf_errors():
    with pytest.raises(ValueError, match=r"residual must be in \[0, 1\)"):
        LearnedBRDF(residual=1.0)
    n = torch.zeros(2, 3)
    with pytest.raises(ValueError, match=r"roughness must have shape \(N,\) or \(N, 1\), got \(2, 3\)"):
        disney_brdf(n, torch.zeros(2, 3), torch.zeros(2), n, n, n)


@pytest.mark.parametrize("rough", [0.3, 0.5, 0.8, 1.0])
@pytest.mark.parametrize("metal", [0.0, 1.0])
def test_directional_albedo_table_equals_a_dense_quadrature(rough, metal):
    """Where a dense cosine-weighted quadrature of the unclamped model is accurate (lobes not too sharp), the table's
    importance-sampled directional albedo equals it within 0.5 %."""
    from spotlessgs.models.brdf import disney_directional_albedo
    from spotlessgs.models.shading import hemisphere_directions

    dirs = hemisphere_directions(200_000, F64)
    count = len(dirs)
    up = torch.tensor([[0.0, 0.0, 1.0]], dtype=F64).expand(count, 3)
    a = torch.tensor([[0.7, 0.4, 0.2]], dtype=F64)
    dense = (math.pi * disney_brdf(a.expand(count, 3), torch.full((count, 1), rough, dtype=F64),
                                   torch.full((count, 1), metal, dtype=F64), up, up, dirs)).mean(0)
    table = disney_directional_albedo(a, torch.tensor([[rough]], dtype=F64), torch.tensor([[metal]], dtype=F64))[0]
    torch.testing.assert_close(table, dense, rtol=5e-3, atol=1e-4)


def test_unclamped_brdf_keeps_glossy_lobes_and_their_albedo():
    """A smooth metal (ρ = 0.05) reflects about its base colour of uniform light (the Fresnel F0 = a); with the upper
    clamp a 16-direction quadrature of f̃ ≤ 1 keeps a few per cent of it. Unclamped, the lobe's peak exceeds 1; the
    table is differentiable in all three material inputs."""
    from spotlessgs.models.brdf import disney_directional_albedo
    from spotlessgs.models.shading import relit_reflectance

    a = torch.tensor([[0.7, 0.5, 0.3]], dtype=F64, requires_grad=True)
    rough = torch.tensor([[0.05]], dtype=F64, requires_grad=True)
    metal = torch.tensor([[1.0]], dtype=F64, requires_grad=True)
    r = disney_directional_albedo(a, rough, metal)
    torch.testing.assert_close(r.detach(), a.detach(), rtol=0.01, atol=0.0)
    normal = torch.tensor([[0.0, 0.0, 1.0]], dtype=F64)
    clamped_r = relit_reflectance(a.detach(), rough.detach(), metal.detach(), normal,
                                  LearnedBRDF(seed=0, hidden=8).double())
    assert _scalar(clamped_r.max()) < 0.1  # the clamped model's 16-direction quadrature: dark
    r.sum().backward()
    assert all(t.grad is not None and torch.isfinite(t.grad).all() for t in (a, rough, metal))
    up = torch.tensor([[0.0, 0.0, 1.0]])
    peak = LearnedBRDF(seed=0, upper_clamp=False)(torch.full((1, 3), 0.7), torch.full((1, 1), 0.05),
                                                   torch.ones(1, 1), up, up, up)
    assert _scalar(peak.min()) > 100.0
    clamped = LearnedBRDF(seed=0)(torch.full((1, 3), 0.7), torch.full((1, 1), 0.05), torch.ones(1, 1), up, up, up)
    assert _scalar(clamped.max()) == 1.0


def test_burley_factor_off_leaves_a_lambertian_diffuse_lobe():
    """Lit and seen 60° off the normal from one direction (ĥ = l̂, l·h = 1), a fully rough dielectric's Burley factor
    is (1 + (F_D90 - 1)(1 - cos 60°)⁵)² with F_D90 = ½ + 2 = 2.5, i.e. (1 + 1.5 / 32)²; without it the diffuse lobe is
    a/π. The specular lobe is the same either way, and so the difference is a/π ((1 + 1.5/32)² - 1)."""
    n = torch.tensor([[0.0, 0.0, 1.0]], dtype=F64)
    d = torch.tensor([[math.sin(math.pi / 3), 0.0, 0.5]], dtype=F64)
    a = torch.tensor([[0.6, 0.3, 0.1]], dtype=F64)
    rough, metal = torch.ones(1, 1, dtype=F64), torch.zeros(1, 1, dtype=F64)
    with_factor = disney_brdf(a, rough, metal, n, d, d)
    lambertian = disney_brdf(a, rough, metal, n, d, d, burley=False)
    torch.testing.assert_close(with_factor - lambertian, a / math.pi * ((1.0 + 1.5 / 32.0) ** 2 - 1.0))
    metal_only = disney_brdf(a, rough, torch.ones(1, 1, dtype=F64), n, d, d, burley=False)
    torch.testing.assert_close(metal_only, disney_brdf(a, rough, torch.ones(1, 1, dtype=F64), n, d, d))
    learned = LearnedBRDF(seed=0, hidden=8, burley=False).double()
    torch.testing.assert_close(learned(a, rough, metal, n, d, d), math.pi * lambertian)  # zero-initialised MLP


def test_directional_albedo_without_burley_has_a_unit_diffuse_integral():
    """The Lambertian lobe's cosine integral is exactly 1 (C = 2 ∫ μ dμ); Burley's is not: at ρ = 0, F_D90 = ½ and
    C = 2 ∫ (1 - ½ (1 - μ)⁵) μ dμ = 1 - B(2, 6) = 1 - 1/42. The specular columns do not depend on the diffuse lobe."""
    from spotlessgs.models.brdf import directional_albedo_table

    burley = directional_albedo_table(size=5, samples=512)
    lambertian = directional_albedo_table(size=5, samples=512, burley=False)
    torch.testing.assert_close(lambertian[:, 2], torch.ones(5, dtype=F64))
    torch.testing.assert_close(lambertian[:, :2], burley[:, :2])
    assert abs(float(burley[0, 2]) - (1.0 - 1.0 / 42.0)) < 1e-5
