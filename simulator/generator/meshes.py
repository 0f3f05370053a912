"""Triangle meshes with per-corner normals and texture coordinates, built from trimesh primitives, and an OBJ writer.

Conventions: y up, metres. A :class:`MeshData` stores *unshared* corners (three per face) so that hard edges keep flat
normals and every face gets its own planar UVs; the OBJ writer deduplicates positions, normals and UVs again.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import trimesh


@dataclass(frozen=True)
class MeshData:
    """A triangle soup ready to write.

    Attributes:
        positions: (V, 3) float64 vertex positions (y up, metres).
        normals: (V, 3) float64 unit vertex normals.
        uvs: (V, 2) float64 texture coordinates.
        faces: (F, 3) int64 vertex indices, counter-clockwise seen from the side the normals point to.
    """

    positions: np.ndarray
    normals: np.ndarray
    uvs: np.ndarray
    faces: np.ndarray

    def bounds(self) -> tuple[np.ndarray, np.ndarray]:
        """Axis-aligned box ``(lo, hi)``, each (3,)."""
        return self.positions.min(axis=0), self.positions.max(axis=0)

    def translated(self, offset: np.ndarray) -> MeshData:
        """A copy moved by ``offset`` (3,)."""
        return MeshData(self.positions + np.asarray(offset, dtype=np.float64), self.normals, self.uvs, self.faces)


def flat_from_trimesh(mesh: trimesh.Trimesh, uv_span: float, smooth: bool = False) -> MeshData:
    """Unshare a trimesh's corners and give every face a planar (triplanar box) projection UV.

    Each face is projected along the world axis closest to its normal; UVs are the two remaining coordinates divided
    by ``uv_span`` (metres covered by one texture repeat), so the texture is not stretched.

    Args:
        mesh: a watertight or open trimesh (V, 3) / (F, 3).
        uv_span: metres per unit of UV.
        smooth: use the mesh's smoothed vertex normals (cylinders, spheres) instead of face normals.

    Returns:
        MeshData with 3F corners.
    """
    if uv_span <= 0:
        raise ValueError(f"uv_span must be positive, got {uv_span}")
    faces = np.asarray(mesh.faces, dtype=np.int64)
    corners = np.asarray(mesh.vertices, dtype=np.float64)[faces].reshape(-1, 3)
    fn = np.asarray(mesh.face_normals, dtype=np.float64)
    if smooth:
        normals = np.asarray(mesh.vertex_normals, dtype=np.float64)[faces].reshape(-1, 3)
    else:
        normals = np.repeat(fn, 3, axis=0)
    axis = np.repeat(np.argmax(np.abs(fn), axis=1), 3)
    uv = np.empty((len(corners), 2))
    for a, (i, j) in enumerate(((2, 1), (0, 2), (0, 1))):
        sel = axis == a
        uv[sel, 0] = corners[sel, i]
        uv[sel, 1] = corners[sel, j]
    uv /= uv_span
    new_faces = np.arange(len(corners), dtype=np.int64).reshape(-1, 3)
    return MeshData(corners, _unit(normals), uv, new_faces)


def concatenate(parts: list[MeshData]) -> MeshData:
    """Join meshes into one (face indices offset), in order."""
    if not parts:
        raise ValueError("concatenate needs at least one mesh")
    offsets = np.cumsum([0] + [len(p.positions) for p in parts[:-1]])
    return MeshData(
        np.concatenate([p.positions for p in parts]),
        np.concatenate([p.normals for p in parts]),
        np.concatenate([p.uvs for p in parts]),
        np.concatenate([p.faces + o for p, o in zip(parts, offsets)]),
    )


def centre_on_floor(mesh: MeshData) -> MeshData:
    """Move a model so that its bounding box is centred in x and z and its bottom is at y = 0."""
    lo, hi = mesh.bounds()
    return mesh.translated(np.array([-(lo[0] + hi[0]) / 2, -lo[1], -(lo[2] + hi[2]) / 2]))


def _unit(v: np.ndarray) -> np.ndarray:
    n = np.linalg.norm(v, axis=1, keepdims=True)
    if np.any(n < 1e-12):
        raise ValueError("degenerate normal (zero length) in mesh")
    return v / n


def _dedupe(a: np.ndarray, decimals: int) -> tuple[np.ndarray, np.ndarray]:
    """Unique rows after rounding, in first-appearance order; returns (unique (U, k), inverse (N,))."""
    r = np.round(a, decimals) + 0.0  # + 0.0 turns -0.0 into 0.0 so that the text is stable
    _, first, inverse = np.unique(r, axis=0, return_index=True, return_inverse=True)
    order = np.argsort(first)
    rank = np.empty_like(order)
    rank[order] = np.arange(len(order))
    return r[first[order]], rank[inverse.reshape(-1)]


def obj_text(mesh: MeshData, mtllib: str, material: str, decimals: int = 6) -> str:
    """Wavefront OBJ text (``v``/``vt``/``vn`` deduplicated, 1-based ``f v/vt/vn``) using one material.

    Byte-stable: fixed formatting, no timestamps, deterministic ordering.
    """
    pos, ip = _dedupe(mesh.positions, decimals)
    uv, it = _dedupe(mesh.uvs, decimals)
    nrm, inn = _dedupe(mesh.normals, decimals)
    fmt = f"{{:.{decimals}f}}"
    lines = [f"mtllib {mtllib}", "o model"]
    lines += ["v " + " ".join(fmt.format(c) for c in p) for p in pos]
    lines += ["vt " + " ".join(fmt.format(c) for c in t) for t in uv]
    lines += ["vn " + " ".join(fmt.format(c) for c in n) for n in nrm]
    lines += [f"usemtl {material}", "s off"]
    for f in mesh.faces:
        lines.append("f " + " ".join(f"{ip[k] + 1}/{it[k] + 1}/{inn[k] + 1}" for k in f))
    return "\n".join(lines) + "\n"


def box(extent: tuple[float, float, float], centre: tuple[float, float, float]) -> trimesh.Trimesh:
    """An axis-aligned box of size ``extent`` (x, y, z) centred at ``centre``."""
    return trimesh.creation.box(extents=extent, transform=trimesh.transformations.translation_matrix(centre))


def cylinder(radius: float, height: float, base_centre: tuple[float, float, float], sections: int = 24,
             top_radius: float | None = None) -> trimesh.Trimesh:
    """A vertical (y axis) cylinder or cone frustum standing on ``base_centre``.

    ``top_radius`` makes a frustum (lamp shades); trimesh's cylinder runs along z, so it is rotated to y.
    """
    if top_radius is None:
        m = trimesh.creation.cylinder(radius=radius, height=height, sections=sections)
    else:
        ang = np.linspace(0, 2 * np.pi, sections, endpoint=False)
        ring = np.stack([np.cos(ang), np.sin(ang), np.zeros_like(ang)], axis=1)
        pts = np.vstack([ring * [radius, radius, 1] + [0, 0, -height / 2], ring * [top_radius, top_radius, 1]
                         + [0, 0, height / 2]])
        m = trimesh.convex.convex_hull(pts)
    rot = trimesh.transformations.rotation_matrix(-np.pi / 2, [1, 0, 0])
    m.apply_transform(rot)
    m.apply_translation(np.asarray(base_centre, dtype=np.float64) + [0, height / 2, 0])
    return m
