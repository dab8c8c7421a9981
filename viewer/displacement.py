"""How far each landmark moved between two snapshots of the same keyframe (two variants, or
A and the A/B run's B): landmarks are matched by id (`points.id`, `lines.id`), displacements
are Euclidean distances in the world frame, in metres. The 3D view colours the shown map
by them (viewer/scene.py); this module holds only the arithmetic.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from backend.pipeline.snapshot import Snapshot

#: The colour scale's top: this percentile of the matched displacements (a few large ones
#: must not flatten the rest of the map into the scale's bottom colour).
SCALE_PERCENTILE = 95.0
#: The smallest top of the scale (m): identical maps get a scale, not a division by zero.
MIN_SCALE_M = 1e-4
#: Landmarks without a match in the other snapshot.
COLOR_UNMATCHED = (200, 200, 200)


@dataclasses.dataclass(frozen=True)
class Displacement:
    """Per landmark of the shown snapshot, its displacement (m) to the same landmark in the
    other snapshot (NaN: not in the other one) and where it lies there (world frame, m; NaN
    where unmatched). A line's displacement is the mean of its two endpoints'."""

    point_m: np.ndarray  # (P,) per point of the shown snapshot
    p_world_other: np.ndarray  # (P, 3)
    line_m: np.ndarray  # (L,) per line of the shown snapshot
    segment_world_other: np.ndarray  # (L, 2, 3)

    @property
    def matched_m(self) -> np.ndarray:
        """Every finite displacement (points, then lines), in metres."""
        both = np.concatenate([self.point_m, self.line_m])
        return both[np.isfinite(both)]

    @property
    def scale_m(self) -> float:
        """The colour scale's top (m): the `SCALE_PERCENTILE` of the matched displacements."""
        matched = self.matched_m
        return max(float(np.percentile(matched, SCALE_PERCENTILE)), MIN_SCALE_M) if len(matched) else MIN_SCALE_M


def match_ids(ids: np.ndarray, other_ids: np.ndarray) -> np.ndarray:
    """For each id of `ids`, the index of the same id in `other_ids` (-1: not there)."""
    ids, other_ids = np.asarray(ids), np.asarray(other_ids)
    if len(other_ids) == 0:
        return np.full(len(ids), -1, np.int64)
    order = np.argsort(other_ids, kind="stable")
    pos = np.clip(np.searchsorted(other_ids[order], ids), 0, len(other_ids) - 1)
    index = order[pos]
    return np.where(other_ids[index] == ids, index, -1).astype(np.int64)


def _moved(p_world: np.ndarray, p_world_other: np.ndarray, index: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Positions (N, ..., 3) in the other snapshot picked by `index` (-1: NaN) and the
    distance of each (N, ...) to `p_world`, in metres."""
    there = np.full(p_world.shape, np.nan)
    found = index >= 0
    there[found] = p_world_other[index[found]]
    return there, np.linalg.norm(p_world - there, axis=-1)


def displacement(shown: Snapshot, other: Snapshot) -> Displacement:
    """How far each of `shown`'s landmarks lies from the same landmark in `other` (metres,
    world frame); NaN where `other` lacks it or either position is not finite."""
    pts, other_pts = shown.points, other.points
    p_other, point_m = _moved(np.asarray(pts.p_world, float), np.asarray(other_pts.p_world, float), match_ids(pts.id, other_pts.id))
    lns, other_lns = shown.lines, other.lines
    s_other, endpoint_m = _moved(np.asarray(lns.segment_world, float), np.asarray(other_lns.segment_world, float), match_ids(lns.id, other_lns.id))
    line_m = endpoint_m.mean(axis=1) if len(endpoint_m) else np.zeros(0)
    return Displacement(point_m=point_m, p_world_other=p_other, line_m=line_m, segment_world_other=s_other)


def displacement_colors(values_m: np.ndarray, *, scale_m: float) -> np.ndarray:
    """Colours (N, 3) uint8 of displacements `values_m` (m) on viridis from 0 (dark blue)
    to `scale_m` and above (yellow); NaN (unmatched) light grey."""
    from matplotlib import colormaps

    values_m = np.asarray(values_m, float)
    t = np.clip(np.nan_to_num(values_m / max(scale_m, MIN_SCALE_M), nan=0.0), 0.0, 1.0)
    rgb = (255.0 * colormaps["viridis"](t)[..., :3]).round().astype(np.uint8)
    rgb[~np.isfinite(values_m)] = COLOR_UNMATCHED
    return rgb.reshape(-1, 3)


def summary_markdown(d: Displacement, *, shown: str, other: str) -> str:
    """The colour key and the figures: matched landmarks, median and maximum displacement
    (cm), and the scale's top."""
    matched = d.matched_m
    n_points, n_lines = int(np.isfinite(d.point_m).sum()), int(np.isfinite(d.line_m).sum())
    head = f"**Displacement {shown} → {other}**: {n_points} of {len(d.point_m)} points and {n_lines} of {len(d.line_m)} lines matched by id"
    if not len(matched):
        return head + "; no landmark in common."
    cm = 100.0 * matched
    return (
        f"{head}; median {np.median(cm):.2f} cm, max {cm.max():.2f} cm.\n\n"
        f"colour: dark blue 0 cm → green {50.0 * d.scale_m:.2f} cm → yellow ≥ {100.0 * d.scale_m:.2f} cm "
        f"(the {SCALE_PERCENTILE:.0f}th percentile); light grey: not in {other}"
    )
