"""Room layouts: floor outline, height, door, light bands and furniture placement (numpy + shapely, no files).

All coordinates are the house file's: y up, metres; plans live in the (x, z) plane. Furniture stands with its back
against a wall (its model front, +z, turned to the wall's inward normal), hangs on a wall, sits on another piece, or
is mounted on the ceiling. Floor furniture stays inside each wall's *band* (a strip along the wall whose depth the
recipe sets); the rest of the floor, the **walkway**, is kept free so that a camera loop with >= 0.6 m clearance on
both sides fits around the room centre.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
import shapely
from shapely.geometry import Polygon

from .architecture import BASEBOARD_DEPTH, Edge, edges, outline

WALKWAY_HALF_WIDTH = 0.6
"""Half the width of the free walkway around the camera loop (m): the walkway is >= 1.2 m wide."""
HANGING_CLEARANCE = 1.9
"""Items whose bottom is at least this high (ceiling lights, pendants) may be above the walkway (m)."""
GAP = 0.03
"""Minimum horizontal gap between two furniture pieces, and from a piece to the door zone (m)."""
CEILING_LAMP_SPACING = 2.0
"""Target distance between ceiling light panels (m)."""
MAX_LAYOUT_ATTEMPTS = 200
"""How many fresh random layouts to try before giving up."""

Rect = tuple[float, float, float, float]


@dataclass(frozen=True)
class ItemSpec:
    """One line of a room recipe.

    Attributes:
        type_name: furniture type (``furniture.FURNITURE_TYPES`` key).
        mode: ``wall`` (floor, back to a wall), ``hang`` (on a wall at ``height``), ``beside`` (left and right of
            ``parent`` along its wall), ``front`` (in front of ``parent``; ``facing`` turns it towards the parent),
            ``top`` (standing on ``parent``), ``pendant`` (hanging from the ceiling above ``parent``),
            ``ceiling`` (a grid of ceiling panels over the whole room).
        count: how many instances (``beside`` places up to two).
        parent: index of an earlier item in the recipe (its first instance) for relative modes.
        height: bottom height above the floor for ``hang`` (m).
        facing: for ``front``: face the parent (chairs) instead of the parent's direction (coffee tables).
        edges: walls allowed for ``wall``/``hang`` (indices into the outline's edges); empty means any.
        required: raise if it cannot be placed (otherwise it is skipped).
    """

    type_name: str
    mode: str
    count: int = 1
    parent: int | None = None
    height: float = 0.0
    facing: bool = False
    edges: tuple[int, ...] = ()
    required: bool = True


@dataclass(frozen=True)
class RoomRecipe:
    """How to lay out one room kind.

    Attributes:
        room_type: 3D-FRONT room type.
        width: (min, max) extent along x (m).
        depth: (min, max) extent along z (m).
        height: (min, max) ceiling height (m).
        notch: (min, max) fraction of width and depth cut from the (+x, +z) corner (L shape), or None.
        bands: furniture band depth per wall index (m); walls not listed use ``default_band``.
        default_band: band depth of the other walls (m).
        door_edge: wall index that holds the door.
        light_bands: add two LightBand strips along the x axis of the ceiling.
        items: furniture, placed in order.
    """

    room_type: str
    width: tuple[float, float]
    depth: tuple[float, float]
    height: tuple[float, float]
    notch: tuple[float, float] | None
    bands: dict[int, float]
    default_band: float
    door_edge: int
    light_bands: bool
    items: tuple[ItemSpec, ...]


@dataclass(frozen=True)
class Placement:
    """One furniture instance.

    Attributes:
        type_name: furniture type.
        position: (3,) world position of the model origin (bottom centre), y up.
        yaw: rotation about +y (radians, a multiple of pi/2).
        size: (3,) model size (x, y, z) before rotation.
        model: index of the model among the models of ``type_name`` (pieces of one type may differ).
    """

    type_name: str
    position: np.ndarray
    yaw: float
    size: np.ndarray
    model: int = 0

    def box(self) -> tuple[np.ndarray, np.ndarray]:
        """World axis-aligned bounding box ``(lo, hi)``, each (3,)."""
        return placed_box(self.position, self.yaw, self.size)


def placed_box(position: np.ndarray, yaw: float, size: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """AABB of a model of ``size`` (centred in x/z, bottom at 0) turned by ``yaw`` about +y and moved to
    ``position``; exact for any yaw (the box's corners are rotated)."""
    c, s = math.cos(yaw), math.sin(yaw)
    ex = abs(c) * size[0] + abs(s) * size[2]
    ez = abs(s) * size[0] + abs(c) * size[2]
    half = np.array([ex / 2, 0.0, ez / 2])
    lo = np.asarray(position, dtype=np.float64) - half
    hi = np.asarray(position, dtype=np.float64) + half
    hi[1] = position[1] + size[1]
    return lo, hi


def yaw_quaternion(yaw: float) -> list[float]:
    """[x, y, z, w] quaternion of a rotation by ``yaw`` about +y."""
    return [0.0, math.sin(yaw / 2), 0.0, math.cos(yaw / 2)]


@dataclass(frozen=True)
class Door:
    """The door: on wall ``edge`` with its centre ``centre`` m from the wall start."""

    edge: int
    centre: float
    width: float = 0.9
    height: float = 2.05
    thickness: float = 0.04


@dataclass(frozen=True)
class RoomPlan:
    """A laid-out room (no meshes or files yet).

    Attributes:
        kind: generator room kind.
        room_type: 3D-FRONT room type.
        rects: floor rectangles (x0, z0, x1, z1) whose union is the outline.
        polygon: floor outline, counter-clockwise in (x, z).
        height: ceiling height (m).
        door: the door.
        walkway: the free floor region kept clear of floor furniture (a polygon in (x, z)).
        light_bands: ceiling light strips as rectangles (x0, z0, x1, z1).
        placements: furniture instances.
    """

    kind: str
    room_type: str
    rects: tuple[Rect, ...]
    polygon: Polygon
    height: float
    door: Door
    walkway: Polygon
    light_bands: tuple[Rect, ...]
    placements: tuple[Placement, ...] = field(default=())

    def camera_loop(self) -> np.ndarray:
        """(K, 2) closed loop in (x, z) (first vertex not repeated) around which a 1.2 m walkway is free."""
        core = self.walkway.buffer(-WALKWAY_HALF_WIDTH, join_style="mitre")
        if core.is_empty:
            raise ValueError(f"{self.kind}: the walkway is narrower than {2 * WALKWAY_HALF_WIDTH} m")
        if core.geom_type == "MultiPolygon":
            core = max(core.geoms, key=lambda g: g.area)
        return np.asarray(core.exterior.coords)[:-1]


def _footprint(lo: np.ndarray, hi: np.ndarray) -> Polygon:
    return shapely.box(lo[0], lo[2], hi[0], hi[2])


def boxes_overlap(a: tuple[np.ndarray, np.ndarray], b: tuple[np.ndarray, np.ndarray], gap: float = 0.0) -> bool:
    """True when two AABBs overlap with positive volume, after growing ``a`` horizontally by ``gap``."""
    grow = np.array([gap, 0.0, gap])
    return bool(np.all(a[0] - grow < b[1] - 1e-9) and np.all(b[0] < a[1] + grow - 1e-9))


class Layout:
    """Mutable state of a placement search; :func:`plan_room` drives it."""

    def __init__(self, polygon: Polygon, walls: list[Edge], height: float, walkway: Polygon,
                 keep_out: list[tuple[np.ndarray, np.ndarray]]):
        self.polygon = polygon
        self.walls = walls
        self.height = height
        self.walkway = walkway
        self.keep_out = keep_out
        self.placed: list[Placement] = []

    def fits(self, p: Placement, ignore: Placement | None = None) -> bool:
        """Whether ``p`` lies inside the room, off the walkway (unless hanging high), and clear of all others."""
        lo, hi = p.box()
        if hi[1] > self.height + 1e-9 or lo[1] < -1e-9:
            return False
        fp = _footprint(lo, hi)
        if not self.polygon.buffer(1e-9).covers(fp):
            return False
        if lo[1] < HANGING_CLEARANCE and fp.intersection(self.walkway).area > 1e-9:
            return False
        if any(boxes_overlap((lo, hi), k, GAP) for k in self.keep_out):
            return False
        return not any(boxes_overlap((lo, hi), q.box(), GAP) for q in self.placed if q is not ignore)

    def against_wall(self, type_name: str, size: np.ndarray, wall: int, s: float, y: float, gap: float,
                     model: int) -> Placement:
        """A piece with its back to wall ``wall``, centred ``s`` m along it, its bottom at height ``y``."""
        e = self.walls[wall]
        c = e.start + e.direction * s + e.normal * (size[2] / 2 + gap)
        return Placement(type_name, np.array([c[0], y, c[1]]), _wrap(math.atan2(e.normal[0], e.normal[1])), size,
                         model)


def _wall_candidates(layout: Layout, rng: np.random.Generator, allowed: tuple[int, ...], width: float):
    """(wall, s) positions along the allowed walls in a random but reproducible order, 5 cm apart."""
    walls = list(allowed) if allowed else list(range(len(layout.walls)))
    cands = []
    for w in walls:
        length = layout.walls[w].length
        if length < width:
            continue
        n = int((length - width) / 0.05) + 1
        s = width / 2 + np.arange(n) * 0.05
        cands += [(w, float(v)) for v in s]
    order = rng.permutation(len(cands))
    return [cands[i] for i in order]


def _place_item(layout: Layout, spec: ItemSpec, sizes: list[np.ndarray], first_model: int,
                rng: np.random.Generator, anchors: dict[int, list[Placement]], index: int) -> list[Placement]:
    """Place the instances of one recipe line; returns them (also appended to ``layout.placed``).

    Instance ``k`` uses model ``first_model + k`` of its type (modulo the number of models, ``len(sizes)``).
    """
    out: list[Placement] = []

    def model_of(k: int) -> tuple[int, np.ndarray]:
        m = (first_model + k) % len(sizes)
        return m, sizes[m]

    if spec.mode in ("wall", "hang"):
        y, gap = (0.0, BASEBOARD_DEPTH + 0.005) if spec.mode == "wall" else (spec.height, 0.002)
        for k in range(spec.count):
            m, size = model_of(k)
            for w, s in _wall_candidates(layout, rng, spec.edges, size[0]):
                p = layout.against_wall(spec.type_name, size, w, s, y, gap, m)
                if layout.fits(p):
                    layout.placed.append(p)
                    out.append(p)
                    break
    elif spec.mode in ("beside", "front", "top", "pendant"):
        parents = anchors.get(spec.parent, []) if spec.parent is not None else []
        if not parents:
            raise ValueError(f"recipe item {index} ({spec.type_name}) needs a placed parent, got {spec.parent}")
        for k in range(spec.count):
            m, size = model_of(k)
            parent = parents[0] if spec.mode == "beside" else parents[k % len(parents)]
            for pos, yaw in _relative_candidates(spec, parent, size, layout.height):
                p = Placement(spec.type_name, np.asarray(pos, dtype=np.float64), _wrap(yaw), size, m)
                if layout.fits(p, ignore=parent if spec.mode == "top" else None) and _rests_on(p, parent, spec.mode):
                    layout.placed.append(p)
                    out.append(p)
                    break
    elif spec.mode == "ceiling":
        out = _ceiling_grid(layout, spec, sizes[first_model % len(sizes)], first_model % len(sizes))
    else:
        raise ValueError(f"recipe item {index} ({spec.type_name}): unknown mode {spec.mode!r}")
    if spec.required and (len(out) < spec.count if spec.mode != "ceiling" else not out):
        raise RuntimeError(f"could not place {spec.count} x {spec.type_name} ({spec.mode}); placed {len(out)}")
    return out


def _relative_candidates(spec: ItemSpec, parent: Placement, size: np.ndarray, room_height: float):
    """Candidate (position (3,), yaw) pairs for a piece placed relative to ``parent``, best first."""
    fwd = np.array([math.sin(parent.yaw), 0.0, math.cos(parent.yaw)])
    right = np.array([math.cos(parent.yaw), 0.0, -math.sin(parent.yaw)])
    if spec.mode == "beside":
        off = parent.size[0] / 2 + GAP + 0.02 + size[0] / 2
        back = (size[2] - parent.size[2]) / 2
        return [(parent.position + sx * off * right + back * fwd, parent.yaw) for sx in (-1, 1)]
    if spec.mode == "front":
        yaw = parent.yaw + (math.pi if spec.facing else 0.0)
        return [(parent.position + (parent.size[2] / 2 + size[2] / 2 + dist) * fwd + lat * right, yaw)
                for dist in np.arange(0.05, 0.6, 0.05) for lat in (0.0, 0.15, -0.15, 0.3, -0.3)]
    if spec.mode == "top":
        top = parent.box()[1][1]
        out = []
        for b in (1.0, 0.6, 0.3, 0.0):
            for side in (-1, 1):
                lat = side * (parent.size[0] / 2 - size[0] / 2 - 0.05)
                back = -(parent.size[2] / 2 - size[2] / 2 - 0.02) * b
                pos = parent.position + lat * right + back * fwd
                out.append((np.array([pos[0], top, pos[2]]), parent.yaw))
        return out
    pos = parent.position.copy()
    pos[1] = room_height - size[1]
    return [(pos, parent.yaw)]


def _wrap(yaw: float) -> float:
    """Yaw wrapped to (-pi, pi] and snapped to the nearest multiple of pi/2 when within 1e-9."""
    y = math.atan2(math.sin(yaw), math.cos(yaw))
    q = round(y / (math.pi / 2)) * (math.pi / 2)
    return q if abs(q - y) < 1e-9 else y


def _rests_on(p: Placement, parent: Placement, mode: str) -> bool:
    """For ``top``: the footprint lies on the parent's top; other modes need nothing."""
    if mode != "top":
        return True
    lo, hi = p.box()
    plo, phi = parent.box()
    return bool(lo[0] >= plo[0] and hi[0] <= phi[0] and lo[2] >= plo[2] and hi[2] <= phi[2])


def _ceiling_grid(layout: Layout, spec: ItemSpec, size: np.ndarray, model: int) -> list[Placement]:
    """Ceiling panels on a regular grid over the outline's bounding box, keeping those inside the room."""
    x0, z0, x1, z1 = layout.polygon.bounds
    nx = max(1, round((x1 - x0) / CEILING_LAMP_SPACING))
    nz = max(1, round((z1 - z0) / CEILING_LAMP_SPACING))
    out = []
    inner = layout.polygon.buffer(-0.3, join_style="mitre")
    for i in range(nx):
        for j in range(nz):
            x = x0 + (i + 0.5) * (x1 - x0) / nx
            z = z0 + (j + 0.5) * (z1 - z0) / nz
            p = Placement(spec.type_name, np.array([x, layout.height - size[1], z]), 0.0, size, model)
            lo, hi = p.box()
            if inner.covers(_footprint(lo, hi)) and layout.fits(p):
                layout.placed.append(p)
                out.append(p)
    return out


def floor_rects(recipe: RoomRecipe, rng: np.random.Generator) -> list[Rect]:
    """The floor rectangles: one box, or an L (two boxes) when the recipe has a notch. Sizes rounded to 5 cm."""
    w = round(float(rng.uniform(*recipe.width)) * 20) / 20
    d = round(float(rng.uniform(*recipe.depth)) * 20) / 20
    if recipe.notch is None:
        return [(0.0, 0.0, w, d)]
    f = float(rng.uniform(*recipe.notch))
    nw, nd = round(w * f * 20) / 20, round(d * f * 20) / 20
    return [(0.0, 0.0, w, round(d - nd, 2)), (0.0, round(d - nd, 2), round(w - nw, 2), d)]


def walkway_region(polygon: Polygon, walls: list[Edge], bands: dict[int, float], default: float) -> Polygon:
    """The floor minus a band of the given depth along every wall."""
    strips = []
    for i, e in enumerate(walls):
        depth = bands.get(i, default)
        a, b = e.start, e.end
        strips.append(Polygon([a, b, b + e.normal * depth, a + e.normal * depth]))
    region = polygon.difference(shapely.union_all(strips))
    if region.geom_type == "MultiPolygon":
        region = max(region.geoms, key=lambda g: g.area)
    if region.is_empty or region.buffer(-WALKWAY_HALF_WIDTH, join_style="mitre").is_empty:
        raise ValueError(f"walkway too narrow for a {2 * WALKWAY_HALF_WIDTH} m loop: bands {bands}, default {default}")
    return region


def model_counts(recipe: RoomRecipe) -> dict[str, int]:
    """How many distinct models each furniture type of a recipe needs: one per instance (so that no two pieces in a
    room are identical, which would mislead structure-from-motion), except one shared ceiling panel."""
    counts: dict[str, int] = {}
    for spec in recipe.items:
        counts[spec.type_name] = counts.get(spec.type_name, 0) + (1 if spec.mode == "ceiling" else spec.count)
    return counts


def plan_room(kind: str, recipe: RoomRecipe, sizes: dict[str, list[np.ndarray]],
              rng: np.random.Generator) -> RoomPlan:
    """Lay out a room.

    Args:
        kind: room kind name (for messages).
        recipe: the recipe.
        sizes: per furniture type, the (3,) sizes of its models (:func:`model_counts` of them).
        rng: the layout stage's generator.

    Returns:
        The plan; raises RuntimeError when a required item does not fit.
    """
    rects = floor_rects(recipe, rng)
    height = round(float(rng.uniform(*recipe.height)) * 20) / 20
    poly = outline(rects)
    walls = edges(poly)
    if not 0 <= recipe.door_edge < len(walls):
        raise ValueError(f"{kind}: door edge {recipe.door_edge} not in 0..{len(walls) - 1}")
    dw = walls[recipe.door_edge]
    door = Door(recipe.door_edge, round(float(rng.uniform(0.3 + 0.45, dw.length - 0.3 - 0.45)) * 20) / 20)
    walkway = walkway_region(poly, walls, recipe.bands, recipe.default_band)
    # the door leaf plus the floor in front of it (1 m) stay free up to just above the door (ceiling lights may pass)
    dc = dw.start + dw.direction * door.centre
    a = dc - dw.direction * (door.width / 2 + 0.1)
    b = dc + dw.direction * (door.width / 2 + 0.1) + dw.normal * 1.0
    keep = (np.array([min(a[0], b[0]), 0.0, min(a[1], b[1])]), np.array([max(a[0], b[0]), door.height + 0.15,
                                                                       max(a[1], b[1])]))
    bands_out: list[Rect] = []
    if recipe.light_bands:
        x0, z0, x1, z1 = poly.bounds
        zc = (z0 + z1) / 2
        for off in (-0.6, 0.6):
            bands_out.append((x0 + 0.4, zc + off - 0.06, x1 - 0.4, zc + off + 0.06))
    failure = ""
    for _ in range(MAX_LAYOUT_ATTEMPTS):
        layout = Layout(poly, walls, height, walkway, [keep])
        try:
            _place_all(kind, recipe, sizes, rng, layout)
        except RuntimeError as err:  # a required piece did not fit: start over with fresh random positions
            failure = str(err)
            continue
        return RoomPlan(kind, recipe.room_type, tuple(rects), poly, height, door, walkway, tuple(bands_out),
                        tuple(layout.placed))
    raise RuntimeError(f"{kind}: no layout after {MAX_LAYOUT_ATTEMPTS} attempts; last failure: {failure}")


def _place_all(kind: str, recipe: RoomRecipe, sizes: dict[str, list[np.ndarray]], rng: np.random.Generator,
               layout: Layout) -> None:
    """Place every recipe line in order (raises RuntimeError when a required piece does not fit)."""
    anchors: dict[int, list[Placement]] = {}
    used: dict[str, int] = {}
    for i, spec in enumerate(recipe.items):
        if spec.type_name not in sizes or not sizes[spec.type_name]:
            raise ValueError(f"{kind}: no model sizes for furniture type {spec.type_name!r}")
        placed = _place_item(layout, spec, sizes[spec.type_name], used.get(spec.type_name, 0), rng, anchors, i)
        used[spec.type_name] = used.get(spec.type_name, 0) + spec.count
        anchors[i] = placed


def _it(*a, **k) -> ItemSpec:
    return ItemSpec(*a, **k)


RECIPES: dict[str, RoomRecipe] = {
    "bedroom": RoomRecipe(
        "Bedroom", (4.2, 4.8), (4.4, 4.8), (2.6, 2.75), None, {0: 2.25}, 0.7, 2, False,
        (
            _it("bed", "wall", edges=(0,)),
            _it("nightstand", "beside", 2, parent=0),
            _it("desk_lamp", "top", parent=1),
            _it("wardrobe", "wall", edges=(1, 3)),
            _it("dresser", "wall"),
            _it("armchair", "wall", required=False),
            _it("floor_lamp", "wall"),
            _it("painting", "hang", 2, height=1.25),
            _it("wall_lamp", "hang", height=1.7, required=False),
            _it("ceiling_lamp", "ceiling"),
        ),
    ),
    "living_room": RoomRecipe(
        "LivingRoom", (5.6, 6.0), (5.2, 5.6), (2.75, 2.9), (0.3, 0.36),
        {0: 0.9, 1: 0.6, 2: 0.5, 3: 0.5, 4: 0.9, 5: 1.95}, 0.9, 3, False,
        (
            _it("sofa", "wall", edges=(5,)),
            _it("coffee_table", "front", parent=0),
            _it("pendant_lamp", "pendant", parent=1),
            _it("tv_stand", "wall", edges=(1,)),
            _it("bookcase", "wall", 2, edges=(0, 4)),
            _it("armchair", "wall", edges=(0, 4)),
            _it("floor_lamp", "wall"),
            _it("painting", "hang", 3, height=1.3),
            _it("wall_lamp", "hang", 2, height=1.75, required=False),
            _it("ceiling_lamp", "ceiling"),
        ),
    ),
    "office": RoomRecipe(
        "Office/Library", (5.0, 5.6), (4.4, 4.8), (2.7, 2.9), None, {0: 1.4}, 0.7, 2, False,
        (
            _it("desk", "wall", 2, edges=(0,)),
            _it("office_chair", "front", 2, parent=0, facing=True),
            _it("desk_lamp", "top", 2, parent=0),
            _it("bookcase", "wall", 2),
            _it("filing_cabinet", "wall", 2),
            _it("metal_shelf", "wall"),
            _it("floor_lamp", "wall"),
            _it("painting", "hang", 2, height=1.3),
            _it("ceiling_lamp", "ceiling"),
        ),
    ),
    "storage_room": RoomRecipe(
        "StorageRoom", (4.6, 5.2), (3.8, 4.2), (2.6, 2.8), None, {}, 0.75, 2, False,
        (
            _it("metal_shelf", "wall", 3),
            _it("steel_cabinet", "wall", 2),
            _it("workbench", "wall"),
            _it("tool_chest", "wall"),
            _it("floor_lamp", "wall"),
            _it("wall_lamp", "hang", 2, height=1.8, required=False),
            _it("painting", "hang", height=1.3, required=False),
            _it("ceiling_lamp", "ceiling"),
        ),
    ),
    # Small and white: strong interreflection (most of what the spotlight lights bounces on to light the rest).
    "white_room": RoomRecipe(
        "OtherRoom", (3.3, 3.6), (3.1, 3.4), (2.6, 2.65), None, {0: 0.9}, 0.55, 1, False,
        (
            _it("dresser", "wall"),
            _it("bookcase", "wall"),
            _it("armchair", "wall", edges=(0,)),
            _it("floor_lamp", "wall"),
            _it("painting", "hang", height=1.3, required=False),
            _it("ceiling_lamp", "ceiling"),
        ),
    ),
    "corridor": RoomRecipe(
        "Hallway", (8.0, 9.0), (2.7, 2.9), (2.6, 2.75), None, {}, 0.45, 1, True,
        (
            _it("console_table", "wall", edges=(0, 2)),
            _it("bench", "wall", edges=(0, 2)),
            _it("shoe_cabinet", "wall", edges=(0, 2)),
            _it("floor_lamp", "wall", edges=(3,)),
            _it("painting", "hang", 4, height=1.3, edges=(0, 2)),
            _it("wall_lamp", "hang", 3, height=1.75, edges=(0, 2)),
            _it("ceiling_lamp", "ceiling"),
        ),
    ),
}
"""Recipes per room kind."""
