"""Where a camera centre may be in a room: inside the floor polygon and clear of walls, floor, ceiling and furniture.

A camera centre ``p`` (3,) is *admissible* when

* its height lies in ``[floor_z + clearance, ceiling_z - clearance]``;
* its x-y lies strictly inside the floor polygon eroded by ``clearance`` (shapely mitred buffer);
* it lies in no obstacle box grown by ``clearance`` on every side (boxes are closed: a point on a face is inside).

Only the camera centre is tested, not the view frustum. bpy-free (numpy + shapely).
"""

from __future__ import annotations

import math

import numpy as np


def floor_polygon_shape(floor_polygon: np.ndarray):
    """A validated shapely polygon from floor vertices (K, 2) (any orientation, not closed)."""
    from shapely.geometry import Polygon

    pts = np.asarray(floor_polygon, dtype=np.float64)
    if pts.ndim != 2 or pts.shape[1] != 2 or pts.shape[0] < 3 or not np.isfinite(pts).all():
        raise ValueError(f"floor polygon must be a finite (K >= 3, 2) array, got shape {pts.shape}")
    poly = Polygon(pts)
    if not poly.is_valid or poly.area <= 0:
        raise ValueError("floor polygon is self-intersecting or has zero area")
    return poly


class FreeSpace:
    """The admissible camera centres of one room (see the module docstring).

    Args:
        floor_polygon: (K, 2) floor outline in world x-y.
        floor_z: floor height, metres.
        ceiling_z: ceiling height, metres (> floor_z).
        obstacles: furniture boxes ``(lo (3,), hi (3,))`` in world coordinates.
        clearance: minimum distance of a camera centre to walls, floor, ceiling and boxes, metres (>= 0).
    """

    def __init__(
        self,
        floor_polygon: np.ndarray,
        floor_z: float,
        ceiling_z: float,
        obstacles: list[tuple[np.ndarray, np.ndarray]],
        clearance: float,
    ) -> None:
        from shapely.geometry import JOIN_STYLE
        from shapely.prepared import prep

        if not (math.isfinite(floor_z) and math.isfinite(ceiling_z) and ceiling_z > floor_z):
            raise ValueError(f"ceiling_z ({ceiling_z}) must be above floor_z ({floor_z})")
        if not (math.isfinite(clearance) and clearance >= 0):
            raise ValueError(f"clearance must be finite and >= 0, got {clearance!r}")
        poly = floor_polygon_shape(floor_polygon)
        free = poly.buffer(-clearance, join_style=JOIN_STYLE.mitre) if clearance > 0 else poly
        self.free_area = None if free.is_empty else free  # x-y region clear of the walls (shapely), or None
        self._prepared_free = None if self.free_area is None else prep(self.free_area)
        self.z_lo = floor_z + clearance  # lowest admissible camera height, metres
        self.z_hi = ceiling_z - clearance  # highest admissible camera height, metres
        # (B, 3) corners of the obstacle boxes grown by the clearance.
        self.boxes_lo = np.array([np.asarray(lo, float) for lo, _ in obstacles]).reshape(-1, 3) - clearance
        self.boxes_hi = np.array([np.asarray(hi, float) for _, hi in obstacles]).reshape(-1, 3) + clearance
        if len(obstacles) and not (np.isfinite(self.boxes_lo).all() and np.isfinite(self.boxes_hi).all()):
            raise ValueError("obstacle boxes must be finite")

    def rejection_reason(self, position: np.ndarray) -> str | None:
        """Why a camera centre (3,) is not admissible, or None when it is."""
        from shapely.geometry import Point

        if not (self.z_lo <= position[2] <= self.z_hi):
            return f"height {position[2]:.3f} m outside [{self.z_lo:.3f}, {self.z_hi:.3f}]"
        if self.free_area is None or not self._prepared_free.contains(Point(position[0], position[1])):
            return "too close to a wall or outside the room"
        if len(self.boxes_lo):
            inside = np.all((position >= self.boxes_lo) & (position <= self.boxes_hi), axis=1)
            if inside.any():
                return f"inside obstacle box {int(np.argmax(inside))}"
        return None

    def is_admissible(self, position: np.ndarray) -> bool:
        """True when the camera centre (3,) is admissible."""
        return self.rejection_reason(np.asarray(position, dtype=np.float64)) is None

    def free_slice(self, z: float):
        """The admissible x-y region (shapely geometry, possibly empty) for camera centres at height ``z``."""
        from shapely.geometry import Polygon, box
        from shapely.ops import unary_union

        if self.free_area is None or not (self.z_lo <= z <= self.z_hi):
            return Polygon()
        spans = (self.boxes_lo[:, 2] <= z) & (z <= self.boxes_hi[:, 2])
        blocked = [box(lo[0], lo[1], hi[0], hi[1]) for lo, hi in zip(self.boxes_lo[spans], self.boxes_hi[spans])]
        return self.free_area.difference(unary_union(blocked)) if blocked else self.free_area

    def nearest_admissible(self, position: np.ndarray, buffer: float, max_shift: float) -> np.ndarray | None:
        """The admissible point nearest to ``position`` (3,) at the same height, at least ``buffer`` metres inside
        the admissible region and at most ``max_shift`` metres away; None when there is none.

        Returns:
            (3,) float64 camera centre, or None.
        """
        from shapely.geometry import Point
        from shapely.ops import nearest_points

        position = np.asarray(position, dtype=np.float64)
        region = self.free_slice(float(position[2]))
        if buffer > 0 and not region.is_empty:
            region = region.buffer(-buffer)
        if region.is_empty:
            return None
        target = Point(position[0], position[1])
        nearest = nearest_points(region, target)[0]
        candidate = np.array([nearest.x, nearest.y, position[2]])
        if np.hypot(*(candidate[:2] - position[:2])) > max_shift or not self.is_admissible(candidate):
            return None
        return candidate
