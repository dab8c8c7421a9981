"""Colours of the map, shared by the viewer and the PLY export (RGB, 0-255)."""

from __future__ import annotations

import numpy as np

NON_PLANAR = np.array([170, 170, 170], dtype=np.uint8)
#: Distinct colours for plane ids (cycled).
#: Distinct colours for plane ids (cycled); no pure red or green, which mark RANSAC
#: outliers and inliers in the viewer.
PLANE_COLORS = np.array(
    [
        [0, 130, 200],
        [245, 130, 48],
        [145, 30, 180],
        [0, 150, 150],
        [170, 110, 40],
        [240, 50, 230],
        [128, 128, 0],
        [0, 0, 128],
        [70, 200, 240],
        [250, 190, 120],
    ],
    dtype=np.uint8,
)


def plane_color(plane: np.ndarray | int) -> np.ndarray:
    """Colour(s) (..., 3) uint8 for plane ids; -1 (no plane) is neutral grey."""
    q = np.asarray(plane)
    out = PLANE_COLORS[np.where(q >= 0, q, 0) % len(PLANE_COLORS)]
    return np.where((q >= 0)[..., None], out, NON_PLANAR)
