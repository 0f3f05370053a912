"""Spotlight shadows: a square in front of a wall casts the shadow that ray geometry predicts, from the lamp's learned
pose; visibility reaches the light pose's gradient; shading scales the spotlight's term only; relighting has none."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest
import torch

from spotlessgs.io.camera_batch import Cameras
from spotlessgs.io.cameras import Intrinsics
from spotlessgs.models.gaussians import GaussianParams
from spotlessgs.models.light import SpotLight
from spotlessgs.models.relightable import RelightableScene
from spotlessgs.models.shading import MODEL_VARIANTS, build_appearance_models, shade
from spotlessgs.models.shadow import map_visibility, render_shadow_map, shadow_map_camera, spot_visibility

WALL_Z, OCCLUDER_Z, OCCLUDER_HALF = 2.0, 1.0, 0.15
K = torch.tensor([[100.0, 0.0, 64.0], [0.0, 100.0, 48.0], [0.0, 0.0, 1.0]])
WIDTH, HEIGHT = 128, 96


def _grid(half: float, z: float, step: float) -> np.ndarray:
    ticks = np.arange(-half, half + 1e-9, step)
    x, y = np.meshgrid(ticks, ticks)
    return np.stack([x.ravel(), y.ravel(), np.full(x.size, z)], axis=1)


def _wall_and_occluder() -> tuple[GaussianParams, int]:
    """An opaque wall at z = 2 m (3 cm grid) and a 30 cm square at z = 1 m (1.5 cm grid), facing the camera at the
    origin (c2w = identity, looking down +z); returns the Gaussians and how many of them are the wall's."""
    wall, occluder = _grid(1.2, WALL_Z, 0.03), _grid(OCCLUDER_HALF, OCCLUDER_Z, 0.015)
    xyz = np.concatenate([wall, occluder])
    g = GaussianParams.from_point_cloud(xyz, np.full((len(xyz), 3), 128, np.uint8), np.tile([0.0, 0.0, -1.0],
                                                                                           (len(xyz), 1)))
    with torch.no_grad():
        g.params["opacity_logits"].fill_(4.0)  # opaque (0.98)
    return g, len(wall)


def _visibility(g: GaussianParams, light: SpotLight) -> torch.Tensor:
    """(N, 1) the lit fraction for the camera at the origin looking down +z, from a new shadow map."""
    return spot_visibility(g, light, render_shadow_map(g, light, torch.eye(4), K, WIDTH, HEIGHT))


def _in_shadow_by_geometry(points: np.ndarray, lamp: np.ndarray, inset: float) -> np.ndarray:
    """Whether the segment from each point to the lamp crosses the occluder square shrunk by ``inset`` (m)."""
    s = (OCCLUDER_Z - lamp[2]) / (points[:, 2] - lamp[2])
    hit = lamp[:2] + s[:, None] * (points[:, :2] - lamp[:2])
    return (np.abs(hit) < OCCLUDER_HALF - inset).all(axis=1) & (points[:, 2] > OCCLUDER_Z + 0.1)


def _lamp_visibility(g: GaussianParams, light: SpotLight) -> torch.Tensor:
    """(N,) the lit fraction against the lamp's own map alone (not relative to the camera's view)."""
    shadow_map = render_shadow_map(g, light, torch.eye(4), K, WIDTH, HEIGHT)
    view = shadow_map.world_to_lamp
    return map_visibility(shadow_map.moments, g.means.detach() @ view[:3, :3].T + view[:3, 3], shadow_map.K_map)[:, 0]


@pytest.mark.parametrize("translation", [[0.1, 0.0, 0.0], [0.0, -0.08, 0.03]])
def test_square_casts_the_shadow_that_ray_geometry_predicts(translation):
    g, n_wall = _wall_and_occluder()
    light = build_appearance_models("darkgs", seed=0, light_translation=translation).light
    vis = _lamp_visibility(g, light).numpy()
    xyz = g.means.detach().numpy()
    lamp = np.asarray(translation, float)
    # The occluder's Gaussians (σ = 1.5 cm) soften its edge by about 3σ: 4.5 cm at its plane, 9 cm on the wall.
    dark = _in_shadow_by_geometry(xyz, lamp, inset=0.01)
    lit = ~_in_shadow_by_geometry(xyz, lamp, inset=-0.045)
    wall_in_view = np.zeros(len(xyz), bool)
    wall_in_view[:n_wall] = (np.abs(xyz[:n_wall, :2]) < 0.9).all(axis=1)
    assert dark.sum() > 50 and (wall_in_view & lit).sum() > 500
    assert vis[dark].max() < 0.01
    assert vis[wall_in_view & lit].min() > 0.99
    assert vis[n_wall:].min() > 0.99  # the occluder itself is lit (it is the first surface)


@pytest.mark.parametrize("translation", [[0.3, 0.0, 0.0], [0.0, -0.3, 0.03]])
def test_the_camera_sees_the_shadow_beside_the_occluder(translation):
    """Relative to the camera's view: what the camera sees is dark where the lamp's shadow falls on it (a lamp 30 cm
    off the camera, so that a band of shadow shows beside the square) and lit elsewhere."""
    g, n_wall = _wall_and_occluder()
    light = build_appearance_models("darkgs", seed=0, light_translation=translation).light
    vis = _visibility(g, light)[:, 0].detach().numpy()
    xyz = g.means.detach().numpy()
    seen = ~_in_shadow_by_geometry(xyz, np.zeros(3), inset=-0.045)  # not behind the square from the camera
    dark = _in_shadow_by_geometry(xyz, np.asarray(translation, float), inset=0.01) & seen
    lit = ~_in_shadow_by_geometry(xyz, np.asarray(translation, float), inset=-0.045) & seen
    lit[:n_wall] &= (np.abs(xyz[:n_wall, :2]) < 0.9).all(axis=1)
    assert dark.sum() > 20 and lit[:n_wall].sum() > 500
    assert vis[dark].max() < 0.01 and vis[lit].min() > 0.99


def test_a_lamp_at_the_camera_casts_no_shadow_the_camera_sees():
    """No parallax, no visible shadow: everything the camera sees is lit, the wall behind the square included where
    the camera sees past its soft edge; the lamp's own map does shadow it there."""
    g, _ = _wall_and_occluder()
    light = build_appearance_models("darkgs", seed=0, light_translation=[0.0, 0.0, 0.0]).light
    vis = _visibility(g, light)[:, 0].detach()
    shadow_map = render_shadow_map(g, light, torch.eye(4), K, WIDTH, HEIGHT)
    camera_lit = map_visibility(shadow_map.camera_moments, g.means.detach(), shadow_map.K_map)[:, 0]
    seen = camera_lit > 0.05
    assert int((seen & (camera_lit < 0.9)).sum()) > 10  # partly hidden Gaussians along the square's soft edge
    assert float(vis[seen].min()) > 0.99


def test_a_fuzzy_surface_does_not_shadow_itself():
    """A thick, half-transparent cloud (a surface fitted loosely, as from a sparse start): the lamp's map alone sees
    its back half behind its front half, but the camera, 5 cm from the lamp, sees it so too: it is lit."""
    rng = np.random.default_rng(0)
    xyz = np.concatenate([rng.uniform(-0.8, 0.8, (3000, 2)), rng.normal(2.0, 0.2, (3000, 1))], axis=1)
    g = GaussianParams.from_point_cloud(xyz, np.full((len(xyz), 3), 128, np.uint8))
    with torch.no_grad():
        g.params["opacity_logits"].fill_(0.0)  # 0.5
        g.params["log_scales"].fill_(float(np.log(0.04)))
    light = build_appearance_models("darkgs", seed=0, light_translation=[0.05, 0.0, 0.0]).light
    lamp_only = _lamp_visibility(g, light)
    vis = _visibility(g, light)[:, 0].detach()
    shadow_map = render_shadow_map(g, light, torch.eye(4), K, WIDTH, HEIGHT)
    camera_lit = map_visibility(shadow_map.camera_moments, g.means.detach(), shadow_map.K_map)[:, 0]
    seen = camera_lit > 0.1
    assert int(seen.sum()) > 1000 and float(lamp_only[seen].mean()) < 0.7  # (0.57)
    assert float(vis[seen].mean()) > 0.95 and float(vis[seen].quantile(0.05)) > 0.85  # (0.98, 0.88)


def test_shadow_moves_with_the_light():
    g, _ = _wall_and_occluder()
    xyz = g.means.detach().numpy()
    # Ray geometry: the shadow's left edge on the wall is at x = t + 2 (-0.15 - t) = -0.3 - t for a lamp at (t, 0, 0).
    band = (xyz[:, 2] > 1.5) & (np.abs(xyz[:, 1]) < 0.1) & (xyz[:, 0] > -0.45) & (xyz[:, 0] < -0.35)
    means = []
    for t in (0.0, 0.2):  # edge at -0.3 (the band lit), then at -0.5 (the band in shadow)
        light = build_appearance_models("darkgs", seed=0, light_translation=[t, 0.0, 0.0]).light
        means.append(float(_visibility(g, light).detach()[torch.from_numpy(band)].mean()))
    assert band.sum() >= 20 and means[0] > 0.9 and means[1] < 0.1


def _band_visibility(g: GaussianParams, band: torch.Tensor, translation) -> tuple[torch.Tensor, SpotLight]:
    light = build_appearance_models("darkgs", seed=0, light_translation=translation).light
    return _visibility(g, light)[band].sum(), light


def test_the_lamp_position_gradient_is_the_shadows_own():
    """The gradient of the lit fraction w.r.t. the lamp's position matches central differences, which re-render the
    map; a fixed map's plain gradient has the opposite sign (the receivers move in it, the occluders do not)."""
    g, _ = _wall_and_occluder()
    xyz = g.means.detach().numpy()
    band = torch.from_numpy((xyz[:, 2] > 1.5) & (np.abs(xyz[:, 1]) < 0.1) & (xyz[:, 0] > -0.5) & (xyz[:, 0] < -0.3))
    lit, light = _band_visibility(g, band, [0.1, 0.0, 0.0])
    lit.backward()
    analytic = float(light.translation.grad[0])
    h = 0.005
    numeric = (float(_band_visibility(g, band, [0.1 + h, 0.0, 0.0])[0].detach())
               - float(_band_visibility(g, band, [0.1 - h, 0.0, 0.0])[0].detach())) / (2 * h)
    assert numeric < -100  # the lamp moving right moves the shadow's left edge into the band
    assert analytic == pytest.approx(numeric, rel=0.25)
    assert light.rotvec.grad is None or float(light.rotvec.grad.abs().max()) == 0.0  # rotation moves no shadow
    assert not g.params["means"].requires_grad or g.params["means"].grad is None


def test_outside_the_map_and_behind_the_lamp_is_lit():
    moments = torch.ones(3, 10, 10)  # an opaque surface at 1 m everywhere: A = 1, S1 = 1 m, S2 = 1 m²
    K_map = torch.tensor([[10.0, 0.0, 5.0], [0.0, 10.0, 5.0], [0.0, 0.0, 1.0]])
    points = torch.tensor([[0.0, 0.0, 3.0],     # behind the surface, inside the map: shadow
                           [0.0, 0.0, 1.0],     # on it: lit
                           [10.0, 0.0, 3.0],    # outside the map
                           [0.0, 0.0, -2.0]])   # behind the lamp
    vis = map_visibility(moments, points, K_map)[:, 0]
    assert vis[0] < 1e-6 and vis[1] == 1.0 and vis[2] == 1.0 and vis[3] == 1.0


def test_map_covers_the_camera_view_with_a_margin():
    K_map, w, h = shadow_map_camera(K, WIDTH, HEIGHT)
    assert w > WIDTH and h > HEIGHT and float(K_map[0, 0]) == 100.0
    K_half, w_half, _ = shadow_map_camera(K, WIDTH, HEIGHT, map_scale=0.5)
    assert abs(w_half - w / 2) <= 1 and float(K_half[0, 0]) == 50.0
    with pytest.raises(ValueError, match="scale"):
        shadow_map_camera(K, WIDTH, HEIGHT, map_scale=0.0)


def test_shading_scales_the_spotlight_term_only_and_relighting_ignores_it():
    g, _ = _wall_and_occluder()
    cfg = MODEL_VARIANTS["darkgs"]
    m = build_appearance_models(cfg, seed=0, light_translation=[0.1, 0.0, 0.0])
    c2w = torch.eye(4)
    vis = torch.rand(len(g), 1, generator=torch.Generator().manual_seed(0))
    halves = shade(cfg, g, m.light, m.lf_light, m.brdf, c2w, split_lights=True)
    shadowed = shade(cfg, g, m.light, m.lf_light, m.brdf, c2w, split_lights=True, spot_visibility=vis)
    torch.testing.assert_close(shadowed[:, :3], halves[:, :3] * vis)
    torch.testing.assert_close(shadowed[:, 3:], halves[:, 3:])
    relit = shade(cfg, g, m.light, m.lf_light, m.brdf, c2w, relight_l0=[1.0, 1.0, 1.0])
    relit_vis = shade(cfg, g, m.light, m.lf_light, m.brdf, c2w, relight_l0=[1.0, 1.0, 1.0], spot_visibility=vis)
    torch.testing.assert_close(relit, relit_vis)
    with pytest.raises(ValueError, match="spot_visibility"):
        shade(cfg, g, m.light, m.lf_light, m.brdf, c2w, spot_visibility=vis[:5])


def test_scene_with_spot_shadows_darkens_the_shadow_the_camera_sees():
    g, _ = _wall_and_occluder()
    camera = Cameras(torch.eye(4), Intrinsics(100.0, 100.0, 64.0, 48.0, WIDTH, HEIGHT))
    renders, relit = {}, {}
    for shadows in (False, True):
        cfg = dataclasses.replace(MODEL_VARIANTS["darkgs"], spot_shadows=shadows)
        scene = RelightableScene.create(cfg, g, seed=0, light_translation=[0.3, 0.0, 0.0])
        with torch.no_grad():
            scene.appearance.lf_light.log_value.fill_(-30.0)  # no ambient: the shadow is black
        renders[shadows] = scene.render(camera).image.detach().mean(-1)
        relit[shadows] = scene.render(camera, relight_l0=[1.0, 1.0, 1.0]).image.detach()
    torch.testing.assert_close(relit[True], relit[False])  # uniform light casts no shadow
    # A lamp 30 cm right of the camera shades the wall from x = 0.3 + 2 (-0.15 - 0.3) = -0.6 m to 0; the camera at
    # the origin sees the wall from -0.6 to -0.3 m of it (pixels u = 64 + 100 x / 2 in [34, 49]; the square's
    # Gaussians cover u >= 45): columns 36-41 show the shadow, rows around the middle.
    strip = (slice(40, 56), slice(36, 42))
    right_of_square = (slice(40, 56), slice(82, 88))
    assert float(renders[True][strip].mean()) < 0.2 * float(renders[False][strip].mean())
    torch.testing.assert_close(renders[True][right_of_square], renders[False][right_of_square], rtol=0.03, atol=1e-4)


def test_a_reused_map_gives_the_shadows_of_when_it_was_rendered():
    g, _ = _wall_and_occluder()
    light = build_appearance_models("darkgs", seed=0, light_translation=[0.0, 0.0, 0.0]).light
    old_map = render_shadow_map(g, light, torch.eye(4), K, WIDTH, HEIGHT)
    before = spot_visibility(g, light, old_map)
    with torch.no_grad():
        light.translation.copy_(torch.tensor([0.2, 0.0, 0.0]))  # a new map would move the shadow by 40 cm
    torch.testing.assert_close(spot_visibility(g, light, old_map), before)
    assert float((_visibility(g, light) - before).detach().abs().max()) > 0.9


def test_training_reuses_each_views_map_for_shadow_map_every_steps():
    from spotlessgs.training.config import TrainConfig
    from spotlessgs.training.view_caches import ShadowMapCache

    g, _ = _wall_and_occluder()
    camera = Cameras(torch.eye(4), Intrinsics(100.0, 100.0, 64.0, 48.0, WIDTH, HEIGHT))
    scene = RelightableScene.create(dataclasses.replace(MODEL_VARIANTS["darkgs"], spot_shadows=True), g, seed=0)
    cache = ShadowMapCache(TrainConfig(shadow_map_every=3))  # (default 180)
    first = cache.get(scene, 0, 10, camera)
    assert cache.get(scene, 0, 12, camera) is first and cache.get(scene, 1, 12, camera) is not first
    assert cache.get(scene, 0, 13, camera) is not first  # three steps old: rendered again
    state = cache.state_dict()
    restored = ShadowMapCache(TrainConfig())
    restored.load_state_dict(state, "cpu")
    assert set(restored.kept) == {0, 1} and restored.kept[0][0] == 13
    torch.testing.assert_close(restored.kept[0][1].camera_moments, cache.kept[0][1].camera_moments)
    lamp_only = {view: {k: v for k, v in entry.items() if k not in ("camera_moments", "world_to_camera")}
                 for view, entry in state.items()}  # a checkpoint from before the camera's own map
    restored.load_state_dict(lamp_only, "cpu")
    assert restored.kept == {}  # its views render new maps
    plain = RelightableScene.create(MODEL_VARIANTS["darkgs"], g, seed=0)
    assert ShadowMapCache(TrainConfig()).get(plain, 0, 0, camera) is None
    with pytest.raises(ValueError, match="shadow_map_every"):
        TrainConfig(shadow_map_every=0)


def test_tiny_huge_and_lamp_hugging_gaussians_give_finite_shadows_and_gradients():
    rng = np.random.default_rng(0)
    xyz = np.concatenate([rng.uniform(-1, 1, (200, 3)) * [1, 1, 0.5] + [0, 0, 2],
                          [[0.1, 0.0, 0.0], [0.1, 0.0, 0.002], [0.0, 0.0, 1e-4], [0.0, 0.0, -1.0]]])
    g = GaussianParams.from_point_cloud(xyz, np.full((len(xyz), 3), 200, np.uint8))
    with torch.no_grad():
        g.params["log_scales"][:50] = math.log(1e-7)   # tiny
        g.params["log_scales"][50:60] = math.log(50.0)  # huge
        g.params["opacity_logits"].fill_(8.0)          # opaque
    light = build_appearance_models("darkgs", seed=0, light_translation=[0.1, 0.0, 0.0]).light
    vis = _visibility(g, light)
    vis.sum().backward()
    assert torch.isfinite(vis).all() and float(vis.detach().min()) >= 0.0 and float(vis.detach().max()) <= 1.0
    assert torch.isfinite(light.translation.grad).all()
