"""rasterize(): golden values, conventions, hard cases (empty views, N = 0, extreme scales, degenerate quaternions),
backend selection and fallback, and every error path."""

from __future__ import annotations

import logging
import math

import numpy as np
import pytest
import torch
from rasterizer_reference import camera, random_scene

from spotlessgs.rasterizer import KernelBuildError, load_kernel, rasterize, resolve_backend
from spotlessgs.rasterizer import cpp_kernel as cpp_module

ALL = ["cpp", "torch"]


def _needs(backend):
    if backend == "cpp" and load_kernel() is None:
        pytest.skip(f"C++ kernel unavailable: {cpp_module.kernel_error()}")


def _single(z=2.0, scale=0.05, opacity=0.8, x=0.0, y=0.0, dtype=torch.float64):
    """One isotropic Gaussian: means, quats, scales, opacities, features (leaf tensors)."""
    return [t.requires_grad_() for t in (
        torch.tensor([[x, y, z]], dtype=dtype), torch.tensor([[1.0, 0, 0, 0]], dtype=dtype),
        torch.full((1, 3), scale, dtype=dtype), torch.tensor([opacity], dtype=dtype),
        torch.tensor([[0.25, 0.5, 1.0]], dtype=dtype))]


@pytest.mark.parametrize("backend", ALL)
def test_single_gaussian_golden_values(backend):
    # Centre lands on the centre of pixel (10, 7): alpha there is the opacity; one pixel to the right it is
    # o·exp(-½ / var) with var = (f·s/z)² + 0.3 (the dilation). Depth is the Gaussian's z.
    _needs(backend)
    width, height, f, z, s, o = 21, 15, 40.0, 2.0, 0.05, 0.8
    K = torch.tensor([[f, 0, 10.5], [0, f, 7.5], [0, 0, 1]], dtype=torch.float64)
    out = rasterize(*_single(z, s, o), torch.eye(4, dtype=torch.float64), K, width, height, backend=backend)
    var = (f * s / z) ** 2 + 0.3
    assert out.alpha[7, 10].item() == pytest.approx(o, abs=1e-12)
    assert out.alpha[7, 11].item() == pytest.approx(o * math.exp(-0.5 / var), abs=1e-12)
    assert out.alpha[8, 11].item() == pytest.approx(o * math.exp(-1.0 / var), abs=1e-12)
    np.testing.assert_allclose(out.image[7, 10].detach().numpy(), [0.2, 0.4, 0.8], atol=1e-12)
    assert out.depth[7, 10].item() == pytest.approx(z, abs=1e-12)
    assert out.means2d[0].tolist() == pytest.approx([10.5, 7.5])
    assert out.radii.tolist() == [math.ceil(math.sqrt(2 * math.log(255 * o) * var))]


@pytest.mark.parametrize("backend", ALL)
def test_background_and_front_to_back_order(backend):
    _needs(backend)
    view, K = camera(16, 16)
    K[0, 2] = K[1, 2] = 8.5  # both centres on the centre of pixel (8, 8)
    near_g, far_g = _single(z=2.0, opacity=0.5), _single(z=3.0, opacity=0.5)
    scene = [torch.cat([a, b]).detach() for a, b in zip(near_g, far_g)]
    scene[4] = torch.tensor([[1.0, 0.0, 0.0], [0.0, 1.0, 0.0]], dtype=torch.float64)
    bg = torch.tensor([0.0, 0.0, 1.0], dtype=torch.float64)
    out = rasterize(*scene, view, K, 16, 16, background=bg, backend=backend)
    # At the centre pixel: 0.5 red, then 0.5·0.5 green, then 0.25 background blue.
    np.testing.assert_allclose(out.image[8, 8].numpy(), [0.5, 0.25, 0.25], atol=1e-12)
    assert out.alpha[8, 8].item() == pytest.approx(0.75, abs=1e-12)
    assert out.depth[8, 8].item() == pytest.approx((0.5 * 2.0 + 0.25 * 3.0) / 0.75, abs=1e-12)
    np.testing.assert_array_equal(out.image[0, 0].numpy(), bg.numpy())  # corner: nothing but background


@pytest.mark.parametrize("backend", ALL)
def test_nothing_visible_returns_background_and_zero_gradients(backend):
    _needs(backend)
    view, K = camera(24, 16)
    scene = random_scene(30, 2, seed=3)
    with torch.no_grad():
        scene[0][:, 2] -= 10.0  # everything behind the camera
    bg = torch.tensor([0.1, 0.7], dtype=torch.float64)
    out = rasterize(*scene, view, K, 24, 16, background=bg, backend=backend)
    np.testing.assert_array_equal(out.image.detach().numpy(), np.broadcast_to(bg.numpy(), (16, 24, 2)))
    assert (out.alpha == 0).all() and (out.depth == 0).all() and (out.radii == 0).all()
    (out.image.sum() + out.alpha.sum() + out.depth.sum()).backward()
    for t in scene:
        assert t.grad is not None and (t.grad == 0).all()


@pytest.mark.parametrize("backend", ALL)
def test_zero_gaussians(backend):
    _needs(backend)
    view, K = camera(12, 10)
    empty = [torch.zeros(0, 3), torch.zeros(0, 4), torch.zeros(0, 3), torch.zeros(0), torch.zeros(0, 5)]
    empty = [t.double().requires_grad_() for t in empty]
    out = rasterize(*empty, view, K, 12, 10, backend=backend)
    assert out.image.shape == (10, 12, 5) and out.alpha.shape == (10, 12) and out.radii.shape == (0,)
    assert (out.image == 0).all()
    out.image.sum().backward()
    assert empty[4].grad.shape == (0, 5)


@pytest.mark.parametrize("backend", ALL)
def test_near_plane_and_behind_camera_are_culled_with_zero_gradient(backend):
    _needs(backend)
    view, K = camera(16, 16)
    parts = [_single(z=z) for z in (-1.0, 0.0, 0.01, 0.5)]
    scene = [torch.cat(ts).detach().requires_grad_() for ts in zip(*parts)]
    out = rasterize(*scene, view, K, 16, 16, near=0.01, backend=backend)
    assert out.visible.tolist() == [False, False, False, True]
    (out.image.sum() + out.alpha.sum()).backward()
    for t in scene:
        assert torch.isfinite(t.grad).all()
        assert (t.grad[:3] == 0).all()
    assert (scene[0].grad[3] != 0).any()
    assert (out.means2d_grad()[:3] == 0).all() and (out.means2d_grad()[3] != 0).any()


@pytest.mark.parametrize("backend", ALL)
@pytest.mark.parametrize("scale", [1e-8, 1e3])
def test_extreme_scales_are_finite(backend, scale):
    _needs(backend)
    view, K = camera(40, 30, dtype=torch.float32)
    scene = random_scene(20, 3, seed=11, dtype=torch.float32)
    with torch.no_grad():
        scene[2].fill_(scale)
    out = rasterize(*scene, view, K, 40, 30, backend=backend)
    (out.image.sum() + out.alpha.sum() + out.depth.sum()).backward()
    assert torch.isfinite(out.image).all() and torch.isfinite(out.depth).all()
    for t in scene:
        assert torch.isfinite(t.grad).all()
    if scale == 1e3:  # huge Gaussians cover the frame (depth is then the mean of huge blobs, alpha high)
        assert float(out.alpha.detach().min()) > 0.5
    else:  # 1e-8 m Gaussians are pure dilation: 0.3 px² footprints, still visible
        assert out.visible.any() and float(out.alpha.detach().max()) > 0.1


@pytest.mark.parametrize("backend", ALL)
def test_zero_quaternion_renders_as_identity(backend):
    _needs(backend)
    view, K = camera(20, 20)
    scene = random_scene(10, 3, seed=12)
    zero = [t.detach().clone() for t in scene]
    zero[1][:4] = 0.0
    ident = [t.clone() for t in zero]
    ident[1][:4] = torch.tensor([1.0, 0, 0, 0], dtype=torch.float64)
    zero = [t.requires_grad_() for t in zero]
    a = rasterize(*zero, view, K, 20, 20, backend=backend)
    b = rasterize(*ident, view, K, 20, 20, backend=backend)
    np.testing.assert_allclose(a.image.detach().numpy(), b.image.numpy(), atol=1e-12)
    a.image.sum().backward()
    assert torch.isfinite(zero[1].grad).all()


def test_huge_gaussian_costs_at_most_one_entry_per_tile():
    from spotlessgs.rasterizer.binning import bin_gaussians
    from spotlessgs.rasterizer.projection import project_gaussians

    view, K = camera(64, 48)
    means, quats, scales, opac, _ = _single(z=0.02, scale=1e3)
    proj = project_gaussians(means, quats, scales, opac, view, K, 64, 48)
    bins = bin_gaussians(proj.means2d, proj.radii, proj.depths, 64, 48, 8)
    assert bins.num_pairs == 8 * 6


def test_means2d_grad_is_the_screen_space_gradient():
    # d loss / d means2d from rasterize equals the gradient of a hand-made loss on a translated render: shifting
    # the Gaussian by +1 px in x must change the loss by ≈ grad_x (finite difference, float64).
    view = torch.eye(4, dtype=torch.float64)
    K = torch.tensor([[40.0, 0, 10.3], [0, 40.0, 7.9], [0, 0, 1]], dtype=torch.float64)
    target = torch.rand(15, 21, 3, dtype=torch.float64, generator=torch.Generator().manual_seed(0))

    def loss_at(cx):
        k = K.clone()
        k[0, 2] = cx
        out = rasterize(*_single(scale=0.08), view, k, 21, 15, backend="torch")
        return ((out.image - target) ** 2).sum(), out

    value, out = loss_at(10.3)
    value.backward()
    grad = out.means2d_grad()
    fd = (loss_at(10.3 + 1e-5)[0] - loss_at(10.3 - 1e-5)[0]) / 2e-5
    assert grad.shape == (1, 2)
    assert grad[0, 0].item() == pytest.approx(fd.item(), rel=1e-5)


def test_env_var_forces_the_torch_backend(monkeypatch):
    monkeypatch.setenv("SPOTLESSGS_RASTER_BACKEND", "torch")
    assert resolve_backend("auto", "cpu") == "torch"
    view, K = camera(8, 8)
    assert rasterize(*_single(), view, K, 8, 8).backend == "torch"
    monkeypatch.setenv("SPOTLESSGS_RASTER_BACKEND", "fortran")
    with pytest.raises(ValueError, match="SPOTLESSGS_RASTER_BACKEND must be 'cpp' or 'torch', got 'fortran'"):
        resolve_backend("auto", "cpu")


def test_build_failure_falls_back_to_torch_with_a_warning(monkeypatch, tmp_path, caplog):
    monkeypatch.setattr(cpp_module, "_cached", {})
    monkeypatch.setenv("TORCH_EXTENSIONS_DIR", str(tmp_path))
    monkeypatch.setenv("CXX", str(tmp_path / "no-such-compiler"))
    monkeypatch.delenv("SPOTLESSGS_RASTER_BACKEND", raising=False)
    with caplog.at_level(logging.WARNING, logger="spotlessgs.rasterizer.composite_cpp"):
        assert resolve_backend("auto", "cpu") == "torch"
    assert "using the pure-torch backend" in caplog.text and "no-such-compiler" in caplog.text
    view, K = camera(8, 8)
    with pytest.raises(KernelBuildError, match="no-such-compiler"):
        rasterize(*_single(), view, K, 8, 8, backend="cpp")


def test_compiler_error_is_reported(monkeypatch, tmp_path):
    bad = tmp_path / "bad.cpp"
    bad.write_text("this is not C++;\n")
    monkeypatch.setenv("TORCH_EXTENSIONS_DIR", str(tmp_path / "cache"))
    monkeypatch.setattr(cpp_module, "SOURCES", (bad,))
    with pytest.raises(KernelBuildError, match="exited with"):
        cpp_module.build_kernel()
    assert not list((tmp_path / "cache").rglob("*.so"))  # nothing half-written left in the cache


def test_build_is_cached(monkeypatch, tmp_path):
    if load_kernel() is None:
        pytest.skip(f"C++ kernel unavailable: {cpp_module.kernel_error()}")
    monkeypatch.setenv("TORCH_EXTENSIONS_DIR", str(tmp_path))
    first = cpp_module.build_kernel()
    stamp = first.stat().st_mtime_ns
    assert first.parent == tmp_path / "spotlessgs_raster" and first.suffix == ".so"
    assert cpp_module.build_kernel() == first and first.stat().st_mtime_ns == stamp


def _args(**over):
    view, K = camera(8, 6)
    args = dict(zip(("means", "quats", "scales", "opacities", "features"), [t.detach() for t in _single()]))
    args.update(viewmat=view, K=K, width=8, height=6)
    args.update(over)
    return args


def _call(**over):
    a = _args(**over)
    kw = {k: a.pop(k) for k in list(a) if k not in ("means", "quats", "scales", "opacities", "features", "viewmat",
                                                    "K", "width", "height")}
    return rasterize(a["means"], a["quats"], a["scales"], a["opacities"], a["features"], a["viewmat"], a["K"],
                     a["width"], a["height"], **kw)


@pytest.mark.parametrize(
    ("override", "message"),
    [
        ({"features": torch.zeros(1, dtype=torch.float64)}, r"features must have shape \(N, C\) with C >= 1"),
        ({"features": torch.zeros(1, 0, dtype=torch.float64)}, r"features must have shape \(N, C\) with C >= 1"),
        ({"features": torch.zeros(1, 3, dtype=torch.int64)}, "features must be float32 or float64"),
        ({"means": torch.zeros(2, 3, dtype=torch.float64)}, r"means must have shape \(1, 3\) \(N=1 from features\)"),
        ({"quats": torch.zeros(1, 3, dtype=torch.float64)}, r"quats must have shape \(1, 4\)"),
        ({"scales": torch.zeros(1, 3)}, "scales has dtype torch.float32 but features has torch.float64"),
        ({"opacities": torch.zeros(1, 1, dtype=torch.float64)}, r"opacities must have shape \(1,\)"),
        ({"viewmat": torch.eye(3, dtype=torch.float64)}, r"viewmat must have shape \(4, 4\)"),
        ({"K": [[1.0]]}, "K must be a torch.Tensor, got list"),
        ({"background": torch.zeros(2, dtype=torch.float64)}, r"background must have shape \(3,\)"),
        ({"width": 0}, "width must be a positive integer, got 0"),
        ({"height": 2.5}, "height must be a positive integer, got 2.5"),
        ({"tile_size": 0}, r"tile_size must be an integer in \[1, 64\], got 0"),
        ({"near": 0.0}, "need 0 < near < far, got near=0.0"),
        ({"near": 2.0, "far": 1.0}, "need 0 < near < far"),
        ({"eps2d": -0.1}, r"eps2d must be at least 0.0001 px² and finite, got -0.1"),
        ({"eps2d": 0.0}, r"eps2d must be at least 0.0001 px²"),  # a needle's conic: NaN gradients in float32
        ({"eps2d": float("nan")}, r"eps2d must be at least 0.0001 px²"),
        ({"backend": "vulkan"}, "backend must be one of .* got 'vulkan'"),
        ({"backend": "gsplat"}, "backend 'gsplat' needs CUDA tensors, got tensors on cpu"),
        ({"num_threads": 0}, "num_threads must be a positive integer or None, got 0"),
    ],
)
def test_invalid_arguments_are_rejected(override, message):
    with pytest.raises(ValueError, match=message):
        _call(**override)


def test_invalid_thread_env_is_rejected(monkeypatch):
    monkeypatch.setenv("SPOTLESSGS_NUM_THREADS", "many")
    with pytest.raises(ValueError, match="SPOTLESSGS_NUM_THREADS must be a positive integer, got 'many'"):
        _call()
    monkeypatch.setenv("SPOTLESSGS_NUM_THREADS", "0")
    with pytest.raises(ValueError, match="SPOTLESSGS_NUM_THREADS must be a positive integer, got '0'"):
        _call()


def test_benchmark_runs_and_reports(monkeypatch, capsys):
    from spotlessgs.rasterizer import benchmark

    monkeypatch.setattr(benchmark, "CASES", (benchmark.BenchCase(32, 24, 300, 3),))
    params, view, K = benchmark.make_scene(benchmark.CASES[0])
    assert [tuple(p.shape) for p in params] == [(300, 3), (300, 4), (300, 3), (300,), (300, 3)]
    out = rasterize(*params, view, K, 32, 24, backend="torch")
    assert float(out.alpha.detach().mean()) > 0.9  # the room's walls close up in front of the camera
    benchmark.main(["--repeats", "1", "--threads", "1", "--backends", "torch"])
    lines = capsys.readouterr().out.splitlines()
    assert "load average" in lines[0] and lines[-1].startswith("32x24 / 0k / 3ch") and "torch" in lines[-1]


def test_cpp_backend_needs_cpu_tensors():
    with pytest.raises(ValueError, match="backend 'cpp' needs CPU tensors, got tensors on meta"):
        resolve_backend("cpp", "meta")


def test_library_with_wrong_abi_version_is_rejected(tmp_path):
    import shutil
    import subprocess

    cxx = shutil.which("g++") or shutil.which("c++")
    if cxx is None:
        pytest.skip("no C++ compiler")
    src = tmp_path / "old.cpp"
    src.write_text('extern "C" int spotless_raster_abi_version() { return 999; }\n')
    lib = tmp_path / "old.so"
    subprocess.run([cxx, "-shared", "-fPIC", str(src), "-o", str(lib)], check=True, capture_output=True)
    with pytest.raises(KernelBuildError, match=r"old\.so: kernel ABI version 999, expected"):
        cpp_module._bind(lib)


@pytest.mark.parametrize("backend", ["torch", "cpp"])
def test_a_needle_at_the_smallest_dilation_renders_as_in_float64_with_finite_gradients(backend):
    """A needle 0.1 m long and 1e-8 m wide at 45 degrees: with eps2d = 0 its float32 conic was indefinite (the torch
    backend's quaternion gradient NaN, 32 pixels lit instead of 7, the backends disagreeing); at the smallest
    dilation accepted both render it as float64 does."""
    import math

    from spotlessgs.rasterizer.api import MIN_EPS2D

    half = math.radians(45) / 2

    def render(dtype):
        params = [torch.tensor(x, dtype=dtype, requires_grad=True) for x in (
            [[0.01, 0.01, 2.0]], [[math.cos(half), 0.0, 0.0, math.sin(half)]], [[0.1, 1e-8, 1e-8]], [0.8], [[1.0]])]
        out = rasterize(*params, torch.eye(4, dtype=dtype),
                        torch.tensor([[100.0, 0, 16], [0, 100.0, 16], [0, 0, 1]], dtype=dtype), 32, 32,
                        eps2d=MIN_EPS2D, backend=backend, num_threads=1)
        out.image.sum().backward()
        return out, params[1].grad

    (single, grad), (double, _grad64) = render(torch.float32), render(torch.float64)
    assert torch.isfinite(grad).all()
    assert float(single.image.detach().sum()) == pytest.approx(float(double.image.detach().sum()), rel=1e-3)
    assert int((single.alpha > 0.5).sum()) == int((double.alpha > 0.5).sum()) == 7
