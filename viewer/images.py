"""GUI images: the Hessian's live sparsity pattern and the -wo | -r | -w comparison (PNG
only: JPEG blurs a one-pixel pattern), and the keyframe's left image with its features
(JPEG, drawn by the backend), with their legends."""

from __future__ import annotations

import collections
import io
from collections.abc import Mapping
from typing import Literal

import numpy as np
import viser
from PIL import Image, ImageDraw, ImageFont
from viser._scene_api import _encode_image_binary

from backend.optim.hessian_image import render_hessian, render_side_by_side
from backend.optim.structure import HessianStructure
from backend.optim.variant import Variant
from backend.pipeline.overlay import decode_keyframe_image
from backend.pipeline.snapshot import KeyframeImage, Tracking

IMAGE_PX = 360


def blank(*, width: int = 8, height: int = 8) -> np.ndarray:
    """A white placeholder image."""
    return np.full((height, width, 3), 255, dtype=np.uint8)


def hessian_image(structure: HessianStructure, *, max_px: int = IMAGE_PX) -> np.ndarray:
    """RGB image (H, W, 3) uint8 of the pattern (its legend is :func:`legend_markdown`).
    Windows of more than `max_px` parameters keep the camera | plane block readable and
    pool the landmark blocks (see :func:`pooled_note`)."""
    return np.asarray(render_hessian(structure.pattern, structure.groups, max_px=max_px, legend=False, focus=True))


def set_encoded(handle: viser.GuiImageHandle, data: bytes, *, image_format: Literal["jpeg", "png"]) -> None:
    """Send `data`, an image already encoded as `image_format`, as the image of `handle`,
    without decoding and encoding it again (the snapshot's keyframe JPEG, a cached Hessian
    PNG). viser 1.1.1's image handle sends its `_format` and `_data` properties; its `.image`
    array is left as it was, so callers keep what they need to show the image large."""
    handle._format = image_format
    handle._data = data


class EncodedHessians:
    """PNG bytes of the Hessian images of the last `size` structures shown (keyed by the
    structure object, which a snapshot keeps): scrubbing back shows a kept keyframe
    without rendering and encoding its Hessian again."""

    def __init__(self, *, size: int = 64) -> None:
        self._size = size
        self._png: collections.OrderedDict[int, tuple[HessianStructure, bytes]] = collections.OrderedDict()

    def png(self, structure: HessianStructure) -> bytes:
        """The PNG of :func:`hessian_image` of `structure`."""
        key = id(structure)
        kept = self._png.get(key)
        if kept is not None and kept[0] is structure:
            self._png.move_to_end(key)
            return kept[1]
        _, data = _encode_image_binary(hessian_image(structure), "png")
        self._png[key] = (structure, data)  # the structure is held, so its id is not reused meanwhile
        while len(self._png) > self._size:
            self._png.popitem(last=False)
        return data


def compare_image(structures: Mapping[Variant, HessianStructure], *, max_px: int = 200) -> np.ndarray:
    """The same window's patterns side by side, labelled with variant, items and params
    (two lines in 18 px type, readable at the panel's width)."""
    images = [render_hessian(s.pattern, s.groups, max_px=max_px, legend=False, focus=True) for s in structures.values()]
    labels = [f"{name}\n{plural(s.items, 'item')}, {plural(s.params, 'param')}" for name, s in structures.items()]
    return np.asarray(render_side_by_side(images, labels=labels, font_px=18))


def compare_png(structures: Mapping[Variant, HessianStructure]) -> bytes:
    """:func:`compare_image` encoded as PNG (the bytes the page is sent; 15-20 times smaller
    than the pixels, so kept comparisons are kept encoded)."""
    return _encode_image_binary(compare_image(structures), "png")[1]


def decode_png(data: bytes) -> np.ndarray:
    """RGB image (H, W, 3) uint8 of PNG bytes."""
    with Image.open(io.BytesIO(data)) as image:
        return np.asarray(image.convert("RGB"))


def plural(count: int, word: str) -> str:
    """`1 frame`, `2 frames`."""
    return f"{count} {word}" if count == 1 else f"{count} {word}s"


def pooled_note(structure: HessianStructure, *, max_px: int = IMAGE_PX) -> str:
    """What the image leaves out when it pools a large window ('' when it does not)."""
    landmarks = sum(g.size for g in structure.groups if g.kind in ("points", "lines"))
    if structure.params <= max_px or landmarks == 0:
        return ""
    return f"{landmarks:,} landmark params pooled into the middle band (a pixel is nonzero if any entry under it is); cameras and planes keep up to one pixel per param"


def legend_markdown(structure: HessianStructure) -> str:
    """A table of the groups: items and params (tangent dimensions), and how the image
    pools a large window."""
    rows = "\n".join(f"| {GROUP_SWATCHES[g.kind]} | {g.kind} | {g.items} | {g.size} |" for g in structure.groups)
    note = pooled_note(structure)
    return (
        f"**{structure.variant}**: H = JᵀJ of the window, {plural(structure.items, 'item')}, "
        f"{plural(structure.params, 'param')}, {structure.nnz:,} nonzeros\n\n"
        f"| colour | group | items | params |\n|---|---|---|---|\n{rows}\n\n"
        "Black: zero. A block between two groups takes the later group's colour (cameras, points, lines, planes); "
        "points and lines share orange, as in the paper's figures." + (f"\n\n{note}" if note else "")
    )


#: The colour of each group in the Hessian images (backend/optim/hessian_image.py's
#: GROUP_COLORS), as a swatch a markdown table can hold.
GROUP_SWATCHES: dict[str, str] = {"cameras": "🟩 green", "points": "🟧 orange", "lines": "🟧 orange", "planes": "🟦 blue"}


KEYFRAME_LEGEND = (
    "**points**: green tracked · cyan new (stereo) · grey dot unused · red outlier of the pose refinement  \n"
    "**segments** and **tinted regions**: colour of their plane (grey segment: no plane)  \n"
    "**light grey, hatched region**: plane instance segmented but rejected by the co-planar RANSAC (or not tested)"
)


def keyframe_image(image: KeyframeImage) -> np.ndarray:
    """RGB image (H, W, 3) uint8 of a snapshot's keyframe image."""
    return decode_keyframe_image(image)


def tracking_markdown(tracking: Tracking | None) -> str:
    """The tracking figures since the previous keyframe, or an empty string."""
    if tracking is None:
        return ""
    t = tracking
    return (
        f"**tracking** since the previous keyframe: {plural(t.frames, 'frame')} · {t.lost_frames} lost · "
        f"{plural(t.reinitializations, 're-initialization')}  \n"
        f"tracked on the keyframe: {plural(t.tracked_points, 'point')} · {plural(t.tracked_lines, 'line')}" + (f"  \nkeyframe by: {t.keyframe_reason}" if t.keyframe_reason else "")
    )


# ----------------------------------------------------------------------------- large view

#: Side of the matrix in the large view, in pixels (the Hessian tab's is IMAGE_PX): a window
#: of up to LARGE_PX parameters gets LARGE_PX // params pixels per parameter.
LARGE_PX = 960
LABEL_FONT_PX = 18
BAR_PX = 8  # the group-coloured bar along the matrix's top and left edges


def zoom_choices(structure: HessianStructure) -> dict[str, tuple[str, ...]]:
    """What the large view can zoom on: the whole window, each non-empty group's diagonal
    block, and each pair of groups with their coupling blocks; label -> group kinds."""
    kinds = [g.kind for g in structure.groups if g.size > 0]
    choices: dict[str, tuple[str, ...]] = {"whole window": tuple(kinds)}
    for i, first in enumerate(kinds):
        choices[first] = (first,)
        for second in kinds[i + 1 :]:
            choices[f"{first} + {second}"] = (first, second)
    return choices


def substructure(structure: HessianStructure, kinds: tuple[str, ...]) -> HessianStructure:
    """The rows and columns of `structure`'s groups of `kinds` only (in their order),
    with the groups renumbered from parameter 0."""
    from backend.optim.hessian_image import HessianGroup

    chosen = [g for g in structure.groups if g.kind in kinds and g.size > 0]
    index = np.concatenate([np.arange(g.start, g.start + g.size) for g in chosen]) if chosen else np.zeros(0, int)
    groups, start = [], 0
    for g in chosen:
        groups.append(HessianGroup(kind=g.kind, start=start, size=g.size, items=g.items))
        start += g.size
    return HessianStructure.of(structure.variant, structure.pattern[index][:, index], tuple(groups))


def _group_spans(matrix: np.ndarray) -> list[tuple[int, int]]:
    """[first, end) pixel columns of each group in a rendered matrix (RGB, square), split at
    the grey separator columns render_hessian inserts between groups."""
    from backend.optim.hessian_image import SEPARATOR_COLOR

    separator = np.all(matrix == np.array(SEPARATOR_COLOR, dtype=np.uint8), axis=(0, 2))
    cuts = [-1, *np.flatnonzero(separator).tolist(), matrix.shape[1]]
    return [(a + 1, b) for a, b in zip(cuts[:-1], cuts[1:]) if b > a + 1]


def _rows(starts: list[int], sizes: list[int], *, gap: int) -> list[int]:
    """The row (0, 1, ...) of each label starting at `starts` and `sizes` long (pixels,
    in order) such that labels in one row do not overlap (greedy)."""
    ends: list[int] = []  # the end of the last label in each row
    rows = []
    for start, size in zip(starts, sizes):
        row = next((r for r, end in enumerate(ends) if start >= end + gap), len(ends))
        if row == len(ends):
            ends.append(0)
        ends[row] = start + size
        rows.append(row)
    return rows


def _centred(spans: list[tuple[int, int]], sizes: list[int], *, extent: int) -> list[int]:
    """Where labels `sizes` long start, centred on their `spans` and kept inside [0, extent)."""
    return [max(0, min((a + b) // 2 - size // 2, extent - size)) for (a, b), size in zip(spans, sizes)]


def _text_width(font: ImageFont.FreeTypeFont | ImageFont.ImageFont, text: str) -> int:
    return int(np.ceil(font.getbbox(text)[2]))


def large_hessian_image(structure: HessianStructure, *, kinds: tuple[str, ...] | None = None, matrix_px: int = LARGE_PX) -> np.ndarray:
    """RGB image (H, W, 3) uint8 for the large view: the pattern of the groups `kinds` (all:
    None) at about `matrix_px` pixels, each group's rows and columns marked by a bar of its
    colour and labelled with its name and parameter range (indices into the shown matrix),
    a title with the scale (pixels per parameter), and the colour key below."""
    from backend.optim.hessian_image import GROUP_COLORS, MARGIN_PX, SEPARATOR_COLOR

    shown = substructure(structure, kinds) if kinds is not None else structure
    rendered = np.asarray(render_hessian(shown.pattern, shown.groups, max_px=matrix_px, legend=False, focus=True))
    matrix = rendered[MARGIN_PX:-MARGIN_PX, MARGIN_PX:-MARGIN_PX] if shown.params else np.zeros((0, 0, 3), np.uint8)
    groups = [g for g in shown.groups if g.size > 0]
    spans = _group_spans(matrix) if shown.params else []
    if len(spans) != len(groups):  # not split as expected: one span per group, in proportion
        spans = [(round(g.start * matrix.shape[0] / shown.params), round((g.start + g.size) * matrix.shape[0] / shown.params)) for g in groups]
    font = ImageFont.load_default(size=LABEL_FONT_PX)
    line = LABEL_FONT_PX + 6
    first: dict[str, int] = {g.kind: g.start for g in structure.groups}  # ranges in the whole window's indices
    labels = [f"{g.kind} {first[g.kind]}-{first[g.kind] + g.size - 1}" for g in groups]
    widths = [_text_width(font, t) for t in labels]
    size = matrix.shape[0]
    top_lefts = _centred(spans, widths, extent=size)
    top_rows = _rows(top_lefts, widths, gap=8)
    left_tops = _centred(spans, [line] * len(spans), extent=size)
    left_rows = _rows(left_tops, [line] * len(spans), gap=2)
    left_columns = [max((w for w, r in zip(widths, left_rows) if r == c), default=0) + 10 for c in range(max(left_rows, default=-1) + 1)]
    title = _large_title(shown, structure, matrix_px=matrix.shape[0])
    key = _key_lines(shown, first=first, matrix_px=matrix.shape[0])
    pad = 12
    title_h = line * len(title) + pad
    top_h = line * (max(top_rows, default=-1) + 1) + BAR_PX + 4
    left_w = sum(left_columns) + BAR_PX + 4
    x0, y0 = pad + left_w, pad + title_h + top_h
    width = max(x0 + size + pad, pad + max((_text_width(font, t) + line for _, t in key), default=0) + pad)
    height = y0 + size + pad + line * len(key) + pad
    canvas = Image.new("RGB", (width, height), (255, 255, 255))
    canvas.paste(Image.fromarray(matrix), (x0, y0))
    draw = ImageDraw.Draw(canvas)
    for row, text in enumerate(title):
        draw.text((pad, pad + row * line), text, fill=(20, 20, 20), font=font)
    grey = tuple(SEPARATOR_COLOR)
    for g, (a, b), text, w, top_left, top_row, left_top, left_row in zip(groups, spans, labels, widths, top_lefts, top_rows, left_tops, left_rows):
        colour = GROUP_COLORS[g.kind]
        draw.rectangle([x0 + a, y0 - BAR_PX - 2, x0 + b - 1, y0 - 3], fill=colour)  # columns
        draw.rectangle([x0 - BAR_PX - 2, y0 + a, x0 - 3, y0 + b - 1], fill=colour)  # rows
        for edge in (a - 1, b):  # the boundaries, drawn out into the label bands
            if 0 <= edge < size:
                draw.line([x0 + edge, pad + title_h, x0 + edge, y0 - 1], fill=grey)
                draw.line([pad, y0 + edge, x0 - 1, y0 + edge], fill=grey)
        draw.text((x0 + top_left, y0 - BAR_PX - 4 - line * (top_row + 1)), text, fill=(20, 20, 20), font=font)
        column_right = x0 - BAR_PX - 6 - sum(left_columns[:left_row])
        draw.text((column_right - w, y0 + left_top), text, fill=(20, 20, 20), font=font)
    y = y0 + size + pad
    for swatch, text in key:
        if swatch is not None:
            draw.rectangle([pad, y + 3, pad + line - 8, y + line - 5], fill=swatch, outline=grey)
        draw.text((pad + line, y), text, fill=(20, 20, 20), font=font)
        y += line
    return np.asarray(canvas)


def _large_title(shown: HessianStructure, whole: HessianStructure, *, matrix_px: int) -> list[str]:
    """The large view's title: what is shown, and how large."""
    part = "" if shown.params == whole.params else f" (zoomed on {' + '.join(g.kind for g in shown.groups)})"
    return [
        f"{whole.variant}: H = J^T J of the window{part}",
        f"{plural(shown.items, 'item')}, {plural(shown.params, 'param')}, {shown.nnz:,} nonzeros; {_scale(shown, matrix_px=matrix_px)}",
    ]


def _scale(structure: HessianStructure, *, matrix_px: int) -> str:
    """The image's scale in pixels per parameter (or parameters per pixel when pooled)."""
    if structure.params == 0:
        return "empty"
    if structure.params <= matrix_px:
        return f"{matrix_px // structure.params} px per param"
    return f"pooled: up to {int(np.ceil(structure.params / max(matrix_px // 2, 1)))} params per px"


def _key_lines(structure: HessianStructure, *, first: Mapping[str, int], matrix_px: int) -> list[tuple[tuple[int, int, int] | None, str]]:
    """The colour key: a swatch and a line per group (items, params = tangent dimensions,
    the labelled parameter range: from `first`, the group's first index in the whole
    window), black zero, and the unit of the axes."""
    from backend.optim.hessian_image import GROUP_COLORS

    lines: list[tuple[tuple[int, int, int] | None, str]] = [
        (GROUP_COLORS[g.kind], f"{GROUP_SWATCHES[g.kind].split()[-1]}: {g.kind}, {plural(g.items, 'item')}, {plural(g.size, 'param')} (index {first[g.kind]}-{first[g.kind] + g.size - 1})")
        for g in structure.groups
        if g.size > 0
    ]
    lines.append(((0, 0, 0), "black: zero; a block between two groups takes the later group's colour"))
    lines.append((None, f"axes: parameter index in the window (tangent dimension), rows = columns; {_scale(structure, matrix_px=matrix_px)}"))
    return lines
