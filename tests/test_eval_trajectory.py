"""Umeyama similarity alignment, ATE and RRE against hand-made trajectories."""

from __future__ import annotations

import numpy as np
import pytest

from evaluation.trajectory import rotation_angle_deg, trajectory_errors, umeyama


def _rot(axis, deg):
    axis = np.asarray(axis, float) / np.linalg.norm(axis)
    k = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
    t = np.radians(deg)
    return np.eye(3) + np.sin(t) * k + (1 - np.cos(t)) * k @ k


def _trajectory(n=12):
    poses = np.tile(np.eye(4), (n, 1, 1))
    for i in range(n):
        poses[i, :3, :3] = _rot([0, 0, 1], 10 * i) @ _rot([1, 0, 0], 3 * np.sin(i))
        poses[i, :3, 3] = [np.cos(i / 3), np.sin(i / 2), 0.1 * i]
    return poses


def test_umeyama_recovers_a_similarity():
    rng = np.random.default_rng(0)
    src = rng.normal(size=(20, 3))
    r, s, t = _rot([1, 2, 3], 40), 2.7, np.array([1.0, -2.0, 0.5])
    sim = umeyama(src, s * src @ r.T + t)
    assert sim.scale == pytest.approx(s, rel=1e-12)
    np.testing.assert_allclose(sim.rotation, r, atol=1e-12)
    np.testing.assert_allclose(sim.translation, t, atol=1e-12)
    rigid = umeyama(src, src @ r.T + t, with_scale=False)
    assert rigid.scale == 1.0


def test_umeyama_returns_a_proper_rotation_for_mirrored_data():
    rng = np.random.default_rng(1)
    src = rng.normal(size=(10, 3))
    sim = umeyama(src, src * np.array([1, 1, -1]))
    assert np.linalg.det(sim.rotation) == pytest.approx(1.0)


def test_errors_vanish_for_a_similar_copy_and_rre_is_alignment_free():
    true = _trajectory()
    s, r, t = 0.3, _rot([0, 1, 1], 70), np.array([5.0, 1.0, -2.0])
    est = true.copy()
    est[:, :3, 3] = s * true[:, :3, 3] @ r.T + t
    est[:, :3, :3] = r @ true[:, :3, :3]
    e = trajectory_errors(est, true)
    assert e.ate_rmse < 1e-10 and e.ate_mean < 1e-10 and e.rre_mean_deg < 1e-6
    assert e.alignment.scale == pytest.approx(1 / s, rel=1e-10)
    assert e.num_poses == len(true)


def test_known_errors():
    true = _trajectory(6)
    est = true.copy()
    # a 2° world-frame rotation applied from frame 3 on changes exactly one relative rotation (2..3), by 2°
    est[3:, :3, :3] = _rot([0, 1, 0], 2.0) @ est[3:, :3, :3]
    e = trajectory_errors(est, true)
    assert e.rre_mean_deg == pytest.approx(2.0 / 5, rel=1e-9)
    assert e.ate_rmse < 1e-10
    # translation noise on one frame: ATE > 0 but below the displacement
    est2 = true.copy()
    est2[2, :3, 3] += [0.1, 0, 0]
    e2 = trajectory_errors(est2, true)
    assert 0 < e2.ate_rmse < 0.1


def test_rotation_angle_edge_cases():
    assert rotation_angle_deg(np.eye(3)) == pytest.approx(0.0, abs=1e-12)
    assert rotation_angle_deg(_rot([0, 0, 1], 180)) == pytest.approx(180.0, abs=1e-9)
    assert rotation_angle_deg(_rot([1, 1, 0], 1e-4)) == pytest.approx(1e-4, rel=1e-6)


def test_errors():
    with pytest.raises(ValueError, match=r"at least 3 points, got 2"):
        umeyama(np.zeros((2, 3)), np.zeros((2, 3)))
    with pytest.raises(ValueError, match="same shape"):
        umeyama(np.zeros((4, 3)), np.zeros((5, 3)))
    with pytest.raises(ValueError, match="all identical"):
        umeyama(np.ones((4, 3)), np.zeros((4, 3)))
    with pytest.raises(ValueError, match=r"\(N, 4, 4\) pose arrays"):
        trajectory_errors(np.zeros((3, 3, 4)), np.zeros((3, 3, 4)))
