"""GUI images: the Hessian's live sparsity pattern and the -wo | -r | -w comparison (PNG
only: JPEG blurs a one-pixel pattern), and the keyframe's left image with its features
(JPEG, drawn by the backend), with their legends."""

from __future__ import annotations

import numpy as np

from backend.optim.hessian_image import render_hessian, render_side_by_side
from backend.optim.structure import HessianStructure
from backend.pipeline.overlay import decode_keyframe_image
from backend.pipeline.snapshot import KeyframeImage, Tracking

IMAGE_PX = 360


def blank(*, width: int = 8, height: int = 8) -> np.ndarray:
    """A white placeholder image."""
    return np.full((height, width, 3), 255, dtype=np.uint8)


def hessian_image(structure: HessianStructure, *, max_px: int = IMAGE_PX) -> np.ndarray:
    """RGB image (H, W, 3) uint8 of the pattern, with its legend."""
    return np.asarray(render_hessian(structure.pattern, structure.groups, max_px=max_px, title=f"{structure.variant}: H = J^T J"))


def compare_image(structures: dict[str, HessianStructure], *, max_px: int = 240) -> np.ndarray:
    """The same window's patterns side by side, labelled with variant, items and params."""
    images = [render_hessian(s.pattern, s.groups, max_px=max_px, legend=False) for s in structures.values()]
    labels = [f"{name}: {s.items} items, {s.params} params" for name, s in structures.items()]
    return np.asarray(render_side_by_side(images, labels=labels))


def legend_markdown(structure: HessianStructure) -> str:
    """A table of the groups: items and params (tangent dimensions)."""
    rows = "\n".join(f"| {g.kind} | {g.items} | {g.size} |" for g in structure.groups)
    return (
        f"**{structure.variant}**: {structure.items} items, {structure.params} params, {structure.nnz:,} nonzeros\n\n"
        f"| group | items | params |\n|---|---|---|\n{rows}"
    )


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
        f"**tracking** since the previous keyframe: {t.frames} frames · {t.lost_frames} lost · "
        f"{t.reinitializations} re-initializations  \n"
        f"tracked on the keyframe: {t.tracked_points} points · {t.tracked_lines} lines"
        + (f"  \nkeyframe by: {t.keyframe_reason}" if t.keyframe_reason else "")
    )
