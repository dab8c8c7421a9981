"""GUI images: the Hessian's live sparsity pattern and the -wo | -r | -w comparison (PNG
only: JPEG blurs a one-pixel pattern), and the keyframe's left image with its features
(JPEG, drawn by the backend), with their legends."""

from __future__ import annotations

import collections
from collections.abc import Mapping
from typing import Literal

import numpy as np
import viser
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
