"""Per-variant shading: shapes and gradients, hand-computed DarkGS colour, 3DGS ignores the light, SH-0 = ambient,
relighting independent of the light pose and of the camera, configuration and module errors."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest
import torch
from scipy.spatial.transform import Rotation

from spotlessgs.models.brdf import LambertianBRDF, LearnedBRDF
from spotlessgs.models.gaussians import GaussianParams
from spotlessgs.models.light import ConstantAmbient, LowFrequencyLight, SpotLight
from spotlessgs.models.sh import SH_C0
from spotlessgs.models.shading import (
    MODEL_VARIANTS, ModelConfig, build_appearance_models, hemisphere_directions, orient_normals, relit_reflectance,
    shade,
)



def _scalar(x) -> float:
    """A Python float of a number or a one-element tensor (detached)."""
    return float(x.detach()) if isinstance(x, torch.Tensor) else float(x)


def _look_at_c2w(center, target, dtype=torch.float32) -> torch.Tensor:
    """OpenCV camera at `center` looking at `target` (z forward, y down, world z up)."""
    c, t = np.asarray(center, float), np.asarray(target, float)
    z = (t - c) / np.linalg.norm(t - c)
    x = np.cross(z, [0.0, 0.0, 1.0])
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    m = np.eye(4)
    m[:3, :3] = np.stack([x, y, z], axis=1)
    m[:3, 3] = c
    return torch.as_tensor(m, dtype=dtype)


def _scene(n: int = 40, seed: int = 0) -> GaussianParams:
    rng = np.random.default_rng(seed)
    xyz = rng.uniform(-1, 1, size=(n, 3)) * [1.0, 1.0, 0.2]
    normals = rng.normal(size=(n, 3)) * 0.2 + [0, 0, 1]
    return GaussianParams.from_point_cloud(xyz, rng.integers(0, 256, (n, 3)).astype(np.uint8), normals)


CAM = _look_at_c2w([0.3, -2.0, 2.5], [0.0, 0.0, 0.0])


@pytest.mark.parametrize("variant", sorted(MODEL_VARIANTS))
def test_each_variant_shape_finite_and_differentiable(variant):
    g = _scene()
    calibrated = MODEL_VARIANTS[variant].calibrated
    extra = {"light_translation": [0.05, -0.03, 0.0], "cone": (0.5, 0.3)} if calibrated else {}
    m = build_appearance_models(variant, seed=1, **extra)
    colours = shade(variant, g, m.light, m.lf_light, m.brdf, CAM)
    assert colours.shape == (40, 3) and torch.isfinite(colours).all() and _scalar(colours.min()) >= 0.0
    colours.sum().backward()
    grads = [p.grad for p in g.parameters() if p.grad is not None] + [
        p.grad for p in m.module_dict().parameters() if p.grad is not None
    ]
    assert grads and all(torch.isfinite(t).all() for t in grads)
    if variant == "3dgs":
        assert g.params["sh0"].grad.abs().sum() > 0 and g.params["albedo_raw"].grad is None
    elif calibrated:  # the pose is frozen: no gradient reaches it
        assert g.params["albedo_raw"].grad.abs().sum() > 0 and m.light.translation.grad is None
    else:
        assert g.params["albedo_raw"].grad.abs().sum() > 0 and m.light.translation.grad.abs().sum() > 0


def test_3dgs_ignores_light_and_relighting():
    g = _scene()
    base = shade("3dgs", g, None, None, None, CAM)
    m = build_appearance_models("spotless")
    torch.testing.assert_close(shade("3dgs", g, m.light, m.lf_light, m.brdf, CAM, relight_l0=(3.0, 3.0, 3.0)), base)
    # Degree-0 initialisation: every view sees the linearised point colour (SH0 · C0 + 0.5).
    torch.testing.assert_close(base, g.params["sh0"][:, 0].detach() * SH_C0 + 0.5)
    # View dependence through the degree-1 band: y_1^0 = C1 · d_z with d the camera → Gaussian direction.
    with torch.no_grad():
        g.params["shN"][:, 1] = 1.0  # row 2 of the 16 = y_1^0
    d = torch.nn.functional.normalize(g.means.detach() - CAM[:3, 3], dim=-1)
    c1 = math.sqrt(3 / (4 * math.pi))
    torch.testing.assert_close(shade("3dgs", g, None, None, None, CAM), (base + c1 * d[:, 2:3]).clamp_min(0.0))


def test_darkgs_colour_by_hand():
    # One Gaussian 2 m in front of a camera whose lamp sits at the camera centre, normal towards the camera.
    c2w = _look_at_c2w([0.0, -2.0, 0.0], [0.0, 0.0, 0.0], torch.float64)
    g = GaussianParams.from_point_cloud(np.zeros((1, 3)), np.array([[0.2, 0.5, 0.8]]), np.array([[0.0, -1.0, 0.0]]),
                                        rgb_is_srgb=False).double()
    light, amb = SpotLight(seed=0).double(), ConstantAmbient(0.05).double()
    colour = shade("darkgs", g, light, amb, LambertianBRDF(), c2w)
    expected = np.array([0.2, 0.5, 0.8]) * (_scalar(light.rid_curve([0.0])[0]) / (0.3 + 4.0) + 0.05)
    np.testing.assert_allclose(colour.detach().numpy()[0], expected, rtol=1e-5)


def test_irradiance_shading_of_the_low_frequency_light_by_hand():
    """A Gaussian whose normal is 60 degrees from the lamp (cosine 0.5): the paper's shading scales the ambient light
    by that cosine, the "irradiance" shading does not (a Lambertian surface under light from all around returns its
    albedo times that light); the spotlight's part is the same in both, and the two-light split sums to the colour."""
    c2w = _look_at_c2w([0.0, -2.0, 0.0], [0.0, 0.0, 0.0], torch.float64)
    tilt = math.radians(60.0)
    g = GaussianParams.from_point_cloud(np.zeros((1, 3)), np.array([[0.2, 0.5, 0.8]]),
                                        np.array([[math.sin(tilt), -math.cos(tilt), 0.0]]), rgb_is_srgb=False).double()
    light, amb = SpotLight(seed=0).double(), ConstantAmbient(0.05).double()
    spot = _scalar(light.rid_curve([0.0])[0]) / (0.3 + 4.0)
    albedo = np.array([0.2, 0.5, 0.8])
    paper = shade("darkgs", g, light, amb, LambertianBRDF(), c2w)
    np.testing.assert_allclose(paper.detach().numpy()[0], albedo * 0.5 * (spot + 0.05), rtol=1e-5)
    config = dataclasses.replace(MODEL_VARIANTS["darkgs"], low_frequency_shading="irradiance")
    irradiance = shade(config, g, light, amb, LambertianBRDF(), c2w)
    np.testing.assert_allclose(irradiance.detach().numpy()[0], albedo * (0.5 * spot + 0.05), rtol=1e-5)
    parts = shade(config, g, light, amb, LambertianBRDF(), c2w, split_lights=True)
    np.testing.assert_allclose(parts.detach().numpy()[0, 3:], albedo * 0.05, rtol=1e-5)
    torch.testing.assert_close(parts[:, :3] + parts[:, 3:], irradiance)
    with pytest.raises(ValueError, match="low_frequency_shading must be"):
        dataclasses.replace(MODEL_VARIANTS["darkgs"], low_frequency_shading="cosine")


def test_irradiance_shading_uses_the_relit_reflectance_of_a_learned_brdf():
    """With the learned BRDF the low-frequency light's share of the spotlit colour (the split's second half) is the
    directional albedo R times L_lf: the relit colour with L0 = 0, as relighting shades it."""
    g = _scene()
    config = dataclasses.replace(MODEL_VARIANTS["spotless"], low_frequency_shading="irradiance", brdf_hidden=16)
    models = build_appearance_models(config, seed=1)
    with torch.no_grad():
        models.lf_light.coeffs.normal_(0.0, 0.3, generator=torch.Generator().manual_seed(4))
    c2w = _look_at_c2w([0.0, -3.0, 0.5], [0.0, 0.0, 0.0])
    parts = shade(config, g, models.light, models.lf_light, models.brdf, c2w, split_lights=True)
    relit = shade(config, g, models.light, models.lf_light, models.brdf, c2w, relight_l0=[0.0, 0.0, 0.0])
    assert float(relit.detach().abs().sum()) > 0
    torch.testing.assert_close(parts[:, 3:], relit, rtol=1e-5, atol=1e-6)
    # R is the Disney model's tabulated directional albedo (no network pass), in training and relighting alike
    from spotlessgs.models.brdf import disney_directional_albedo

    normals = orient_normals(g.normals(c2w[:3, 3]), torch.nn.functional.normalize(c2w[:3, 3] - g.means, dim=-1))
    expected = disney_directional_albedo(g.albedo, g.roughness, g.metalness) * models.lf_light.radiance(normals)
    torch.testing.assert_close(relit, expected, rtol=1e-5, atol=1e-6)
    paper = shade("spotless", g, models.light, models.lf_light, models.brdf, c2w, split_lights=True)
    assert not torch.allclose(paper[:, 3:], relit, atol=1e-3)  # the paper's shading differs


@pytest.mark.parametrize("low_frequency_shading", ["spot_cosine", "irradiance"])
def test_with_spot_part_gives_the_colour_and_the_split_renders_first_half_exactly(low_frequency_shading):
    """``with_spot_part`` (the lamp bounce's emitters, in the training render's own pass) gives the normal colour and
    the spotlight's part of the split bit for bit, with shadows and a bounce light present, the part detached; it
    refuses a relit or unlit render and the split."""
    g = _scene()
    config = dataclasses.replace(MODEL_VARIANTS["spotless"], brdf_hidden=16, bounce_light_degree=2,
                                 low_frequency_shading=low_frequency_shading)
    models = build_appearance_models(config, seed=2)
    assert models.bounce_light is not None
    with torch.no_grad():
        models.lf_light.coeffs.normal_(0.0, 0.3, generator=torch.Generator().manual_seed(5))
    c2w = _look_at_c2w([0.0, -3.0, 0.5], [0.0, 0.0, 0.0])
    visibility = torch.rand((len(g), 1), generator=torch.Generator().manual_seed(6))
    common = dict(bounce_light=models.bounce_light, spot_visibility=visibility)
    parts = shade(config, g, models.light, models.lf_light, models.brdf, c2w, split_lights=True, **common)
    assert float(parts[:, 3:].detach().abs().sum()) > 0 and float(parts[:, :3].detach().abs().sum()) > 0
    colour = shade(config, g, models.light, models.lf_light, models.brdf, c2w, **common)
    both = shade(config, g, models.light, models.lf_light, models.brdf, c2w, with_spot_part=True, **common)
    torch.testing.assert_close(both[:, :3], colour, rtol=0, atol=0)
    torch.testing.assert_close(both[:, 3:], parts[:, :3], rtol=0, atol=0)
    # the part carries no gradient: the colour's alone reaches the albedo
    (grad_part,) = torch.autograd.grad(both[:, 3:].sum(), g.params["albedo_raw"], retain_graph=True)
    assert float(grad_part.abs().sum()) == 0
    (grad_both,) = torch.autograd.grad(both.sum(), g.params["albedo_raw"])
    (grad_colour,) = torch.autograd.grad(colour.sum(), g.params["albedo_raw"])
    torch.testing.assert_close(grad_both, grad_colour, rtol=0, atol=0)
    with pytest.raises(ValueError, match="with_spot_part needs a spotlight-lit render"):
        shade(config, g, models.light, models.lf_light, models.brdf, c2w, relight_l0=[1.0, 1.0, 1.0],
              with_spot_part=True)
    with pytest.raises(ValueError, match="with_spot_part needs a spotlight-lit render of a lit variant, not '3dgs'"):
        shade("3dgs", g, None, None, None, c2w, with_spot_part=True)
    with pytest.raises(ValueError, match="already the first half of split_lights"):
        shade(config, g, models.light, models.lf_light, models.brdf, c2w, split_lights=True, with_spot_part=True)


def test_grazing_and_back_facing_light_give_zero_spot_colour_with_finite_gradients():
    # Normal ⟂ light direction (grazing) and pointing away from the lamp (one-sided normals).
    c2w = _look_at_c2w([0.0, -2.0, 0.0], [0.0, 0.0, 0.0])
    g = GaussianParams.from_point_cloud(np.zeros((2, 3)) + [[0, 0, 0], [0.1, 0, 0]], np.full((2, 3), 0.5),
                                        np.array([[0.0, 0.0, 1.0], [0.0, 1.0, 0.0]]))
    cfg = dataclasses.replace(MODEL_VARIANTS["spotless"], two_sided_normals=False)
    m = build_appearance_models(cfg)
    colour = shade(cfg, g, m.light, m.lf_light, m.brdf, c2w)
    assert _scalar(colour[0].abs().max()) < 1e-3 and _scalar(colour[1].abs().max()) == 0.0
    colour.sum().backward()
    assert all(torch.isfinite(p.grad).all() for p in g.parameters() if p.grad is not None)


def test_sh_degree_zero_equals_constant_ambient_variant():
    g = _scene()
    sh0 = ModelConfig("darkgs+sh0", ambient="sh", sh_degree=0, brdf="lambert")
    m = build_appearance_models("darkgs", seed=2)
    lf = LowFrequencyLight(0)
    with torch.no_grad():
        lf.coeffs.fill_(_scalar(m.lf_light.value) / SH_C0)
    torch.testing.assert_close(shade(sh0, g, m.light, lf, m.brdf, CAM), shade("darkgs", g, m.light, m.lf_light, m.brdf, CAM))


@pytest.mark.parametrize("variant", ["darkgs", "darkgs+sh", "darkgs+brdf", "spotless"])
def test_relit_colours_ignore_light_pose_and_camera(variant):
    g = _scene()
    m = build_appearance_models(variant, seed=3)
    if m.lf_light.__class__ is LowFrequencyLight:
        with torch.no_grad():
            m.lf_light.coeffs.normal_(0.0, 0.2, generator=torch.Generator().manual_seed(0))
    l0 = (0.8, 0.9, 1.0)
    relit = shade(variant, g, m.light, m.lf_light, m.brdf, CAM, relight_l0=l0)
    with torch.no_grad():
        m.light.translation.copy_(torch.tensor([0.3, -0.2, 0.1]))
        m.light.rotvec.copy_(torch.tensor([0.2, 0.4, -0.1]))
        m.light.log_tau.fill_(2.0)
    torch.testing.assert_close(shade(variant, g, m.light, m.lf_light, m.brdf, CAM, relight_l0=l0), relit)
    torch.testing.assert_close(shade(variant, g, None, m.lf_light, m.brdf, CAM, relight_l0=l0), relit)
    other = _look_at_c2w([-1.0, -1.5, 3.0], [0.2, 0.1, 0.0])  # same side of the (upward) normals
    torch.testing.assert_close(shade(variant, g, m.light, m.lf_light, m.brdf, other, relight_l0=l0), relit)
    assert _scalar(relit.min()) >= 0.0


def test_relit_lambertian_is_albedo_times_total_light_and_not_clipped():
    g = _scene()
    m = build_appearance_models("darkgs")
    relit = shade("darkgs", g, m.light, m.lf_light, m.brdf, CAM, relight_l0=(4.0, 4.0, 4.0))
    torch.testing.assert_close(relit, g.albedo * (4.0 + m.lf_light.value))
    assert _scalar(relit.max()) > 1.0


def test_relit_learned_reflectance_is_a_bounded_directional_albedo():
    g = _scene()
    normals = orient_normals(g.normals(CAM[:3, 3]), torch.nn.functional.normalize(CAM[:3, 3] - g.means, dim=-1))
    brdf = LearnedBRDF(seed=0)
    args = (g.albedo.detach(), g.roughness.detach(), g.metalness.detach(), normals.detach())
    r = relit_reflectance(*args, brdf, directions=32)
    assert r.shape == (40, 3) and _scalar(r.min()) >= 0.0 and _scalar(r.max()) <= 1.0
    # The 32-direction estimate converges to the directional albedo (reference: 512 directions); ρ = 0.5 keeps the
    # specular lobe wide enough for 32 directions.
    dense = relit_reflectance(*args, brdf, directions=512)
    torch.testing.assert_close(r, dense, rtol=0.05, atol=2e-3)
    # Dielectric (η = 0.01): albedo + ~4 % Fresnel specular, and Burley's factor at ρ = 0.5 is ~1: close to a + 0.04.
    torch.testing.assert_close(dense, args[0] + 0.04, rtol=0.08, atol=0.02)
    torch.testing.assert_close(relit_reflectance(g.albedo, None, None, normals, LambertianBRDF()), g.albedo)


def test_irradiance_reflectance_is_the_learned_reflectance_where_the_clamp_does_not_bite():
    """The irradiance shading's R (the unclamped Disney model's tabulated directional albedo) equals the clamped
    learned BRDF's 512-direction quadrature while the MLP residual is zero and the lobes are wide (ρ ≥ 0.7: f̃ stays
    below 1); gradients reach the material."""
    from spotlessgs.models.brdf import disney_directional_albedo

    g = _scene()
    normals = orient_normals(g.normals(CAM[:3, 3]), torch.nn.functional.normalize(CAM[:3, 3] - g.means, dim=-1))
    albedo, metal = 0.9 * g.albedo.detach(), g.metalness.detach()  # an albedo near 1: Burley's f̃ exceeds 1
    rough = 0.7 + 0.3 * torch.rand(len(albedo), 1, generator=torch.Generator().manual_seed(3))
    full = relit_reflectance(albedo, rough, metal, normals.detach(), LearnedBRDF(seed=0, hidden=16), directions=512)
    torch.testing.assert_close(disney_directional_albedo(albedo, rough, metal), full, rtol=0.02, atol=2e-3)
    leaves = [t.clone().requires_grad_(True) for t in (albedo, rough, metal)]
    disney_directional_albedo(*leaves).sum().backward()
    assert all(t.grad is not None and torch.isfinite(t.grad).all() and _scalar(t.grad.abs().sum()) > 0
               for t in leaves)


def test_hemisphere_directions_are_cosine_weighted():
    d = hemisphere_directions(512, torch.float64)
    np.testing.assert_allclose(d.norm(dim=-1).numpy(), 1.0, atol=1e-12)
    assert _scalar(d[:, 2].min()) > 0.0
    # (1/π) ∫ cos · cos dω = 2/3 and (1/π) ∫ x · cos dω = 0.
    assert _scalar(d[:, 2].mean()) == pytest.approx(2 / 3, abs=2e-3)
    assert abs(_scalar(d[:, 0].mean())) < 5e-3


def test_relit_reflectance_uses_a_full_hemisphere_around_any_normal():
    normals = torch.tensor(Rotation.random(50, random_state=0).apply([0.0, 0.0, 1.0]), dtype=torch.float32)
    normals[0] = torch.tensor([0.0, 0.0, -1.0])  # the branch point of the basis construction
    calls = []

    class Probe(LearnedBRDF):
        def forward(self, albedo, roughness, metalness, n, v, l):  # noqa: D401 - records the light directions
            calls.append((n * l).sum(-1))
            return albedo

    relit_reflectance(torch.ones(50, 3), torch.ones(50, 1), torch.zeros(50, 1), normals, Probe(), directions=64)
    cosines = torch.stack(calls)  # (64, 50)
    assert _scalar(cosines.min()) > 0.0
    np.testing.assert_allclose(cosines.mean(0).numpy(), 2 / 3, atol=5e-3)


def test_config_and_module_errors():
    g = _scene(5)
    m = build_appearance_models("spotless")
    with pytest.raises(ValueError, match=r"unknown model variant 'nerf'; known: \['3dgs'"):
        shade("nerf", g, m.light, m.lf_light, m.brdf, CAM)
    with pytest.raises(ValueError, match="needs a ConstantAmbient, got LowFrequencyLight"):
        shade("darkgs", g, m.light, m.lf_light, LambertianBRDF(), CAM)
    with pytest.raises(ValueError, match="needs a LambertianBRDF, got LearnedBRDF"):
        shade("darkgs+sh", g, m.light, m.lf_light, m.brdf, CAM)
    with pytest.raises(ValueError, match="needs a SpotLight, got NoneType"):
        shade("spotless", g, None, m.lf_light, m.brdf, CAM)
    with pytest.raises(ValueError, match="wants SH degree 3, the LowFrequencyLight has 1"):
        shade("spotless", g, m.light, LowFrequencyLight(1), m.brdf, CAM)
    with pytest.raises(ValueError, match="relight_l0 must be three finite non-negative"):
        shade("spotless", g, m.light, m.lf_light, m.brdf, CAM, relight_l0=(1.0, -1.0, 1.0))
    with pytest.raises(ValueError, match=r"c2w must be a \(4, 4\)"):
        shade("spotless", g, m.light, m.lf_light, m.brdf, CAM[:3])
    with pytest.raises(ValueError, match="light_model must be 'none' or 'spotlight'"):
        ModelConfig("x", light_model="lamp")
    with pytest.raises(ValueError, match="ambient must be 'none', 'constant' or 'sh'"):
        ModelConfig("x", ambient="env")
    with pytest.raises(ValueError, match="brdf must be 'lambert' or 'mlp'"):
        ModelConfig("x", brdf="phong")
    with pytest.raises(ValueError, match="ambient 'none' goes with light_model 'none' only"):
        ModelConfig("x", ambient="none")
    with pytest.raises(ValueError, match="calibrated needs light_model 'spotlight'"):
        ModelConfig("x", light_model="none", ambient="none", calibrated=True)
    with pytest.raises(ValueError, match="SH degree must be an integer"):
        ModelConfig("x", sh_degree=5)
    with pytest.raises(ValueError, match="relight_directions must be >= 1"):
        ModelConfig("x", relight_directions=0)
    with pytest.raises(ValueError, match="brdf_hidden must be >= 1"):
        ModelConfig("x", brdf_hidden=0)
    with pytest.raises(dataclasses.FrozenInstanceError):
        MODEL_VARIANTS["spotless"].brdf = "lambert"


def test_calibrated_build_freezes_pose_and_fits_cone():
    calibrated = dataclasses.replace(MODEL_VARIANTS["darkgs"], calibrated=True)
    with pytest.raises(ValueError, match="is calibrated: pass light_translation"):
        build_appearance_models(calibrated)
    m = build_appearance_models(calibrated, light_translation=[0.1, 0.0, 0.0], cone=(math.radians(40), 0.5))
    assert not m.light.translation.requires_grad and not m.light.rotvec.requires_grad
    curve = m.light.rid_curve([0.0, math.radians(60)])
    assert _scalar(curve[0]) == pytest.approx(1.0, abs=0.05) and _scalar(curve[1]) < 0.05
    small = build_appearance_models(dataclasses.replace(MODEL_VARIANTS["spotless"], brdf_hidden=32))
    assert small.brdf.mlp[0].out_features == 32 and small.brdf.mlp[0].in_features == 117
    assert build_appearance_models("3dgs").module_dict() is not None and len(build_appearance_models("3dgs").module_dict()) == 0


def test_spotless_gradients_match_central_differences():
    g = _scene(12, seed=5).double()
    m = build_appearance_models("spotless", seed=4)
    m.module_dict().double()
    with torch.no_grad():
        m.lf_light.coeffs.normal_(0.0, 0.3, generator=torch.Generator().manual_seed(1))
        m.lf_light.coeffs[0] += 1.0
        m.brdf.mlp[-1].weight.normal_(0.0, 0.1, generator=torch.Generator().manual_seed(2))
        m.light.translation.copy_(torch.tensor([0.05, -0.02, 0.01]))
    cam = CAM.double()
    weights = torch.rand(12, 3, dtype=torch.float64, generator=torch.Generator().manual_seed(3))

    def loss() -> torch.Tensor:
        return (shade("spotless", g, m.light, m.lf_light, m.brdf, cam) * weights).sum()

    loss().backward()
    probes = [
        (g.params["means"], (0, 1)), (g.params["albedo_raw"], (1, 2)), (g.params["normals_raw"], (2, 0)),
        (g.params["roughness_raw"], (3,)), (g.params["metalness_raw"], (4,)), (m.light.translation, (2,)),
        (m.light.rotvec, (0,)), (m.light.log_gamma, ()), (m.light.log_tau, ()), (m.lf_light.coeffs, (1, 0)),
        (m.brdf.mlp[-1].bias, (0,)),
    ]
    h = 1e-6
    for param, idx in probes:
        with torch.no_grad():
            old = param[idx].clone()
            param[idx] = old + h
            up = loss()
            param[idx] = old - h
            down = loss()
            param[idx] = old
        numeric = _scalar((up - down) / (2 * h))
        assert _scalar(param.grad[idx]) == pytest.approx(numeric, rel=1e-4, abs=1e-8), f"gradient of {tuple(param.shape)}{idx}"


def test_falloff_initial_values_and_freezing():
    """The fall-off starts at the config's τ and γ; frozen, it gets no gradient and the trainer leaves it out of the
    optimiser; τ or γ that is not > 0 is refused."""
    from spotlessgs.training.config import TrainConfig
    from spotlessgs.models.relightable import RelightableScene
    from spotlessgs.training.trainer import build_optimizers, model_config

    config = dataclasses.replace(MODEL_VARIANTS["darkgs"], falloff_tau=0.01, falloff_gamma=1.0, learn_falloff=False)
    light = build_appearance_models(config).light
    assert _scalar(light.tau) == pytest.approx(0.01) and _scalar(light.gamma) == pytest.approx(1.0)
    assert not light.log_tau.requires_grad and not light.log_gamma.requires_grad
    x_l = torch.tensor([[0.0, 0.0, 2.0]])
    assert _scalar(light.falloff(x_l)) == pytest.approx(1.0 / 4.01)  # (τ + d²)^(-γ) by hand
    assert build_appearance_models("darkgs").light.log_tau.requires_grad  # learns by default
    with pytest.raises(ValueError, match="falloff_tau and falloff_gamma must be finite and > 0"):
        dataclasses.replace(MODEL_VARIANTS["darkgs"], falloff_tau=0.0)
    train = TrainConfig(falloff_tau=0.02, learn_falloff=False)
    frozen = model_config("darkgs", train)
    assert (frozen.falloff_tau, frozen.learn_falloff) == (0.02, False)
    scene = RelightableScene.create(frozen, _scene(), seed=0)
    optimised = {id(p) for opt in build_optimizers(scene, train, extent=1.0).values()
                 for group in opt.param_groups for p in group["params"]}
    light = scene.appearance.light
    assert id(light.log_tau) not in optimised and id(light.log_gamma) not in optimised
    assert id(next(light.rid.parameters())) in optimised


def test_unclamped_learned_brdf_relights_with_the_tabulated_directional_albedo():
    """brdf_upper_clamp=False: the relit colour is the Disney model's directional albedo × (L0 + L_lf), in both
    low-frequency shadings; the clamped default keeps the quadrature of the clamped model."""
    from spotlessgs.models.brdf import disney_directional_albedo

    g = _scene()
    for shading in ("spot_cosine", "irradiance"):
        config = dataclasses.replace(MODEL_VARIANTS["spotless"], brdf_hidden=16, brdf_upper_clamp=False,
                                     low_frequency_shading=shading)
        models = build_appearance_models(config, seed=1)
        assert not models.brdf.upper_clamp
        relit = shade(config, g, None, models.lf_light, models.brdf, CAM, relight_l0=[1.0, 1.0, 1.0])
        expected = disney_directional_albedo(g.albedo, g.roughness, g.metalness)  # L_lf starts at 0
        torch.testing.assert_close(relit, expected, rtol=1e-5, atol=1e-6)
    models = build_appearance_models(dataclasses.replace(MODEL_VARIANTS["spotless"], brdf_hidden=16), seed=1)
    assert models.brdf.upper_clamp


def test_lambertian_diffuse_setting_reaches_the_learned_brdf_and_its_relit_albedo():
    """TrainConfig.brdf_burley_diffuse=False reaches the learned BRDF through model_config, and an unclamped model
    relights with the table of the Lambertian lobe: a rough dielectric's directional albedo differs from Burley's."""
    from spotlessgs.models.brdf import disney_directional_albedo
    from spotlessgs.training.config import TrainConfig
    from spotlessgs.training.trainer import model_config

    config = model_config("spotless", TrainConfig(brdf_hidden=16, brdf_burley_diffuse=False, brdf_upper_clamp=False))
    assert not config.brdf_burley_diffuse
    models = build_appearance_models(config, seed=1)
    assert not models.brdf.burley
    g = _scene()
    relit = shade(config, g, None, models.lf_light, models.brdf, CAM, relight_l0=[1.0, 1.0, 1.0])
    torch.testing.assert_close(relit, disney_directional_albedo(g.albedo, g.roughness, g.metalness, burley=False),
                               rtol=1e-5, atol=1e-6)
    assert not torch.allclose(relit, disney_directional_albedo(g.albedo, g.roughness, g.metalness), atol=1e-3)
    assert build_appearance_models(model_config("spotless", TrainConfig(brdf_hidden=16)), seed=1).brdf.burley


def test_brdf_network_input_gradients_setting_reaches_the_learned_brdf():
    """TrainConfig.brdf_network_input_gradients reaches the learned BRDF through model_config (the paper's by
    default), and with it off a spotlit colour's gradient to the Gaussians' positions no longer has the network's."""
    from spotlessgs.training.config import TrainConfig
    from spotlessgs.training.trainer import model_config

    off = model_config("darkgs+brdf", TrainConfig(brdf_hidden=16, brdf_network_input_gradients=False))
    assert not build_appearance_models(off, seed=1).brdf.input_gradients
    assert build_appearance_models(model_config("darkgs+brdf", TrainConfig(brdf_hidden=16)), seed=1).brdf.input_gradients
    position_grads = []
    for config in (model_config("darkgs+brdf", TrainConfig(brdf_hidden=16)), off):
        models = build_appearance_models(config, seed=1)
        with torch.no_grad():
            models.brdf.mlp[-1].weight.fill_(0.5)  # a non-zero residual
        g = _scene()
        g.means.requires_grad_(True)
        shade(config, g, models.light, models.lf_light, models.brdf, CAM).sum().backward()
        position_grads.append(g.means.grad.clone())
    assert not torch.allclose(position_grads[0], position_grads[1])


def _rotated(g: GaussianParams, q: np.ndarray) -> GaussianParams:
    """The Gaussians' positions and normals turned by the rotation q (3, 3) about the origin (same colours)."""
    with torch.no_grad():
        means, normals = g.means.double().numpy() @ q.T, g.normals(torch.zeros(3)).double().numpy() @ q.T
        albedo = g.albedo.double().numpy()
    return GaussianParams.from_point_cloud(means, albedo, normals, rgb_is_srgb=False)


def test_bounce_light_moves_with_the_camera_and_is_left_out_of_relighting():
    """The bounce light is an SH of the normal in the camera frame: turning the whole scene and the camera together
    leaves the colour unchanged (the spotlight is camera-borne too), which a world-frame SH light does not; it adds to
    the low-frequency half of the split; relighting never sees it; by hand, head-on: a (L_spot + A + b)."""
    config = dataclasses.replace(MODEL_VARIANTS["darkgs+sh"], bounce_light_degree=2)
    models = build_appearance_models(config, seed=1)
    assert isinstance(models.bounce_light, LowFrequencyLight) and models.bounce_light.degree == 2
    assert "bounce_light" in models.module_dict()
    g = _scene()
    q = Rotation.from_rotvec([0.4, -0.7, 1.1]).as_matrix()
    turned_cam = CAM.clone()
    turned_cam[:3, :3] = torch.as_tensor(q, dtype=CAM.dtype) @ CAM[:3, :3]
    turned_cam[:3, 3] = torch.as_tensor(q, dtype=CAM.dtype) @ CAM[:3, 3]
    at_zero = shade(config, g, models.light, models.lf_light, models.brdf, CAM, bounce_light=models.bounce_light)
    torch.testing.assert_close(at_zero, shade("darkgs+sh", g, models.light, models.lf_light, models.brdf, CAM))
    with torch.no_grad():
        models.bounce_light.coeffs.normal_(0.0, 0.3, generator=torch.Generator().manual_seed(5))
        models.bounce_light.coeffs[0] = 0.5  # positive somewhere

    def colour(scene, cam):
        return shade(config, scene, models.light, models.lf_light, models.brdf, cam, bounce_light=models.bounce_light)

    with_bounce = colour(g, CAM)
    assert float((with_bounce - at_zero).detach().abs().max()) > 1e-2
    torch.testing.assert_close(colour(_rotated(g, q), turned_cam), with_bounce, rtol=1e-4, atol=1e-5)
    with torch.no_grad():  # a world-frame light is not invariant: the check above can fail
        models.lf_light.coeffs[:9] = models.bounce_light.coeffs
    assert float((colour(_rotated(g, q), turned_cam) - colour(g, CAM)).detach().abs().max()) > 1e-2
    parts = shade(config, g, models.light, models.lf_light, models.brdf, CAM, split_lights=True,
                  bounce_light=models.bounce_light)
    torch.testing.assert_close(parts[:, :3] + parts[:, 3:], colour(g, CAM))
    relit = shade(config, g, models.light, models.lf_light, models.brdf, CAM, relight_l0=[1.0, 1.0, 1.0],
                  bounce_light=models.bounce_light)
    torch.testing.assert_close(relit, shade(config, g, models.light, models.lf_light, models.brdf, CAM,
                                            relight_l0=[1.0, 1.0, 1.0]))
    # By hand: a Gaussian facing the camera head-on has the camera-frame normal (0, 0, -1); a degree-0 bounce light
    # b adds to DarkGS's constant ambient A inside the spotlight's cosine (the paper's shading).
    c2w = _look_at_c2w([0.0, -2.0, 0.0], [0.0, 0.0, 0.0], torch.float64)
    one = GaussianParams.from_point_cloud(np.zeros((1, 3)), np.array([[0.2, 0.5, 0.8]]), np.array([[0.0, -1.0, 0.0]]),
                                          rgb_is_srgb=False).double()
    flat = dataclasses.replace(MODEL_VARIANTS["darkgs+sh"], sh_degree=0, bounce_light_degree=0)
    m = build_appearance_models(flat, seed=0)
    m.module_dict().double()
    with torch.no_grad():
        m.lf_light.coeffs.fill_(0.05 / SH_C0)  # an ambient 0.05
        m.bounce_light.coeffs.fill_(0.1 / SH_C0)  # radiance 0.1
    got = shade(flat, one, m.light, m.lf_light, m.brdf, c2w, bounce_light=m.bounce_light)
    spot = _scalar(m.light.rid_curve([0.0])[0]) / (0.3 + 4.0)
    np.testing.assert_allclose(got.detach().numpy()[0], np.array([0.2, 0.5, 0.8]) * (spot + 0.05 + 0.1), rtol=1e-5)
    with pytest.raises(ValueError, match="bounce light degree 0"):
        shade(flat, one, m.light, m.lf_light, m.brdf, c2w)
    with pytest.raises(ValueError, match="degree"):
        dataclasses.replace(MODEL_VARIANTS["darkgs+sh"], bounce_light_degree=4)
    # only an SH light has a bounce light: DarkGS's constant ambient and 3DGS ignore the setting
    for name in ("3dgs", "darkgs", "darkgs+brdf"):
        cfg = dataclasses.replace(MODEL_VARIANTS[name], bounce_light_degree=2)
        assert cfg.bounce_degree == -1 and build_appearance_models(cfg).bounce_light is None


def test_the_low_frequency_light_can_be_kept_from_turning_the_normals():
    """low_frequency_turns_normals=False: the same colours, but the SH light (and the SH bounce light) pass no
    gradient to the normals; relit by a Lambertian BRDF the normals then get none at all (the albedo still does)."""
    base = dataclasses.replace(MODEL_VARIANTS["darkgs+sh"], bounce_light_degree=2)
    for turns in (True, False):
        g = _scene()
        cfg = dataclasses.replace(base, low_frequency_turns_normals=turns)
        m = build_appearance_models(cfg, seed=0)
        with torch.no_grad():
            m.lf_light.coeffs.normal_(0.0, 0.3, generator=torch.Generator().manual_seed(3))
            m.lf_light.coeffs[0] = 0.8
            m.bounce_light.coeffs.normal_(0.0, 0.3, generator=torch.Generator().manual_seed(4))
        lit = shade(cfg, g, m.light, m.lf_light, m.brdf, CAM, bounce_light=m.bounce_light)
        relit = shade(cfg, g, m.light, m.lf_light, m.brdf, CAM, relight_l0=[0.2, 0.2, 0.2])
        if turns:
            reference = (lit.detach(), relit.detach())
        else:
            torch.testing.assert_close(lit, reference[0])
            torch.testing.assert_close(relit, reference[1])
        relit.sum().backward()
        normal_grad = g.params["normals_raw"].grad
        assert (normal_grad is not None and float(normal_grad.abs().sum()) > 0) == turns
        assert float(g.params["albedo_raw"].grad.abs().sum()) > 0
