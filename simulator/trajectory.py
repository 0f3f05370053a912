"""Camera paths of the paper: a rectangle around the room interior, perturbed by Gaussian pose noise (bpy-free).

Construction (all in the world frame: metres, z up):

1. **Rectangle.** The room's floor polygon is eroded by ``margin`` (shapely mitred buffer). If the eroded polygon is an
   axis-aligned rectangle, that is the path; otherwise (L-shaped or irregular rooms) the path is the *largest-area
   axis-aligned rectangle contained in the eroded polygon*, searched exactly over the grid of the polygon's vertex
   coordinates refined by uniform lines (so it is exact for rectilinear rooms and within one grid step otherwise).
2. **Positions.** ``n_frames`` points uniformly spaced by arc length along the rectangle, counter-clockwise (seen from
   above) starting half a step after the (x_min, y_min) corner, at ``floor_z + height``.
3. **Orientation.** The camera looks horizontally, perpendicular to the local path direction: inward (to the left of
   the counter-clockwise direction) by default, or outward. Camera up is world +z. OpenGL/Blender axes: x right, y up,
   the camera looks along -z.
4. **Noise.** Position += N(0, pos_sigma^2 I_3); rotation := R @ exp([w]x) with w ~ N(0, rot_sigma^2 I_3) an axis-angle
   vector in the camera frame.
5. **Rejection.** A noisy pose is redrawn (up to ``max_tries`` times) when its camera centre is closer than
   ``clearance`` to a wall (outside the polygon eroded by ``clearance``), to the floor or ceiling, or inside an
   obstacle box grown by ``clearance``. Only the camera centre is tested, not the view frustum.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from spotlessgs.io.cameras import axis_angle_to_matrix


@dataclass(frozen=True)
class TrajectoryConfig:
    """Settings of the rectangular camera path."""

    n_frames: int = 316  # number of poses (paper: 287 train + 29 test)
    height: float = 1.5  # camera height above the floor before noise, metres
    margin: float = 0.6  # distance between the walls and the path rectangle, metres
    facing: str = "inward"  # "inward" (towards the room centre) or "outward" (towards the walls)
    pos_sigma: float = 0.1  # standard deviation of the position noise per axis, metres
    rot_sigma: float = 0.1  # standard deviation of each axis-angle noise component, radians
    clearance: float = 0.15  # minimum distance of a camera centre to walls, floor, ceiling and obstacle boxes, metres
    max_tries: int = 100  # noise draws per frame before giving up
    grid_steps: int = 64  # uniform refinement lines per axis for the largest-rectangle search in non-rectangular rooms

    def __post_init__(self) -> None:
        if self.n_frames < 1:
            raise ValueError(f"TrajectoryConfig.n_frames must be >= 1, got {self.n_frames}")
        if self.facing not in ("inward", "outward"):
            raise ValueError(f"TrajectoryConfig.facing must be 'inward' or 'outward', got {self.facing!r}")
        for name in ("height", "margin", "pos_sigma", "rot_sigma", "clearance"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value >= 0):
                raise ValueError(f"TrajectoryConfig.{name} must be finite and >= 0, got {value!r}")
        if self.max_tries < 1 or self.grid_steps < 1:
            raise ValueError("TrajectoryConfig.max_tries and grid_steps must be >= 1")


def _polygon(floor_polygon: np.ndarray):
    from shapely.geometry import Polygon

    pts = np.asarray(floor_polygon, dtype=np.float64)
    if pts.ndim != 2 or pts.shape[1] != 2 or pts.shape[0] < 3 or not np.isfinite(pts).all():
        raise ValueError(f"floor polygon must be a finite (K >= 3, 2) array, got shape {pts.shape}")
    poly = Polygon(pts)
    if not poly.is_valid or poly.area <= 0:
        raise ValueError("floor polygon is self-intersecting or has zero area")
    return poly


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

    poly = _polygon(floor_polygon)
    eroded = poly.buffer(-margin, join_style=JOIN_STYLE.mitre) if margin > 0 else poly
    if eroded.is_empty or eroded.area <= 0:
        raise ValueError(f"the room is too small for a margin of {margin} m: nothing is left of its floor polygon")
    if eroded.geom_type == "MultiPolygon":  # a narrow waist split the room: use the largest part
        eroded = max(eroded.geoms, key=lambda g: g.area)
    bx0, by0, bx1, by1 = eroded.bounds
    if abs(eroded.area - (bx1 - bx0) * (by1 - by0)) <= 1e-9 * max(eroded.area, 1.0):
        return float(bx0), float(by0), float(bx1), float(by1)
    return largest_inscribed_rectangle(eroded, grid_steps)


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
    forward = inward if config.facing == "inward" else -inward
    poses = np.tile(np.eye(4), (config.n_frames, 1, 1))
    poses[:, :3, :3] = look_rotation(forward)
    poses[:, :2, 3] = xy
    poses[:, 2, 3] = floor_z + config.height
    return poses


def _rejection_reason(position: np.ndarray, free_area, prepared_free, z_lo: float, z_hi: float,
                      boxes_lo: np.ndarray, boxes_hi: np.ndarray) -> str | None:
    """Why a camera centre (3,) is not allowed, or None when it is."""
    from shapely.geometry import Point

    if not (z_lo <= position[2] <= z_hi):
        return f"height {position[2]:.3f} m outside [{z_lo:.3f}, {z_hi:.3f}]"
    if free_area is None or not prepared_free.contains(Point(position[0], position[1])):
        return "too close to a wall or outside the room"
    if len(boxes_lo):
        inside = np.all((position >= boxes_lo) & (position <= boxes_hi), axis=1)
        if inside.any():
            return f"inside obstacle box {int(np.argmax(inside))}"
    return None


def sample_trajectory(
    floor_polygon: np.ndarray,
    floor_z: float,
    ceiling_z: float,
    obstacles: list[tuple[np.ndarray, np.ndarray]],
    config: TrajectoryConfig,
    rng: np.random.Generator,
) -> np.ndarray:
    """Sample the noisy camera path of one room.

    Args:
        floor_polygon: (K, 2) floor outline in world x-y (any orientation, not closed).
        floor_z: floor height, metres.
        ceiling_z: ceiling height, metres.
        obstacles: furniture boxes ``(lo (3,), hi (3,))`` that camera centres must keep ``clearance`` away from.
        config: path settings.
        rng: the stage's random generator (draws happen frame by frame: position noise (3), then rotation noise (3)).

    Returns:
        (N, 4, 4) float64 camera-to-world matrices, OpenGL camera axes (x right, y up, looking along -z).

    Raises:
        ValueError: for invalid rooms, or when some frame has no admissible noise draw within ``max_tries``
            (the message names the frame, its nominal position and the last rejection reason).
    """
    from shapely.geometry import JOIN_STYLE
    from shapely.prepared import prep

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
    poly = _polygon(floor_polygon)
    free_area = poly.buffer(-config.clearance, join_style=JOIN_STYLE.mitre) if config.clearance > 0 else poly
    free_area = None if free_area.is_empty else free_area
    prepared_free = None if free_area is None else prep(free_area)
    boxes_lo = np.array([np.asarray(lo, float) for lo, _ in obstacles]).reshape(-1, 3) - config.clearance
    boxes_hi = np.array([np.asarray(hi, float) for _, hi in obstacles]).reshape(-1, 3) + config.clearance
    if len(obstacles) and not (np.isfinite(boxes_lo).all() and np.isfinite(boxes_hi).all()):
        raise ValueError("obstacle boxes must be finite")

    out = poses.copy()
    for i in range(config.n_frames):
        reason = None
        for _ in range(config.max_tries):
            position = poses[i, :3, 3] + rng.normal(0.0, config.pos_sigma, 3)
            rotvec = rng.normal(0.0, config.rot_sigma, 3)
            reason = _rejection_reason(position, free_area, prepared_free, z_lo, z_hi, boxes_lo, boxes_hi)
            if reason is None:
                out[i, :3, 3] = position
                out[i, :3, :3] = poses[i, :3, :3] @ axis_angle_to_matrix(rotvec)
                break
        else:
            raise ValueError(
                f"frame {i}: no admissible camera pose near {np.round(poses[i, :3, 3], 3).tolist()} after "
                f"{config.max_tries} tries (last rejection: {reason}); increase the margin or reduce the clearance"
            )
    return out
