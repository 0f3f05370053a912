"""CLAHE: contrast-limited adaptive histogram equalisation of the CIE L* channel (Zuiderveld 1994), chroma kept.

The image is split into a grid of tiles; each tile's lightness histogram is clipped at ``clip_limit`` times its mean
bin height, the clipped excess is spread evenly over all bins, and the tile's cumulative histogram becomes its tone
curve. Each pixel's new lightness is the bilinear blend of the curves of the four nearest tile centres.

Differences from scikit-image's ``equalize_adapthist`` (deliberate): lightness is equalised on its fixed range
[0, 100] without a min-max stretch before and after (so an evenly lit image changes little, a black frame stays black
and a white one white), and each tone curve is piecewise linear inside bins (a tile with a flat histogram keeps
exactly its values). With a very large ``clip_limit`` and one tile the method is global histogram equalisation.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from spotlessgs.baselines2d._validate import check_rgb_image
from spotlessgs.baselines2d.lab import lab_to_srgb, srgb_to_lab


@dataclass(frozen=True)
class ClaheConfig:
    # Histogram clip limit as a multiple of a tile's mean bin height (>= 1; closer to 1 = closer to the identity).
    clip_limit: float = 2.5
    # Number of tiles along the image height (reduced to the image height for tiny images).
    tiles_y: int = 8
    # Number of tiles along the image width (reduced to the image width for tiny images).
    tiles_x: int = 8
    # Number of histogram bins over the lightness range [0, 100].
    nbins: int = 256

    def __post_init__(self) -> None:
        if not np.isfinite(self.clip_limit) or self.clip_limit < 1.0:
            raise ValueError(f"ClaheConfig.clip_limit must be a finite number >= 1, got {self.clip_limit}")
        for name in ("tiles_y", "tiles_x", "nbins"):
            value = getattr(self, name)
            if not isinstance(value, int) or value < 1:
                raise ValueError(f"ClaheConfig.{name} must be a positive integer, got {value!r}")
        if self.nbins < 2:
            raise ValueError(f"ClaheConfig.nbins must be at least 2, got {self.nbins}")


def tile_tone_curves(lightness: np.ndarray, config: ClaheConfig) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Clipped, redistributed histograms of each tile as tone curves.

    Args:
        lightness: (H, W) values in [0, 1].
    Returns:
        start: (Ty, Tx, nbins) curve value at the lower edge of each bin (exclusive cumulative histogram / tile size).
        slope_mass: (Ty, Tx, nbins) increase of the curve across each bin (bin height / tile size).
        edges: a pair of int arrays (Ty + 1,) and (Tx + 1,) with the tile boundaries in pixels, stacked in an object
            array of length 2.
    """
    height, width = lightness.shape
    tiles_y, tiles_x, nbins = min(config.tiles_y, height), min(config.tiles_x, width), config.nbins
    edges_y = np.round(np.linspace(0, height, tiles_y + 1)).astype(np.int64)
    edges_x = np.round(np.linspace(0, width, tiles_x + 1)).astype(np.int64)
    tile_row = np.searchsorted(edges_y, np.arange(height), side="right") - 1
    tile_col = np.searchsorted(edges_x, np.arange(width), side="right") - 1
    bins = np.minimum((lightness * nbins).astype(np.int64), nbins - 1)
    tile_id = tile_row[:, None] * tiles_x + tile_col[None, :]
    hist = np.bincount((tile_id * nbins + bins).ravel(), minlength=tiles_y * tiles_x * nbins).astype(np.float64)
    hist = hist.reshape(tiles_y, tiles_x, nbins)
    tile_pixels = hist.sum(axis=2, keepdims=True)
    limit = config.clip_limit * tile_pixels / nbins
    excess = np.maximum(hist - limit, 0.0).sum(axis=2, keepdims=True)
    clipped = np.minimum(hist, limit) + excess / nbins
    mass = clipped / tile_pixels
    start = np.cumsum(mass, axis=2) - mass
    edges = np.empty(2, dtype=object)
    edges[0], edges[1] = edges_y, edges_x
    return start, mass, edges


def _blend_weights(edges: np.ndarray, size: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """For pixel centres 0.5 .. size - 0.5: indices of the lower/upper neighbouring tile centres and the upper weight.

    Pixels outside the first/last tile centre use that tile alone (weight clamped to 0 or 1).
    """
    centres = 0.5 * (edges[:-1] + edges[1:])
    pos = np.arange(size) + 0.5
    upper = np.clip(np.searchsorted(centres, pos, side="right"), 1, max(len(centres) - 1, 1))
    lower = upper - 1
    if len(centres) == 1:
        return np.zeros(size, np.int64), np.zeros(size, np.int64), np.zeros(size)
    span = centres[upper] - centres[lower]
    weight = np.clip((pos - centres[lower]) / span, 0.0, 1.0)
    return lower, upper, weight


def clahe_lightness(lightness: np.ndarray, config: ClaheConfig = ClaheConfig()) -> np.ndarray:
    """CLAHE of one channel.

    Args:
        lightness: (H, W) values in [0, 1] (clipped).
    Returns:
        (H, W) float64 values in [0, 1].
    """
    lightness = np.clip(np.asarray(lightness, dtype=np.float64), 0.0, 1.0)
    if lightness.ndim != 2 or lightness.size == 0:
        raise ValueError(f"clahe_lightness: expected a non-empty (H, W) array, got shape {lightness.shape}")
    start, mass, edges = tile_tone_curves(lightness, config)
    nbins = config.nbins
    scaled = lightness * nbins
    bins = np.minimum(scaled.astype(np.int64), nbins - 1)
    frac = scaled - bins  # position inside the bin, in [0, 1] (1 only for the value 1.0)
    row_lo, row_hi, wy = _blend_weights(edges[0], lightness.shape[0])
    col_lo, col_hi, wx = _blend_weights(edges[1], lightness.shape[1])

    def curve(rows: np.ndarray, cols: np.ndarray) -> np.ndarray:
        r, c = rows[:, None], cols[None, :]
        return start[r, c, bins] + frac * mass[r, c, bins]

    top = (1.0 - wx)[None, :] * curve(row_lo, col_lo) + wx[None, :] * curve(row_lo, col_hi)
    bottom = (1.0 - wx)[None, :] * curve(row_hi, col_lo) + wx[None, :] * curve(row_hi, col_hi)
    out = (1.0 - wy)[:, None] * top + wy[:, None] * bottom
    return np.clip(out, 0.0, 1.0)


def clahe(img: np.ndarray, config: ClaheConfig = ClaheConfig()) -> np.ndarray:
    """CLAHE on the L* channel of an sRGB image; a* and b* (chroma) are kept.

    Args:
        img: (H, W, 3) sRGB values in [0, 1].
    Returns:
        (H, W, 3) float32 sRGB values in [0, 1] (colours that leave the gamut are clipped per channel).
    """
    rgb = check_rgb_image(img, "clahe input")
    lab = srgb_to_lab(rgb)
    lab[..., 0] = 100.0 * clahe_lightness(lab[..., 0] / 100.0, config)
    return lab_to_srgb(lab).astype(np.float32)
