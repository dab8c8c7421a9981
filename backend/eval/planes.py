"""Plane-map accuracy: which ground-truth planes the map recovered."""

from __future__ import annotations

from collections.abc import Sequence
from typing import TYPE_CHECKING, Any, Protocol, runtime_checkable

import numpy as np

if TYPE_CHECKING:
    from backend.geometry.camera import PinholeCamera

MIN_IMAGE_SHARE = 0.05  # a true plane counts as seen when it covers this share of some keyframe's left image


class MapPlane(Protocol):
    """A map plane as :func:`plane_recovery` reads it (`backend.pipeline.snapshot.PlaneLandmark`):
    `n·X + d = 0` (world, m) and its patch's world vertices `hull_world` (H, 3)."""

    n: np.ndarray
    d: float
    hull_world: np.ndarray


@runtime_checkable
class RenderedPlanes(Protocol):
    """What :func:`plane_recovery` reads of a rendered sequence (`SyntheticSequence`): its
    frames' times (ns), its left camera, its true planes (id -> (n, d), world) and each
    frame's left plane ids."""

    timestamps_ns: np.ndarray
    plane_table: dict[int, np.ndarray]

    @property
    def camera(self) -> PinholeCamera: ...

    def left_plane_ids(self, index: int) -> np.ndarray: ...


def recovered_planes(
    n_est_world: np.ndarray,
    d_est_world: np.ndarray,
    n_true_world: np.ndarray,
    d_true_world: np.ndarray,
    *,
    hulls_est_world: Sequence[np.ndarray] | None = None,
    max_angle_deg: float = 10.0,
    max_offset_m: float = 0.1,
) -> np.ndarray:
    """For each true plane (T, 3), (T,) (`n·X + d = 0`, world, metres): whether some estimated
    plane (E, 3), (E,) agrees with it in normal (either sign, within `max_angle_deg`) and in
    position (within `max_offset_m`). Returns (T,) bool.

    Position: without `hulls_est_world`, the offsets `d` are compared (the planes' distances
    at the world origin, with the sign that goes with the normal). With the estimated
    planes' patches (`hulls_est_world[e]`: (H_e, 3) world vertices of the area the map
    holds for plane e), the farthest vertex from the true plane is compared instead: the
    patch lies within `max_offset_m` of the true plane everywhere (the distance to a plane is
    largest at a vertex of a convex patch). This does not depend on where the origin is: a
    floor mapped from a strip 2.5 m from the origin with a 3° tilt is 12 cm off at the
    origin yet within 5 cm over the strip. A plane with an empty patch falls back to `d`.
    """
    n_est = np.asarray(n_est_world, dtype=float).reshape(-1, 3)
    d_est = np.asarray(d_est_world, dtype=float).reshape(-1)
    n_true = np.asarray(n_true_world, dtype=float).reshape(-1, 3)
    d_true = np.asarray(d_true_world, dtype=float).reshape(-1)
    if len(n_est) == 0:
        return np.zeros(len(n_true), bool)
    dots = n_true @ n_est.T  # (T, E)
    sign = np.where(dots < 0, -1.0, 1.0)
    angle_ok = np.abs(dots) >= np.cos(np.radians(max_angle_deg))
    offset = np.abs(sign * d_est[None, :] - d_true[:, None])  # (T, E)
    if hulls_est_world is not None:
        if len(hulls_est_world) != len(n_est):
            raise ValueError(f"{len(hulls_est_world)} patches for {len(n_est)} estimated planes")
        for e, hull in enumerate(hulls_est_world):
            hull = np.asarray(hull, dtype=float).reshape(-1, 3)
            if len(hull):
                offset[:, e] = np.max(np.abs(hull @ n_true.T + d_true[None, :]), axis=0)
    return np.any(angle_ok & (offset <= max_offset_m), axis=1)


def plane_recovery(truth: RenderedPlanes, keyframe_timestamps_ns: np.ndarray, planes: Sequence[MapPlane], *, min_share: float = MIN_IMAGE_SHARE) -> dict[str, Any]:
    """The rendered scene's true planes the final map recovered: `seen`, the true planes
    covering at least `min_share` of some keyframe's left image (the keyframes at
    `keyframe_timestamps_ns`, frames of `truth`); `recovered`, those of them matched by a
    map plane (`planes`, world frame) within 10° whose patch lies within 10 cm of the true
    plane (:func:`recovered_planes` with the hulls); `recovered_by_origin_offset`, the older
    count comparing the offsets at the world origin instead. Plane ids are the scene's."""
    frames = np.searchsorted(np.asarray(truth.timestamps_ns), np.asarray(keyframe_timestamps_ns))
    pixels = truth.camera.width * truth.camera.height
    seen: set[int] = set()
    for i in frames:
        in_view, counts = np.unique(truth.left_plane_ids(int(i)), return_counts=True)
        seen |= {int(p) for p, c in zip(in_view, counts) if p >= 0 and c >= min_share * pixels}
    ids = sorted(seen)
    n_true = np.array([truth.plane_table[i][:3] for i in ids], dtype=float).reshape(-1, 3)
    d_true = np.array([truth.plane_table[i][3] for i in ids], dtype=float)
    n_est = np.array([p.n for p in planes], dtype=float).reshape(-1, 3)
    d_est = np.array([p.d for p in planes], dtype=float)
    found = recovered_planes(n_est, d_est, n_true, d_true, hulls_est_world=[p.hull_world for p in planes])
    at_origin = recovered_planes(n_est, d_est, n_true, d_true)
    return {
        "seen": len(ids),
        "recovered": int(found.sum()),
        "recovered_by_origin_offset": int(at_origin.sum()),
        "recovered_ids": [i for i, f in zip(ids, found) if f],
        "missed_ids": [i for i, f in zip(ids, found) if not f],
    }
