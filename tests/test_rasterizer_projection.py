"""Projection (quaternion + scale → EWA 2D Gaussian) against an independent numpy implementation, plus hard cases."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch
from rasterizer_reference import camera, project_numpy, quat_to_rotmat_numpy, random_scene
from scipy.spatial.transform import Rotation

from spotlessgs.rasterizer import covariance_3d, project_gaussians, quat_to_rotmat
from spotlessgs.rasterizer.projection import ALPHA_MIN


def _tilted_view() -> torch.Tensor:
    view = torch.eye(4, dtype=torch.float64)
    view[:3, :3] = torch.from_numpy(Rotation.from_euler("xyz", [0.2, -0.3, 0.1]).as_matrix())
    view[:3, 3] = torch.tensor([0.2, -0.1, 0.5], dtype=torch.float64)
    return view


def test_rotation_matches_scipy_and_is_orthonormal():
    q = torch.randn(64, 4, dtype=torch.float64, generator=torch.Generator().manual_seed(3)) * 2.5
    rot = quat_to_rotmat(q)
    expected = Rotation.from_quat(q[:, [1, 2, 3, 0]].numpy()).as_matrix()  # scipy stores (x, y, z, w)
    np.testing.assert_allclose(rot.numpy(), expected, atol=1e-12)
    np.testing.assert_allclose((rot @ rot.transpose(1, 2)).numpy(), np.broadcast_to(np.eye(3), (64, 3, 3)), atol=1e-12)
    np.testing.assert_allclose(quat_to_rotmat_numpy(q[0].numpy()), expected[0], atol=1e-12)


def test_zero_quaternion_is_identity_with_finite_gradient():
    q = torch.zeros(2, 4, dtype=torch.float64, requires_grad=True)
    rot = quat_to_rotmat(q)
    np.testing.assert_array_equal(rot.detach().numpy(), np.broadcast_to(np.eye(3), (2, 3, 3)))
    rot.sum().backward()
    assert torch.isfinite(q.grad).all()


def test_covariance_is_rotated_scale_squared():
    # 90° about z swaps the x and y axes: diag(sx², sy², sz²) becomes diag(sy², sx², sz²).
    q = torch.tensor([[math.cos(math.pi / 4), 0.0, 0.0, math.sin(math.pi / 4)]], dtype=torch.float64)
    s = torch.tensor([[0.1, 0.3, 0.2]], dtype=torch.float64)
    np.testing.assert_allclose(covariance_3d(q, s)[0].numpy(), np.diag([0.09, 0.01, 0.04]), atol=1e-15)


@pytest.mark.parametrize("view_kind", ["identity", "tilted"])
def test_projection_matches_independent_numpy(view_kind):
    width, height = 64, 48
    means, quats, scales, opac, _ = (t.detach() for t in random_scene(200, 1, seed=1))
    view, K = camera(width, height)
    K[0, 2], K[1, 1] = 30.0, 65.0  # off-centre principal point, non-square pixels
    if view_kind == "tilted":
        view = _tilted_view()
    proj = project_gaussians(means, quats, scales, opac, view, K, width, height)
    ref_m, ref_c, ref_d, ref_cov = project_numpy(means.numpy(), quats.numpy(), scales.numpy(), view.numpy(),
                                                 K.numpy(), width, height)
    ok = ref_d > 0.01
    np.testing.assert_allclose(proj.means2d.numpy()[ok], ref_m[ok], rtol=1e-10, atol=1e-9)
    np.testing.assert_allclose(proj.conics.numpy()[ok], ref_c[ok], rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(proj.cov2d.numpy()[ok], ref_cov[ok], rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(proj.depths.numpy(), ref_d, rtol=1e-12)


def test_float32_projection_matches_float64():
    width, height = 64, 48
    scene = [t.detach() for t in random_scene(100, 1, seed=2)]
    view, K = camera(width, height)
    p64 = project_gaussians(*scene[:4], view, K, width, height)
    p32 = project_gaussians(*(t.float() for t in scene[:4]), view.float(), K.float(), width, height)
    assert p32.means2d.dtype == torch.float32
    np.testing.assert_allclose(p32.means2d.double().numpy(), p64.means2d.numpy(), rtol=1e-5, atol=1e-4)
    np.testing.assert_allclose(p32.conics.double().numpy(), p64.conics.numpy(), rtol=1e-4, atol=1e-6)


def test_radius_bounds_every_pixel_above_the_alpha_threshold():
    # Outside the bounding box the Gaussian's alpha must be < 1/255 (tile culling then changes no pixel).
    width, height = 64, 48
    means, quats, scales, opac, _ = (t.detach() for t in random_scene(60, 1, seed=4))
    view, K = camera(width, height)
    proj = project_gaussians(means, quats, scales, opac, view, K, width, height)
    ys, xs = torch.meshgrid(torch.arange(-40, 110, dtype=torch.float64) + 0.5,
                            torch.arange(-40, 110, dtype=torch.float64) + 0.5, indexing="ij")
    for i in torch.nonzero(proj.visible).squeeze(1).tolist():
        dx, dy = proj.means2d[i, 0] - xs, proj.means2d[i, 1] - ys
        a, b, c = proj.conics[i]
        alpha = opac[i] * torch.exp(-(0.5 * (a * dx * dx + c * dy * dy) + b * dx * dy))
        outside = (dx.abs() > proj.radii[i, 0]) | (dy.abs() > proj.radii[i, 1])
        assert float(torch.where(outside, alpha, 0.0).max()) < ALPHA_MIN, i
    # The extent factor never exceeds gsplat's 3.33 sigma.
    sd = torch.sqrt(torch.diagonal(proj.cov2d, dim1=1, dim2=2))
    assert (proj.radii[proj.visible] <= torch.ceil(3.33 * sd[proj.visible])).all()


def test_culling_behind_camera_at_near_plane_and_beyond_far():
    width, height = 32, 32
    view, K = camera(width, height)
    means = torch.tensor([[0.0, 0.0, -1.0], [0.0, 0.0, 0.01], [0.0, 0.0, 0.0100001], [0.0, 0.0, 2e4],
                          [0.0, 0.0, 0.0], [0.0, 0.0, 2.0]], dtype=torch.float64, requires_grad=True)
    n = means.shape[0]
    quats = torch.tensor([[1.0, 0, 0, 0]] * n, dtype=torch.float64)
    scales = torch.full((n, 3), 0.05, dtype=torch.float64, requires_grad=True)
    opac = torch.full((n,), 0.5, dtype=torch.float64)
    proj = project_gaussians(means, quats, scales, opac, view, K, width, height, near=0.01, far=1e4)
    assert proj.visible.tolist() == [False, False, True, False, False, True]
    (proj.means2d.sum() + proj.conics.sum()).backward()
    assert torch.isfinite(means.grad).all() and torch.isfinite(scales.grad).all()


@pytest.mark.parametrize("scale", [1e-8, 1e3])
def test_extreme_scales_give_finite_conics_and_gradients(scale):
    width, height = 40, 30
    view, K = camera(width, height)
    means = torch.tensor([[0.0, 0.0, 0.02], [0.3, -0.2, 3.0], [50.0, 0.0, 1.0]], dtype=torch.float32,
                         requires_grad=True)
    scales = torch.full((3, 3), scale, dtype=torch.float32, requires_grad=True)
    quats = torch.tensor([[1.0, 0.2, 0, 0]] * 3, dtype=torch.float32, requires_grad=True)
    opac = torch.full((3,), 0.9, dtype=torch.float32)
    proj = project_gaussians(means, quats, scales, opac, view.float(), K.float(), width, height)
    assert torch.isfinite(proj.conics).all() and torch.isfinite(proj.means2d).all()
    assert (proj.radii >= 0).all() and (proj.radii <= 1 << 20).all()
    (proj.conics.sum() + proj.means2d.sum()).backward()
    for t in (means, scales, quats):
        assert torch.isfinite(t.grad).all()
    if scale == 1e3:  # a huge Gaussian right in front of the camera covers the whole image
        assert proj.visible[0] and (proj.radii[0] > max(width, height)).all()


def test_low_opacity_gaussian_is_not_visible():
    width, height = 16, 16
    view, K = camera(width, height)
    means = torch.tensor([[0.0, 0.0, 2.0]] * 2, dtype=torch.float64)
    quats = torch.tensor([[1.0, 0, 0, 0]] * 2, dtype=torch.float64)
    scales = torch.full((2, 3), 0.1, dtype=torch.float64)
    opac = torch.tensor([0.5 / 255.0, 0.5], dtype=torch.float64)
    proj = project_gaussians(means, quats, scales, opac, view, K, width, height)
    assert proj.visible.tolist() == [False, True]


def _hard_scene(dtype=torch.float64):
    """Random Gaussians plus culled, clamped-Jacobian, zero-quaternion and extreme-scale ones."""
    means, quats, scales, opac, _ = (t.detach().to(dtype) for t in random_scene(200, 1, seed=21))
    extra_means = torch.tensor([[0.0, 0.0, -1.0], [0.0, 0.0, 0.01], [30.0, -20.0, 1.0], [0.1, 0.1, 0.02],
                                [0.2, 0.0, 3.0], [0.0, 0.1, 2.0]], dtype=dtype)
    extra_quats = torch.tensor([[1.0, 0, 0, 0], [0.3, 0.1, 0, 0], [0.5, 0.5, 0.5, 0.5], [1.0, 0.2, 0, 0],
                                [0.0, 0.0, 0.0, 0.0], [2.0, -1.0, 0.5, 0.1]], dtype=dtype)
    extra_scales = torch.tensor([[0.1] * 3, [0.1] * 3, [0.5] * 3, [1e3] * 3, [0.05, 0.1, 0.02], [1e-8] * 3],
                                dtype=dtype)
    extra_opac = torch.tensor([0.5, 0.5, 0.9, 0.9, 0.7, 0.99], dtype=dtype)
    return (torch.cat([means, extra_means]), torch.cat([quats, extra_quats]), torch.cat([scales, extra_scales]),
            torch.cat([opac, extra_opac]))


@pytest.mark.parametrize("dtype", [torch.float64, torch.float32])
def test_cpp_projection_matches_torch_projection(dtype):
    from spotlessgs.rasterizer import load_kernel
    from spotlessgs.rasterizer.projection_cpp import project_gaussians_cpp

    if load_kernel() is None:
        pytest.skip("C++ kernel unavailable")
    width, height = 64, 48
    view = _tilted_view().to(dtype)
    _, K = camera(width, height, dtype=dtype)
    means, quats, scales, opac = _hard_scene(dtype)
    results = []
    for project in (project_gaussians, project_gaussians_cpp):
        params = [t.clone().requires_grad_() for t in (means, quats, scales)]
        proj = project(*params, opac, view, K, width, height)
        gen = torch.Generator().manual_seed(5)
        loss = ((proj.means2d * torch.randn(proj.means2d.shape, generator=gen, dtype=dtype)).sum()
                + (proj.conics * torch.randn(proj.conics.shape, generator=gen, dtype=dtype)).sum()
                + (proj.depths * torch.randn(proj.depths.shape, generator=gen, dtype=dtype)).sum())
        results.append((proj, torch.autograd.grad(loss, params)))
    (ref, ref_grads), (got, got_grads) = results
    rtol = 1e-9 if dtype == torch.float64 else 1e-5
    assert torch.equal(got.radii, ref.radii)
    behind = ref.depths.detach() <= 0.01
    assert got.visible.sum() > 100 and behind.any() and not got.visible[behind].any()  # culling is exercised
    assert (got.means2d[behind] == 0).all()
    for name in ("means2d", "conics", "depths", "cov2d"):
        a, b = getattr(got, name).detach(), getattr(ref, name).detach()
        np.testing.assert_allclose(a.numpy(), b.numpy(), rtol=rtol, atol=rtol * float(b.abs().max()), err_msg=name)
    for name, a, b in zip(("means", "quats", "scales"), got_grads, ref_grads):
        assert torch.isfinite(a).all(), name
        np.testing.assert_allclose(a.numpy(), b.numpy(), rtol=rtol, atol=rtol * float(b.abs().max()), err_msg=name)


def test_cpp_projection_gradcheck():
    from spotlessgs.rasterizer import load_kernel
    from spotlessgs.rasterizer.projection_cpp import project_gaussians_cpp

    if load_kernel() is None:
        pytest.skip("C++ kernel unavailable")
    means, quats, scales, opac = (t[:5].clone() for t in _hard_scene())
    view = _tilted_view()
    _, K = camera(64, 48)

    def fn(m, q, s):
        p = project_gaussians_cpp(m, q, s, opac, view, K, 64, 48)
        return p.means2d, p.conics, p.depths

    inputs = tuple(t.requires_grad_() for t in (means, quats, scales))
    assert torch.autograd.gradcheck(fn, inputs, eps=1e-7, atol=1e-5, rtol=1e-5)


@pytest.mark.parametrize("dtype", [torch.float64, torch.float32])
def test_may_touch_image_keeps_every_gaussian_the_projection_draws(dtype):
    """may_touch_image (what a caller shades) is conservative against both projections' bounding boxes: anisotropic,
    rotated, near the image's edges and off-axis (where the Jacobian stretches a Gaussian beyond f s / z), tiny and
    huge; and it still leaves out Gaussians far outside the view or behind the camera."""
    from spotlessgs.rasterizer import load_kernel, may_touch_image
    from spotlessgs.rasterizer.projection_cpp import project_gaussians_cpp

    width, height = 64, 48
    view = _tilted_view().to(dtype)
    _, K = camera(width, height, dtype=dtype)
    gen = torch.Generator().manual_seed(11)
    n = 4000
    # camera-frame positions around the frustum's edges, a wide spread of depths and sizes, opacity up to 0.999
    z = torch.rand(n, generator=gen, dtype=torch.float64) * 6.0 - 0.5
    x = (torch.rand(n, generator=gen, dtype=torch.float64) * 3.0 - 1.5) * z.abs().clamp_min(0.05)
    y = (torch.rand(n, generator=gen, dtype=torch.float64) * 2.4 - 1.2) * z.abs().clamp_min(0.05)
    cam = torch.stack([x, y, z], -1)
    inverse = torch.linalg.inv(view.to(torch.float64))
    means = (cam @ inverse[:3, :3].T + inverse[:3, 3]).to(dtype)
    scales = (10.0 ** (torch.rand((n, 3), generator=gen, dtype=torch.float64) * 3.0 - 3.0)).to(dtype)
    quats = torch.randn((n, 4), generator=gen, dtype=torch.float64).to(dtype)
    opac = (torch.rand(n, generator=gen, dtype=torch.float64) * 0.999).to(dtype)
    mask = may_touch_image(means, scales, view, K, width, height)
    projections = [project_gaussians] + ([project_gaussians_cpp] if load_kernel() is not None else [])
    for project in projections:
        drawn = project(means, quats, scales, opac, view, K, width, height).visible
        assert drawn.sum() > 500
        assert not (drawn & ~mask).any(), f"{project.__name__} draws {int((drawn & ~mask).sum())} left out"
    assert (~mask).sum() > 500 and not mask[z.to(dtype) <= 0.01].any()
    # the old mask's rule (3 s_max f / z + 1 around the centre) missed some of them
    u = K[0, 0] * cam[:, 0] / cam[:, 2].clamp_min(0.01) + K[0, 2]
    v = K[1, 1] * cam[:, 1] / cam[:, 2].clamp_min(0.01) + K[1, 2]
    r = 3.0 * scales.to(torch.float64).max(1).values * float(K[0, 0]) / cam[:, 2].clamp_min(0.01) + 1.0
    old = (cam[:, 2] > 0.01) & (u + r > 0) & (u - r < width) & (v + r > 0) & (v - r < height)
    assert (drawn & ~old).any()
