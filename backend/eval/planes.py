"""Plane-map accuracy: which ground-truth planes the map recovered."""

from __future__ import annotations

import numpy as np


def recovered_planes(
    n_est_world: np.ndarray,
    d_est_world: np.ndarray,
    n_true_world: np.ndarray,
    d_true_world: np.ndarray,
    *,
    max_angle_deg: float = 10.0,
    max_offset_m: float = 0.1,
) -> np.ndarray:
    """For each true plane (T, 3), (T,) (`n·X + d = 0`, world, metres): whether some estimated
    plane (E, 3), (E,) agrees with it in normal (either sign, within `max_angle_deg`) and in
    offset (within `max_offset_m`, with the sign that goes with the normal). Returns (T,) bool."""
    n_est = np.asarray(n_est_world, dtype=float).reshape(-1, 3)
    d_est = np.asarray(d_est_world, dtype=float).reshape(-1)
    n_true = np.asarray(n_true_world, dtype=float).reshape(-1, 3)
    d_true = np.asarray(d_true_world, dtype=float).reshape(-1)
    if len(n_est) == 0:
        return np.zeros(len(n_true), bool)
    dots = n_true @ n_est.T  # (T, E)
    sign = np.where(dots < 0, -1.0, 1.0)
    angle_ok = np.abs(dots) >= np.cos(np.radians(max_angle_deg))
    offset_ok = np.abs(sign * d_est[None, :] - d_true[:, None]) <= max_offset_m
    return np.any(angle_ok & offset_ok, axis=1)
