"""Procedural grayscale textures (uint8) for synthetic scenes.

Every texture has corners and straight edges at centimetre scales, so that ORB finds
corners and LSD finds segments on it: tiles with grout lines, posters of rectangles, bars
and text-like blocks, wood-like panels with seams, and a noisy checker for floors.

A texture is a pure function of `(kind, seed, height_px, width_px)`; `texture_image`
caches the results. Texture size follows the surface: `texture_shape` gives about
`texel_m` (5 mm) per texel, capped at `MAX_TEXTURE_PX` per side.
"""

from __future__ import annotations

import functools
import math
from collections.abc import Callable

import cv2
import numpy as np

KINDS = ("tiles", "poster", "panels", "checker", "door", "plaster")
MAX_TEXTURE_PX = 2048
DEFAULT_TEXEL_M = 0.005


def texture_shape(width_m: float, height_m: float, *, texel_m: float = DEFAULT_TEXEL_M) -> tuple[int, int]:
    """(rows, cols) of the texture of a `width_m` × `height_m` surface (metres): about
    `texel_m` metres per texel, at least 8 and at most `MAX_TEXTURE_PX` per side."""
    cols = int(np.clip(math.ceil(width_m / texel_m), 8, MAX_TEXTURE_PX))
    rows = int(np.clip(math.ceil(height_m / texel_m), 8, MAX_TEXTURE_PX))
    return rows, cols


def _finish(img: np.ndarray, rng: np.random.Generator, *, grain: float = 6.0) -> np.ndarray:
    """Adds fine grain and converts float (0..255) to uint8."""
    img = img + rng.normal(0.0, grain, img.shape).astype(np.float32)
    return np.clip(img, 0, 255).astype(np.uint8)


def tiles(rng: np.random.Generator, shape: tuple[int, int], *, tile_px: int = 60, grout_px: int = 3) -> np.ndarray:
    """A grid of square tiles, each with its own shade (and some with a diagonal split),
    separated by dark grout lines."""
    rows, cols = shape
    nty, ntx = rows // tile_px + 1, cols // tile_px + 1
    shade = rng.uniform(90, 230, (nty, ntx)).astype(np.float32)
    img = np.repeat(np.repeat(shade, tile_px, axis=0), tile_px, axis=1)[:rows, :cols].copy()
    yy, xx = np.mgrid[0:rows, 0:cols]
    # a diagonal split in a third of the tiles: more corners and slanted edges
    split = rng.random((nty, ntx)) < 0.33
    ty, tx = yy // tile_px, xx // tile_px
    diag = ((xx % tile_px) > (yy % tile_px)) & split[ty, tx]
    img[diag] = np.clip(img[diag] * 0.6 + 30, 0, 255)
    grout = ((yy % tile_px) < grout_px) | ((xx % tile_px) < grout_px)
    img[grout] = 45.0
    return _finish(img, rng)


def poster(rng: np.random.Generator, shape: tuple[int, int]) -> np.ndarray:
    """A light page with a dark frame, filled rectangles, bars and rows of text-like blocks."""
    rows, cols = shape
    img = np.full(shape, rng.uniform(200, 240), np.float32)
    m = max(2, min(rows, cols) // 30)
    cv2.rectangle(img, (0, 0), (cols - 1, rows - 1), 30.0, thickness=m)
    # big filled rectangles
    for _ in range(int(rng.integers(3, 7))):
        x0, y0 = int(rng.integers(0, cols * 3 // 4)), int(rng.integers(0, rows * 3 // 4))
        w, h = int(rng.integers(cols // 10, cols // 3 + 2)), int(rng.integers(rows // 10, rows // 3 + 2))
        cv2.rectangle(img, (x0, y0), (x0 + w, y0 + h), float(rng.uniform(10, 160)), thickness=-1)
    # bars
    for _ in range(int(rng.integers(2, 5))):
        y0 = int(rng.integers(0, rows))
        cv2.rectangle(img, (m, y0), (cols - m, y0 + max(2, rows // 60)), float(rng.uniform(0, 90)), thickness=-1)
    # text-like blocks: rows of small dark rectangles of random width
    char_h = max(4, rows // 40)
    y = int(rows * rng.uniform(0.55, 0.7))
    while y + char_h < rows - 2 * m:
        x = 2 * m
        while x < cols - 2 * m:
            w = int(rng.integers(char_h // 2, 2 * char_h + 1))
            if rng.random() < 0.8:
                cv2.rectangle(img, (x, y), (min(x + w, cols - 2 * m), y + char_h), 25.0, thickness=-1)
            x += w + max(2, char_h // 3) + (char_h if rng.random() < 0.15 else 0)
        y += 2 * char_h
    return _finish(img, rng, grain=4.0)


def panels(rng: np.random.Generator, shape: tuple[int, int], *, panel_px: int = 80, seam_px: int = 3) -> np.ndarray:
    """Wood-like vertical panels: wavy grain stripes along the rows, a shade per panel,
    dark seams between panels and an occasional horizontal joint."""
    rows, cols = shape
    yy, xx = np.mgrid[0:rows, 0:cols].astype(np.float32)
    n_panels = cols // panel_px + 1
    shade = rng.uniform(110, 200, n_panels).astype(np.float32)
    phase = rng.uniform(0, 2 * np.pi, n_panels).astype(np.float32)
    k = (xx // panel_px).astype(np.int64)
    wave = 6.0 * np.sin(yy / 37.0 + phase[k])
    grain = 18.0 * np.sign(np.sin((xx + wave) / 3.1 + phase[k] * 3))
    img = shade[k] + grain
    seam = (xx % panel_px) < seam_px
    img[seam] = 35.0
    # horizontal joints at a random height per panel
    joint = rng.integers(rows // 4, rows, n_panels)
    hj = (np.abs(yy - joint[k]) < seam_px) & ~seam
    img[hj] = 50.0
    return _finish(img, rng, grain=5.0)


def checker(rng: np.random.Generator, shape: tuple[int, int], *, cell_px: int = 50) -> np.ndarray:
    """A checker of two random shades with per-cell brightness jitter and blotchy noise."""
    rows, cols = shape
    yy, xx = np.mgrid[0:rows, 0:cols]
    parity = ((yy // cell_px) + (xx // cell_px)) % 2
    a, b = rng.uniform(60, 110), rng.uniform(160, 220)
    jitter = rng.uniform(-25, 25, (rows // cell_px + 1, cols // cell_px + 1)).astype(np.float32)
    img = np.where(parity == 0, a, b).astype(np.float32) + jitter[yy // cell_px, xx // cell_px]
    blotch = rng.normal(0.0, 1.0, (rows // 16 + 2, cols // 16 + 2)).astype(np.float32)
    blotch = cv2.resize(blotch, (cols, rows), interpolation=cv2.INTER_CUBIC)  # type: ignore[assignment]  # float32 in, float32 out (OpenCV's stubs say any)
    img += 12.0 * blotch
    return _finish(img, rng)


def door(rng: np.random.Generator, shape: tuple[int, int]) -> np.ndarray:
    """A door: a frame, two to four recessed rectangular panels and a handle."""
    rows, cols = shape
    base = rng.uniform(90, 170)
    img = np.full(shape, base, np.float32)
    f = max(3, cols // 12)
    cv2.rectangle(img, (0, 0), (cols - 1, rows - 1), 30.0, thickness=f)
    n = int(rng.integers(2, 5))
    h = (rows - 2 * f) // n
    for i in range(n):
        y0 = f + i * h + f
        cv2.rectangle(img, (2 * f, y0), (cols - 2 * f, y0 + h - 2 * f), base - 45, thickness=-1)
        cv2.rectangle(img, (2 * f + 3, y0 + 3), (cols - 2 * f - 3, y0 + h - 2 * f - 3), base + 25, thickness=-1)
    hx, hy = int(cols * 0.85), rows // 2
    cv2.rectangle(img, (hx - f // 2, hy - 2 * f), (hx + f // 2, hy + 2 * f), 20.0, thickness=-1)
    return _finish(img, rng, grain=4.0)


def plaster(rng: np.random.Generator, shape: tuple[int, int], *, block_px: tuple[int, int] = (40, 80), mortar_px: int = 2) -> np.ndarray:
    """A painted block wall: courses of blocks (running bond) in light, slightly varied
    shades with thin mortar lines, low-frequency blotches, a few switch-like boxes, and a
    dark skirting board along rows 0.. (row 0 is the surface's v = 0 edge, a wall's bottom)."""
    rows, cols = shape
    bh, bw = block_px
    yy, xx = np.mgrid[0:rows, 0:cols]
    course = yy // bh
    xs = xx + (course % 2) * (bw // 2)  # running bond
    n_c, n_b = rows // bh + 1, cols // bw + 2
    shade = rng.uniform(165, 215, (n_c, n_b)).astype(np.float32)
    img = shade[course, xs // bw]
    mortar = ((yy % bh) < mortar_px) | ((xs % bw) < mortar_px)
    img[mortar] = 125.0
    blotch = rng.normal(0.0, 1.0, (rows // 40 + 2, cols // 40 + 2)).astype(np.float32)
    img += 8.0 * cv2.resize(blotch, (cols, rows), interpolation=cv2.INTER_CUBIC)
    skirting = max(4, rows // 25)
    img[:skirting] = 60.0
    img[skirting : skirting + 2] = 120.0
    for _ in range(int(rng.integers(2, 6))):
        x0, y0 = int(rng.integers(0, max(1, cols - 30))), int(rng.integers(skirting, max(skirting + 1, rows - 30)))
        s = int(rng.integers(12, 30))
        cv2.rectangle(img, (x0, y0), (x0 + s, y0 + s), 235.0, thickness=-1)
        cv2.rectangle(img, (x0, y0), (x0 + s, y0 + s), 80.0, thickness=2)
    return _finish(img, rng, grain=5.0)


_GENERATORS: dict[str, Callable[[np.random.Generator, tuple[int, int]], np.ndarray]] = {
    "tiles": tiles,
    "poster": poster,
    "panels": panels,
    "checker": checker,
    "door": door,
    "plaster": plaster,
}


@functools.lru_cache(maxsize=256)
def texture_image(kind: str, seed: int, rows: int, cols: int) -> np.ndarray:
    """The texture `kind` of size (rows, cols), uint8, deterministic per `seed`. Cached:
    the returned array is read-only."""
    if kind not in _GENERATORS:
        raise ValueError(f"unknown texture kind {kind!r} (known: {', '.join(KINDS)})")
    rng = np.random.default_rng([seed, KINDS.index(kind), rows, cols])
    img = _GENERATORS[kind](rng, (rows, cols))
    img.setflags(write=False)
    return img


@functools.lru_cache(maxsize=256)
def texture_pyramid(kind: str, seed: int, rows: int, cols: int) -> tuple[np.ndarray, ...]:
    """The texture and its successive `cv2.pyrDown` halvings down to about 8 px (level i
    has texels 2**i times larger); used to limit aliasing of distant surfaces."""
    levels = [texture_image(kind, seed, rows, cols)]
    while min(levels[-1].shape) >= 16:
        levels.append(cv2.pyrDown(levels[-1]))
    for level in levels:
        level.setflags(write=False)
    return tuple(levels)
