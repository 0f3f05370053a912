"""Point clouds as PLY files in the layout that 3D Gaussian Splatting reads as its initial point cloud.

Vertex properties, in order: ``x y z nx ny nz`` (float32) and ``red green blue`` (uint8); binary little endian.
Positions that float32 would round by a millimetre or more (a coordinate of 16,384 m or more: georeferenced clouds)
are written as float64 instead.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import NamedTuple

import numpy as np

from spotlessgs.io.atomic import atomic_path

#: A position coordinate at least this large (metres) is written as float64: float32's spacing there is 2 mm.
FLOAT64_POSITIONS_FROM = 2.0**14


def _vertex_dtype(position: str) -> np.dtype:
    """The vertex layout with positions of numpy type ``position`` (``<f4`` or ``<f8``)."""
    return np.dtype([("x", position), ("y", position), ("z", position),
                     ("nx", "<f4"), ("ny", "<f4"), ("nz", "<f4"),
                     ("red", "u1"), ("green", "u1"), ("blue", "u1")])


class PointCloud(NamedTuple):
    """A coloured point cloud.

    Attributes:
        xyz: (N, 3) float32 positions, world frame, metres.
        rgb: (N, 3) uint8 sRGB colours.
        normals: (N, 3) float32 normals, or None when the file has none.
    """

    xyz: np.ndarray
    rgb: np.ndarray
    normals: np.ndarray | None


def write_point_cloud(
    path: str | os.PathLike, xyz: np.ndarray, rgb: np.ndarray, normals: np.ndarray | None = None
) -> None:
    """Write a binary little-endian PLY atomically.

    Args:
        path: output file.
        xyz: (N, 3) finite positions (stored as float32; as float64 from :data:`FLOAT64_POSITIONS_FROM`).
        rgb: (N, 3) uint8 colours.
        normals: (N, 3) finite normals, or None (zeros are stored, as 3DGS expects the properties to exist).
    """
    from plyfile import PlyData, PlyElement

    xyz = np.asarray(xyz)
    rgb = np.asarray(rgb)
    if xyz.ndim != 2 or xyz.shape[1] != 3:
        raise ValueError(f"{path}: xyz must be (N, 3), got shape {xyz.shape}")
    n = xyz.shape[0]
    if rgb.shape != (n, 3):
        raise ValueError(f"{path}: rgb must be ({n}, 3) like xyz, got shape {rgb.shape}")
    if rgb.dtype != np.uint8:
        raise ValueError(f"{path}: rgb must be uint8, got {rgb.dtype}")
    if not np.isfinite(xyz).all():
        raise ValueError(f"{path}: xyz contains NaN or inf")
    if normals is not None:
        normals = np.asarray(normals)
        if normals.shape != (n, 3):
            raise ValueError(f"{path}: normals must be ({n}, 3) like xyz, got shape {normals.shape}")
        if not np.isfinite(normals).all():
            raise ValueError(f"{path}: normals contain NaN or inf")
    far = n > 0 and float(np.abs(xyz).max()) >= FLOAT64_POSITIONS_FROM
    vertices = np.zeros(n, dtype=_vertex_dtype("<f8" if far else "<f4"))
    for k, axis in enumerate("xyz"):
        vertices[axis] = xyz[:, k]
        if normals is not None:
            vertices["n" + axis] = normals[:, k]
    for k, colour in enumerate(("red", "green", "blue")):
        vertices[colour] = rgb[:, k]
    ply = PlyData([PlyElement.describe(vertices, "vertex")], text=False, byte_order="<")
    with atomic_path(path, suffix=".ply") as tmp:
        ply.write(str(tmp))


def read_point_cloud(path: str | os.PathLike, origin: np.ndarray | None = None) -> PointCloud:
    """Read a PLY point cloud (binary or ASCII) with ``x y z``, ``red green blue`` and optionally ``nx ny nz``.

    Positions and normals are returned as float32, colours as uint8 (16-bit or float colours are rejected); positions
    relative to ``origin`` ((3,) float64, subtracted before they become float32) when given.
    """
    from plyfile import PlyData

    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"{path}: PLY file not found")
    try:
        ply = PlyData.read(str(path))
    except Exception as exc:  # plyfile raises several exception types for malformed headers/bodies
        raise ValueError(f"{path}: cannot parse PLY file ({exc})") from exc
    if "vertex" not in ply:
        raise ValueError(f"{path}: PLY file has no 'vertex' element")
    vertex = ply["vertex"].data
    names = set(vertex.dtype.names or ())
    missing = [p for p in ("x", "y", "z", "red", "green", "blue") if p not in names]
    if missing:
        raise ValueError(f"{path}: PLY vertex element lacks properties {missing}")
    for colour in ("red", "green", "blue"):
        if vertex[colour].dtype != np.uint8:
            raise ValueError(f"{path}: PLY property {colour!r} must be uchar, got {vertex[colour].dtype}")
    xyz = np.stack([vertex[a] for a in "xyz"], axis=1).astype(np.float64)
    xyz = (xyz if origin is None else xyz - np.asarray(origin, dtype=np.float64)).astype(np.float32)
    rgb = np.stack([vertex[c] for c in ("red", "green", "blue")], axis=1).astype(np.uint8)
    normals = None
    if {"nx", "ny", "nz"} <= names:
        normals = np.stack([vertex[a] for a in ("nx", "ny", "nz")], axis=1).astype(np.float32)
    return PointCloud(xyz=xyz, rgb=rgb, normals=normals)
