"""Colours of the map, shared by the viewer and the PLY export (RGB, 0-255)."""

from __future__ import annotations

import numpy as np

NON_PLANAR = np.array([170, 170, 170], dtype=np.uint8)
#: Distinct colours for plane ids (cycled).
PLANE_COLORS = np.array(
    [
        [230, 25, 75], [60, 180, 75], [0, 130, 200], [245, 130, 48], [145, 30, 180],
        [70, 240, 240], [240, 50, 230], [210, 245, 60], [0, 128, 128], [170, 110, 40],
        [128, 0, 0], [0, 0, 128],
    ],
    dtype=np.uint8,
)


def plane_color(plane: np.ndarray | int) -> np.ndarray:
    """Colour(s) (..., 3) uint8 for plane ids; -1 (no plane) is neutral grey."""
    q = np.asarray(plane)
    out = PLANE_COLORS[np.where(q >= 0, q, 0) % len(PLANE_COLORS)]
    return np.where((q >= 0)[..., None], out, NON_PLANAR)
