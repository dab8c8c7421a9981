"""Plane-map accuracy: which ground-truth planes the map recovered."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np


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
