"""Tests of the rectangular camera path: geometry, noise statistics, rejection, determinism, non-rectangular rooms."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from scipy.spatial.transform import Rotation
from scipy.stats import chi2, norm
from shapely.geometry import Point, Polygon

from simulator.trajectory import (
    PATHS,
    TrajectoryConfig,
    largest_inscribed_rectangle,
    nominal_trajectory,
    rectangle_path,
    sample_trajectory,
    trajectory_rectangle,
)

SQUARE = np.array([[0.0, 0.0], [4.0, 0.0], [4.0, 4.0], [0.0, 4.0]])
L_ROOM = np.array([[0.0, 0.0], [6.0, 0.0], [6.0, 3.0], [3.0, 3.0], [3.0, 5.0], [0.0, 5.0]])
# Two-sided probability of a false alarm for each statistical check (the seeds are fixed, so the tests are
# deterministic; this only sets how wide the acceptance bands are).
ALPHA = 1e-6


def _forward(c2w: np.ndarray) -> np.ndarray:
    """Viewing direction of OpenGL camera-to-world poses: the camera looks along its -z axis."""
    return -c2w[..., :3, 2]


def test_square_room_hand_computed_poses():
    # 4x4 room, margin 0.5 -> rectangle [0.5, 3.5]^2, perimeter 12; 4 frames at arc length 1.5, 4.5, 7.5, 10.5.
    cfg = TrajectoryConfig(n_frames=4, height=1.2, margin=0.5)
    poses = nominal_trajectory(SQUARE, floor_z=0.3, config=cfg)
    expected_xy = [[2.0, 0.5], [3.5, 2.0], [2.0, 3.5], [0.5, 2.0]]
    np.testing.assert_allclose(poses[:, :2, 3], expected_xy, atol=1e-12)
    np.testing.assert_allclose(poses[:, 2, 3], 1.5)
    expected_forward = [[0, 1, 0], [-1, 0, 0], [0, -1, 0], [1, 0, 0]]  # towards the room centre
    np.testing.assert_allclose(_forward(poses), expected_forward, atol=1e-12)
    np.testing.assert_allclose(poses[:, :3, 1], np.tile([0.0, 0.0, 1.0], (4, 1)), atol=1e-12)  # camera up = +z
    np.testing.assert_allclose(np.linalg.det(poses[:, :3, :3]), 1.0)
    outward = nominal_trajectory(SQUARE, 0.3, TrajectoryConfig(n_frames=4, height=1.2, margin=0.5, facing="outward"))
    np.testing.assert_allclose(_forward(outward), -np.array(expected_forward), atol=1e-12)


def test_facing_the_centre_turns_smoothly_where_the_paper_loop_turns_by_90_degrees():
    """4x4 room, margin 0.5: the rectangle [0.5, 3.5]^2 around the centre (2, 2). Facing the centre, a frame at
    (2, 0.5) looks along +y; along a 40-frame loop (0.3 m apart) consecutive views turn by at most 11.4°, never by the
    paper loop's 90° at the corners."""
    poses = nominal_trajectory(SQUARE, 0.0, TrajectoryConfig(n_frames=4, margin=0.5, facing="centre"))
    np.testing.assert_allclose(_forward(poses), [[0, 1, 0], [-1, 0, 0], [0, -1, 0], [1, 0, 0]], atol=1e-12)
    n = 40
    centre_view = _forward(nominal_trajectory(SQUARE, 0.0, TrajectoryConfig(n_frames=n, margin=0.5, facing="centre")))
    paper_view = _forward(nominal_trajectory(SQUARE, 0.0, TrajectoryConfig(n_frames=n, margin=0.5)))

    def turns(forward):  # degrees between consecutive frames, around the loop
        cos = np.einsum("ij,ij->i", forward, np.roll(forward, -1, axis=0))
        return np.degrees(np.arccos(np.clip(cos, -1, 1)))

    assert turns(paper_view).max() == pytest.approx(90.0) and (turns(paper_view) < 1e-6).sum() == n - 4
    # most at mid-side, nearest the centre: frames 0.15 m either side of (2, 0.5) turn by 2 atan(0.15 / 1.5) = 11.4°
    assert turns(centre_view).max() == pytest.approx(np.degrees(2 * np.arctan(0.15 / 1.5)), abs=1e-6)
    assert turns(centre_view).sum() == pytest.approx(360.0)
    sample = sample_trajectory(SQUARE, 0.0, 3.0, [], dataclasses.replace(PATHS["robot"], n_frames=n, margin=0.5),
                               np.random.default_rng(0))
    assert turns(_forward(sample)).max() < 20.0  # 2 cm / 0.02 rad noise keeps the views overlapping


def _arc_length(xy: np.ndarray, rect) -> np.ndarray:
    """Counter-clockwise arc length from (x0, y0), computed from which side of the rectangle a point lies on."""
    x0, y0, x1, y1 = rect
    w, h = x1 - x0, y1 - y0
    s = np.empty(len(xy))
    for k, (x, y) in enumerate(xy):
        if abs(y - y0) < 1e-9 and x < x1:
            s[k] = x - x0
        elif abs(x - x1) < 1e-9 and y < y1:
            s[k] = w + (y - y0)
        elif abs(y - y1) < 1e-9 and x > x0:
            s[k] = w + h + (x1 - x)
        elif abs(x - x0) < 1e-9:
            s[k] = 2 * w + h + (y1 - y)
        else:
            raise AssertionError(f"point {x, y} is not on the rectangle {rect}")
    return s


@pytest.mark.parametrize("n_frames", [7, 40, 316])
def test_positions_on_rectangle_uniform_perpendicular_inward(n_frames):
    room = np.array([[-1.0, 2.0], [5.0, 2.0], [5.0, 6.5], [-1.0, 6.5]])
    cfg = TrajectoryConfig(n_frames=n_frames, margin=0.7)
    poses = nominal_trajectory(room, 0.0, cfg)
    rect = (-0.3, 2.7, 4.3, 5.8)
    assert trajectory_rectangle(room, 0.7) == pytest.approx(rect)
    s = _arc_length(poses[:, :2, 3], rect)
    perimeter = 2 * (4.6 + 3.1)
    np.testing.assert_allclose(np.diff(s), perimeter / n_frames, atol=1e-9)  # uniform spacing by arc length
    np.testing.assert_allclose(s[0], 0.5 * perimeter / n_frames, atol=1e-9)
    forward = _forward(poses)
    np.testing.assert_allclose(forward[:, 2], 0.0, atol=1e-12)  # horizontal
    # Direction of travel from the side each point is on (by its arc length): +x, +y, -x, -y.
    side = np.searchsorted(np.cumsum([4.6, 3.1, 4.6, 3.1]), s, side="right")
    travel = np.array([[1.0, 0.0], [0.0, 1.0], [-1.0, 0.0], [0.0, -1.0]])[side]
    np.testing.assert_allclose(np.einsum("ij,ij->i", forward[:, :2], travel), 0.0, atol=1e-12)  # perpendicular
    centre = np.array([(rect[0] + rect[2]) / 2, (rect[1] + rect[3]) / 2])
    assert (np.einsum("ij,ij->i", forward[:, :2], centre - poses[:, :2, 3]) > 0).all()  # inward
    np.testing.assert_allclose(poses[:, :3, 1], np.tile([0.0, 0.0, 1.0], (n_frames, 1)), atol=1e-12)


def test_noise_statistics_match_sigma():
    n = 3000
    cfg = TrajectoryConfig(n_frames=n, margin=1.0, height=2.0, clearance=0.0)
    room = np.array([[0.0, 0.0], [40.0, 0.0], [40.0, 40.0], [0.0, 40.0]])
    rng = np.random.default_rng(1234)
    poses = sample_trajectory(room, 0.0, 4.0, [], cfg, rng)
    nominal = nominal_trajectory(room, 0.0, cfg)
    pos_noise = poses[:, :3, 3] - nominal[:, :3, 3]
    local = np.einsum("nji,njk->nik", nominal[:, :3, :3], poses[:, :3, :3])  # R0^T R = exp([w]x)
    rot_noise = Rotation.from_matrix(local).as_rotvec()  # independent logarithm map (scipy)
    lo, hi = chi2.ppf(ALPHA / 2, n - 1), chi2.ppf(1 - ALPHA / 2, n - 1)
    z = norm.ppf(1 - ALPHA / 2)
    for noise, sigma in ((pos_noise, cfg.pos_sigma), (rot_noise, cfg.rot_sigma)):
        for axis in range(3):
            x = noise[:, axis]
            stat = (n - 1) * x.var(ddof=1) / sigma**2  # ~ chi2(n - 1)
            assert lo < stat < hi, (axis, x.std(ddof=1))
            assert abs(x.mean()) < z * sigma / np.sqrt(n)
        corr = np.corrcoef(noise.T)[np.triu_indices(3, 1)]
        assert np.abs(corr).max() < z / np.sqrt(n)  # axes independent (Fisher: corr ~ N(0, 1/n))


def test_rejection_keeps_clear_of_obstacles_walls_floor_and_ceiling():
    cfg = TrajectoryConfig(n_frames=300, margin=0.5, height=0.5, pos_sigma=0.3, clearance=0.2, max_tries=200)
    obstacles = [
        (np.array([1.0, 0.0, 0.0]), np.array([1.6, 0.7, 0.6])),  # crosses the path near (1.3, 0.5)
        (np.array([3.2, 1.5, 0.0]), np.array([4.0, 2.5, 0.45])),
    ]
    poses = sample_trajectory(L_ROOM, 0.0, 1.2, obstacles, cfg, np.random.default_rng(7))
    centres = poses[:, :3, 3]
    free = Polygon(L_ROOM).buffer(-cfg.clearance, join_style=2)
    assert all(free.contains(Point(x, y)) for x, y, _ in centres)
    assert (centres[:, 2] >= 0.2).all() and (centres[:, 2] <= 1.0).all()
    for lo, hi in obstacles:
        inside = np.all((centres >= lo - cfg.clearance) & (centres <= hi + cfg.clearance), axis=1)
        assert not inside.any()
    # Without the obstacles the same seed gives different poses: the rejection really redrew some.
    free_run = sample_trajectory(L_ROOM, 0.0, 1.2, [], cfg, np.random.default_rng(7))
    assert not np.array_equal(free_run, poses)


def test_impossible_pose_raises_clear_error():
    blocker = [(np.array([-1.0, -1.0, 0.0]), np.array([10.0, 10.0, 3.0]))]
    cfg = TrajectoryConfig(n_frames=3, max_tries=5)
    match = r"frame 0: no admissible camera pose .* after 5 tries .*inside obstacle box 0"
    with pytest.raises(ValueError, match=match):
        sample_trajectory(SQUARE, 0.0, 3.0, blocker, cfg, np.random.default_rng(0))


def test_deterministic_given_seed():
    cfg = TrajectoryConfig(n_frames=50)
    a = sample_trajectory(L_ROOM, 0.0, 2.8, [], cfg, np.random.default_rng(42))
    b = sample_trajectory(L_ROOM, 0.0, 2.8, [], cfg, np.random.default_rng(42))
    c = sample_trajectory(L_ROOM, 0.0, 2.8, [], cfg, np.random.default_rng(43))
    np.testing.assert_array_equal(a, b)
    assert np.abs(a - c).max() > 1e-3
    rot = a[:, :3, :3]
    np.testing.assert_allclose(np.einsum("nji,njk->nik", rot, rot), np.tile(np.eye(3), (50, 1, 1)), atol=1e-12)
    np.testing.assert_allclose(a[:, 3], np.tile([0.0, 0.0, 0.0, 1.0], (50, 1)))


def test_l_shaped_room_uses_largest_rectangle_inside():
    # Eroded by 0.5 the L is [0.5, 5.5]x[0.5, 2.5] (area 10) joined to [0.5, 2.5]x[0.5, 4.5] (area 8).
    assert trajectory_rectangle(L_ROOM, 0.5) == pytest.approx((0.5, 0.5, 5.5, 2.5))
    tall_l = L_ROOM[:, ::-1]  # mirror x <-> y: the long arm becomes vertical
    assert trajectory_rectangle(tall_l, 0.5) == pytest.approx((0.5, 0.5, 2.5, 5.5))
    poses = nominal_trajectory(L_ROOM, 0.0, TrajectoryConfig(n_frames=60, margin=0.5))
    eroded = Polygon(L_ROOM).buffer(-0.5 + 1e-9, join_style=2)
    assert all(eroded.covers(Point(x, y)) for x, y in poses[:, :2, 3])


def test_largest_rectangle_in_non_rectilinear_polygons():
    triangle = Polygon([(0, 0), (4, 0), (0, 4)])  # optimum: the 2 x 2 square in the right-angle corner
    assert largest_inscribed_rectangle(triangle) == pytest.approx((0.0, 0.0, 2.0, 2.0))
    diamond = Polygon([(2, 0), (4, 2), (2, 4), (0, 2)])  # |x-2| + |y-2| <= 2: optimum is a 2 x 2 square, area 4
    x0, y0, x1, y1 = largest_inscribed_rectangle(diamond, grid_steps=64)
    area = (x1 - x0) * (y1 - y0)
    assert 4.0 * (1 - 2 * 4 / 64) <= area <= 4.0 + 1e-9  # within one grid step of the optimum
    corners = [(x0, y0), (x1, y0), (x1, y1), (x0, y1)]
    assert all(diamond.buffer(1e-9).covers(Point(c)) for c in corners)


def test_rectangle_path_tangents():
    xy, tangent = rectangle_path((0.0, 0.0, 2.0, 1.0), 6)  # perimeter 6: s = 0.5, 1.5, ..., 5.5
    np.testing.assert_allclose(xy, [[0.5, 0], [1.5, 0], [2, 0.5], [1.5, 1], [0.5, 1], [0, 0.5]], atol=1e-12)
    np.testing.assert_allclose(tangent, [[1, 0], [1, 0], [0, 1], [-1, 0], [-1, 0], [0, -1]], atol=1e-12)


def test_invalid_inputs_raise():
    with pytest.raises(ValueError, match="facing must be one of inward, outward, centre"):
        TrajectoryConfig(facing="sideways")
    with pytest.raises(ValueError, match="n_frames must be >= 1"):
        TrajectoryConfig(n_frames=0)
    with pytest.raises(ValueError, match=r"pos_sigma must be finite and >= 0"):
        TrajectoryConfig(pos_sigma=-0.1)
    with pytest.raises(ValueError, match="max_tries and grid_steps must be >= 1"):
        TrajectoryConfig(max_tries=0)
    with pytest.raises(ValueError, match="too small for a margin of 2.5 m"):
        trajectory_rectangle(SQUARE, 2.5)
    with pytest.raises(ValueError, match=r"floor polygon must be a finite \(K >= 3, 2\) array"):
        trajectory_rectangle(SQUARE[:2], 0.1)
    with pytest.raises(ValueError, match="self-intersecting"):
        trajectory_rectangle(np.array([[0, 0], [1, 1], [1, 0], [0, 1]], float), 0.1)
    with pytest.raises(ValueError, match=r"ceiling_z \(1.0\) must be above floor_z \(2.0\)"):
        sample_trajectory(SQUARE, 2.0, 1.0, [], TrajectoryConfig(), np.random.default_rng(0))
    with pytest.raises(ValueError, match="leaves less than the clearance"):
        sample_trajectory(SQUARE, 0.0, 1.5, [], TrajectoryConfig(height=1.4), np.random.default_rng(0))
    with pytest.raises(ValueError, match="obstacle boxes must be finite"):
        bad = [(np.array([0.0, 0.0, np.nan]), np.ones(3))]
        sample_trajectory(SQUARE, 0.0, 3.0, bad, TrajectoryConfig(n_frames=2), np.random.default_rng(0))
