"""Procedural grayscale textures (uint8) for synthetic scenes.

Every texture has corners and straight edges at centimetre scales, so that ORB finds
corners and LSD finds segments on it: tiles with grout lines, posters of rectangles, bars
and text-like blocks, wood-like panels with seams, and a noisy checker for floors. The
`street` scene adds building fronts with rows of windows (`facade`), a road cross-section
with sidewalks and lane markings (`road`) and plain patched asphalt (`asphalt`), all meant
for texels of a few centimetres; `low-texture` adds `faint`: a near-uniform paint with a
few low-contrast marks, just above the ORB detector's threshold.

A texture is a pure function of `(kind, seed, height_px, width_px)`; `texture_image`
caches the results. Texture size follows the surface: `texture_shape` gives about
`texel_m` (5 mm) per texel, capped at `MAX_TEXTURE_PX` per side.

Kinds made elsewhere can join for one process with `register_texture` (the segmenter's
training data adds photographs this way, `training/real_textures.py`); `known_kinds()`
lists them with the built-in `KINDS`.
"""

from __future__ import annotations

import functools
import math
import zlib
from collections.abc import Callable

import cv2
import numpy as np

KINDS = ("tiles", "poster", "panels", "checker", "door", "plaster", "facade", "road", "asphalt", "faint")
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


def facade(rng: np.random.Generator, shape: tuple[int, int], *, storey_px: int = 100) -> np.ndarray:
    """A building front (row 0 at the street; about 3 cm texels): a wall shade with faint
    courses, a ground floor of shop windows and a door, storeys of framed windows with
    mullions and sills in regular bays, and a cornice band at the top."""
    rows, cols = shape
    wall = rng.uniform(120, 215)
    img = np.full(shape, wall, np.float32)
    img[(np.arange(rows) % 12) == 0, :] = wall - 12.0  # courses
    blotch = rng.normal(0.0, 1.0, (rows // 40 + 2, cols // 40 + 2)).astype(np.float32)
    img += 6.0 * cv2.resize(blotch, (cols, rows), interpolation=cv2.INTER_CUBIC)
    ground = min(rows, int(storey_px * 1.3))
    # ground floor: shop windows and a door
    x = int(rng.integers(4, 20))
    while x < cols - 30:
        w = int(rng.integers(40, 110))
        if rng.random() < 0.25:  # a door
            w = 34
            cv2.rectangle(img, (x, 0), (x + w, int(ground * 0.75)), float(rng.uniform(40, 90)), thickness=-1)
            cv2.rectangle(img, (x, 0), (x + w, int(ground * 0.75)), 25.0, thickness=3)
        else:
            glass = float(rng.uniform(35, 110))
            cv2.rectangle(img, (x, int(ground * 0.12)), (min(x + w, cols - 2), int(ground * 0.8)), glass, thickness=-1)
            cv2.rectangle(img, (x, int(ground * 0.12)), (min(x + w, cols - 2), int(ground * 0.8)), 235.0, thickness=3)
            for k in range(1, int(rng.integers(1, 4))):
                xm = x + k * w // 3
                cv2.line(img, (xm, int(ground * 0.12)), (xm, int(ground * 0.8)), 235.0, 2)
        x += w + int(rng.integers(10, 30))
    img[ground - 4 : ground, :] = wall - 50.0  # the ground floor's ledge
    # storeys of windows
    bay = int(rng.integers(60, 90))
    win_w, win_h = int(bay * rng.uniform(0.45, 0.6)), int(storey_px * rng.uniform(0.45, 0.6))
    frame = float(rng.choice([235.0, 60.0]))
    offset = int(rng.integers(0, bay))
    y = ground + int(storey_px * 0.25)
    while y + win_h < rows - 20:
        for x0 in range(offset % bay, cols - win_w, bay):
            glass = float(rng.uniform(25, 90) if rng.random() < 0.8 else rng.uniform(150, 210))  # some reflect the sky
            cv2.rectangle(img, (x0, y), (x0 + win_w, y + win_h), glass, thickness=-1)
            cv2.rectangle(img, (x0, y), (x0 + win_w, y + win_h), frame, thickness=3)
            cv2.line(img, (x0 + win_w // 2, y), (x0 + win_w // 2, y + win_h), frame, 2)
            cv2.line(img, (x0, y + win_h * 2 // 3), (x0 + win_w, y + win_h * 2 // 3), frame, 2)
            cv2.rectangle(img, (x0 - 3, y - 6), (x0 + win_w + 3, y - 2), wall - 45.0, thickness=-1)  # the sill (below: row 0 is down)
        y += storey_px
    img[max(rows - 8, 0) :, :] = wall - 60.0  # cornice
    return _finish(img, rng, grain=4.0)


def _asphalt(rng: np.random.Generator, shape: tuple[int, int]) -> np.ndarray:
    """Float asphalt: dark grain, blotches, lighter and darker repair patches, a few cracks."""
    rows, cols = shape
    img = np.full(shape, rng.uniform(70, 95), np.float32)
    blotch = rng.normal(0.0, 1.0, (rows // 24 + 2, cols // 24 + 2)).astype(np.float32)
    img += 7.0 * cv2.resize(blotch, (cols, rows), interpolation=cv2.INTER_CUBIC)
    for _ in range(max(1, rows * cols // 60000)):
        x0, y0 = int(rng.integers(0, cols)), int(rng.integers(0, rows))
        w, h = int(rng.integers(10, 80)), int(rng.integers(10, 60))
        cv2.rectangle(img, (x0, y0), (x0 + w, y0 + h), float(rng.uniform(45, 125)), thickness=-1)
    for _ in range(max(1, rows * cols // 150000)):
        pts = np.cumsum(rng.integers(-12, 13, (8, 2)), axis=0) + [int(rng.integers(0, cols)), int(rng.integers(0, rows))]
        cv2.polylines(img, [pts.astype(np.int32)], False, 35.0, 1)
    return img


def asphalt(rng: np.random.Generator, shape: tuple[int, int]) -> np.ndarray:
    """Plain patched asphalt (a junction's surface) with the odd manhole cover."""
    rows, cols = shape
    img = _asphalt(rng, shape)
    for _ in range(max(1, rows * cols // 400000)):
        c = (int(rng.integers(0, cols)), int(rng.integers(0, rows)))
        cv2.circle(img, c, 14, 55.0, thickness=-1)
        cv2.circle(img, c, 14, 130.0, thickness=2)
    return _finish(img, rng, grain=7.0)


def road(rng: np.random.Generator, shape: tuple[int, int]) -> np.ndarray:
    """A street's cross-section along the rows (19 m across: a 3.5 m paved sidewalk, a curb,
    a 2.5 m parking lane with bay marks, two 3.5 m lanes split by a dashed centre line, a
    parking lane, a curb, a sidewalk), the road running along the columns (about 2.5 cm
    texels: 3 m dashes every 9 m)."""
    rows, cols = shape
    img = _asphalt(rng, shape)
    m = rows / 19.0  # texels per metre across
    walk = int(round(3.5 * m))
    slab = max(4, int(round(1.0 * m)))
    for y0, y1 in ((0, walk), (rows - walk, rows)):  # sidewalks: slabs with joints
        yy, xx = np.mgrid[y0:y1, 0:cols]
        shade = rng.uniform(140, 190, ((y1 - y0) // slab + 2, cols // slab + 2)).astype(np.float32)
        part = shade[(yy - y0) // slab, xx // slab]
        part[((yy - y0) % slab < 2) | (xx % slab < 2)] = 105.0
        img[y0:y1] = part
    curb = max(2, int(round(0.15 * m)))
    img[walk : walk + curb] = 205.0
    img[rows - walk - curb : rows - walk] = 205.0
    line = max(2, int(round(0.12 * m)))
    for y in (walk + int(round(2.5 * m)), rows - walk - int(round(2.5 * m))):  # lane edges
        img[y : y + line] = 215.0
    period, dash = max(8, int(round(9.0 * m))), max(4, int(round(3.0 * m)))
    centre = rows // 2 - line // 2
    start = int(rng.integers(0, period))
    for x0 in range(start - period, cols, period):
        img[centre : centre + line, max(x0, 0) : max(x0 + dash, 0)] = 220.0
    bay = max(8, int(round(5.5 * m)))
    for y0, y1 in ((walk + curb, walk + int(round(2.5 * m))), (rows - walk - int(round(2.5 * m)), rows - walk - curb)):
        for x0 in range(int(rng.integers(0, bay)), cols, bay):
            img[y0:y1, x0 : x0 + line] = 200.0
    return _finish(img, rng, grain=6.0)


def faint(rng: np.random.Generator, shape: tuple[int, int]) -> np.ndarray:
    """Low-texture paint: a near-uniform shade with a slow gradient and, sparsely, a few
    marks (rectangles, lines) only 14-22 grey levels off it: barely enough for ORB's FAST
    threshold of 10, and for LSD."""
    rows, cols = shape
    base = rng.uniform(120, 190)
    yy, xx = np.mgrid[0:rows, 0:cols].astype(np.float32)
    img = base + 8.0 * (xx / max(cols, 1) - 0.5) + 5.0 * (yy / max(rows, 1) - 0.5)
    for _ in range(max(1, rows * cols // 40000)):
        x0, y0 = int(rng.integers(0, cols)), int(rng.integers(0, rows))
        w, h = int(rng.integers(20, 120)), int(rng.integers(20, 120))
        delta = float(rng.choice([-1.0, 1.0]) * rng.uniform(14, 22))
        if rng.random() < 0.6:
            cv2.rectangle(img, (x0, y0), (x0 + w, y0 + h), base + delta, thickness=-1)
        else:
            cv2.line(img, (x0, y0), (x0 + w, y0 + h // 4), base + delta, 3)
    return _finish(img, rng, grain=1.5)


TextureGenerator = Callable[[np.random.Generator, tuple[int, int]], np.ndarray]
"""`(rng, (rows, cols))` -> a uint8 texture image of that shape."""

_GENERATORS: dict[str, TextureGenerator] = {
    "tiles": tiles,
    "poster": poster,
    "panels": panels,
    "checker": checker,
    "door": door,
    "plaster": plaster,
    "facade": facade,
    "road": road,
    "asphalt": asphalt,
    "faint": faint,
}


_REGISTERED: dict[str, TextureGenerator] = {}


def register_texture(kind: str, generator: TextureGenerator) -> None:
    """Adds (or replaces) the texture kind `kind`, made by `generator`, for this process
    only: scenes using it are not portable. Built-in kinds cannot be replaced."""
    if kind in _GENERATORS:
        raise ValueError(f"{kind!r} is a built-in texture kind")
    _REGISTERED[kind] = generator
    texture_image.cache_clear()
    texture_pyramid.cache_clear()


def known_kinds() -> tuple[str, ...]:
    """The built-in `KINDS`, then the kinds registered in this process."""
    return KINDS + tuple(_REGISTERED)


@functools.lru_cache(maxsize=256)
def texture_image(kind: str, seed: int, rows: int, cols: int) -> np.ndarray:
    """The texture `kind` of size (rows, cols), uint8, deterministic per `seed`. Cached:
    the returned array is read-only."""
    generator = _GENERATORS.get(kind) or _REGISTERED.get(kind)
    if generator is None:
        raise ValueError(f"unknown texture kind {kind!r} (known: {', '.join(known_kinds())})")
    kind_key = KINDS.index(kind) if kind in KINDS else zlib.crc32(kind.encode())
    rng = np.random.default_rng([seed, kind_key, rows, cols])
    img = generator(rng, (rows, cols))
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
