"""Procedural surface textures (numpy only) with plenty of non-repeating detail for SIFT.

Every generator takes its own ``numpy.random.Generator`` and an image height ``size`` and returns an sRGB image as a
``(size, size, 3)`` uint8 array; the floor/wall/ceiling kinds also take a ``width`` for long rooms and walls. Patterns
that are regular by nature (planks, tiles) always carry per-element random variation and large-scale noise on top, so
that no two patches of a texture look alike: repetitive textures make structure-from-motion match the wrong patches.
"""

from __future__ import annotations

from typing import Callable

import numpy as np
from scipy import ndimage

from spotlessgs.io.colorspace import to_uint8

RGB = tuple[int, int, int]


def _cubic_matrix(n_out: int, cells: int) -> np.ndarray:
    """(n_out, cells + 4) Catmull-Rom interpolation weights that sample a lattice of ``cells + 4`` knots at
    ``n_out`` evenly spaced points spanning ``cells`` cells (knots 1.5 .. cells + 1.5, away from the lattice ends)."""
    t = np.linspace(1.5, cells + 1.5, n_out)
    i = np.floor(t).astype(int)
    f = t - i
    w = np.stack([(-f + 2 * f**2 - f**3) / 2, (2 - 5 * f**2 + 3 * f**3) / 2, (f + 4 * f**2 - 3 * f**3) / 2,
                  (-(f**2) + f**3) / 2], axis=1)
    m = np.zeros((n_out, cells + 4))
    rows = np.arange(n_out)
    for k in range(4):
        m[rows, np.clip(i - 1 + k, 0, cells + 3)] += w[:, k]
    return m


def value_noise(rng: np.random.Generator, shape: tuple[int, int], cells: tuple[int, int]) -> np.ndarray:
    """Smooth random noise: a ``(cells_y + 4, cells_x + 4)`` random lattice interpolated by Catmull-Rom splines
    (separable, as two matrix products).

    Args:
        rng: random generator.
        shape: output ``(H, W)``.
        cells: lattice cells ``(cy, cx)`` across the image (feature size is about ``H / cy`` pixels).

    Returns:
        (H, W) float64 with zero mean and unit standard deviation (not tileable, by design).
    """
    h, w = shape
    cy, cx = max(1, int(cells[0])), max(1, int(cells[1]))
    lattice = rng.standard_normal((cy + 4, cx + 4))
    return _standardise(_cubic_matrix(h, cy) @ lattice @ _cubic_matrix(w, cx).T)


def fbm(rng: np.random.Generator, shape: tuple[int, int], cells: int, octaves: int = 5, gain: float = 0.55,
        aspect: float = 1.0) -> np.ndarray:
    """Fractal sum of :func:`value_noise` octaves (cells doubling, amplitude times ``gain`` per octave).

    Args:
        rng: random generator.
        shape: output ``(H, W)``.
        cells: lattice cells of the coarsest octave along the image height.
        octaves: number of octaves.
        gain: amplitude ratio between consecutive octaves.
        aspect: cells along x per cell along y (> 1 stretches features along y, < 1 along x).

    Returns:
        (H, W) float64, zero mean, unit standard deviation.
    """
    total = np.zeros(shape)
    amp = 1.0
    for o in range(octaves):
        c = cells * 2**o
        total += amp * value_noise(rng, shape, (c, max(1, round(c * aspect))))
        amp *= gain
    return _standardise(total)


def _standardise(a: np.ndarray) -> np.ndarray:
    std = float(a.std())
    return (a - a.mean()) / (std if std > 1e-12 else 1.0)


def _tint(color: RGB, shade: np.ndarray) -> np.ndarray:
    """(H, W) multiplicative shade (1 = unchanged) times an sRGB colour -> (H, W, 3) float in [0, 1]."""
    base = np.asarray(color, dtype=np.float64) / 255.0
    return np.clip(shade[..., None] * base[None, None, :], 0.0, 1.0)


def _jitter(rng: np.random.Generator, color: RGB, amount: float) -> np.ndarray:
    """A colour varied by a random brightness factor and small hue shift; (3,) float in [0, 1]."""
    base = np.asarray(color, dtype=np.float64) / 255.0
    return np.clip(base * (1.0 + amount * rng.uniform(-1, 1)) + 0.35 * amount * rng.uniform(-1, 1, 3) * base, 0, 1)


def plaster(rng: np.random.Generator, size: int, color: RGB, width: int | None = None) -> np.ndarray:
    """Painted plaster: mottled large-scale shading, trowel marks, fine grit and a few faint stains.

    Returns (size, width or size, 3) uint8.
    """
    shape = (size, width or size)
    aspect = shape[1] / shape[0]
    shade = 1.0 + 0.045 * fbm(rng, shape, 3, 6, 0.6, aspect) + 0.04 * fbm(rng, shape, 24, 3, 0.6, aspect)
    shade += 0.015 * rng.standard_normal(shape)
    yy, xx = np.mgrid[0 : shape[0], 0 : shape[1]]
    for _ in range(int(6 * aspect)):
        cy, cx = rng.uniform(0, shape[0]), rng.uniform(0, shape[1])
        r = rng.uniform(0.03, 0.12) * shape[0]
        blob = np.exp(-(((yy - cy) ** 2 + (xx - cx) ** 2) / (2 * r * r)))
        shade -= rng.uniform(0.03, 0.08) * blob * (1 + 0.5 * fbm(rng, shape, 12, 2))
    return to_uint8(_tint(color, shade))


def wood(rng: np.random.Generator, size: int, color: RGB, planks: int = 0, width: int | None = None) -> np.ndarray:
    """Wood with warped growth rings and knots; ``planks > 0`` splits it into that many rows of floor boards (rows of
    random width, boards of random length with staggered end joints).

    Each board has its own tone and its own grain, so the texture never repeats. Grain runs along x.
    Returns (size, width or size, 3) uint8.
    """
    w_img = width or size
    img = np.zeros((size, w_img, 3))
    rows = max(1, planks)
    widths = rng.uniform(0.7, 1.3, rows)
    edges = np.concatenate([[0], np.cumsum(widths) / widths.sum() * size]).round().astype(int)
    for r in range(rows):
        y0, y1 = edges[r], edges[r + 1]
        if planks == 0:
            cuts = [0, w_img]
        else:
            n_cuts = 2 * max(1, round(w_img / size))
            cuts = sorted({0, w_img, *rng.integers(size // 5, w_img - size // 5, n_cuts).tolist()})
        for x0, x1 in zip(cuts[:-1], cuts[1:]):
            h, w = y1 - y0, x1 - x0
            if h <= 0 or w <= 0:
                continue
            warp = 0.25 * h * fbm(rng, (h, w), 1, 3, 0.5, w / max(h, 1) / 6)
            yy = np.arange(h)[:, None] + warp + rng.uniform(0, 100)
            freq = rng.uniform(0.25, 0.45) * (64.0 / size) ** 0.5
            rings = 0.5 + 0.5 * np.sin(yy * freq * 2 * np.pi / 4 + 1.5 * fbm(rng, (h, w), 2, 3, 0.5, 0.2))
            streaks = fbm(rng, (h, w), max(2, h // 3), 2, 0.5, 0.08)
            shade = 1.0 - 0.22 * rings**3 + 0.06 * streaks + 0.012 * rng.standard_normal((h, w))
            yk, xk = np.mgrid[0:h, 0:w]
            for _ in range(rng.integers(0, 3)):
                ky, kx, kr = rng.uniform(0, h), rng.uniform(0, w), rng.uniform(0.2, 0.45) * h
                d2 = ((yk - ky) / (0.6 * kr)) ** 2 + ((xk - kx) / kr) ** 2
                shade -= 0.35 * np.exp(-d2) * (0.7 + 0.3 * np.sin(np.sqrt(d2) * 9.0))
            tone = _jitter(rng, color, 0.12)
            img[y0:y1, x0:x1] = np.clip(shade[..., None] * tone, 0, 1)
            if planks:
                img[y0:y1, x0 : min(x0 + 1, x1)] *= 0.7
        if planks:
            img[y0 : min(y0 + 1, y1)] *= 0.7
    return to_uint8(img)


def _joints(rng: np.random.Generator, length: int, count: int) -> np.ndarray:
    """``count + 1`` jittered joint positions from 0 to ``length`` (hand-laid tiles), (count + 1,) int."""
    pitch = length / count
    pos = np.round(np.arange(count + 1) * pitch + rng.uniform(-0.04 * pitch, 0.04 * pitch, count + 1))
    pos = np.clip(pos, 0, length).astype(int)
    pos[0], pos[-1] = 0, length
    return pos


def tiles(rng: np.random.Generator, size: int, color: RGB, count: int, width: int | None = None) -> np.ndarray:
    """Marble-like tiles (``count`` along the height, as many as fit square along the width; every joint line is
    jittered, as when laid by hand), each with its own tone and veins, separated by thin grout a little darker than
    the tiles. Returns (size, width or size, 3) uint8."""
    w_img = width or size
    count_x = max(1, round(count * w_img / size))
    img = np.zeros((size, w_img, 3))
    ys = _joints(rng, size, count)
    gw = max(1, size // (count * 32))
    grout = np.asarray(color, dtype=np.float64) / 255.0 * 0.72
    for i in range(count):
        xs = _joints(rng, w_img, count_x)
        for j in range(count_x):
            y0, y1, x0, x1 = ys[i], ys[i + 1], xs[j], xs[j + 1]
            h, w = y1 - y0, x1 - x0
            if h <= 0 or w <= 0:
                continue
            vein = np.abs(fbm(rng, (h, w), 2, 5, 0.6))
            shade = (1.0 - 0.35 * np.exp(-vein * 6.0) + 0.05 * fbm(rng, (h, w), 8, 3)
                     + 0.01 * rng.standard_normal((h, w)))
            img[y0:y1, x0:x1] = np.clip(shade[..., None] * _jitter(rng, color, 0.1), 0, 1)
            img[y0 : y0 + gw, x0:x1] = grout
            img[y0:y1, x0 : x0 + gw] = grout
    return to_uint8(img)


def terrazzo(rng: np.random.Generator, size: int, color: RGB, chips: int = 2500,
             width: int | None = None) -> np.ndarray:
    """Polished terrazzo/epoxy: a base with random stone chips of varied size, colour and shape (``chips`` per
    512 x 512 pixels). Returns (size, width or size, 3) uint8.
    """
    w_img = width or size
    shade = 1.0 + 0.06 * fbm(rng, (size, w_img), 3, 5, aspect=w_img / size)
    img = _tint(color, shade)
    n = int(chips * size * w_img / 512**2)
    yy, xx = np.mgrid[0:size, 0:w_img]
    palette = np.array([[0.15, 0.15, 0.16], [0.55, 0.52, 0.48], [0.85, 0.84, 0.8], [0.62, 0.35, 0.25],
                        [0.3, 0.36, 0.42]])
    for _ in range(n):
        cy, cx = rng.uniform(0, size), rng.uniform(0, w_img)
        r = size * rng.uniform(0.002, 0.008)
        a, b = r * rng.uniform(0.5, 1.5), r * rng.uniform(0.5, 1.5)
        th = rng.uniform(0, np.pi)
        y0, y1 = int(max(0, cy - 2 * r - 2)), int(min(size, cy + 2 * r + 3))
        x0, x1 = int(max(0, cx - 2 * r - 2)), int(min(w_img, cx + 2 * r + 3))
        dy, dx = yy[y0:y1, x0:x1] - cy, xx[y0:y1, x0:x1] - cx
        u = dx * np.cos(th) + dy * np.sin(th)
        v = -dx * np.sin(th) + dy * np.cos(th)
        mask = (u / a) ** 2 + (v / b) ** 2 <= 1.0
        img[y0:y1, x0:x1][mask] = np.clip(palette[rng.integers(len(palette))] * rng.uniform(0.8, 1.2), 0, 1)
    return to_uint8(img)


def carpet(rng: np.random.Generator, size: int, color: RGB, width: int | None = None) -> np.ndarray:
    """Cut-pile carpet: fibre speckle over a mottled, irregularly patterned tone.

    Returns (size, width or size, 3) uint8."""
    shape = (size, width or size)
    aspect = shape[1] / shape[0]
    bands = np.tanh(3.0 * fbm(rng, shape, 4, 4, 0.6, aspect))
    shade = 1.0 + 0.18 * bands + 0.1 * fbm(rng, shape, 40, 2, 0.5, aspect) + 0.05 * rng.standard_normal(shape)
    shade = ndimage.gaussian_filter(shade, 0.6)
    return to_uint8(_tint(color, shade))


def fabric(rng: np.random.Generator, size: int, color: RGB, accent: RGB | None = None) -> np.ndarray:
    """Upholstery: fine irregular slub (yarn) noise, wavy stripes of irregular width in an accent colour, and large
    soft folds. No periodic weave: a regular pattern finer than a pixel would alias into moire.

    Returns (size, size, 3) uint8.
    """
    shape = (size, size)
    yy, xx = np.mgrid[0:size, 0:size].astype(np.float64)
    slub = fbm(rng, shape, max(4, size // 6), 2, 0.5, 0.25)
    shade = 1.0 + 0.07 * slub + 0.14 * fbm(rng, shape, 3, 5, 0.6) + 0.015 * rng.standard_normal(shape)
    img = _tint(color, shade)
    if accent is not None:
        warp = 0.04 * size * fbm(rng, shape, 2, 2)
        cols = xx + warp
        accent_img = _tint(accent, shade)
        x = float(rng.uniform(0, 0.1) * size)
        while x < size:
            w = rng.uniform(0.01, 0.06) * size
            x0 = x + rng.uniform(0.03, 0.2) * size
            stripe = (cols >= x0) & (cols < x0 + w)
            img[stripe] = accent_img[stripe]
            x = x0 + w
    return to_uint8(img)


def brushed_metal(rng: np.random.Generator, size: int, color: RGB) -> np.ndarray:
    """Brushed steel: streaks along x, random scratches in all directions and a few dull smudges.

    Returns (size, size, 3) uint8.
    """
    shape = (size, size)
    streak = ndimage.gaussian_filter1d(rng.standard_normal(shape), sigma=size / 12, axis=1)
    streak = _standardise(streak)
    shade = 1.0 + 0.06 * streak + 0.08 * fbm(rng, shape, 3, 4) + 0.008 * rng.standard_normal(shape)
    img = _tint(color, shade)
    for _ in range(int(60 * size / 256)):
        y0, x0 = rng.uniform(0, size, 2)
        ang, length = rng.uniform(0, np.pi), rng.uniform(0.03, 0.3) * size
        t = np.linspace(0, 1, int(length) + 2)
        ys = np.clip((y0 + t * length * np.sin(ang)).astype(int), 0, size - 1)
        xs = np.clip((x0 + t * length * np.cos(ang)).astype(int), 0, size - 1)
        img[ys, xs] = np.clip(img[ys, xs] * rng.choice([0.7, 1.25]), 0, 1)
    return to_uint8(img)


def painting(rng: np.random.Generator, size: int) -> np.ndarray:
    """An abstract high-contrast painting/poster: coloured blocks, discs and brush strokes over a textured ground.

    Returns (size, size, 3) uint8.
    """
    shape = (size, size)
    hue = rng.uniform(0, 1)
    palette = np.array([_hsv(hue + rng.uniform(-0.5, 0.5), rng.uniform(0.3, 1.0), rng.uniform(0.15, 1.0))
                        for _ in range(6)])
    img = np.broadcast_to(palette[0], shape + (3,)).copy()
    img *= (1.0 + 0.15 * fbm(rng, shape, 3, 4))[..., None]
    yy, xx = np.mgrid[0:size, 0:size].astype(np.float64)
    for _ in range(rng.integers(6, 12)):
        y0, x0 = rng.uniform(-0.1, 0.9, 2) * size
        h, w = rng.uniform(0.08, 0.45, 2) * size
        img[(yy >= y0) & (yy < y0 + h) & (xx >= x0) & (xx < x0 + w)] = palette[rng.integers(len(palette))]
    for _ in range(rng.integers(5, 10)):
        cy, cx, r = rng.uniform(0, size), rng.uniform(0, size), rng.uniform(0.03, 0.18) * size
        img[(yy - cy) ** 2 + (xx - cx) ** 2 < r * r] = palette[rng.integers(len(palette))]
    for _ in range(rng.integers(10, 25)):
        _stroke(rng, img, yy, xx, palette[rng.integers(len(palette))])
    img *= (1.0 + 0.12 * fbm(rng, shape, 32, 2))[..., None]
    border = max(2, size // 40)
    img[:border], img[-border:], img[:, :border], img[:, -border:] = 0.08, 0.08, 0.08, 0.08
    return to_uint8(np.clip(img, 0, 1))


def _stroke(rng: np.random.Generator, img: np.ndarray, yy: np.ndarray, xx: np.ndarray, color: np.ndarray) -> None:
    """Paint one curved brush stroke (a thick quadratic Bezier) in place."""
    size = img.shape[0]
    p = rng.uniform(0, size, (3, 2))
    width = rng.uniform(0.004, 0.02) * size
    steps = int(np.linalg.norm(p[1] - p[0]) + np.linalg.norm(p[2] - p[1])) // max(1, int(width)) + 2
    for t in np.linspace(0, 1, steps):
        c = (1 - t) ** 2 * p[0] + 2 * (1 - t) * t * p[1] + t**2 * p[2]
        y0, y1 = int(max(0, c[0] - width - 1)), int(min(size, c[0] + width + 2))
        x0, x1 = int(max(0, c[1] - width - 1)), int(min(size, c[1] + width + 2))
        sub = (yy[y0:y1, x0:x1] - c[0]) ** 2 + (xx[y0:y1, x0:x1] - c[1]) ** 2 < width**2
        img[y0:y1, x0:x1][sub] = color


def _hsv(h: float, s: float, v: float) -> np.ndarray:
    """HSV in [0, 1] (hue wraps) -> (3,) RGB in [0, 1]."""
    h = (h % 1.0) * 6.0
    i, f = int(h) % 6, h - int(h)
    p, q, t = v * (1 - s), v * (1 - s * f), v * (1 - s * (1 - f))
    return np.array([(v, t, p), (q, v, p), (p, v, t), (p, q, v), (t, p, v), (v, p, q)][i])


def lamp_diffuser(rng: np.random.Generator, size: int, color: RGB) -> np.ndarray:
    """A lamp shade / light panel: bright with faint fibres so that it is not flat. Returns (size, size, 3) uint8."""
    shape = (size, size)
    shade = 1.0 + 0.04 * fbm(rng, shape, 4, 4)
    return to_uint8(_tint(color, shade))


TEXTURE_KINDS: dict[str, Callable[..., np.ndarray]] = {
    "plaster": plaster,
    "wood": wood,
    "tiles": tiles,
    "terrazzo": terrazzo,
    "carpet": carpet,
    "fabric": fabric,
    "brushed_metal": brushed_metal,
    "painting": painting,
    "lamp_diffuser": lamp_diffuser,
}
"""Texture generators by name; each is called as ``fn(rng, size, **params)``."""


def make_texture(kind: str, rng: np.random.Generator, size: int, **params) -> np.ndarray:
    """Generate a texture by kind name (see :data:`TEXTURE_KINDS`); returns (size, W, 3) uint8."""
    if kind not in TEXTURE_KINDS:
        raise ValueError(f"unknown texture kind {kind!r}; known: {', '.join(sorted(TEXTURE_KINDS))}")
    if size < 16:
        raise ValueError(f"texture size must be >= 16 pixels, got {size}")
    return TEXTURE_KINDS[kind](rng, size, **params)
