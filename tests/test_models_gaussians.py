"""Gaussian parameters: initialisation values, nearest-neighbour scales on hard inputs, activations, normals."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from spotlessgs.io.colorspace import srgb_to_linear
from spotlessgs.models.gaussians import PARAM_NAMES, GaussianParams, initial_scales, logit_roughness



def _scalar(x) -> float:
    """A Python float of a number or a one-element tensor (detached)."""
    return float(x.detach()) if isinstance(x, torch.Tensor) else float(x)


def _cloud(n: int = 10, seed: int = 0):
    rng = np.random.default_rng(seed)
    return rng.normal(size=(n, 3)), rng.integers(0, 256, size=(n, 3)).astype(np.uint8)


def test_initial_values_follow_the_paper():
    xyz, rgb = _cloud()
    rgb[0] = [128, 0, 255]
    normals = np.tile([0.0, 0.0, 2.0], (10, 1))
    g = GaussianParams.from_point_cloud(xyz, rgb, normals)
    assert len(g) == 10 and sorted(g.params.keys()) == sorted(PARAM_NAMES)
    np.testing.assert_allclose(g.roughness.detach().numpy(), 0.5, rtol=1e-6)
    np.testing.assert_allclose(g.metalness.detach().numpy(), 0.01, rtol=1e-5)
    np.testing.assert_allclose(g.opacities.detach().numpy(), 0.1, rtol=1e-6)
    # sRGB 128/255 → ((0.50196 + 0.055)/1.055)^2.4 = 0.21586; 0 → clamped to 0.01; 255 → 1 → clamped to 0.99.
    np.testing.assert_allclose(g.albedo[0].detach().numpy(), [0.2158605, 0.01, 0.99], rtol=1e-5)
    np.testing.assert_allclose(g.quats.detach().numpy(), np.tile([1.0, 0, 0, 0], (10, 1)))
    np.testing.assert_allclose(g.params["normals_raw"].detach().numpy(), np.tile([0, 0, 1.0], (10, 1)))
    assert g.sh_colour_coeffs().shape == (10, 16, 3)


def test_srgb_linearisation_hand_values():
    np.testing.assert_allclose(srgb_to_linear([0.0, 0.04045, 0.5, 1.0]), [0.0, 0.04045 / 12.92, 0.21404114, 1.0], rtol=1e-7)


def test_scales_are_mean_distance_to_three_neighbours():
    xyz = np.array([[0.0, 0, 0], [1.0, 0, 0], [3.0, 0, 0], [6.0, 0, 0]])
    np.testing.assert_allclose(initial_scales(xyz), [(1 + 3 + 6) / 3, (1 + 2 + 5) / 3, (2 + 3 + 3) / 3, (3 + 5 + 6) / 3])
    g = GaussianParams.from_point_cloud(xyz, np.full((4, 3), 0.5))
    np.testing.assert_allclose(g.scales[:, 0].detach().numpy(), [10 / 3, 8 / 3, 8 / 3, 14 / 3], rtol=1e-6)


def test_extreme_scales_duplicates_single_and_pairs():
    dup = np.array([[0.0, 0, 0]] * 4 + [[1.0, 0, 0], [2.0, 0, 0], [3.0, 0, 0]])
    s = initial_scales(dup)
    assert np.isfinite(s).all() and (s > 0).all()
    positive = [1.0, 1.0, 1.0, 1.0, 1.0, 1.0, 1.0, 1.0, 1.0, 2.0, 1.0, 2.0, 1.0, 2.0, 3.0]  # the nonzero NN distances
    assert s[:4].min() >= 0.1 * np.median(positive) - 1e-12  # duplicates (all-zero distances) get the floor
    np.testing.assert_allclose(initial_scales(np.zeros((5, 3))), 0.01)  # all identical
    np.testing.assert_allclose(initial_scales(np.ones((1, 3))), 0.01)  # single point
    np.testing.assert_allclose(initial_scales(np.array([[0.0, 0, 0], [0, 0, 2.0]])), [2.0, 2.0])  # k = 1
    g = GaussianParams.from_point_cloud(np.zeros((3, 3)), np.zeros((3, 3)))
    assert torch.isfinite(g.params["log_scales"]).all()


def test_zero_normal_faces_camera_with_finite_nonzero_gradient():
    g = GaussianParams.from_point_cloud(np.array([[0.0, 0, 0], [1.0, 0, 0]]), np.full((2, 3), 0.5), None)
    cam = torch.tensor([0.0, 0.0, 5.0])
    n = g.normals(cam)
    torch.testing.assert_close(n[0], torch.tensor([0.0, 0.0, 1.0]))
    torch.testing.assert_close(n[1], torch.nn.functional.normalize(cam - torch.tensor([1.0, 0, 0]), dim=0))
    (n * torch.tensor([1.0, 2.0, 3.0])).sum().backward()
    grad = g.params["normals_raw"].grad
    assert torch.isfinite(grad).all() and _scalar(grad.abs().sum()) > 0


def test_held_normals_carry_no_gradient_unless_a_row_falls_back_to_the_camera():
    """Held normals (normals_raw without a gradient) whose fallback weight is 0 on every row give n̂ without a gradient
    (the same values as the full formula); one raw row near 0 keeps the path through f̂ to the means for all rows, and
    learned normals always have it."""
    normals = np.array([[0.0, 1.0, 0.0], [0.6, 0.0, 0.8], [0.0, 0.0, -1.0]])
    g = GaussianParams.from_point_cloud(np.array([[0.0, 0, 0], [1.0, 1, 1], [2.0, 0, 1]]), np.full((3, 3), 0.5),
                                        normals)
    cam = torch.tensor([3.0, -2.0, 1.0])
    learned = g.normals(cam)
    assert learned.requires_grad
    g.params["normals_raw"].requires_grad_(False)
    held = g.normals(cam)
    assert not held.requires_grad
    torch.testing.assert_close(held, learned.detach(), rtol=0, atol=0)
    with torch.no_grad():
        g.params["normals_raw"][2] = 1e-3 * torch.tensor([0.0, 0.0, 1.0])  # |raw| = δ: the fallback weight is δ/e
    falling_back = g.normals(cam)
    assert falling_back.requires_grad
    (falling_back * torch.tensor([1.0, 2.0, 3.0])).sum().backward()
    assert _scalar(g.params["means"].grad[2].abs().sum()) > 0  # that row turns with its position, as before
    assert _scalar(g.params["means"].grad[:2].abs().sum()) == 0  # the others' weights are exactly 0


def test_unit_normals_are_kept_and_fully_degenerate_normal_is_finite():
    normals = np.array([[0.0, 1.0, 0.0], [0.6, 0.0, 0.8]])
    g = GaussianParams.from_point_cloud(np.array([[0.0, 0, 0], [1.0, 1, 1]]), np.full((2, 3), 0.5), normals)
    cam = torch.tensor([3.0, -2.0, 1.0])
    np.testing.assert_array_equal(g.normals(cam).detach().numpy(), g.normals(-cam).detach().numpy())
    np.testing.assert_allclose(g.normals(cam).detach().numpy(), normals, atol=1e-7)
    # raw = -δ u f̂ with u = exp(-u²) cancels the fallback term; a Gaussian at the camera centre has no direction.
    u = 0.5
    for _ in range(30):  # Newton on u - exp(-u²)
        u -= (u - math.exp(-u * u)) / (1 + 2 * u * math.exp(-u * u))
    g = g.double()
    cam = cam.double()
    with torch.no_grad():
        f = torch.nn.functional.normalize(cam - g.means[0], dim=0)
        g.params["normals_raw"][0] = -1e-3 * u * f
        g.params["means"][1] = cam
    n = g.normals(cam)
    assert torch.isfinite(n).all()
    np.testing.assert_allclose(n.norm(dim=-1).detach().numpy(), 1.0, rtol=1e-6)
    n.sum().backward()
    assert torch.isfinite(g.params["normals_raw"].grad).all() and torch.isfinite(g.params["means"].grad).all()


def test_activations_stay_in_their_open_intervals_with_finite_gradients():
    xyz, rgb = _cloud(4)
    g = GaussianParams.from_point_cloud(xyz, rgb)
    with torch.no_grad():
        g.params["roughness_raw"].copy_(torch.tensor([-1e4, 1e4, 0.0, 30.0]))
        g.params["metalness_raw"].copy_(torch.tensor([-1e4, 1e4, 0.0, -30.0]))
        g.params["quats"][0] = 0.0
    r, m = g.roughness.detach(), g.metalness.detach()
    # float32 sigmoid saturates to exactly 0/1, so the bounds are reached (never passed) at extreme raw values.
    assert _scalar(r.min()) >= 0.09 - 1e-7 and _scalar(r.max()) <= 0.99 + 1e-7 and r.shape == (4, 1) and m.shape == (4, 1)
    assert _scalar(m.min()) >= 0.0 and _scalar(m.max()) <= 1.0
    torch.testing.assert_close(g.quats[0], torch.tensor([1.0, 0, 0, 0]))
    (g.roughness.sum() + g.metalness.sum() + g.quats.sum()).backward()
    assert all(torch.isfinite(g.params[k].grad).all() for k in ("roughness_raw", "metalness_raw", "quats"))
    assert logit_roughness(0.5) == pytest.approx(math.log(0.41 / 0.49), rel=1e-12)


@pytest.mark.parametrize("backend", ["torch", "cpp"])
def test_a_log_scale_beyond_float32s_range_covers_the_view_with_finite_gradients(backend):
    """e^88.8 overflows float32: without the limit the rasterizer's R·S is 0·inf = NaN, the Gaussian silently
    vanishes and every gradient of it is NaN. At the limit (e^30 m) it covers the view like any huge Gaussian."""
    from spotlessgs.rasterizer import rasterize

    g = GaussianParams.from_point_cloud(np.array([[0.0, 0.0, 2.0]]), np.full((1, 3), 200, np.uint8))
    K = torch.tensor([[30.0, 0.0, 16.0], [0.0, 30.0, 12.0], [0.0, 0.0, 1.0]])
    alphas = {}
    for log_scale in (20.0, 88.8):
        with torch.no_grad():
            g.params["log_scales"].fill_(log_scale)
        g.zero_grad()
        out = rasterize(g.means, g.quats, g.scales, g.opacities, torch.ones(1, 3), torch.eye(4), K, 32, 24,
                        backend=backend)
        out.image.sum().backward()
        alphas[log_scale] = out.alpha.detach()
        for name in ("means", "quats", "log_scales", "opacity_logits"):
            assert torch.isfinite(g.params[name].grad).all(), (log_scale, name)
    assert float(alphas[88.8].min()) > 0.05  # every pixel covered (the initial opacity is 0.1)
    torch.testing.assert_close(alphas[88.8], alphas[20.0])


def test_parameter_dict_supports_indexing_for_densification():
    xyz, rgb = _cloud(6)
    g = GaussianParams.from_point_cloud(xyz, rgb)
    keep = torch.tensor([0, 2, 5])
    sub = GaussianParams({k: v.detach()[keep] for k, v in g.params.items()})
    assert len(sub) == 3
    torch.testing.assert_close(sub.albedo, g.albedo.detach()[keep])
    assert all(isinstance(p, torch.nn.Parameter) for p in sub.params.values())


def test_errors():
    xyz, rgb = _cloud(3)
    with pytest.raises(ValueError, match=r"non-empty \(N, 3\) array, got shape \(0, 3\)"):
        GaussianParams.from_point_cloud(np.zeros((0, 3)), np.zeros((0, 3)))
    bad = xyz.copy()
    bad[1, 0] = np.nan
    with pytest.raises(ValueError, match="1 non-finite rows"):
        GaussianParams.from_point_cloud(bad, rgb)
    with pytest.raises(ValueError, match=r"rgb must have shape \(3, 3\), got \(2, 3\)"):
        GaussianParams.from_point_cloud(xyz, rgb[:2])
    with pytest.raises(ValueError, match=r"float rgb must be finite and in \[0, 1\]"):
        GaussianParams.from_point_cloud(xyz, rgb.astype(np.float64))
    with pytest.raises(ValueError, match=r"normals must be a finite \(3, 3\) array"):
        GaussianParams.from_point_cloud(xyz, rgb, np.zeros((3, 2)))
    g = GaussianParams.from_point_cloud(xyz, rgb)
    params = {k: v.detach() for k, v in g.params.items()}
    with pytest.raises(ValueError, match=r"missing parameters \['shN'\], unknown parameters \['extra'\]"):
        GaussianParams({**{k: v for k, v in params.items() if k != "shN"}, "extra": torch.zeros(3)})
    with pytest.raises(ValueError, match=r"'albedo_raw' must have shape \(3, 3\), got \(3, 4\)"):
        GaussianParams({**params, "albedo_raw": torch.zeros(3, 4)})
    with pytest.raises(ValueError, match=r"camera_center must have shape \(3,\)"):
        g.normals(torch.zeros(1, 3))
    with pytest.raises(ValueError, match=r"roughness must be in \(0.09, 0.99"):
        logit_roughness(0.05)


def test_the_shortest_axis_is_a_flat_splats_normal_and_the_normal_shape_term_measures_the_angle():
    """A splat flat along its local y axis (scales 1, 0.01, 1), rotated 90° about x: its shortest axis is world ±z.
    The normal-shape term is 1 - |cos| of the angle between normal and axis, over the visible Gaussians only."""
    from spotlessgs.training.losses import normal_shape_loss

    half = math.sqrt(0.5)
    g = GaussianParams.from_point_cloud(np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0]]), np.full((2, 3), 128, np.uint8),
                                        normals=np.array([[0.0, 0.0, -1.0], [1.0, 0.0, 1.0]]))
    with torch.no_grad():
        g.params["quats"].copy_(torch.tensor([[half, half, 0.0, 0.0], [1.0, 0.0, 0.0, 0.0]]))
        g.params["log_scales"].copy_(torch.log(torch.tensor([[1.0, 0.01, 1.0], [1.0, 1.0, 0.01]])))
    axes = g.shortest_axes()
    np.testing.assert_allclose(axes.abs().detach().numpy(), [[0.0, 0.0, 1.0], [0.0, 0.0, 1.0]], atol=1e-6)
    normals = g.normals(torch.tensor([0.0, 0.0, 5.0]))
    both = normal_shape_loss(normals, axes, torch.tensor([True, True]))
    assert _scalar(both) == pytest.approx((0.0 + (1.0 - half)) / 2, abs=1e-6)  # anti-parallel counts as aligned
    assert float(normal_shape_loss(normals, axes, torch.tensor([True, False])).detach()) == pytest.approx(0.0, abs=1e-6)
    assert float(normal_shape_loss(normals, axes, torch.tensor([False, False])).detach()) == 0.0
    both.backward()
    assert g.params["quats"].grad.abs().sum() > 0 and g.params["normals_raw"].grad.abs().sum() > 0
