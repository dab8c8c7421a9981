"""Where the 3D view's camera goes: a view that frames the map, and marker sizes that suit
its extent. World frame, metres, z up.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from backend.pipeline.snapshot import Snapshot

#: Direction from the framed centre to the camera (seen from the front left, above).
VIEW_DIRECTION = np.array([-0.45, -0.75, 0.60]) / np.linalg.norm([-0.45, -0.75, 0.60])
#: The framed sphere fills this fraction of the smaller field of view.
FILL = 0.8


@dataclasses.dataclass(frozen=True)
class Bounds:
    """A robust box around what a snapshot draws: `centre` (3,) and `radius` (m) of its
    bounding sphere, around the map points (far outliers left out) and every keyframe
    position."""

    centre: np.ndarray
    radius: float


#: A map point (or line endpoint, plane hull vertex) is left out of the framing when it lies
#: farther from the points' median than this many times the 90th percentile of the points'
#: distances to it: a few badly triangulated landmarks (13 m away in a 3 m room) must not
#: shrink the map to a dot, while a whole wall seen by a quarter of the points is kept.
OUTLIER_FACTOR = 2.0


def _robust(p_world: np.ndarray, centre: np.ndarray, cut_m: float) -> np.ndarray:
    """The finite rows of `p_world` (N, 3) within `cut_m` metres of `centre`."""
    p_world = p_world[np.all(np.isfinite(p_world), axis=1)]
    return p_world[np.linalg.norm(p_world - centre, axis=1) <= cut_m]


def snapshot_bounds(snapshot: Snapshot) -> Bounds:
    """The region to frame (world frame, m): every keyframe position and what the map draws,
    its points, line segments and plane patches, leaving out those farther from the points'
    median than `OUTLIER_FACTOR` times the 90th percentile of the points' distances to it.
    (A cut at three times the median distance left out a quarter of the room's first map,
    the part of the back wall left of the first camera, so the map ran past the view's left
    edge for the first ten keyframes.)"""
    t = np.asarray(snapshot.estimate.t_world_camera, float)
    p = np.asarray(snapshot.points.p_world, float)
    p = p[np.all(np.isfinite(p), axis=1)]
    parts = [t[np.all(np.isfinite(t), axis=1)]]
    if len(p):
        centre = np.median(p, axis=0)
        cut_m = max(OUTLIER_FACTOR * float(np.quantile(np.linalg.norm(p - centre, axis=1), 0.9)), 0.1)
        hulls = [np.asarray(plane.hull_world, float).reshape(-1, 3) for plane in snapshot.planes]
        drawn = [p, np.asarray(snapshot.lines.segment_world, float).reshape(-1, 3), *hulls]
        parts += [_robust(x, centre, cut_m) for x in drawn]
    pts = np.concatenate(parts) if any(len(x) for x in parts) else np.zeros((1, 3))
    lo, hi = pts.min(axis=0), pts.max(axis=0)
    return Bounds(centre=0.5 * (lo + hi), radius=max(0.5 * float(np.linalg.norm(hi - lo)), 0.5))


def framing_pose(bounds: Bounds, *, fov_y: float, aspect: float, direction: np.ndarray = VIEW_DIRECTION) -> tuple[np.ndarray, np.ndarray]:
    """Camera `(position, look_at)` (world, m) that shows the bounding sphere of `bounds`
    whole: it fills `FILL` of the smaller of the vertical field of view `fov_y` (radians)
    and the horizontal one (from `aspect` = width / height), seen along `direction`."""
    fov_x = 2.0 * np.arctan(np.tan(0.5 * fov_y) * max(aspect, 1e-3))
    half = 0.5 * min(fov_y, fov_x) * FILL
    distance = bounds.radius / np.sin(half)
    d = np.asarray(direction, float) / np.linalg.norm(direction)
    return bounds.centre + distance * d, bounds.centre.copy()


def follow_pose(position: np.ndarray, look_at: np.ndarray, target: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The view moved so that it looks at `target` with the same offset and distance."""
    offset = np.asarray(position, float) - np.asarray(look_at, float)
    return np.asarray(target, float) + offset, np.asarray(target, float).copy()


def marker_size_m(bounds: Bounds, *, scale: float = 1.0) -> float:
    """Map point size in metres for a map of this extent: 0.4 % of the framed diameter
    (1.2 cm for a 3 m room, 8 cm for a 20 m hall), times the user's `scale`."""
    return float(np.clip(0.004 * 2.0 * bounds.radius, 0.003, 0.2) * scale)
