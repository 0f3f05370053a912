"""Tile binning: which Gaussians touch which square tile, in front-to-back order.

Every visible Gaussian is listed once per tile that its screen bounding box overlaps (the box is clipped to the
image, so a huge Gaussian costs at most one entry per tile). Entries are grouped by tile (row-major tile order) and,
inside a tile, sorted by camera depth with ties broken by Gaussian index, so the order is deterministic.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch
from torch import Tensor

from .cpp_kernel import load_kernel
from .cpp_kernel import pointer as _p


@dataclass(frozen=True)
class TileBins:
    """Per-tile lists of Gaussians; P is the number of (Gaussian, tile) pairs."""

    tile_size: int  # tile side in pixels
    tiles_x: int  # number of tile columns, ceil(width / tile_size)
    tiles_y: int  # number of tile rows, ceil(height / tile_size)
    gauss_ids: Tensor  # (P,) int32 Gaussian index of each pair, grouped by tile, front to back inside a tile
    tile_offsets: Tensor  # (tiles_y * tiles_x + 1,) int64: pairs of tile t are gauss_ids[offsets[t]:offsets[t+1]]

    @property
    def num_tiles(self) -> int:
        return self.tiles_x * self.tiles_y

    @property
    def num_pairs(self) -> int:
        return int(self.gauss_ids.shape[0])

    def tile_counts(self) -> Tensor:
        """(tiles_y * tiles_x,) int64 number of Gaussians listed in each tile."""
        return self.tile_offsets[1:] - self.tile_offsets[:-1]


def bin_gaussians_cpp(
    means2d: Tensor, radii: Tensor, depths: Tensor, width: int, height: int, tile_size: int
) -> TileBins:
    """The same binning as :func:`bin_gaussians` (identical output) done by the C++ kernel on CPU tensors.

    Raises:
        spotlessgs.rasterizer.cpp_kernel.KernelBuildError: the kernel is not available.
    """
    kernel = load_kernel(raise_errors=True)
    suffix = {torch.float32: "f32", torch.float64: "f64"}[means2d.dtype]
    tiles_x = -(-width // tile_size)
    tiles_y = -(-height // tile_size)
    means2d = means2d.detach().contiguous()
    depths = depths.detach().to(means2d.dtype).contiguous()
    radii = radii.to(torch.int32).contiguous()
    n = means2d.shape[0]
    order = torch.empty(n, dtype=torch.int32)
    counts = torch.empty(tiles_x * tiles_y, dtype=torch.int64)
    visible = getattr(kernel.lib, f"spotless_bin_count_{suffix}")(
        _p(means2d), _p(radii), _p(depths), n, tile_size, tiles_x, tiles_y, _p(order), _p(counts)
    )
    offsets = torch.zeros(tiles_x * tiles_y + 1, dtype=torch.int64)
    torch.cumsum(counts, 0, out=offsets[1:])
    gauss_ids = torch.empty(int(offsets[-1]), dtype=torch.int32)
    getattr(kernel.lib, f"spotless_bin_fill_{suffix}")(
        _p(means2d), _p(radii), _p(order), visible, tile_size, tiles_x, tiles_y, _p(offsets), _p(gauss_ids)
    )
    return TileBins(tile_size, tiles_x, tiles_y, gauss_ids, offsets)


def bin_gaussians(
    means2d: Tensor, radii: Tensor, depths: Tensor, width: int, height: int, tile_size: int
) -> TileBins:
    """Assign Gaussians to the tiles their bounding boxes overlap.

    Args:
        means2d: (N, 2) pixel coordinates of the centres (no gradient is needed or kept).
        radii: (N, 2) int half-extents in pixels; a Gaussian with any radius 0 is skipped.
        depths: (N,) camera z used for the front-to-back order.
        width, height: image size in pixels.
        tile_size: tile side in pixels.
    Returns:
        TileBins on the device of ``means2d``.
    """
    device = means2d.device
    tiles_x = -(-width // tile_size)
    tiles_y = -(-height // tile_size)
    n_tiles = tiles_x * tiles_y
    with torch.no_grad():
        visible = (radii > 0).all(dim=-1)
        ids = torch.nonzero(visible).squeeze(1)
        if ids.numel() == 0:
            return TileBins(
                tile_size, tiles_x, tiles_y,
                torch.zeros(0, dtype=torch.int32, device=device),
                torch.zeros(n_tiles + 1, dtype=torch.int64, device=device),
            )
        # Front to back (stable: equal depths keep index order).
        order = torch.sort(depths.detach()[ids].to(torch.float64), stable=True).indices
        ids = ids[order]
        centre = means2d.detach()[ids].to(torch.float64)
        rad = radii[ids].to(torch.float64)
        lo = torch.floor((centre - rad) / tile_size)
        hi = torch.floor((centre + rad) / tile_size)
        x0 = lo[:, 0].clamp(0, tiles_x - 1).to(torch.int64)
        x1 = hi[:, 0].clamp(0, tiles_x - 1).to(torch.int64)
        y0 = lo[:, 1].clamp(0, tiles_y - 1).to(torch.int64)
        y1 = hi[:, 1].clamp(0, tiles_y - 1).to(torch.int64)
        span_x = x1 - x0 + 1
        span_y = y1 - y0 + 1
        counts = span_x * span_y
        owner = torch.repeat_interleave(torch.arange(ids.numel(), device=device), counts)
        first = torch.cumsum(counts, 0) - counts
        local = torch.arange(owner.numel(), device=device) - first[owner]
        tile_x = x0[owner] + local % span_x[owner]
        tile_y = y0[owner] + local // span_x[owner]
        tile_id = tile_y * tiles_x + tile_x
        # Stable sort by tile keeps the depth order inside each tile.
        by_tile = torch.sort(tile_id, stable=True).indices
        gauss_ids = ids[owner[by_tile]].to(torch.int32)
        per_tile = torch.bincount(tile_id, minlength=n_tiles)
        offsets = torch.zeros(n_tiles + 1, dtype=torch.int64, device=device)
        offsets[1:] = torch.cumsum(per_tile, 0)
    return TileBins(tile_size, tiles_x, tiles_y, gauss_ids.contiguous(), offsets)


__all__ = ["TileBins", "bin_gaussians", "bin_gaussians_cpp"]
