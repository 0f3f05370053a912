"""RelightableScene's render shades only the Gaussians that may touch the view (rasterizer.may_touch_image); the others get zero
colour. Shading every Gaussian gives the same image: the mask leaves out only what the rasterizer never draws."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from spotlessgs.io.camera_batch import Cameras
from spotlessgs.io.cameras import Intrinsics
from spotlessgs.models.gaussians import GaussianParams
from spotlessgs.models.relightable import RelightableScene
from spotlessgs.rasterizer import may_touch_image, rasterize


@pytest.mark.parametrize("variant", ["3dgs", "darkgs"])
def test_shading_only_the_frustums_gaussians_changes_no_pixel(variant):
    # a wall of Gaussians reaching past the image's edges, large ones at the sides and corners, seen off-axis
    rng = np.random.default_rng(4)
    n = 3000
    points = np.stack([rng.uniform(-4.0, 4.0, n), rng.uniform(-3.0, 3.0, n), rng.uniform(1.0, 3.0, n)], -1)
    g = GaussianParams.from_point_cloud(points, rng.integers(40, 256, (n, 3)).astype(np.uint8),
                                        np.tile([0.0, 0.0, -1.0], (n, 1)))
    with torch.no_grad():
        g.params["log_scales"].copy_(torch.from_numpy(np.log(rng.uniform(0.005, 0.4, (n, 3)))).float())
        g.params["opacity_logits"].fill_(5.0)
    width, height = 64, 48
    c2w = torch.eye(4)
    c2w[:3, :3] = torch.tensor([[math.cos(0.3), 0.0, math.sin(0.3)], [0.0, 1.0, 0.0],
                                [-math.sin(0.3), 0.0, math.cos(0.3)]])
    camera = Cameras(c2w, Intrinsics(50.0, 50.0, width / 2, height / 2, width, height))
    scene = RelightableScene.create(variant, g, seed=0)
    mask = may_touch_image(g.means, g.scales, camera.viewmat, camera.K, width, height)
    assert 0 < int(mask.sum()) < n  # some are left out
    with torch.no_grad():
        masked = scene.render(camera).image
        everything = rasterize(g.means, g.quats, g.scales, g.opacities, scene.colours(camera.c2w), camera.viewmat,
                               camera.K, width, height).image
        drawn = rasterize(g.means, g.quats, g.scales, g.opacities, torch.ones(n, 1), camera.viewmat, camera.K, width,
                          height)
    assert bool((drawn.radii[~mask] == 0).all())
    torch.testing.assert_close(masked, everything, rtol=0, atol=0)
