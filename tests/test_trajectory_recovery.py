"""Robust camera loops: frames whose noise draws are all rejected are recovered, on synthetic and shipped rooms."""

from __future__ import annotations

import logging
from pathlib import Path

import numpy as np
import pytest
from shapely.geometry import Point, Polygon

from simulator.free_space import FreeSpace
from simulator.front3d import LoadOptions, load_house
from simulator.lighting import GroundTruthLighting, with_ground_truth_lighting
from simulator.trajectory import (
    RecoveryConfig,
    TrajectoryConfig,
    clearing_margin,
    nominal_trajectory,
    rectangle_path,
    sample_trajectory,
    trajectory_rectangle,
)
from spotlessgs.io.cameras import axis_angle_to_matrix
from spotlessgs.io.seeding import numpy_rng

ROOT = Path(__file__).resolve().parents[1]
SCENES = sorted(p.parent.name for p in (ROOT / "scenes").glob("*/house.json"))
SQUARE = np.array([[0.0, 0.0], [4.0, 0.0], [4.0, 4.0], [0.0, 4.0]])
FULL_HEIGHT = (0.0, 3.0)  # z range of synthetic obstacles: floor to ceiling


def _box(x0, y0, x1, y1, z=FULL_HEIGHT):
    return np.array([x0, y0, z[0]]), np.array([x1, y1, z[1]])


@pytest.fixture(scope="module")
def rooms():
    """Per shipped scene: (room, furniture boxes), exactly as ``simulator.render_pipeline.plan_poses`` builds them."""
    out = {}
    for name in SCENES:
        scene = load_house(ROOT / "scenes" / name / "house.json", LoadOptions())
        room = scene.room(None)
        scene = with_ground_truth_lighting(scene, scene.objects_in(room), GroundTruthLighting())
        out[name] = (room, scene.furniture_boxes(room))
    return out


def _sample(room, boxes, n_frames, seed):
    cfg = TrajectoryConfig(n_frames=n_frames)
    poses = sample_trajectory(
        room.floor_polygon, room.floor_z, room.ceiling_z, boxes, cfg, numpy_rng(seed, "trajectory")
    )
    return poses, cfg


def _assert_admissible_loop(room, boxes, poses, cfg):
    """Every centre admissible (module check and an independent one) and the centres still form the loop."""
    centres = poses[:, :3, 3]
    space = FreeSpace(room.floor_polygon, room.floor_z, room.ceiling_z, boxes, cfg.clearance)
    assert all(space.is_admissible(c) for c in centres)
    # Independent check: shapely room polygon eroded by the clearance, height band, closed grown furniture boxes.
    free = Polygon(room.floor_polygon).buffer(-cfg.clearance, join_style=2)
    assert all(free.contains(Point(x, y)) for x, y, _ in centres)
    assert (centres[:, 2] >= room.floor_z + cfg.clearance).all()
    assert (centres[:, 2] <= room.ceiling_z - cfg.clearance).all()
    for lo, hi in boxes:
        inside = np.all((centres >= np.asarray(lo) - cfg.clearance) & (centres <= np.asarray(hi) + cfg.clearance), 1)
        assert not inside.any(), (lo, hi, np.flatnonzero(inside))
    # Still a loop: every centre within 6 sigma (3-D) of its nominal point, consecutive steps (closing step included)
    # between the nominal spacing d and the root-mean-square step sqrt(d^2 + 6 sigma^2) on average, no big jump.
    nominal = nominal_trajectory(room.floor_polygon, room.floor_z, cfg)[:, :3, 3]
    assert np.linalg.norm(centres - nominal, axis=1).max() <= 6 * cfg.pos_sigma
    steps = np.linalg.norm(np.roll(centres, -1, axis=0) - centres, axis=1)
    spacing = np.linalg.norm(np.roll(nominal, -1, axis=0) - nominal, axis=1).mean()
    assert spacing <= steps.mean() <= 1.15 * np.sqrt(spacing**2 + 6 * cfg.pos_sigma**2)
    assert steps.max() <= 4.0 * steps.mean()
    rot = poses[:, :3, :3]
    np.testing.assert_allclose(np.einsum("nji,njk->nik", rot, rot), np.tile(np.eye(3), (len(poses), 1, 1)), atol=1e-12)


@pytest.mark.parametrize("seed", [0, 1, 2, 3, 7])
@pytest.mark.parametrize("n_frames", [36, 40, 44, 48, 316])
def test_bedroom_places_admissible_loops(rooms, n_frames, seed):
    # Seed 0 with 40, 44, 48 and 316 frames (and seed 3 with 120) failed before recovery existed.
    room, boxes = rooms["bedroom"]
    poses, cfg = _sample(room, boxes, n_frames, seed)
    assert poses.shape == (n_frames, 4, 4)
    _assert_admissible_loop(room, boxes, poses, cfg)


@pytest.mark.parametrize("n_frames", [36, 316])
@pytest.mark.parametrize("scene", SCENES)
def test_every_shipped_room_places_admissible_loops(rooms, scene, n_frames):
    room, boxes = rooms[scene]
    for seed in (0, 1):
        poses, cfg = _sample(room, boxes, n_frames, seed)
        _assert_admissible_loop(room, boxes, poses, cfg)


def test_shipped_scene_count():
    assert SCENES == ["bedroom", "corridor", "living_room", "office", "storage_room", "white_room"]


def test_render_pipeline_plans_the_bedroom_loop_that_used_to_fail(rooms):
    from simulator.render_pipeline import RenderConfig, plan_poses

    config = RenderConfig(frames=316, seed=0)
    _, _, _, poses = plan_poses(ROOT / "scenes/bedroom/house.json", config, LoadOptions())
    room, boxes = rooms["bedroom"]
    np.testing.assert_array_equal(poses, _sample(room, boxes, 316, 0)[0])  # the fixture mirrors the pipeline
    _assert_admissible_loop(room, boxes, poses, TrajectoryConfig(n_frames=316))


def _plain_rejection_sampler(floor_polygon, floor_z, ceiling_z, boxes, cfg, rng):
    """Obvious reference of the sampler without recovery (the behaviour before it existed).

    Returns:
        (poses (N, 4, 4) filled up to the first frame that failed, index of that frame or None).
    """
    nominal = nominal_trajectory(floor_polygon, floor_z, cfg)
    free = Polygon(floor_polygon).buffer(-cfg.clearance, join_style=2)
    lo = np.array([b[0] for b in boxes]) - cfg.clearance
    hi = np.array([b[1] for b in boxes]) + cfg.clearance
    out = nominal.copy()
    for i in range(len(nominal)):
        for _ in range(cfg.max_tries):
            p = nominal[i, :3, 3] + rng.normal(0.0, cfg.pos_sigma, 3)
            w = rng.normal(0.0, cfg.rot_sigma, 3)
            ok = floor_z + cfg.clearance <= p[2] <= ceiling_z - cfg.clearance and free.contains(Point(p[0], p[1]))
            if ok and not np.all((p >= lo) & (p <= hi), axis=1).any():
                out[i, :3, 3] = p
                out[i, :3, :3] = nominal[i, :3, :3] @ axis_angle_to_matrix(w)
                break
        else:
            return out, i
    return out, None


@pytest.mark.parametrize("n_frames, seed", [(36, 0), (40, 0), (316, 0), (316, 1), (120, 3)])
def test_loops_that_always_worked_are_unchanged(rooms, n_frames, seed):
    room, boxes = rooms["bedroom"]
    poses, cfg = _sample(room, boxes, n_frames, seed)
    args = (room.floor_polygon, room.floor_z, room.ceiling_z, boxes, cfg, numpy_rng(seed, "trajectory"))
    reference, failed = _plain_rejection_sampler(*args)
    if failed is None:
        np.testing.assert_array_equal(poses, reference)  # bit for bit
    else:
        np.testing.assert_array_equal(poses[:failed], reference[:failed])  # identical up to the recovered frame
    assert (failed is None) == ((n_frames, seed) in {(36, 0), (316, 1)})  # the cases are what they claim to be


def test_recovered_loop_is_deterministic(rooms):
    room, boxes = rooms["bedroom"]
    a, _ = _sample(room, boxes, 316, 0)
    b, _ = _sample(room, boxes, 316, 0)
    c, _ = _sample(room, boxes, 316, 4)
    np.testing.assert_array_equal(a, b)
    assert np.abs(a[:, :3, 3] - c[:, :3, 3]).max() > 1e-3


def test_more_draws_recover_a_frame_inside_a_thin_obstacle(caplog):
    # The nominal point (2, 0.5) of frame 0 sits inside a 0.2 m thin wall: one draw escapes with probability
    # 2 * (1 - Phi(1)) = 0.32 (it does not with this seed), 400 more draws always do.
    cfg = TrajectoryConfig(n_frames=4, height=1.2, margin=0.5, clearance=0.0, pos_sigma=0.1, max_tries=1)
    obstacles = [_box(1.9, 0.0, 2.1, 1.5)]
    with caplog.at_level(logging.INFO, logger="simulator.trajectory"):
        poses = sample_trajectory(SQUARE, 0.0, 3.0, obstacles, cfg, np.random.default_rng(0), label="thin wall")
    assert "thin wall: frame 0: placed after more than 1 noise draws" in caplog.text
    x = poses[0, 0, 3]
    assert x < 1.9 or x > 2.1


# One frame (nominal point (3.5, 3.5) at 1.2 m) whose only free x-y space is a 2 cm x 2 cm column around it.
POCKET = [_box(0, 0, 3.49, 4), _box(3.51, 0, 4, 4), _box(3.49, 0, 3.51, 3.49), _box(3.49, 3.51, 3.51, 4)]


def test_shrinking_noise_places_a_frame_in_a_tiny_pocket(caplog):
    # The nominal point is admissible, but draws with sigma 1 m almost never are: the noise is halved until a draw
    # fits (at worst the nominal point is used).
    cfg = TrajectoryConfig(n_frames=1, height=1.2, margin=0.5, clearance=0.0, pos_sigma=1.0, max_tries=20)
    with caplog.at_level(logging.INFO, logger="simulator.trajectory"):
        poses = sample_trajectory(SQUARE, 0.0, 3.0, POCKET, cfg, np.random.default_rng(3),
                                  recovery=RecoveryConfig(extra_tries=10))
    assert "frame 0: placed with position noise reduced to" in caplog.text
    x, y, z = poses[0, :3, 3]
    assert 3.49 < x < 3.51 and 3.49 < y < 3.51 and 0.0 <= z <= 3.0
    assert abs(z - 1.2) > 1e-9  # a noisy draw, not the nominal point
    assert FreeSpace(SQUARE, 0.0, 3.0, POCKET, 0.0).is_admissible(poses[0, :3, 3])


def test_zero_shrink_steps_use_the_nominal_point_without_position_noise(caplog):
    cfg = TrajectoryConfig(n_frames=1, height=1.2, margin=0.5, clearance=0.0, pos_sigma=1.0, max_tries=2)
    recovery = RecoveryConfig(extra_tries=0, shrink_steps=0)
    with caplog.at_level(logging.INFO, logger="simulator.trajectory"):
        poses = sample_trajectory(SQUARE, 0.0, 3.0, POCKET, cfg, np.random.default_rng(0), recovery=recovery)
    assert "frame 0: placed with no position noise" in caplog.text
    np.testing.assert_allclose(poses[0, :3, 3], [3.5, 3.5, 1.2], atol=1e-12)
    nominal = nominal_trajectory(SQUARE, 0.0, cfg)
    assert not np.allclose(poses[0, :3, :3], nominal[0, :3, :3])  # the rotation noise is still applied


def test_blocked_nominal_point_moves_to_the_nearest_admissible_point(caplog):
    # A cupboard x in [1.6, 2.6], y in [0, 1.2] covers frame 0's nominal point (2, 0.5). Grown by the clearance 0.15
    # it spans x in [1.45, 2.75], y up to 1.35; the nearest exits are left 0.55 m, right 0.75 m, up 0.85 m away.
    # Without noise the centre moves left to x = 1.45 - min_buffer (0.01) = 1.44.
    cupboard = [_box(1.6, 0.0, 2.6, 1.2)]
    cfg = TrajectoryConfig(n_frames=4, height=1.5, margin=0.5, clearance=0.15, pos_sigma=0.0, rot_sigma=0.0)
    with caplog.at_level(logging.INFO, logger="simulator.trajectory"):
        poses = sample_trajectory(SQUARE, 0.0, 3.0, cupboard, cfg, np.random.default_rng(0))
    assert "moved 0.560 m to the nearest admissible point" in caplog.text
    np.testing.assert_allclose(poses[0, :3, 3], [1.44, 0.5, 1.5], atol=1e-9)
    nominal = nominal_trajectory(SQUARE, 0.0, cfg)
    np.testing.assert_array_equal(poses[1:], nominal[1:])  # the other frames are not affected
    np.testing.assert_allclose(poses[0, :3, :3], nominal[0, :3, :3], atol=1e-15)  # orientation kept
    # With noise the centre keeps pos_sigma (0.05) away from the cupboard: x = 1.40, then a full-noise draw.
    noisy = TrajectoryConfig(n_frames=4, height=1.5, margin=0.5, clearance=0.15, pos_sigma=0.05)
    poses = sample_trajectory(SQUARE, 0.0, 3.0, cupboard, noisy, np.random.default_rng(0))
    assert FreeSpace(SQUARE, 0.0, 3.0, cupboard, 0.15).is_admissible(poses[0, :3, 3])
    assert poses[0, 0, 3] < 1.45 and abs(poses[0, 1, 3] - 0.5) < 6 * 0.05


def test_no_admissible_point_within_max_shift_raises_naming_the_room_and_frame():
    cupboard = [_box(1.6, 0.0, 2.6, 1.2)]
    cfg = TrajectoryConfig(n_frames=4, height=1.5, margin=0.5, clearance=0.15, pos_sigma=0.0)
    ok = sample_trajectory(SQUARE, 0.0, 3.0, cupboard, cfg, np.random.default_rng(0),
                           recovery=RecoveryConfig(max_shift=0.57))
    assert ok[0, 0, 3] == pytest.approx(1.44)
    match = (r"^scenes/x/house.json room R: frame 0: no admissible camera pose near \[2.0, 0.5, 1.5\] after 100 tries "
             r"\(last rejection: inside obstacle box 0\) nor 400 more, and no admissible position lies within 0.5 m")
    with pytest.raises(ValueError, match=match):
        sample_trajectory(SQUARE, 0.0, 3.0, cupboard, cfg, np.random.default_rng(0),
                          recovery=RecoveryConfig(max_shift=0.5), label="scenes/x/house.json room R")


def test_room_filled_by_furniture_raises():
    blocker = [_box(-1.0, -1.0, 10.0, 10.0)]
    with pytest.raises(ValueError, match=r"frame 0: .*nominal position: inside obstacle box 0\)"):
        sample_trajectory(SQUARE, 0.0, 3.0, blocker, TrajectoryConfig(n_frames=3), np.random.default_rng(0))


def test_recovery_config_validation():
    with pytest.raises(ValueError, match=r"extra_tries and shrink_steps must be >= 0, got -1, 4"):
        RecoveryConfig(extra_tries=-1)
    with pytest.raises(ValueError, match=r"RecoveryConfig.max_shift must be finite and > 0, got 0.0"):
        RecoveryConfig(max_shift=0.0)
    with pytest.raises(ValueError, match=r"RecoveryConfig.min_buffer must be finite and > 0, got nan"):
        RecoveryConfig(min_buffer=float("nan"))


def test_free_space_reasons_slices_and_nearest_points():
    # A table (top at 0.8 m) and a wardrobe against the wall in a 4 x 4 room, clearance 0.1.
    table, wardrobe = _box(1.0, 1.0, 2.0, 2.0, z=(0.0, 0.8)), _box(0.0, 3.0, 1.0, 4.0)
    space = FreeSpace(SQUARE, 0.0, 2.5, [table, wardrobe], 0.1)
    assert space.rejection_reason(np.array([1.5, 1.5, 1.5])) is None  # above the table (0.8 + 0.1 < 1.5)
    assert space.rejection_reason(np.array([1.5, 1.5, 0.85])) == "inside obstacle box 0"
    assert space.rejection_reason(np.array([0.5, 3.5, 1.5])) == "inside obstacle box 1"
    assert space.rejection_reason(np.array([0.05, 2.0, 1.5])) == "too close to a wall or outside the room"
    assert space.rejection_reason(np.array([2.0, 2.0, 2.45])) == "height 2.450 m outside [0.100, 2.400]"
    assert space.rejection_reason(np.array([1.1, 3.0, 1.5])) == "inside obstacle box 1"  # closed box: on the face
    # Free x-y area at 1.5 m: the room eroded by 0.1 ([0.1, 3.9]^2) minus the grown wardrobe inside it
    # ([0.1, 1.1] x [2.9, 3.9]); at 0.5 m also minus the grown table ([0.9, 2.1]^2).
    assert space.free_slice(1.5).area == pytest.approx(3.8 * 3.8 - 1.0 * 1.0)
    assert space.free_slice(0.5).area == pytest.approx(3.8 * 3.8 - 1.0 * 1.0 - 1.2 * 1.2)
    assert space.free_slice(2.45).is_empty
    # Nearest point out of the wardrobe from (0.4, 3.5), 0.05 inside: down to y = 2.9 - 0.05 (0.65 m away) beats
    # right to x = 1.1 + 0.05 (0.75 m away).
    np.testing.assert_allclose(space.nearest_admissible(np.array([0.4, 3.5, 1.5]), 0.05, 1.0), [0.4, 2.85, 1.5])
    assert space.nearest_admissible(np.array([0.4, 3.5, 1.5]), 0.05, 0.64) is None
    np.testing.assert_allclose(space.nearest_admissible(np.array([2.0, 2.0, 1.5]), 0.05, 1.0), [2.0, 2.0, 1.5])
    with pytest.raises(ValueError, match=r"clearance must be finite and >= 0, got -0.1"):
        FreeSpace(SQUARE, 0.0, 2.5, [], -0.1)
    with pytest.raises(ValueError, match=r"ceiling_z \(0.0\) must be above floor_z \(0.0\)"):
        FreeSpace(SQUARE, 0.0, 0.0, [], 0.1)


def _clearance_of_loop(room, boxes, cfg, margin):
    """Least horizontal distance (m) from the path rectangle (sampled every 5 mm) to the walls grown by the clearance
    and to the grown footprints of the boxes that reach the camera height; plain numpy, rectangular rooms only."""
    rect = trajectory_rectangle(room.floor_polygon, margin)
    perimeter = 2 * (rect[2] - rect[0] + rect[3] - rect[1])
    xy, _ = rectangle_path(rect, int(perimeter / 0.005))
    (x0, y0), (x1, y1) = room.floor_polygon.min(axis=0), room.floor_polygon.max(axis=0)
    walls = np.min([xy[:, 0] - x0, x1 - xy[:, 0], xy[:, 1] - y0, y1 - xy[:, 1]], axis=0) - cfg.clearance
    z = room.floor_z + cfg.height
    least = walls.min()
    for lo, hi in boxes:
        lo, hi = np.asarray(lo) - cfg.clearance, np.asarray(hi) + cfg.clearance
        if lo[2] <= z <= hi[2]:
            outside = np.maximum(np.maximum(lo[:2] - xy, xy - hi[:2]), 0.0)
            least = min(least, np.linalg.norm(outside, axis=1).min())
    return least


def test_clearing_margin_of_the_bedroom(rooms):
    # The default 0.6 m loop runs through the wardrobe; 0.9 m is the first margin (0.05 m steps) clearing it by sigma.
    room, boxes = rooms["bedroom"]
    cfg = TrajectoryConfig()
    margin = clearing_margin(room.floor_polygon, room.floor_z, room.ceiling_z, boxes, cfg)
    assert margin == 0.9
    assert _clearance_of_loop(room, boxes, cfg, 0.6) == 0.0  # nominal centres inside (grown) furniture
    assert _clearance_of_loop(room, boxes, cfg, 0.85) < cfg.pos_sigma
    assert _clearance_of_loop(room, boxes, cfg, 0.9) >= cfg.pos_sigma
    for n_frames in (40, 316):
        wider = TrajectoryConfig(n_frames=n_frames, margin=margin)
        args = (room.floor_polygon, room.floor_z, room.ceiling_z, boxes, wider)
        poses = sample_trajectory(*args, numpy_rng(0, "trajectory"))
        _assert_admissible_loop(room, boxes, poses, wider)
        assert _plain_rejection_sampler(*args, numpy_rng(0, "trajectory"))[1] is None  # no recovery was needed


def test_clearing_margin_synthetic_cases():
    # A low cabinet reaching y = 0.52 (0.67 grown by the clearance 0.15) under the 0.5 m loop of a 4 x 4 room: the
    # loop must keep pos_sigma = 0.05 from it, y0 >= 0.72, so the margin grows from 0.5 to 0.75.
    cabinet = [_box(1.6, 0.0, 2.6, 0.52, z=(0.0, 1.6))]
    cfg = TrajectoryConfig(height=1.5, margin=0.5, clearance=0.15, pos_sigma=0.05)
    assert clearing_margin(SQUARE, 0.0, 3.0, cabinet, cfg) == 0.75
    assert clearing_margin(SQUARE, 0.0, 3.0, cabinet, TrajectoryConfig(height=1.8, margin=0.5)) == 0.5  # above it
    assert clearing_margin(SQUARE, 0.0, 3.0, [], cfg) == 0.5
    blocker = [_box(-1.0, -1.0, 10.0, 10.0)]
    with pytest.raises(ValueError, match=r"no wall margin from 0.5 m in steps of 0.05 m gives a camera loop that "
                                         r"clears the furniture by 0.05 m \(the room is too small for a margin"):
        clearing_margin(SQUARE, 0.0, 3.0, blocker, cfg)
    with pytest.raises(ValueError, match=r"clearing_margin step must be finite and > 0, got 0.0"):
        clearing_margin(SQUARE, 0.0, 3.0, [], cfg, step=0.0)
