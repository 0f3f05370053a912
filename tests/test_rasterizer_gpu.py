"""The gsplat CUDA backend against the CPU backends (needs a CUDA GPU and gsplat 1.5.3: ``pip install -e '.[gpu]'``)."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from rasterizer_reference import camera, random_scene

from spotlessgs.rasterizer import rasterize, resolve_backend

pytestmark = pytest.mark.gpu


@pytest.fixture(scope="module")
def gsplat_module():
    return pytest.importorskip("gsplat", reason="gsplat is not installed (pip install -e '.[gpu]')")


@pytest.mark.parametrize("channels", [3, 12])
def test_gsplat_matches_the_cpu_backend(gsplat_module, channels):
    assert resolve_backend("auto", "cuda") == "gsplat"
    width, height = 96, 72
    cpu_scene = random_scene(400, channels, seed=31, dtype=torch.float32, log_scale=-2.0)
    view, K = camera(width, height, dtype=torch.float32)
    gpu_scene = [t.detach().cuda().requires_grad_() for t in cpu_scene]
    bg = torch.linspace(0.0, 1.0, channels)
    cpu = rasterize(*cpu_scene, view, K, width, height, background=bg, backend="torch")
    gpu = rasterize(*gpu_scene, view.cuda(), K.cuda(), width, height, background=bg.cuda(), tile_size=16)
    assert gpu.backend == "gsplat"
    np.testing.assert_allclose(gpu.image.detach().cpu().numpy(), cpu.image.detach().numpy(), atol=2e-3)
    np.testing.assert_allclose(gpu.alpha.detach().cpu().numpy(), cpu.alpha.detach().numpy(), atol=2e-3)
    covered = cpu.alpha.detach().numpy() > 0.5
    np.testing.assert_allclose(gpu.depth.detach().cpu().numpy()[covered], cpu.depth.detach().numpy()[covered],
                               rtol=1e-3)
    assert gpu.radii.shape == (400,) and gpu.radii.dtype == torch.int32

    gpu.image.sum().backward()
    cpu.image.sum().backward()
    grad2d = gpu.means2d_grad()
    assert grad2d is not None and grad2d.shape == (400, 2)
    np.testing.assert_allclose(gpu_scene[4].grad.cpu().numpy(), cpu_scene[4].grad.numpy(), atol=2e-3)
    np.testing.assert_allclose(grad2d.cpu().numpy(), cpu.means2d_grad().numpy(),
                               atol=2e-3 * float(cpu.means2d_grad().abs().max()))
