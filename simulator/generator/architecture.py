"""Architecture meshes of one room in world coordinates (y up, metres): floor, ceiling, inner walls, baseboards,
door and ceiling light bands.

The floor outline is a rectilinear polygon in the (x, z) plane given by its vertices in counter-clockwise order
(x to the right, z up, as drawn by shapely); every face is counter-clockwise seen from the side its normal points to,
and floor, ceiling and wall normals point into the room. Floor and ceiling UVs map the texture once over the room's
bounding square; walls map it once around the whole perimeter (u = arc length / perimeter, v = height / room height),
so no surface repeats its texture.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import shapely
from shapely.geometry import Polygon

from .meshes import MeshData, box, concatenate, flat_from_trimesh

BASEBOARD_HEIGHT = 0.08
"""Baseboard height (m)."""
BASEBOARD_DEPTH = 0.012
"""How far baseboards stand out of the wall (m)."""


@dataclass(frozen=True)
class Edge:
    """One wall of the floor outline.

    Attributes:
        start, end: (2,) endpoints in the (x, z) plane.
        normal: (2,) unit normal pointing into the room.
        offset: arc length of ``start`` along the outline (m), for continuous wall UVs.
    """

    start: np.ndarray
    end: np.ndarray
    normal: np.ndarray
    offset: float

    @property
    def length(self) -> float:
        """Edge length (m)."""
        return float(np.linalg.norm(self.end - self.start))

    @property
    def direction(self) -> np.ndarray:
        """(2,) unit vector from start to end."""
        return (self.end - self.start) / self.length


def outline(rects: list[tuple[float, float, float, float]]) -> Polygon:
    """The floor polygon of a union of axis-aligned rectangles ``(x0, z0, x1, z1)``: counter-clockwise, starting at
    the lowest-(x, z) vertex, without collinear vertices. Raises if the union is not one simple polygon."""
    poly = shapely.union_all([shapely.box(*r) for r in rects]).simplify(0.0)
    if not isinstance(poly, Polygon) or len(poly.interiors) or not poly.is_valid:
        raise ValueError(f"rectangles {rects} do not form one simple polygon without holes")
    poly = shapely.geometry.polygon.orient(poly, sign=1.0)
    pts = np.asarray(poly.exterior.coords)[:-1]
    start = int(np.lexsort((pts[:, 1], pts[:, 0]))[0])
    return Polygon(np.roll(pts, -start, axis=0))


def edges(poly: Polygon) -> list[Edge]:
    """The walls of a counter-clockwise polygon in order; the inward normal is the edge direction turned left."""
    pts = np.asarray(poly.exterior.coords)[:-1]
    out, s = [], 0.0
    for i in range(len(pts)):
        a, b = pts[i], pts[(i + 1) % len(pts)]
        d = (b - a) / np.linalg.norm(b - a)
        e = Edge(a.copy(), b.copy(), np.array([-d[1], d[0]]), s)
        out.append(e)
        s += e.length
    return out


def _quad(corners: np.ndarray, normal: np.ndarray, uvs: np.ndarray) -> MeshData:
    """Two triangles over 4 corners (4, 3) given in counter-clockwise order seen from ``normal``'s side."""
    e1, e2 = corners[1] - corners[0], corners[2] - corners[0]
    if np.dot(np.cross(e1, e2), normal) <= 0:
        raise ValueError("quad corners are not counter-clockwise seen from the normal side")
    return MeshData(corners.astype(np.float64), np.tile(normal.astype(np.float64), (4, 1)), uvs.astype(np.float64),
                    np.array([[0, 1, 2], [0, 2, 3]], dtype=np.int64))


def _join(parts: list[MeshData]) -> MeshData:
    return concatenate(parts)


def floor_aspect(bounds: tuple[float, float, float, float]) -> int:
    """Width/height of the floor and ceiling textures: the room's long/short side ratio rounded to 1, 2 or 3."""
    x0, z0, x1, z1 = bounds
    ex, ez = x1 - x0, z1 - z0
    return int(min(3, max(1, round(max(ex, ez) / min(ex, ez)))))


def horizontal(rects: list[tuple[float, float, float, float]], y: float, up: bool,
               bounds: tuple[float, float, float, float]) -> MeshData:
    """Floor (``up``: normal +y) or ceiling (normal -y) at height ``y`` over the rectangles.

    UVs map ``bounds`` (x0, z0, x1, z1) onto the unit square once, u along the longer side (use a texture
    :func:`floor_aspect` times wider than high to keep texels about square).
    """
    bx0, bz0, bx1, bz1 = bounds
    ex, ez = bx1 - bx0, bz1 - bz0
    normal = np.array([0.0, 1.0 if up else -1.0, 0.0])
    parts = []
    for x0, z0, x1, z1 in rects:
        # seen from +y (looking down), counter-clockwise in (x, z) appears clockwise: order accordingly
        xz = [(x0, z0), (x0, z1), (x1, z1), (x1, z0)] if up else [(x0, z0), (x1, z0), (x1, z1), (x0, z1)]
        corners = np.array([[x, y, z] for x, z in xz])
        st = np.array([[(x - bx0) / ex, (z - bz0) / ez] for x, z in xz])
        uv = st if ex >= ez else st[:, ::-1]
        parts.append(_quad(corners, normal, uv))
    return _join(parts)


def disjoint_rects(rects: list[tuple[float, float, float, float]]) -> list[tuple[float, float, float, float]]:
    """Split overlapping rectangles into non-overlapping ones covering the same union (grid decomposition)."""
    xs = sorted({r[0] for r in rects} | {r[2] for r in rects})
    zs = sorted({r[1] for r in rects} | {r[3] for r in rects})
    out = []
    for x0, x1 in zip(xs[:-1], xs[1:]):
        for z0, z1 in zip(zs[:-1], zs[1:]):
            cx, cz = (x0 + x1) / 2, (z0 + z1) / 2
            if any(r[0] <= cx <= r[2] and r[1] <= cz <= r[3] for r in rects):
                out.append((x0, z0, x1, z1))
    return out


def wall(edge: Edge, height: float, perimeter: float) -> MeshData:
    """One inner wall quad from the floor to ``height``, normal into the room."""
    a, b = edge.start, edge.end
    corners = np.array([[a[0], 0, a[1]], [b[0], 0, b[1]], [b[0], height, b[1]], [a[0], height, a[1]]])
    n = np.array([edge.normal[0], 0.0, edge.normal[1]])
    u0, u1 = edge.offset / perimeter, (edge.offset + edge.length) / perimeter
    uv = np.array([[u0, 0.0], [u1, 0.0], [u1, 1.0], [u0, 1.0]])
    if np.dot(np.cross(corners[1] - corners[0], corners[2] - corners[0]), n) <= 0:
        corners, uv = corners[[1, 0, 3, 2]], uv[[1, 0, 3, 2]]
    return _quad(corners, n, uv)


def baseboards(walls: list[Edge], perimeter: float) -> MeshData:
    """A baseboard strip along every wall: a front face ``BASEBOARD_DEPTH`` off the wall and a top face, mitred at
    the corners (outline offset inwards along both adjacent normals)."""
    k = len(walls)
    inner = [walls[i].start + BASEBOARD_DEPTH * (walls[i].normal + walls[i - 1].normal) for i in range(k)]
    parts = []
    for i, e in enumerate(walls):
        a, b = inner[i], inner[(i + 1) % k]
        u0, u1 = e.offset / perimeter * 8, (e.offset + e.length) / perimeter * 8
        n = np.array([e.normal[0], 0.0, e.normal[1]])
        hb = BASEBOARD_HEIGHT
        front = np.array([[a[0], 0, a[1]], [b[0], 0, b[1]], [b[0], hb, b[1]], [a[0], hb, a[1]]])
        uv = np.array([[u0, 0], [u1, 0], [u1, 0.1], [u0, 0.1]])
        if np.dot(np.cross(front[1] - front[0], front[2] - front[0]), n) <= 0:
            front, uv = front[[1, 0, 3, 2]], uv[[1, 0, 3, 2]]
        parts.append(_quad(front, n, uv))
        wa, wb = e.start, e.end
        top = np.array([[wa[0], BASEBOARD_HEIGHT, wa[1]], [wb[0], BASEBOARD_HEIGHT, wb[1]],
                        [b[0], BASEBOARD_HEIGHT, b[1]], [a[0], BASEBOARD_HEIGHT, a[1]]])
        uvt = np.array([[u0, 0.1], [u1, 0.1], [u1, 0.12], [u0, 0.12]])
        if np.dot(np.cross(top[1] - top[0], top[2] - top[0]), [0, 1, 0]) <= 0:
            top, uvt = top[[1, 0, 3, 2]], uvt[[1, 0, 3, 2]]
        parts.append(_quad(top, np.array([0.0, 1.0, 0.0]), uvt))
    return _join(parts)


def door(edge: Edge, centre: float, width: float, height: float, thickness: float) -> MeshData:
    """A closed door leaf standing on the floor against ``edge``, its centre ``centre`` m from the edge start.

    Returns a box (open at the back) whose front face carries the whole texture once.
    """
    c = edge.start + edge.direction * centre + edge.normal * thickness / 2
    along_x = abs(edge.direction[0]) > 0.5
    ext = (width, height, thickness) if along_x else (thickness, height, width)
    m = flat_from_trimesh(box(ext, (c[0], height / 2, c[1])), 1.0)
    n3 = np.array([edge.normal[0], 0.0, edge.normal[1]])
    keep = (m.normals @ n3) > -0.99  # drop the face against the wall
    faces = m.faces[keep[m.faces[:, 0]]]
    uv = m.uvs.copy()
    front = (m.normals @ n3) > 0.99
    s = (m.positions[:, [0, 2]] - edge.start) @ edge.direction
    uv[front, 0] = (s[front] - (centre - width / 2)) / width
    uv[front, 1] = m.positions[front, 1] / height
    return MeshData(m.positions, m.normals, uv, faces)


def light_band(x0: float, z0: float, x1: float, z1: float, y: float) -> MeshData:
    """A flat emissive strip facing down (normal -y) at height ``y`` over the rectangle (x0, z0)-(x1, z1)."""
    corners = np.array([[x0, y, z0], [x1, y, z0], [x1, y, z1], [x0, y, z1]])
    uv = np.array([[0, 0], [1, 0], [1, 1], [0, 1]], dtype=np.float64)
    n = np.array([0.0, -1.0, 0.0])
    if np.dot(np.cross(corners[1] - corners[0], corners[2] - corners[0]), n) <= 0:
        corners, uv = corners[[1, 0, 3, 2]], uv[[1, 0, 3, 2]]
    return _quad(corners, n, uv)
