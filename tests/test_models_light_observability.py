"""The lamp-position cues measured from true geometry (spotlessgs.models.light_observability)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from spotlessgs.models.light_observability import edge_parallax, shading_sensitivity


def test_edge_parallax_is_the_shadow_shift_per_metre_of_lamp_offset_at_depth_edges():
    # An occluder 1 m away over a wall 2 m away, f = 100 px: a lamp 1 m to the side moves the shadow edge
    # f (1/1 - 1/2) = 50 px (the occluder's image by f/1, the wall's by f/2); one edge pair per row.
    depth = np.full((4, 6), 2.0)
    depth[:, :3] = 1.0
    np.testing.assert_allclose(edge_parallax(depth, 100.0), np.full(4, 50.0))
    # The same across rows (a horizontal edge), and nothing behind the occluder (inf) is no edge.
    np.testing.assert_allclose(edge_parallax(depth.T, 100.0), np.full(4, 50.0))
    sky = depth.copy()
    sky[:, 3:] = np.inf
    assert edge_parallax(sky, 100.0).size == 0
    # A slanted wall whose neighbouring depths differ by less than 10 % has no edge.
    assert edge_parallax(np.tile(np.linspace(1.0, 1.2, 6), (4, 1)), 100.0).size == 0
    with pytest.raises(ValueError, match="depth must be"):
        edge_parallax(np.ones(5), 100.0)


def _sphere(count: int) -> np.ndarray:
    """(count, 3) unit vectors spread evenly over the sphere (Fibonacci lattice)."""
    i = np.arange(count) + 0.5
    z = 1.0 - 2.0 * i / count
    phi = math.pi * (1.0 + math.sqrt(5.0)) * i
    rho = np.sqrt(1.0 - z * z)
    return np.stack([rho * np.cos(phi), rho * np.sin(phi), z], axis=1)


def test_shading_sensitivity_on_a_sphere_around_the_lamp():
    # Points on a sphere of radius R around the lamp, facing it (cos θ = 1). Moving the lamp by δ changes each one's
    # distance by -δ·u (u its direction from the lamp) and its cosine only to second order, so log(cos/r²) changes by
    # 2 δ·u / R: its spread over the sphere is 2 δ / (R √3) along every axis.
    radius, step = 2.0, 0.01
    directions = _sphere(20000)
    points = radius * directions
    expected = 2.0 * step / (radius * math.sqrt(3.0))
    np.testing.assert_allclose(shading_sensitivity(points, -directions, np.zeros(3), step), expected, rtol=0.02)
    # Twice as far: half the cue.
    np.testing.assert_allclose(shading_sensitivity(2 * points, -directions, np.zeros(3), step), expected / 2,
                               rtol=0.02)


def test_shading_sensitivity_ignores_a_common_factor_and_points_facing_away():
    # One point alone: any move changes its light by one factor, which the learned power absorbs.
    assert np.all(shading_sensitivity(np.array([[0.0, 0.0, 2.0]]), np.array([[0.0, 0.0, -1.0]]), np.zeros(3)) == 0.0)
    # Points facing away from the lamp do not count.
    away = shading_sensitivity(np.array([[0.0, 0.0, 2.0], [1.0, 0.0, 2.0]]), np.array([[0.0, 0.0, 1.0]] * 2),
                               np.zeros(3))
    assert np.all(away == 0.0)
    with pytest.raises(ValueError, match="must be"):
        shading_sensitivity(np.zeros((2, 3)), np.zeros((3, 3)), np.zeros(3))
