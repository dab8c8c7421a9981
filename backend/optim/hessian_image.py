"""Render the nonzero pattern of a Gauss-Newton Hessian `H = JᵀJ` to an image.

Mimics Fig. 1(d)(e) of Li et al., "Co-Planar Parametrization for Stereo-SLAM and VIO"
(RA-L 2020): zeros are black, nonzeros are coloured by the group of their parameter
block (cameras green, points and lines orange, planes blue), with thin grey separator
lines at group boundaries and an optional legend below the matrix.

Colour rule. Entry `(i, j)` takes the colour of the *later* of the two groups of
parameter `i` (row) and parameter `j` (column) in the fixed order
`cameras < points < lines < planes`. Diagonal blocks therefore have their own colour,
a camera-point coupling block is orange, a camera-plane or point-plane block is blue.
The rule is symmetric, so a symmetric `H` gives a symmetric picture. The rule uses the
*kind* of the group, not its position in `groups`.

Geometry (all sizes in pixels). With `n` parameters and `max_px` the target size:

* `n <= max_px`: each parameter is an `s × s` square, `s = max_px // n >= 1`
  (nearest neighbour, no blur), so the matrix is about `max_px` pixels wide.
* `n > max_px`: downsampled by max pooling. The `max_px` pixels are shared among the
  non-empty groups in proportion to their sizes (at least one pixel each), and every
  pixel covers parameters of exactly one group, so a pixel is nonzero iff any entry in
  its cell is nonzero and never mixes colours of two blocks. Vectorized: cost is
  O(nnz + max_px²), independent of n².

One-pixel grey separators are *inserted* between consecutive non-empty groups (they add
pixels, they never cover matrix entries), so the matrix is `data_px + separators`
pixels wide, where `separators = (number of non-empty groups) - 1`. The matrix sits at
`(MARGIN_PX, MARGIN_PX + title height)` on a white canvas; the legend follows below.

Entries count as nonzero when `value != 0` (so NaN and ±inf show up as nonzero, which is
what one wants when debugging a Hessian). Sparse input is summed over duplicates and
explicit zeros are eliminated before its stored structure is used.
"""

from __future__ import annotations

import dataclasses
import functools
import io
import pathlib
from collections.abc import Sequence
from typing import Literal, TypeGuard

import numpy as np
import scipy.sparse
from PIL import Image, ImageDraw, ImageFont

GroupKind = Literal["cameras", "points", "lines", "planes"]

#: Order used by the colour rule (later wins on off-diagonal blocks).
GROUP_ORDER: tuple[GroupKind, ...] = ("cameras", "points", "lines", "planes")

#: RGB colour of each group kind (points and lines share orange, as in the paper).
GROUP_COLORS: dict[str, tuple[int, int, int]] = {
    "cameras": (40, 200, 60),
    "points": (255, 145, 20),
    "lines": (255, 145, 20),
    "planes": (40, 120, 255),
}
#: Colour of a zero entry.
ZERO_COLOR: tuple[int, int, int] = (0, 0, 0)
#: Colour of the inserted group separator lines.
SEPARATOR_COLOR: tuple[int, int, int] = (128, 128, 128)
#: Canvas background (outside the matrix).
BACKGROUND_COLOR: tuple[int, int, int] = (255, 255, 255)
#: Text colour of title, legend and labels.
TEXT_COLOR: tuple[int, int, int] = (20, 20, 20)
#: Blank border around the matrix / legend, in pixels.
MARGIN_PX: int = 10
#: Horizontal gap between images in `render_side_by_side`, in pixels.
SIDE_BY_SIDE_GAP_PX: int = 16

# Codes of the intermediate uint8 image: 0 zero, 1..4 group rank, 5 separator.
_SEPARATOR_CODE = len(GROUP_ORDER) + 1
_PALETTE = np.array([ZERO_COLOR, *(GROUP_COLORS[k] for k in GROUP_ORDER), SEPARATOR_COLOR], dtype=np.uint8)
_RANK = {kind: i + 1 for i, kind in enumerate(GROUP_ORDER)}


@dataclasses.dataclass(frozen=True)
class HessianGroup:
    """A contiguous range of parameters (columns/rows of H) of one kind.

    Attributes:
        kind: what the parameters belong to ("cameras", "points", "lines", "planes").
        start: first parameter index (column) of the group in H.
        size: number of parameters (tangent dimensions) of the group; 0 is allowed.
        items: number of optimized variables in the group (e.g. 50 cameras of 6 dof
            each have `items=50, size=300`); only used by the legend.
    """

    kind: GroupKind
    start: int
    size: int
    items: int

    def __post_init__(self) -> None:
        if self.kind not in _RANK:
            raise ValueError(f"unknown group kind {self.kind!r}, expected one of {GROUP_ORDER}")
        for name in ("start", "size", "items"):
            value = getattr(self, name)
            if int(value) != value or value < 0:
                raise ValueError(f"HessianGroup.{name} must be a non-negative integer, got {value!r}")


# ----------------------------------------------------------------------------- helpers


@functools.lru_cache(maxsize=16)
def _font(size: int) -> ImageFont.FreeTypeFont | ImageFont.ImageFont:
    """PIL's default font at `size` pixels (bitmap fallback without FreeType)."""
    try:
        return ImageFont.load_default(size=size)
    except (TypeError, ImportError, OSError):  # pragma: no cover - Pillow without FreeType
        return ImageFont.load_default()


def _text_size(font: ImageFont.FreeTypeFont | ImageFont.ImageFont, text: str) -> tuple[int, int]:
    """Width and height in pixels of `text` drawn from the origin (including ascent)."""
    if not text:
        return 0, 0
    left, top, right, bottom = font.getbbox(text)
    return int(np.ceil(right)), int(np.ceil(bottom))


def _line_height(font: ImageFont.FreeTypeFont | ImageFont.ImageFont) -> int:
    return _text_size(font, "Ag|")[1]


def _plural(count: int, word: str) -> str:
    return f"{count} {word}" if count == 1 else f"{count} {word}s"


def _format_percent(p: float) -> str:
    if p == 0.0 or p >= 0.1:
        return f"{p:.1f}%"
    return f"{p:.2g}%"


def _validate_groups(groups: Sequence[HessianGroup]) -> int:
    """Check that `groups` tile [0, n) contiguously; return n."""
    position = 0
    for g in groups:
        if not isinstance(g, HessianGroup):
            raise TypeError(f"groups must contain HessianGroup, got {type(g).__name__}")
        if g.start != position:
            raise ValueError(f"groups must cover [0, n) contiguously in order: group {g.kind!r} starts at {g.start}, expected {position}")
        position += g.size
    return position


def _is_sparse(pattern: object) -> TypeGuard[scipy.sparse.spmatrix | scipy.sparse.sparray]:
    """`scipy.sparse.issparse`, narrowing for mypy (scipy ships no type information, so its own result narrows nothing)."""
    return scipy.sparse.issparse(pattern)


def _nonzero_coordinates(pattern: object, n: int) -> tuple[np.ndarray, np.ndarray]:
    """Row and column indices (intp) of the entries `!= 0` of the n×n `pattern`."""
    if _is_sparse(pattern):
        shape = pattern.shape
        if tuple(shape) != (n, n):
            raise ValueError(f"pattern has shape {tuple(shape)}, groups cover {n} parameters")
        fmt = pattern.format
        if fmt in ("csr", "csc") and pattern.has_canonical_format:
            # Fast path: no duplicates, so the structure is exact once zeros are dropped.
            indptr = pattern.indptr
            stored = int(indptr[-1]) if len(indptr) else 0
            major = np.repeat(np.arange(n, dtype=np.intp), np.diff(indptr))
            minor = pattern.indices[:stored].astype(np.intp, copy=False)
            keep = pattern.data[:stored] != 0
            if not keep.all():
                major, minor = major[keep], minor[keep]
            return (major, minor) if fmt == "csr" else (minor, major)
        coo = scipy.sparse.coo_array(pattern, copy=True)
        coo.sum_duplicates()
        coo.eliminate_zeros()
        return coo.row.astype(np.intp, copy=False), coo.col.astype(np.intp, copy=False)
    array = np.asarray(pattern)
    if array.shape != (n, n):
        raise ValueError(f"pattern has shape {array.shape}, groups cover {n} parameters")
    rows, cols = np.nonzero(array)
    return rows, cols


def _shares(sizes: np.ndarray, budget: int) -> np.ndarray:
    """`budget` pixels shared among groups of `sizes` params in proportion (rounded on
    the cumulative boundaries), at least 1 and at most `size` each."""
    if len(sizes) == 0:
        return np.zeros(0, np.intp)
    bounds = np.rint(np.concatenate([[0], np.cumsum(sizes)]) * (budget / max(int(sizes.sum()), 1))).astype(np.intp)
    return np.clip(np.diff(bounds), 1, sizes)


def _group_pixels(sizes: np.ndarray, kinds: list[str], max_px: int, *, focus: bool) -> np.ndarray:
    """Pixels per group when the n > max_px parameters are pooled: in proportion to the
    sizes, or with `focus` the cameras and planes first (up to half of `max_px`, at
    least one pixel per parameter when they fit) and the landmarks the rest."""
    if not focus:
        return _shares(sizes, max_px)
    small = np.array([k in ("cameras", "planes") for k in kinds])
    c, l = int(sizes[small].sum()), int(sizes[~small].sum())
    budget_c = min(c, max_px // 2) if l else max_px
    pixels = np.zeros(len(sizes), np.intp)
    pixels[small] = _shares(sizes[small], budget_c)
    pixels[~small] = _shares(sizes[~small], max_px - budget_c)
    return pixels


def _matrix_codes(pattern: object, groups: Sequence[HessianGroup], max_px: int, *, focus: bool = False) -> tuple[np.ndarray, int]:
    """uint8 code image of the matrix (separators included) and the number of nonzeros."""
    n = _validate_groups(groups)
    rows, cols = _nonzero_coordinates(pattern, n)
    nnz = int(rows.size)
    nonempty = [g for g in groups if g.size > 0]
    if n == 0:
        return np.zeros((0, 0), dtype=np.uint8), nnz

    sizes = np.array([g.size for g in nonempty], dtype=np.intp)
    ranks = np.array([_RANK[g.kind] for g in nonempty], dtype=np.uint8)
    param_rank = np.repeat(ranks, sizes)  # (n,) group rank of each parameter

    if n <= max_px:
        scale = max_px // n
        pixels = sizes  # compact grid: one cell per parameter, upscaled below
        param_pixel = np.arange(n, dtype=np.intp)
    else:
        scale = 1
        # Share max_px among groups by rounding cumulative boundaries, >= 1 px per group.
        pixels = _group_pixels(sizes, [g.kind for g in nonempty], max_px, focus=focus)
        offsets = np.concatenate([[0], np.cumsum(pixels)[:-1]])
        local = np.arange(n, dtype=np.intp) - np.repeat(np.concatenate([[0], np.cumsum(sizes)[:-1]]), sizes)
        # pixels <= sizes, so each parameter maps to one pixel and every pixel is hit.
        param_pixel = np.repeat(offsets, sizes) + (local * np.repeat(pixels, sizes)) // np.repeat(sizes, sizes)
    cells = int(np.sum(pixels))

    codes = np.zeros(cells * cells, dtype=np.uint8)
    if nnz:
        # Every cell lies in one (row group, col group) block, so all entries falling into
        # the same cell carry the same code: duplicate writes are harmless (max pooling).
        codes[param_pixel[rows] * cells + param_pixel[cols]] = np.maximum(param_rank[rows], param_rank[cols])
    image = codes.reshape(cells, cells)
    if scale > 1:
        image = np.repeat(np.repeat(image, scale, axis=0), scale, axis=1)
    if len(nonempty) > 1:
        separators = np.cumsum(pixels)[:-1] * scale
        image = np.insert(image, separators, _SEPARATOR_CODE, axis=0)
        image = np.insert(image, separators, _SEPARATOR_CODE, axis=1)
    return image, nnz


def _legend_lines(groups: Sequence[HessianGroup], nnz: int) -> list[tuple[tuple[int, int, int] | None, str]]:
    lines: list[tuple[tuple[int, int, int] | None, str]] = []
    for g in groups:
        if g.size > 0:
            lines.append((GROUP_COLORS[g.kind], f"{g.kind}: {_plural(g.items, 'item')}, {_plural(g.size, 'param')}"))
    n = sum(g.size for g in groups)
    items = sum(g.items for g in groups)
    percent = 100.0 * nnz / (n * n) if n else 0.0
    lines.append((None, f"total: {_plural(items, 'item')}, {_plural(n, 'param')}, nnz {nnz:,} ({_format_percent(percent)})"))
    return lines


# ----------------------------------------------------------------------------- public API


def render_hessian(
    pattern: scipy.sparse.spmatrix | scipy.sparse.sparray | np.ndarray,
    groups: Sequence[HessianGroup],
    *,
    max_px: int = 800,
    legend: bool = True,
    title: str | None = None,
    focus: bool = False,
) -> Image.Image:
    """Render the nonzero pattern of an n×n Hessian as an RGB image.

    Args:
        pattern: n×n matrix (dense array or scipy sparse); entries `!= 0` are nonzero.
            Sparse input: duplicates are summed and explicit zeros eliminated first.
        groups: parameter groups tiling [0, n) contiguously (cameras | points | lines |
            planes); groups with `size == 0` are allowed and draw nothing.
        max_px: target side of the matrix area in pixels (>= 1). Smaller matrices are
            upscaled by the integer factor `max_px // n`, larger ones max-pooled down to
            about `max_px` pixels. Separators add one pixel per group boundary.
        legend: draw a legend below the matrix (one line per non-empty group + total).
        title: optional text above the matrix.
        focus: when the matrix is pooled (n > max_px), give the cameras and planes up to
            half of the pixels (one per parameter when they fit) and pool the landmarks
            into the rest, so that the camera | plane structure stays readable beside
            thousands of landmark parameters. Off: every group in proportion to its size.

    Returns:
        RGB `PIL.Image.Image`: white canvas, matrix at `(MARGIN_PX, MARGIN_PX + title
        height)`, black zeros, group-coloured nonzeros (later group wins on off-diagonal
        blocks, see module docstring), grey separators.
    """
    if int(max_px) != max_px or max_px < 1:
        raise ValueError(f"max_px must be a positive integer, got {max_px!r}")
    codes, nnz = _matrix_codes(pattern, groups, int(max_px), focus=focus)
    matrix_px = codes.shape[0]

    reference = max(matrix_px, 300)
    font = _font(int(np.clip(round(reference / 50), 12, 18)))
    line_h = _line_height(font)
    spacing = max(2, line_h // 3)

    title_w, title_h = _text_size(font, title) if title else (0, 0)
    title_block = title_h + spacing if title else 0

    lines = _legend_lines(groups, nnz) if legend else []
    swatch = line_h
    legend_w = 0
    for color, text in lines:
        indent = swatch + spacing if color is not None else 0
        legend_w = max(legend_w, indent + _text_size(font, text)[0])
    legend_block = (spacing + len(lines) * (line_h + spacing)) if lines else 0

    width = 2 * MARGIN_PX + max(matrix_px, legend_w, title_w, 1)
    height = 2 * MARGIN_PX + title_block + matrix_px + legend_block
    canvas = Image.new("RGB", (width, height), BACKGROUND_COLOR)
    draw = ImageDraw.Draw(canvas)

    if title:
        draw.text((MARGIN_PX, MARGIN_PX), title, fill=TEXT_COLOR, font=font)
    top = MARGIN_PX + title_block
    if matrix_px:
        # Palette image + C-side conversion: ~10x faster than numpy fancy indexing.
        matrix = Image.frombytes("P", (matrix_px, matrix_px), np.ascontiguousarray(codes).tobytes())
        matrix.putpalette(_PALETTE.tobytes())
        canvas.paste(matrix.convert("RGB"), (MARGIN_PX, top))

    y = top + matrix_px + spacing
    for color, text in lines:
        x = MARGIN_PX
        if color is not None:
            draw.rectangle([x, y, x + swatch - 1, y + swatch - 1], fill=color, outline=SEPARATOR_COLOR)
            x += swatch + spacing
        draw.text((x, y), text, fill=TEXT_COLOR, font=font)
        y += line_h + spacing
    return canvas


def hessian_png_bytes(
    pattern: scipy.sparse.spmatrix | scipy.sparse.sparray | np.ndarray,
    groups: Sequence[HessianGroup],
    *,
    max_px: int = 800,
    legend: bool = True,
    title: str | None = None,
) -> bytes:
    """`render_hessian(...)` encoded as PNG (lossless; never JPEG). Same arguments."""
    image = render_hessian(pattern, groups, max_px=max_px, legend=legend, title=title)
    buffer = io.BytesIO()
    image.save(buffer, format="PNG")
    return buffer.getvalue()


def write_hessian_png(
    path: pathlib.Path | str,
    pattern: scipy.sparse.spmatrix | scipy.sparse.sparray | np.ndarray,
    groups: Sequence[HessianGroup],
    *,
    max_px: int = 800,
    legend: bool = True,
    title: str | None = None,
) -> None:
    """Write `render_hessian(...)` as a PNG file at `path` (parent directory must exist;
    complete or not at all)."""
    from backend.common.atomic import write_bytes_atomic

    write_bytes_atomic(path, hessian_png_bytes(pattern, groups, max_px=max_px, legend=legend, title=title))


def render_side_by_side(images: Sequence[Image.Image], *, labels: Sequence[str], font_px: int = 16) -> Image.Image:
    """Place images left to right, top-aligned, each with its label centred above it
    (`font_px` high; a label may have several lines).

    Each column is as wide as its image (or its label, if the label is wider); columns are
    separated by `SIDE_BY_SIDE_GAP_PX` pixels, so with short labels the width is
    `sum(widths) + SIDE_BY_SIDE_GAP_PX * (len(images) - 1)`. The height is the label band
    plus the tallest image. Background white; images converted to RGB.
    """
    if len(images) == 0:
        raise ValueError("render_side_by_side needs at least one image")
    if len(labels) != len(images):
        raise ValueError(f"got {len(images)} images but {len(labels)} labels")
    font = _font(font_px)
    line_h = _line_height(font)
    label_h = max((line_h * len(label.splitlines()) for label in labels if label), default=0)
    band = label_h + MARGIN_PX // 2 if label_h else 0
    widths = [max((_text_size(font, part)[0] for part in label.splitlines()), default=0) for label in labels]
    columns = [max(im.width, w) for im, w in zip(images, widths)]
    width = sum(columns) + SIDE_BY_SIDE_GAP_PX * (len(images) - 1)
    height = band + max(im.height for im in images)
    canvas = Image.new("RGB", (width, height), BACKGROUND_COLOR)
    draw = ImageDraw.Draw(canvas)
    x = 0
    for im, label, column in zip(images, labels, columns):
        for row, part in enumerate(label.splitlines()):
            draw.text((x + (column - _text_size(font, part)[0]) // 2, row * line_h), part, fill=TEXT_COLOR, font=font)
        canvas.paste(im.convert("RGB"), (x + (column - im.width) // 2, band))
        x += column + SIDE_BY_SIDE_GAP_PX
    return canvas
