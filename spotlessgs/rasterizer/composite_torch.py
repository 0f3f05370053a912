"""Tile compositing in pure PyTorch (the fallback when the C++ kernel is unavailable); autograd gives the gradients.

Same maths as ``csrc/composite.cpp``: for pixel centre p = (x + 0.5, y + 0.5) and the Gaussians of its tile in
front-to-back order,

    sigma_i = ½(a dx² + c dy²) + b dx dy,  d = mean_i - p
    alpha_i = min(0.99, o_i exp(-sigma_i)), set to 0 where alpha_i < 1/255
    T_i = Π_{j<i} (1 - alpha_j); Gaussian i is dropped (with all later ones) once T_i (1 - alpha_i) <= 1e-4
    colour = Σ_i f_i alpha_i T_i,  alpha_out = 1 - Π_i (1 - alpha_i)

Each tile is evaluated densely against its padded Gaussian list (tiles are grouped by list length to keep padding
small) with the transmittance as an exclusive cumulative sum of log(1 - alpha). Large images are checkpointed
chunk by chunk (recomputed in backward) so the memory stays bounded.
"""

from __future__ import annotations

import math

import torch
from torch import Tensor
from torch.utils.checkpoint import checkpoint

from .binning import TileBins
from .projection import ALPHA_MIN

ALPHA_MAX = 0.99  # alpha clamp, as in 3DGS
TRANSMITTANCE_MIN = 1e-4  # early termination threshold
_CHUNK_ELEMENTS = 1 << 19  # tiles × list length × pixels evaluated at once (2^19 measured as fast as 2^21, less memory)
# Above this many evaluated (Gaussian, pixel) pairs in one image the chunks are recomputed during backward instead of
# keeping their intermediates (about 200 bytes per pair in float32, i.e. > 3 GB here), bounding the memory at ~50 %
# more time. 320×240 with 50k Gaussians evaluates ~9M pairs (0.6 GB peak) and is not checkpointed.
_CHECKPOINT_ABOVE = 1 << 24


def composite_torch(
    means2d: Tensor,
    conics: Tensor,
    opacities: Tensor,
    features: Tensor,
    bins: TileBins,
    width: int,
    height: int,
) -> tuple[Tensor, Tensor]:
    """Alpha-composite screen-space Gaussians, differentiably.

    Args:
        means2d: (N, 2) pixel-coordinate centres.
        conics: (N, 3) inverse 2D covariances (a, b, c).
        opacities: (N,) opacities in (0, 1).
        features: (N, C) per-Gaussian features (colours, depth, ...).
        bins: tile lists from :func:`spotlessgs.rasterizer.binning.bin_gaussians`.
        width, height: image size in pixels.
    Returns:
        color (H, W, C) = Σ f_i alpha_i T_i and alpha (H, W) = 1 - T_final, without background.
    """
    dtype, device = features.dtype, features.device
    channels = features.shape[1]
    ts = bins.tile_size
    npix = ts * ts
    counts = bins.tile_counts()
    tiles = torch.nonzero(counts > 0).squeeze(1)
    tiles = tiles[torch.sort(counts[tiles], stable=True).indices]
    local = torch.arange(npix, device=device)
    local_xy = torch.stack([local % ts, local // ts], dim=-1).to(dtype) + 0.5  # (P, 2) pixel centres in a tile

    colors, alphas, done = [], [], []
    counts_list = counts[tiles].tolist()
    recompute = torch.is_grad_enabled() and sum(counts_list) * npix > _CHECKPOINT_ABOVE
    start = 0
    while start < len(counts_list):
        stop = start + 1
        while stop < len(counts_list) and (stop + 1 - start) * counts_list[stop] * npix <= _CHUNK_ELEMENTS:
            stop += 1
        chunk = tiles[start:stop]
        args = (means2d, conics, opacities, features, bins, chunk, counts_list[stop - 1], local_xy)
        if recompute:
            col, alp = checkpoint(_composite_tiles, *args, use_reentrant=False)
        else:
            col, alp = _composite_tiles(*args)
        colors.append(col)
        alphas.append(alp)
        done.append(chunk)
        start = stop

    n_tiles = bins.num_tiles
    # An empty slice keeps the outputs attached to every input, so an empty view still back-propagates zeros.
    anchor = means2d[:0].sum() + conics[:0].sum() + opacities[:0].sum() + features[:0].sum()
    color_tiles = torch.zeros(n_tiles, npix, channels, dtype=dtype, device=device) + anchor
    alpha_tiles = torch.zeros(n_tiles, npix, dtype=dtype, device=device) + anchor
    if done:
        order = torch.cat(done)
        color_tiles = color_tiles.index_copy(0, order, torch.cat(colors))
        alpha_tiles = alpha_tiles.index_copy(0, order, torch.cat(alphas))
    color = _tiles_to_image(color_tiles.reshape(bins.tiles_y, bins.tiles_x, ts, ts, channels), width, height)
    alpha = _tiles_to_image(alpha_tiles.reshape(bins.tiles_y, bins.tiles_x, ts, ts, 1), width, height)[..., 0]
    return color, alpha


def _composite_tiles(
    means2d: Tensor,
    conics: Tensor,
    opacities: Tensor,
    features: Tensor,
    bins: TileBins,
    tiles: Tensor,
    length: int,
    local_xy: Tensor,
) -> tuple[Tensor, Tensor]:
    """Composite a group of tiles padded to ``length`` Gaussians: colour (n, P, C), alpha (n, P)."""
    ts = bins.tile_size
    starts = bins.tile_offsets[tiles]
    n_in_tile = bins.tile_offsets[tiles + 1] - starts
    slot = torch.arange(length, device=tiles.device)
    valid = slot[None, :] < n_in_tile[:, None]  # (n, L)
    pair = torch.clamp(starts[:, None] + slot[None, :], max=max(bins.num_pairs - 1, 0))
    gid = bins.gauss_ids[pair].long()  # (n, L)

    origin = torch.stack([tiles % bins.tiles_x, tiles // bins.tiles_x], dim=-1).to(local_xy.dtype) * ts  # (n, 2)
    centres = origin[:, None, :] + local_xy[None]  # (n, P, 2)
    mean = means2d[gid]  # (n, L, 2)
    dx = mean[..., 0, None] - centres[:, None, :, 0]  # (n, L, P)
    dy = mean[..., 1, None] - centres[:, None, :, 1]
    con = conics[gid]  # (n, L, 3)
    sigma = 0.5 * (con[..., 0, None] * dx * dx + con[..., 2, None] * dy * dy) + con[..., 1, None] * dx * dy
    alpha = torch.clamp(opacities[gid][..., None] * torch.exp(-sigma), max=ALPHA_MAX)
    keep = (alpha >= ALPHA_MIN) & valid[..., None]
    alpha = torch.where(keep, alpha, torch.zeros_like(alpha))
    with torch.no_grad():
        # Gaussian i is kept while the transmittance after it stays above the threshold (a prefix of the list).
        after = torch.cumsum(torch.log1p(-alpha), dim=1)
        alive = after > math.log(TRANSMITTANCE_MIN)
    alpha = torch.where(alive, alpha, torch.zeros_like(alpha))
    log_one_minus = torch.log1p(-alpha)
    cum = torch.cumsum(log_one_minus, dim=1)
    weights = alpha * torch.exp(cum - log_one_minus)  # alpha_i T_i, (n, L, P)
    color = torch.einsum("nlp,nlc->npc", weights, features[gid])
    out_alpha = 1.0 - torch.exp(cum[:, -1, :])
    return color, out_alpha


def _tiles_to_image(tiles: Tensor, width: int, height: int) -> Tensor:
    """(ty, tx, ts, ts, C) tile grid → (H, W, C) image (cropped)."""
    ty, tx, ts, _, ch = tiles.shape
    return tiles.permute(0, 2, 1, 3, 4).reshape(ty * ts, tx * ts, ch)[:height, :width]


__all__ = ["ALPHA_MAX", "TRANSMITTANCE_MIN", "composite_torch"]
