"""The lamp's bounce light from the model's geometry (models.lamp_bounce): the matrix-product moments equal a
pair-by-pair sum, a facing disk gives the form factor's irradiance, a box seen from inside gets the light where a
brute-force sum over its pixels puts it, and RelightableScene adds it in training only."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest
import torch

from spotlessgs.io.camera_batch import Cameras
from spotlessgs.io.cameras import Intrinsics
from spotlessgs.models.gaussians import GaussianParams
from spotlessgs.models.lamp_bounce import (
    MIN_ALPHA, LampBounce, _clamped_cosine_irradiance, _incident_moments, one_bounce_irradiance,
)
from spotlessgs.models.relightable import RelightableScene
from spotlessgs.rasterizer import may_touch_image, rasterize
from spotlessgs.models.shading import MODEL_VARIANTS, build_appearance_models


def _legendre_cosine(c: np.ndarray) -> np.ndarray:
    """max(0, c) to degree 2 in Legendre polynomials (what the moments can hold)."""
    return 0.25 + 0.5 * c + (5.0 / 16.0) * (3.0 * c * c - 1.0) / 2.0


def test_moments_equal_a_pair_by_pair_sum():
    rng = np.random.default_rng(0)
    receivers, senders = rng.normal(size=(7, 3)), rng.normal(size=(11, 3)) + [0.0, 0.0, 3.0]
    sender_normals = rng.normal(size=(11, 3))
    sender_normals /= np.linalg.norm(sender_normals, axis=1, keepdims=True)
    area, flux = rng.uniform(0.01, 0.1, 11), rng.uniform(0.0, 2.0, (11, 3))
    normals = rng.normal(size=(7, 3))
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    expected = np.zeros((7, 3))
    for r in range(7):
        for s in range(11):
            t = senders[s] - receivers[r]
            softened = t @ t + area[s] / math.pi
            d = t / math.sqrt(softened)
            emission = max(0.0, -(sender_normals[s] @ d))
            w = flux[s] * emission / softened
            c = normals[r] @ d
            # the moments hold Σ w [1, d, d dᵀ]; with |d| < 1 (softened) the quadratic is 3 (n·d)² - 1 as written
            expected[r] += w * _legendre_cosine(c)
    as_t = {k: torch.as_tensor(v, dtype=torch.float64) for k, v in
            dict(receivers=receivers, senders=senders, sender_normals=sender_normals, sender_area=area,
                 flux=flux).items()}
    got = _clamped_cosine_irradiance(_incident_moments(**as_t), torch.as_tensor(normals))
    np.testing.assert_allclose(got.numpy(), expected, rtol=1e-9, atol=1e-12)


def test_a_facing_disk_gives_its_form_factor():
    """A Lambertian disk of radius a and radiance L at height h above a receiver facing it gives E = π L a² /
    (h² + a²) (the disk's form factor); the degree-2 cosine holds it to a few per cent."""
    radius, height, radiance = 1.0, 1.0, 0.7
    step = 0.02
    grid = np.arange(-radius, radius, step) + step / 2
    x, y = np.meshgrid(grid, grid)
    inside = x * x + y * y <= radius * radius
    senders = np.stack([x[inside], y[inside], np.full(inside.sum(), height)], -1)
    count = len(senders)
    moments = _incident_moments(
        torch.zeros((1, 3), dtype=torch.float64), torch.as_tensor(senders),
        torch.as_tensor(np.tile([0.0, 0.0, -1.0], (count, 1))), torch.full((count,), step * step, dtype=torch.float64),
        torch.full((count, 3), radiance * step * step, dtype=torch.float64))
    got = _clamped_cosine_irradiance(moments, torch.tensor([[0.0, 0.0, 1.0]], dtype=torch.float64))
    exact = math.pi * radiance * radius**2 / (height**2 + radius**2)
    np.testing.assert_allclose(got.numpy(), exact, rtol=0.05)
    # a receiver turned away from the disk gets (almost) nothing
    away = _clamped_cosine_irradiance(moments, torch.tensor([[0.0, 0.0, -1.0]], dtype=torch.float64))
    assert float(away.abs().max()) < 0.05 * exact


def _box_view(width: int = 64, height: int = 48):
    """A camera at the origin looking down +z into a box: left wall x = -1 (normal +x), floor y = +1 (OpenCV y down,
    normal -y), back wall z = 3 (normal -z). Returns depth (H, W), normals (H, W, 3), which plane (H, W) and K."""
    fx = fy = 40.0
    K = torch.tensor([[fx, 0.0, width / 2], [0.0, fy, height / 2], [0.0, 0.0, 1.0]], dtype=torch.float64)
    u, v = np.meshgrid(np.arange(width) + 0.5, np.arange(height) + 0.5)
    rays = np.stack([(u - width / 2) / fx, (v - height / 2) / fy, np.ones_like(u)], -1)
    planes = [(np.array([1.0, 0.0, 0.0]), -1.0, 0), (np.array([0.0, -1.0, 0.0]), 1.0, 1),
              (np.array([0.0, 0.0, -1.0]), 3.0, 2)]  # (normal, coordinate along its axis, id)
    depth = np.full((height, width), np.inf)
    normals = np.zeros((height, width, 3))
    which = np.full((height, width), -1)
    for normal, coordinate, plane in planes:
        axis = int(np.flatnonzero(normal)[0])
        with np.errstate(divide="ignore", invalid="ignore"):
            t = coordinate / rays[..., axis]  # z along the ray (rays have z = 1)
        hit = (t > 0) & (t < depth)
        depth[hit], normals[hit], which[hit] = t[hit], normal, plane
    return (torch.as_tensor(depth), torch.as_tensor(normals), which, K)


def test_a_box_gets_the_light_a_pixel_by_pixel_sum_gives():
    depth, normals, which, K = _box_view()
    surface = torch.ones(depth.shape, dtype=torch.bool)
    radiance = torch.zeros(*depth.shape, 3, dtype=torch.float64)
    radiance[torch.as_tensor(which == 2)] = torch.tensor([1.0, 0.5, 0.0], dtype=torch.float64)  # the back wall glows
    got = one_bounce_irradiance(radiance, depth, normals, surface, K).numpy()
    # the glowing wall does not light itself (beyond the cells at its edges, whose pooled points leave its plane);
    # red twice green, no blue
    floor_mean = got[which == 1][:, 0].mean()
    assert got[which == 2][:, 0].max() < 0.1 * floor_mean
    assert got[which == 2][:, 0].mean() < 0.01 * floor_mean
    assert np.abs(got[..., 2]).max() < 1e-9
    np.testing.assert_allclose(got[which != 2][..., 1], got[which != 2][..., 0] / 2, atol=1e-9)
    # a floor pixel against the sum over every glowing pixel: footprint z² / (fx fy |cos|) · cos³ of the off-axis angle
    h, w = depth.shape
    u, v = np.meshgrid(np.arange(w) + 0.5, np.arange(h) + 0.5)
    rays = np.stack([(u - w / 2) / 40.0, (v - h / 2) / 40.0, np.ones_like(u)], -1)
    points = rays * depth.numpy()[..., None]
    glowing = which == 2
    length = np.linalg.norm(rays, axis=-1)
    area = depth.numpy() ** 2 / (40.0 * 40.0 * length) / np.abs((normals.numpy() * rays).sum(-1) / length)
    # (pixels a cell or more from the wall's foot: nearer, the pooled emitters sit further than the true ones)
    for row, col in ((h - 3, w // 2), (h - 4, w // 2 - 9), (h - 2, w // 2 + 12)):
        assert which[row, col] == 1
        t = points[glowing] - points[row, col]
        r2 = (t * t).sum(-1)
        d = t / np.sqrt(r2)[:, None]
        exact = (area[glowing] * np.clip(d[:, 2], 0, None) * np.clip(-d[:, 1], 0, None) / r2).sum()
        np.testing.assert_allclose(got[row, col, 0], exact, rtol=0.15)


def test_a_flat_surface_lights_nothing_of_itself():
    w, h = 40, 30
    K = torch.tensor([[30.0, 0.0, 20.0], [0.0, 30.0, 15.0], [0.0, 0.0, 1.0]])
    normals = torch.zeros(h, w, 3)
    normals[..., 2] = -1.0
    got = one_bounce_irradiance(torch.ones(h, w, 3), torch.full((h, w), 2.0), normals, torch.ones(h, w, dtype=torch.bool), K)
    assert float(got.abs().max()) < 1e-6


WIDTH, HEIGHT = 48, 36


def _wall_scene(seed: int = 0) -> GaussianParams:
    """Gaussians on the floor and the back wall of a box seen by a camera at the origin looking down +z."""
    rng = np.random.default_rng(seed)
    floor = np.stack([rng.uniform(-1.5, 1.5, 300), np.full(300, 1.0), rng.uniform(1.0, 3.0, 300)], -1)
    wall = np.stack([rng.uniform(-1.5, 1.5, 300), rng.uniform(-1.0, 1.0, 300), np.full(300, 3.0)], -1)
    normals = np.concatenate([np.tile([0.0, -1.0, 0.0], (300, 1)), np.tile([0.0, 0.0, -1.0], (300, 1))])
    g = GaussianParams.from_point_cloud(np.concatenate([floor, wall]), rng.integers(60, 256, (600, 3)).astype(np.uint8),
                                        normals)
    with torch.no_grad():
        g.params["log_scales"].fill_(math.log(0.12))
        g.params["opacity_logits"].fill_(4.0)
    return g


@pytest.mark.parametrize("variant", ["darkgs", "spotless"])
def test_the_scene_adds_the_bounce_in_training_and_not_in_relighting(variant):
    camera = Cameras(torch.eye(4), Intrinsics(40.0, 40.0, WIDTH / 2, HEIGHT / 2, WIDTH, HEIGHT))
    config = dataclasses.replace(MODEL_VARIANTS[variant], lamp_bounce=True)
    g = _wall_scene()
    with_bounce = RelightableScene.create(config, g, seed=0)
    assert isinstance(with_bounce.appearance.lamp_bounce, LampBounce)
    assert any(k.startswith("modules_.lamp_bounce.") for k in with_bounce.state_dict())  # saved with the run
    without = RelightableScene(MODEL_VARIANTS[variant], g, dataclasses.replace(with_bounce.appearance, lamp_bounce=None))
    lit, plain = with_bounce.render(camera), without.render(camera)
    extra = (lit.image - plain.image).detach()
    assert float(extra.min()) >= -1e-6 and float(extra.max()) > 1e-3  # the floor and the wall light each other
    split = with_bounce.render(camera, split_lights=True).image
    torch.testing.assert_close(split[..., :3] + split[..., 3:], lit.image)
    torch.testing.assert_close(split[..., :3], without.render(camera, split_lights=True).image[..., :3])
    # relighting leaves it out
    torch.testing.assert_close(with_bounce.render(camera, relight_l0=[1.0, 1.0, 1.0]).image,
                               without.render(camera, relight_l0=[1.0, 1.0, 1.0]).image)
    # the gain scales it, and the loss reaches the gain and the albedo through it
    with torch.no_grad():
        with_bounce.appearance.lamp_bounce.log_gain.fill_(math.log(2.0))
    torch.testing.assert_close(with_bounce.render(camera).image - plain.image, 2.0 * extra, rtol=1e-4, atol=1e-6)
    with_bounce.render(camera).image.sum().backward()
    assert float(with_bounce.appearance.lamp_bounce.log_gain.grad) > 0
    assert g.params["albedo_raw"].grad is not None and float(g.params["albedo_raw"].grad.abs().sum()) > 0


def test_only_variants_with_a_lamp_get_one():
    assert build_appearance_models(dataclasses.replace(MODEL_VARIANTS["3dgs"], lamp_bounce=True)).lamp_bounce is None
    assert build_appearance_models(MODEL_VARIANTS["spotless"]).lamp_bounce is None  # off by default


def test_a_given_irradiance_is_the_one_the_render_uses():
    camera = Cameras(torch.eye(4), Intrinsics(40.0, 40.0, WIDTH / 2, HEIGHT / 2, WIDTH, HEIGHT))
    g = _wall_scene()
    scene = RelightableScene.create(dataclasses.replace(MODEL_VARIANTS["spotless"], lamp_bounce=True), g, seed=0)
    without = RelightableScene(MODEL_VARIANTS["spotless"], g, dataclasses.replace(scene.appearance, lamp_bounce=None))
    irradiance = scene.lamp_bounce_irradiance(camera)
    assert irradiance.shape == (HEIGHT, WIDTH, 3) and not irradiance.requires_grad and float(irradiance.max()) > 0
    # the irradiance it would compute itself, the same render; none, the render without the bounce
    torch.testing.assert_close(scene.render(camera, lamp_irradiance=irradiance).image, scene.render(camera).image,
                               rtol=0, atol=0)
    plain = without.render(camera).image
    torch.testing.assert_close(scene.render(camera, lamp_irradiance=torch.zeros_like(irradiance)).image, plain)
    # an older one (here: twice as bright) gives the bounce light of its own irradiance
    doubled = scene.render(camera, lamp_irradiance=2.0 * irradiance).image - plain
    torch.testing.assert_close(doubled, 2.0 * (scene.render(camera).image - plain), rtol=1e-4, atol=1e-6)
    out, moments = scene.render_with_depth_moments(camera, lamp_irradiance=irradiance)
    torch.testing.assert_close(out.image, scene.render(camera).image, rtol=0, atol=0)
    assert out.lamp_irradiance is irradiance and scene.render(camera, relight_l0=[1.0, 1.0, 1.0]).lamp_irradiance is None
    with pytest.raises(ValueError, match="no lamp bounce"):
        without.lamp_bounce_irradiance(camera)


@pytest.mark.parametrize("split_lights", [False, True])
def test_the_irradiance_computed_in_the_renders_own_pass_equals_a_pass_of_its_own(split_lights):
    """The render computes a new irradiance from channels it composites beside the colour; a separate forward pass
    of the spotlight's part of the colour and the camera-frame normals gives the same, bit for bit, and so does
    the pass with the depth moments."""
    camera = Cameras(torch.eye(4), Intrinsics(40.0, 40.0, WIDTH / 2, HEIGHT / 2, WIDTH, HEIGHT))
    g = _wall_scene(seed=3)
    scene = RelightableScene.create(dataclasses.replace(MODEL_VARIANTS["spotless"], lamp_bounce=True), g, seed=1)
    with torch.no_grad():
        scene.appearance.lf_light.coeffs.normal_(0.0, 0.3, generator=torch.Generator().manual_seed(2))
    out = scene.render(camera, split_lights=split_lights)
    with torch.no_grad():
        mask = may_touch_image(g.means, g.scales, camera.viewmat, camera.K, camera.width, camera.height)
        spot = scene.colours(camera.c2w, mask=mask, split_lights=True)[:, :3]
        alone = rasterize(g.means, g.quats, g.scales, g.opacities, torch.cat([spot, scene.camera_normals(camera.c2w)], 1),
                          camera.viewmat, camera.K, camera.width, camera.height)
        normals = torch.nn.functional.normalize(alone.image[..., 3:], dim=-1)
        expected = one_bounce_irradiance(alone.image[..., :3], alone.depth, normals, alone.alpha >= MIN_ALPHA,
                                         camera.K)
    assert float(expected.max()) > 0
    torch.testing.assert_close(out.lamp_irradiance, expected, rtol=0, atol=0)
    assert out.image.shape == (HEIGHT, WIDTH, 6 if split_lights else 3)  # the bounce's channels are taken off
    given = scene.render(camera, split_lights=split_lights, lamp_irradiance=expected)
    torch.testing.assert_close(out.image, given.image, rtol=0, atol=0)
    with_moments, moments = scene.render_with_depth_moments(camera)
    torch.testing.assert_close(with_moments.lamp_irradiance, expected, rtol=0, atol=0)
    assert moments.shape == (HEIGHT, WIDTH, 2)


def test_training_reuses_each_views_irradiance_for_lamp_bounce_every_steps():
    from spotlessgs.training.config import TrainConfig
    from spotlessgs.training.view_caches import LampBounceCache

    camera = Cameras(torch.eye(4), Intrinsics(40.0, 40.0, WIDTH / 2, HEIGHT / 2, WIDTH, HEIGHT))
    g = _wall_scene()
    scene = RelightableScene.create(dataclasses.replace(MODEL_VARIANTS["darkgs"], lamp_bounce=True), g, seed=0)
    cache = LampBounceCache(TrainConfig(lamp_bounce_every=3))

    def fitted(view: int, step: int) -> torch.Tensor:  # as the trainer's step renders a view
        irradiance = scene.render(camera, lamp_irradiance=cache.fresh(view, step)).lamp_irradiance
        cache.keep(view, step, irradiance)
        return irradiance

    assert cache.fresh(0, 10) is None
    first = fitted(0, 10)
    torch.testing.assert_close(first, scene.lamp_bounce_irradiance(camera), rtol=0, atol=0)
    with torch.no_grad():
        g.params["albedo_raw"].add_(1.0)  # a brighter spotlit render: more bounce light once recomputed
    assert fitted(0, 12) is first and cache.fresh(0, 12) is first and fitted(1, 12) is not first
    again = fitted(0, 13)  # three steps old: computed again
    assert float(again.sum()) > 1.01 * float(first.sum())
    cache.keep(0, 14, first)  # a fresh one is not replaced
    assert cache.fresh(0, 14) is again
    restored = LampBounceCache(TrainConfig())
    restored.load_state_dict(cache.state_dict(), "cpu")
    assert set(restored.kept) == {0, 1} and restored.kept[0][0] == 13
    torch.testing.assert_close(restored.kept[0][1], again, rtol=0, atol=0)
    restored.load_state_dict({0: {"step": 4}}, "cpu")  # an entry without its tensor: computed anew when next used
    assert restored.kept == {}
    assert RelightableScene.create(MODEL_VARIANTS["darkgs"], g, seed=0).render(camera).lamp_irradiance is None
    with pytest.raises(ValueError, match="lamp_bounce_every"):
        TrainConfig(lamp_bounce_every=0)
