"""Camera paths of the paper: a rectangle around the room interior, perturbed by Gaussian pose noise (bpy-free).

Construction (all in the world frame: metres, z up):

1. **Rectangle.** The room's floor polygon is eroded by ``margin`` (shapely mitred buffer). If the eroded polygon is an
   axis-aligned rectangle, that is the path; otherwise (L-shaped or irregular rooms) the path is the *largest-area
   axis-aligned rectangle contained in the eroded polygon*, searched exactly over the grid of the polygon's vertex
   coordinates refined by uniform lines (so it is exact for rectilinear rooms and within one grid step otherwise).
2. **Positions.** ``n_frames`` points uniformly spaced by arc length along the rectangle, counter-clockwise (seen from
   above) starting half a step after the (x_min, y_min) corner, at ``floor_z + height``.
3. **Orientation.** The camera looks horizontally, perpendicular to the local path direction: inward (to the left of
   the counter-clockwise direction) by default, or outward; or (``facing="centre"``) at the rectangle's centre, so
   that the view turns continuously along the loop instead of by 90° between the two frames at each corner (the
   paper's loop falls apart into four sides that share no view: SfM builds one model per side). Camera up is world
   +z. OpenGL/Blender axes: x right, y up, the camera looks along -z.
4. **Noise.** Position += N(0, pos_sigma^2 I_3); rotation := R @ exp([w]x) with w ~ N(0, rot_sigma^2 I_3) an axis-angle
   vector in the camera frame.
5. **Rejection.** A noisy pose is redrawn (up to ``max_tries`` times) when its camera centre is not admissible
   (:mod:`simulator.free_space`): closer than ``clearance`` to a wall (outside the polygon eroded by ``clearance``), to
   the floor or ceiling, or inside an obstacle box grown by ``clearance``. Only the camera centre is tested, not the
   view frustum.
6. **Recovery** (:class:`RecoveryConfig`), only for a frame whose ``max_tries`` draws were all rejected, so every
   loop that the plain rejection sampler places is unchanged (same seed, same poses). In order:
   (a) ``extra_tries`` more draws with the full noise around the nominal centre; (b) if the nominal centre is itself
   admissible: rounds of ``max_tries`` draws with the position noise halved each round, then the nominal centre
   without position noise; (c) otherwise the centre moves to the nearest admissible point at the same height that is
   at least ``max(pos_sigma, min_buffer)`` (else ``min_buffer``) inside the admissible region and at most
   ``max_shift`` away, and (a)-(b) are repeated around it (``max_tries`` full-noise draws, halved noise, no noise).
   Only when no such point exists does sampling fail, naming the room (``label``) and the frame. The rotation noise
   is always drawn with the full ``rot_sigma`` (rotations never make a pose inadmissible).

Furniture against the walls can reach into the nominal loop (the shipped bedroom's wardrobe does at the default 0.6 m
margin). :func:`clearing_margin` finds the smallest larger margin whose loop clears it; using it is the caller's choice
because it changes the poses of a room.
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass

import numpy as np

from simulator.free_space import FreeSpace, floor_polygon_shape
from spotlessgs.io.cameras import axis_angle_to_matrix, interpolate_pose

log = logging.getLogger(__name__)


#: Where the camera looks along the loop (:class:`TrajectoryConfig` ``facing``).
FACINGS = ("inward", "outward", "centre")


@dataclass(frozen=True)
class TrajectoryConfig:
    """Settings of the rectangular camera path."""

    n_frames: int = 316  # number of poses (paper: 287 train + 29 test)
    height: float = 1.5  # camera height above the floor before noise, metres
    margin: float = 0.6  # distance between the walls and the path rectangle, metres
    # "inward" / "outward": perpendicular to the path, towards the inside / the walls; "centre": at the loop's centre
    facing: str = "inward"
    pos_sigma: float = 0.1  # standard deviation of the position noise per axis, metres
    rot_sigma: float = 0.1  # standard deviation of each axis-angle noise component, radians
    clearance: float = 0.15  # minimum distance of a camera centre to walls, floor, ceiling and obstacle boxes, metres
    max_tries: int = 100  # noise draws per frame before giving up
    grid_steps: int = 64  # uniform refinement lines per axis for the largest-rectangle search in non-rectangular rooms

    def __post_init__(self) -> None:
        if self.n_frames < 1:
            raise ValueError(f"TrajectoryConfig.n_frames must be >= 1, got {self.n_frames}")
        if self.facing not in FACINGS:
            raise ValueError(f"TrajectoryConfig.facing must be one of {', '.join(FACINGS)}, got {self.facing!r}")
        for name in ("height", "margin", "pos_sigma", "rot_sigma", "clearance"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value >= 0):
                raise ValueError(f"TrajectoryConfig.{name} must be finite and >= 0, got {value!r}")
        if self.max_tries < 1 or self.grid_steps < 1:
            raise ValueError("TrajectoryConfig.max_tries and grid_steps must be >= 1")


#: Named camera paths (``spotless-sim render --path``): ``paper``, the paper's loop (perpendicular to the path, a 90°
#: turn at each corner, pose noise 10 cm / 0.1 rad per frame and axis, drawn independently per frame); ``robot``, a
#: camera that a robot carries round the room: it looks at the loop's centre and turns smoothly, pose noise 2 cm /
#: 0.02 rad (consecutive frames of the quick preset's 60 overlap as a video's do, so SfM can chain them).
PATHS: dict[str, TrajectoryConfig] = {
    "paper": TrajectoryConfig(),
    "robot": TrajectoryConfig(facing="centre", pos_sigma=0.02, rot_sigma=0.02),
}


@dataclass(frozen=True)
class RecoveryConfig:
    """How a frame is placed when its ``max_tries`` noise draws were all rejected (module docstring, step 6).

    Kept apart from :class:`TrajectoryConfig` on purpose: it only acts where the plain sampler fails, and leaving it
    out of the render settings keeps the settings fingerprint of existing datasets unchanged.
    """

    extra_tries: int = 400  # further full-noise draws around the nominal centre before anything else
    shrink_steps: int = 4  # rounds of max_tries draws with the position noise halved each round (sigma/2 .. /2^k)
    max_shift: float = 1.0  # farthest an inadmissible nominal centre may be moved (horizontally), metres
    min_buffer: float = 0.01  # least distance between a moved centre and the inadmissible region, metres

    def __post_init__(self) -> None:
        if self.extra_tries < 0 or self.shrink_steps < 0:
            raise ValueError(
                f"RecoveryConfig.extra_tries and shrink_steps must be >= 0, got {self.extra_tries}, {self.shrink_steps}"
            )
        for name in ("max_shift", "min_buffer"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value > 0):
                raise ValueError(f"RecoveryConfig.{name} must be finite and > 0, got {value!r}")


def largest_inscribed_rectangle(polygon, grid_steps: int = 64) -> tuple[float, float, float, float]:
    """Largest-area axis-aligned rectangle ``(x0, y0, x1, y1)`` covered by a shapely polygon.

    Candidate edges are the polygon's vertex coordinates plus ``grid_steps`` uniform lines per axis; a grid cell counts
    as inside when the polygon covers it, and the best rectangle of inside cells is found exhaustively: for every range
    of columns, the tallest run of rows whose cells are all inside (O(nx^2) vectorised steps).
    """
    from shapely.geometry import box
    from shapely.prepared import prep

    x0, y0, x1, y1 = polygon.bounds
    coords = np.asarray(polygon.exterior.coords)
    for ring in polygon.interiors:
        coords = np.vstack([coords, np.asarray(ring.coords)])
    xs = np.unique(np.concatenate([coords[:, 0], np.linspace(x0, x1, grid_steps + 1)]))
    ys = np.unique(np.concatenate([coords[:, 1], np.linspace(y0, y1, grid_steps + 1)]))
    prepared = prep(polygon.buffer(1e-9 * max(x1 - x0, y1 - y0)))
    inside = np.array(
        [
            [prepared.covers(box(xs[i], ys[j], xs[i + 1], ys[j + 1])) for j in range(len(ys) - 1)]
            for i in range(len(xs) - 1)
        ]
    )
    cell_h = np.diff(ys)
    cell_index = np.arange(len(cell_h))
    col_prefix = np.zeros((len(xs), len(cell_h)), dtype=np.int64)  # inside cells in columns [0, i) for each row
    col_prefix[1:] = np.cumsum(inside, axis=0)
    best, best_rect = 0.0, None
    for i0 in range(len(xs) - 1):
        for i1 in range(i0 + 1, len(xs)):
            full = (col_prefix[i1] - col_prefix[i0]) == (i1 - i0)  # rows whose cells i0..i1-1 are all inside
            if not full.any():
                break  # a wider x-range starting at i0 cannot be inside anywhere
            run_top = np.cumsum(np.where(full, cell_h, 0.0))
            run_base = np.maximum.accumulate(np.where(full, 0.0, run_top))
            run = run_top - run_base  # height of the run of full rows ending at each row
            j = int(np.argmax(run))
            area = (xs[i1] - xs[i0]) * run[j]
            if area > best:
                start = int(np.maximum.accumulate(np.where(full, -1, cell_index))[j]) + 1
                best, best_rect = area, (xs[i0], ys[start], xs[i1], ys[j + 1])
    if best_rect is None:
        raise ValueError("polygon contains no axis-aligned rectangle on the search grid")
    return tuple(float(v) for v in best_rect)


def trajectory_rectangle(
    floor_polygon: np.ndarray, margin: float, grid_steps: int = 64
) -> tuple[float, float, float, float]:
    """The path rectangle ``(x0, y0, x1, y1)`` for a floor polygon (K, 2) and a wall margin (see module docstring)."""
    from shapely.geometry import JOIN_STYLE

    poly = floor_polygon_shape(floor_polygon)
    eroded = poly.buffer(-margin, join_style=JOIN_STYLE.mitre) if margin > 0 else poly
    if eroded.is_empty or eroded.area <= 0:
        raise ValueError(f"the room is too small for a margin of {margin} m: nothing is left of its floor polygon")
    if eroded.geom_type == "MultiPolygon":  # a narrow waist split the room: use the largest part
        eroded = max(eroded.geoms, key=lambda g: g.area)
    bx0, by0, bx1, by1 = eroded.bounds
    if abs(eroded.area - (bx1 - bx0) * (by1 - by0)) <= 1e-9 * max(eroded.area, 1.0):
        return float(bx0), float(by0), float(bx1), float(by1)
    return largest_inscribed_rectangle(eroded, grid_steps)


def clearing_margin(
    floor_polygon: np.ndarray,
    floor_z: float,
    ceiling_z: float,
    obstacles: list[tuple[np.ndarray, np.ndarray]],
    config: TrajectoryConfig,
    step: float = 0.05,
    min_buffer: float = 0.01,
) -> float:
    """The smallest wall margin ``config.margin + k * step`` (k = 0, 1, ...) whose nominal loop clears the furniture.

    Opt-in (the sampler itself never changes the margin): the whole path rectangle, at the nominal camera height, must
    lie at least ``max(config.pos_sigma, min_buffer)`` inside the admissible region (:mod:`simulator.free_space`), so
    that no nominal centre sits inside a grown obstacle box and most noise draws are admissible at once. Returns
    ``config.margin`` itself when its loop already clears.

    Raises:
        ValueError: when every margin up to the one that leaves no room for a rectangle fails.
    """
    from shapely.geometry import box

    if not (math.isfinite(step) and step > 0):
        raise ValueError(f"clearing_margin step must be finite and > 0, got {step!r}")
    space = FreeSpace(floor_polygon, floor_z, ceiling_z, obstacles, config.clearance)
    clear = space.free_slice(floor_z + config.height).buffer(-max(config.pos_sigma, min_buffer))
    k = 0
    while True:
        margin = round(config.margin + k * step, 9)  # 0.6 + 6 * 0.05 is 0.9, not 0.8999999999999999
        try:
            rect = trajectory_rectangle(floor_polygon, margin, config.grid_steps)
        except ValueError as err:
            raise ValueError(
                f"no wall margin from {config.margin} m in steps of {step} m gives a camera loop that clears the "
                f"furniture by {max(config.pos_sigma, min_buffer)} m ({err})"
            ) from None
        if box(*rect).exterior.within(clear):
            return float(margin)
        k += 1


def rectangle_path(
    rect: tuple[float, float, float, float], n_frames: int
) -> tuple[np.ndarray, np.ndarray]:
    """Points uniformly spaced by arc length on a rectangle, counter-clockwise from the (x0, y0) corner.

    Returns:
        xy: (N, 2) positions, the i-th at arc length (i + 0.5) * perimeter / N.
        tangent: (N, 2) unit direction of travel at each position.
    """
    x0, y0, x1, y1 = rect
    w, h = x1 - x0, y1 - y0
    if not (w > 0 and h > 0):
        raise ValueError(f"rectangle {rect} has no area")
    corners = np.array([[x0, y0], [x1, y0], [x1, y1], [x0, y1], [x0, y0]])
    lengths = np.array([w, h, w, h])
    starts = np.concatenate([[0.0], np.cumsum(lengths)[:-1]])
    perimeter = 2.0 * (w + h)
    s = (np.arange(n_frames) + 0.5) * perimeter / n_frames
    side = np.clip(np.searchsorted(starts, s, side="right") - 1, 0, 3)
    direction = (corners[side + 1] - corners[side]) / lengths[side, None]
    xy = corners[side] + direction * (s - starts[side])[:, None]
    return xy, direction


def look_rotation(forward: np.ndarray) -> np.ndarray:
    """Camera-to-world rotations (N, 3, 3), OpenGL axes, looking along horizontal unit vectors ``forward`` (N, 3).

    Columns: x = right = forward x up, y = up = +z, z = -forward.
    """
    forward = np.asarray(forward, dtype=np.float64)
    up = np.broadcast_to([0.0, 0.0, 1.0], forward.shape)
    right = np.cross(forward, up)
    right /= np.linalg.norm(right, axis=-1, keepdims=True)
    true_up = np.cross(right, forward)
    return np.stack([right, true_up, -forward], axis=-1)


def nominal_trajectory(floor_polygon: np.ndarray, floor_z: float, config: TrajectoryConfig) -> np.ndarray:
    """The noise-free poses (N, 4, 4), camera-to-world, OpenGL camera axes."""
    rect = trajectory_rectangle(floor_polygon, config.margin, config.grid_steps)
    xy, tangent = rectangle_path(rect, config.n_frames)
    # Left of the counter-clockwise direction of travel is the inside of the rectangle.
    inward = np.stack([-tangent[:, 1], tangent[:, 0], np.zeros(len(tangent))], axis=1)
    if config.facing == "centre":
        to_centre = np.array([(rect[0] + rect[2]) / 2, (rect[1] + rect[3]) / 2]) - xy
        forward = np.concatenate([to_centre / np.linalg.norm(to_centre, axis=1, keepdims=True),
                                  np.zeros((len(xy), 1))], axis=1)
    else:
        forward = inward if config.facing == "inward" else -inward
    poses = np.tile(np.eye(4), (config.n_frames, 1, 1))
    poses[:, :3, :3] = look_rotation(forward)
    poses[:, :2, 3] = xy
    poses[:, 2, 3] = floor_z + config.height
    return poses


def _draw_admissible(
    centre: np.ndarray, pos_sigma: float, rot_sigma: float, tries: int, space: FreeSpace, rng: np.random.Generator
) -> tuple[tuple[np.ndarray, np.ndarray] | None, str | None]:
    """Up to ``tries`` noise draws around ``centre`` (3,): position noise (3), then rotation noise (3), per draw.

    Returns:
        ((position (3,), axis-angle (3,)) of the first admissible draw, or None; the last rejection reason).
    """
    reason = None
    for _ in range(tries):
        position = centre + rng.normal(0.0, pos_sigma, 3)
        rotvec = rng.normal(0.0, rot_sigma, 3)
        reason = space.rejection_reason(position)
        if reason is None:
            return (position, rotvec), None
    return None, reason


def _shrinking_draws(
    centre: np.ndarray, config: TrajectoryConfig, recovery: RecoveryConfig, space: FreeSpace, rng: np.random.Generator
) -> tuple[tuple[np.ndarray, np.ndarray], str]:
    """Draws around an admissible ``centre`` (3,) with the position noise halved each round, then no position noise.

    Returns:
        ((position (3,), axis-angle (3,)), how it was placed).
    """
    for k in range(1, recovery.shrink_steps + 1):
        sigma = config.pos_sigma / 2**k
        placed, _ = _draw_admissible(centre, sigma, config.rot_sigma, config.max_tries, space, rng)
        if placed is not None:
            return placed, f"position noise reduced to {sigma:.4g} m"
    return (centre.copy(), rng.normal(0.0, config.rot_sigma, 3)), "no position noise"


def _recover_frame(
    index: int,
    nominal: np.ndarray,
    last_reason: str | None,
    config: TrajectoryConfig,
    recovery: RecoveryConfig,
    space: FreeSpace,
    rng: np.random.Generator,
    label: str | None,
) -> tuple[np.ndarray, np.ndarray]:
    """Place frame ``index`` whose ``max_tries`` draws around ``nominal`` (3,) were all rejected (module step 6).

    Returns:
        (position (3,), axis-angle rotation noise (3,)).

    Raises:
        ValueError: when the nominal centre is inadmissible and no admissible point lies within ``max_shift``.
    """
    placed, _ = _draw_admissible(nominal, config.pos_sigma, config.rot_sigma, recovery.extra_tries, space, rng)
    if placed is not None:
        log.info("%sframe %d: placed after more than %d noise draws", _prefix(label), index, config.max_tries)
        return placed
    nominal_reason = space.rejection_reason(nominal)
    if nominal_reason is None:
        placed, how = _shrinking_draws(nominal, config, recovery, space, rng)
        log.info("%sframe %d: placed with %s", _prefix(label), index, how)
        return placed
    # Prefer a centre one noise sigma inside the admissible region (most draws around it fit), else min_buffer.
    buffers = dict.fromkeys((max(config.pos_sigma, recovery.min_buffer), recovery.min_buffer))  # ordered, unique
    centre = None
    for buffer in buffers:
        centre = space.nearest_admissible(nominal, buffer, recovery.max_shift)
        if centre is not None:
            break
    if centre is None:
        raise ValueError(
            f"{_prefix(label)}frame {index}: no admissible camera pose near {np.round(nominal, 3).tolist()} after "
            f"{config.max_tries} tries (last rejection: {last_reason}) nor {recovery.extra_tries} more, and no "
            f"admissible position lies within {recovery.max_shift} m of it at its height (nominal position: "
            f"{nominal_reason}); increase the margin (clearing_margin finds one) or reduce the clearance"
        )
    shift = float(np.hypot(*(centre[:2] - nominal[:2])))
    placed, _ = _draw_admissible(centre, config.pos_sigma, config.rot_sigma, config.max_tries, space, rng)
    how = "full noise"
    if placed is None:
        placed, how = _shrinking_draws(centre, config, recovery, space, rng)
    log.info("%sframe %d: nominal centre %s, moved %.3f m to the nearest admissible point, %s",
             _prefix(label), index, nominal_reason, shift, how)
    return placed


def _prefix(label: str | None) -> str:
    """``"label: "`` for log lines and errors, or nothing without a label."""
    return f"{label}: " if label else ""


def sample_trajectory(
    floor_polygon: np.ndarray,
    floor_z: float,
    ceiling_z: float,
    obstacles: list[tuple[np.ndarray, np.ndarray]],
    config: TrajectoryConfig,
    rng: np.random.Generator,
    *,
    recovery: RecoveryConfig = RecoveryConfig(),
    label: str | None = None,
) -> np.ndarray:
    """Sample the noisy camera path of one room.

    Args:
        floor_polygon: (K, 2) floor outline in world x-y (any orientation, not closed).
        floor_z: floor height, metres.
        ceiling_z: ceiling height, metres.
        obstacles: furniture boxes ``(lo (3,), hi (3,))`` that camera centres must keep ``clearance`` away from.
        config: path settings.
        rng: the stage's random generator (draws happen frame by frame: position noise (3), then rotation noise (3),
            per try).
        recovery: how frames whose ``max_tries`` draws were all rejected are placed (module docstring, step 6).
        label: names the room in log lines and errors (e.g. ``"scenes/bedroom/house.json room Bedroom-1"``).

    Returns:
        (N, 4, 4) float64 camera-to-world matrices, OpenGL camera axes (x right, y up, looking along -z). Every camera
        centre is admissible (:class:`simulator.free_space.FreeSpace` with ``config.clearance``).

    Raises:
        ValueError: for invalid rooms, or when some frame's nominal centre is inadmissible and no admissible point
            lies within ``recovery.max_shift`` of it (the message names the label, the frame, its nominal position
            and the rejection reasons).
    """
    if not (math.isfinite(floor_z) and math.isfinite(ceiling_z) and ceiling_z > floor_z):
        raise ValueError(f"ceiling_z ({ceiling_z}) must be above floor_z ({floor_z})")
    z_lo, z_hi = floor_z + config.clearance, ceiling_z - config.clearance
    nominal_z = floor_z + config.height
    if not z_lo <= nominal_z <= z_hi:
        raise ValueError(
            f"camera height {config.height} m above the floor leaves less than the clearance {config.clearance} m "
            f"to the floor or the ceiling (room height {ceiling_z - floor_z:.3f} m)"
        )
    poses = nominal_trajectory(floor_polygon, floor_z, config)
    space = FreeSpace(floor_polygon, floor_z, ceiling_z, obstacles, config.clearance)

    out = poses.copy()
    for i in range(config.n_frames):
        nominal = poses[i, :3, 3]
        placed, reason = _draw_admissible(nominal, config.pos_sigma, config.rot_sigma, config.max_tries, space, rng)
        if placed is None:
            placed = _recover_frame(i, nominal, reason, config, recovery, space, rng, label)
        position, rotvec = placed
        out[i, :3, 3] = position
        out[i, :3, :3] = poses[i, :3, :3] @ axis_angle_to_matrix(rotvec)
    return out


def shutter_poses(poses: np.ndarray, index: int, exposure: float) -> tuple[np.ndarray, np.ndarray]:
    """The camera poses at shutter open and close of frame ``index`` of a closed loop of ``poses`` (N, 4, 4), for a
    shutter open ``exposure`` (in (0, 1]) of the time between two frames, centred on the frame: open lies
    ``exposure / 2`` of the way to the previous frame, close as far towards the next (the loop wraps)."""
    if not 0.0 < exposure <= 1.0:
        raise ValueError(f"shutter_poses: exposure must be in (0, 1], got {exposure}")
    n = len(poses)
    here = poses[index]
    return (interpolate_pose(here, poses[(index - 1) % n], exposure / 2),
            interpolate_pose(here, poses[(index + 1) % n], exposure / 2))
