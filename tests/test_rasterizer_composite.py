"""Compositing backends (C++ kernel, pure torch) against the slow dense reference, finite differences and each other.

Tolerances: float64 forward vs the reference 1e-10 (same maths, different summation order); float64 gradients
1e-8 relative; float32 C++ vs torch 2e-5 (different exp implementations and summation order).
"""

from __future__ import annotations

import numpy as np
import pytest
import torch
from rasterizer_reference import camera, composite_reference, random_scene

from spotlessgs.rasterizer import load_kernel, project_gaussians, rasterize
from spotlessgs.rasterizer.binning import bin_gaussians

WIDTH, HEIGHT = 37, 29  # not multiples of the tile size on purpose


def _needs_kernel():
    if load_kernel() is None:
        from spotlessgs.rasterizer.cpp_kernel import kernel_error

        pytest.skip(f"C++ kernel unavailable: {kernel_error()}")


def _backend_param(name):
    return pytest.param(name, id=name)


BACKENDS = [_backend_param("cpp"), _backend_param("torch")]


def _render(backend, scene, view, K, width=WIDTH, height=HEIGHT, **kw):
    if backend == "cpp":
        _needs_kernel()
    return rasterize(*scene, view, K, width, height, backend=backend, **kw)


def _reference(scene, view, K, width=WIDTH, height=HEIGHT):
    """Dense reference colour (H, W, C) and alpha (H, W) for a scene (projection shared with the library)."""
    means, quats, scales, opac, feats = scene
    proj = project_gaussians(means, quats, scales, opac, view, K, width, height)
    return composite_reference(proj.means2d, proj.conics, opac, feats, proj.depths, width, height)


@pytest.mark.parametrize("backend", BACKENDS)
@pytest.mark.parametrize("kind", ["translucent", "opaque"])
def test_forward_and_gradients_match_dense_reference(backend, kind):
    # "opaque": high opacities, so the 0.99 clamp and the T <= 1e-4 early stop both occur.
    opacity_range = (0.1, 0.95) if kind == "translucent" else (0.9, 1.0)
    scene = random_scene(80, 3, seed=10, log_scale=-1.2, opacity_range=opacity_range)
    view, K = camera(WIDTH, HEIGHT)
    out = _render(backend, scene, view, K)
    ref_color, ref_alpha = _reference(scene, view, K)
    assert out.backend == backend
    coverage = ref_alpha.detach()
    assert 0.5 < float(coverage.mean()) < 0.99  # a scene with overlaps, not an empty picture
    if kind == "opaque":  # the early stop changes the picture here, so this case exercises it
        means, quats, scales, opac, feats = scene
        proj = project_gaussians(means, quats, scales, opac, view, K, WIDTH, HEIGHT)
        no_stop, _ = composite_reference(proj.means2d, proj.conics, opac, feats, proj.depths, WIDTH, HEIGHT,
                                         t_min=0.0)
        assert float((no_stop - ref_color).detach().abs().max()) > 1e-5
    np.testing.assert_allclose(out.image.detach().numpy(), ref_color.detach().numpy(), atol=1e-10)
    np.testing.assert_allclose(out.alpha.detach().numpy(), ref_alpha.detach().numpy(), atol=1e-10)

    weights = torch.rand(HEIGHT, WIDTH, 3, dtype=torch.float64, generator=torch.Generator().manual_seed(1))
    loss = (out.image * weights).sum() + 0.7 * out.alpha.sum()
    ref_loss = (ref_color * weights).sum() + 0.7 * ref_alpha.sum()
    got = torch.autograd.grad(loss, scene)
    want = torch.autograd.grad(ref_loss, scene)
    for name, g, w in zip(("means", "quats", "scales", "opacities", "features"), got, want):
        np.testing.assert_allclose(g.numpy(), w.numpy(), rtol=1e-8, atol=1e-10, err_msg=name)


@pytest.mark.parametrize("backend", BACKENDS)
def test_gradcheck_finite_differences(backend):
    # Tiny float64 case, opacities kept away from the 0.99 clamp so the function is smooth at this point.
    width, height = 10, 8
    means = torch.tensor([[0.02, 0.01, 2.0], [-0.05, 0.03, 2.5], [0.04, -0.04, 3.0]], dtype=torch.float64)
    quats = torch.tensor([[1.0, 0.1, -0.2, 0.3], [0.9, 0.0, 0.4, 0.1], [0.2, 0.7, 0.1, -0.3]], dtype=torch.float64)
    scales = torch.tensor([[0.05, 0.03, 0.04], [0.04, 0.06, 0.02], [0.08, 0.05, 0.03]], dtype=torch.float64)
    opac = torch.tensor([0.6, 0.5, 0.7], dtype=torch.float64)
    feats = torch.tensor([[0.2, 0.9], [0.7, 0.1], [0.4, 0.5]], dtype=torch.float64)
    view, K = camera(width, height, focal=25.0)
    inputs = tuple(t.requires_grad_() for t in (means, quats, scales, opac, feats))
    if backend == "cpp":
        _needs_kernel()

    def render(*params):
        out = rasterize(*params, view, K, width, height, backend=backend, background=torch.tensor(
            [0.3, 0.1], dtype=torch.float64))
        return out.image, out.alpha, out.depth

    assert torch.autograd.gradcheck(render, inputs, eps=1e-6, atol=1e-6, rtol=1e-5)


@pytest.mark.parametrize("channels", [1, 5, 32])
def test_cpp_and_torch_agree_in_float32(channels):
    _needs_kernel()
    scene = random_scene(300, channels, seed=channels, dtype=torch.float32, log_scale=-3.0)
    view, K = camera(64, 48, dtype=torch.float32)
    outs = {}
    for backend in ("cpp", "torch"):
        out = rasterize(*scene, view, K, 64, 48, backend=backend)
        loss = out.image.square().sum() + out.alpha.sum() + 0.1 * out.depth.sum()
        outs[backend] = (out, torch.autograd.grad(loss, scene))
    (a, ga), (b, gb) = outs["cpp"], outs["torch"]
    np.testing.assert_allclose(a.image.detach().numpy(), b.image.detach().numpy(), atol=2e-5)
    np.testing.assert_allclose(a.alpha.detach().numpy(), b.alpha.detach().numpy(), atol=2e-5)
    np.testing.assert_allclose(a.depth.detach().numpy(), b.depth.detach().numpy(), rtol=2e-5, atol=2e-4)
    for name, x, y in zip(("means", "quats", "scales", "opacities", "features"), ga, gb):
        scale = float(y.abs().max())
        np.testing.assert_allclose(x.numpy(), y.numpy(), atol=2e-4 * scale, err_msg=name)


@pytest.mark.parametrize("backend", BACKENDS)
def test_tile_size_does_not_change_the_image(backend):
    # The opacity-aware bounding boxes make tiling exact: every tile size gives the dense result.
    scene = random_scene(60, 2, seed=5)
    view, K = camera(WIDTH, HEIGHT)
    images = [_render(backend, scene, view, K, tile_size=t).image.detach() for t in (4, 8, 16)]
    for img in images[1:]:
        np.testing.assert_allclose(img.numpy(), images[0].numpy(), atol=1e-12)


def test_cpp_threads_and_repeats_are_bit_identical():
    _needs_kernel()
    scene = random_scene(500, 4, seed=7, dtype=torch.float32, log_scale=-3.0)
    view, K = camera(64, 48, dtype=torch.float32)
    results = []
    for threads in (1, 2, 2):
        out = rasterize(*scene, view, K, 64, 48, backend="cpp", num_threads=threads)
        grads = torch.autograd.grad(out.image.sum() + out.alpha.sum(), scene)
        results.append([out.image.detach(), out.alpha.detach(), *grads])
    for other in results[1:]:
        for x, y in zip(results[0], other):
            assert torch.equal(x, y)


def test_torch_backend_threads_agree():
    scene = random_scene(300, 3, seed=8, dtype=torch.float32, log_scale=-3.0)
    view, K = camera(64, 48, dtype=torch.float32)
    runs = []
    for threads in (1, 2):
        out = rasterize(*scene, view, K, 64, 48, backend="torch", num_threads=threads)
        runs.append([out.image.detach(), *torch.autograd.grad(out.image.sum(), scene)])
    for x, y in zip(*runs):
        np.testing.assert_allclose(x.numpy(), y.numpy(), rtol=1e-5, atol=1e-6)


def test_binning_lists_each_overlap_once_front_to_back():
    scene = [t.detach() for t in random_scene(80, 1, seed=9)]
    view, K = camera(WIDTH, HEIGHT)
    proj = project_gaussians(*scene[:4], view, K, WIDTH, HEIGHT)
    bins = bin_gaussians(proj.means2d, proj.radii, proj.depths, WIDTH, HEIGHT, 8)
    assert (bins.tiles_x, bins.tiles_y) == (5, 4)
    expected_pairs = 0
    for i in torch.nonzero(proj.visible).squeeze(1).tolist():
        (mx, my), (rx, ry) = proj.means2d[i].tolist(), proj.radii[i].tolist()
        x0, x1 = max(int((mx - rx) // 8), 0), min(int((mx + rx) // 8), 4)
        y0, y1 = max(int((my - ry) // 8), 0), min(int((my + ry) // 8), 3)
        expected_pairs += (x1 - x0 + 1) * (y1 - y0 + 1)
        for ty in range(y0, y1 + 1):
            for tx in range(x0, x1 + 1):
                t = ty * 5 + tx
                assert i in bins.gauss_ids[bins.tile_offsets[t]:bins.tile_offsets[t + 1]].tolist()
    assert bins.num_pairs == expected_pairs
    for t in range(bins.num_tiles):
        ids = bins.gauss_ids[bins.tile_offsets[t]:bins.tile_offsets[t + 1]].long()
        assert (proj.depths[ids][1:] >= proj.depths[ids][:-1]).all()


def test_torch_checkpointed_chunks_give_the_same_result(monkeypatch):
    import spotlessgs.rasterizer.composite_torch as composite_torch

    scene = random_scene(80, 3, seed=13, log_scale=-1.5)
    view, K = camera(WIDTH, HEIGHT)
    runs = []
    for limit in (1 << 40, 0):  # never / always recompute in backward
        monkeypatch.setattr(composite_torch, "_CHECKPOINT_ABOVE", limit)
        monkeypatch.setattr(composite_torch, "_CHUNK_ELEMENTS", 4096)  # many small chunks
        out = rasterize(*scene, view, K, WIDTH, HEIGHT, backend="torch")
        runs.append([out.image.detach(), *torch.autograd.grad(out.image.sum() + out.alpha.sum(), scene)])
    for x, y in zip(*runs):
        np.testing.assert_allclose(x.numpy(), y.numpy(), rtol=1e-12, atol=1e-12)


@pytest.mark.parametrize("tile_size", [4, 8, 16])
def test_cpp_binning_equals_torch_binning(tile_size):
    from spotlessgs.rasterizer.binning import bin_gaussians_cpp

    _needs_kernel()
    scene = [t.detach().float() for t in random_scene(400, 1, seed=14, log_scale=-2.0)]
    scene[0][:20, 2] = 4.0  # equal depths: ties must keep index order in both
    view, K = camera(WIDTH, HEIGHT, dtype=torch.float32)
    proj = project_gaussians(*scene[:4], view, K, WIDTH, HEIGHT)
    ref = bin_gaussians(proj.means2d, proj.radii, proj.depths, WIDTH, HEIGHT, tile_size)
    got = bin_gaussians_cpp(proj.means2d, proj.radii, proj.depths, WIDTH, HEIGHT, tile_size)
    assert (got.tiles_x, got.tiles_y) == (ref.tiles_x, ref.tiles_y) and ref.num_pairs > 400
    assert torch.equal(got.tile_offsets, ref.tile_offsets)
    assert torch.equal(got.gauss_ids, ref.gauss_ids)


def test_camera_pose_gradient_matches_reference():
    # With a trainable view matrix the cpp backend projects in torch; both backends must match the dense reference.
    scene = random_scene(50, 3, seed=15, log_scale=-1.5)
    view, K = camera(WIDTH, HEIGHT)
    view = view.clone()
    view[:3, 3] = torch.tensor([0.05, -0.02, 0.1], dtype=torch.float64)
    grads = {}
    for backend in ("cpp", "torch", "reference"):
        v = view.clone().requires_grad_()
        if backend == "reference":
            means, quats, scales, opac, feats = scene
            proj = project_gaussians(means, quats, scales, opac, v, K, WIDTH, HEIGHT)
            image, _ = composite_reference(proj.means2d, proj.conics, opac, feats, proj.depths, WIDTH, HEIGHT)
        else:
            image = _render(backend, scene, v, K).image
        (grads[backend],) = torch.autograd.grad(image.square().sum(), [v])
    assert float(grads["reference"][:3].abs().max()) > 1e-3
    for backend in ("cpp", "torch"):
        np.testing.assert_allclose(grads[backend].numpy(), grads["reference"].numpy(), rtol=1e-8, atol=1e-10)
