"""Infinite planes `π = (n, d)` with `|n| = 1`: points satisfy `n·X + d = 0` (d in metres).

In optimization a plane has 3 degrees of freedom: the normal moves on S² in its tangent
space, `n <- normalize(n + B(n) δn)` with `B(n)` a fixed 3×2 orthonormal tangent basis,
and `d <- d + δd`. The 3-vector is ordered `(δn, δd)`.
"""

from __future__ import annotations

import numpy as np

from backend.geometry import so3


def tangent_basis(n: np.ndarray) -> np.ndarray:
    """Orthonormal basis (..., 3, 2) of the tangent space of unit normals n (..., 3).

    Deterministic: the first axis is `normalize(a × n)` with `a` the coordinate axis least
    aligned with n (as gtsam's Unit3 does), the second `n × b1`.
    """
    n = np.asarray(n, dtype=float)
    a = np.eye(3)[np.argmin(np.abs(n), axis=-1)]
    b1 = so3.cross(a, n)
    b1 /= np.linalg.norm(b1, axis=-1, keepdims=True)
    b2 = so3.cross(n, b1)
    return np.stack([b1, b2], axis=-1)


def retract(n: np.ndarray, d: np.ndarray, delta: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Apply (..., 3) increments `(δn, δd)` to planes (n (..., 3), d (...))."""
    n = np.asarray(n, dtype=float)
    delta = np.asarray(delta, dtype=float)
    B = tangent_basis(n)
    n_new = n + np.einsum("...ij,...j->...i", B, delta[..., :2])
    n_new /= np.linalg.norm(n_new, axis=-1, keepdims=True)
    return n_new, np.asarray(d, dtype=float) + delta[..., 2]


def to_camera(n_world: np.ndarray, d_world: np.ndarray, R_world_camera: np.ndarray, t_world_camera: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Express world planes in camera frames: `n_c = Rᵀ n_w`, `d_c = d_w + n_w·t`."""
    n_c = np.einsum("...ji,...j->...i", R_world_camera, n_world)
    d_c = d_world + np.sum(n_world * t_world_camera, axis=-1)
    return n_c, d_c


def signed_distance(n: np.ndarray, d: np.ndarray, p: np.ndarray) -> np.ndarray:
    """Signed distance (metres) `n·p + d` of points p (..., 3) to planes (n, d)."""
    return np.sum(np.asarray(n) * np.asarray(p), axis=-1) + d


def fit_plane(points: np.ndarray) -> tuple[np.ndarray, float]:
    """Least-squares plane through (N >= 3, 3) points: the normal is the direction of least
    variance. Raises ValueError for fewer than 3 points or (near) collinear points."""
    p = np.asarray(points, dtype=float)
    if p.ndim != 2 or p.shape[0] < 3 or p.shape[1] != 3:
        raise ValueError(f"fit_plane needs at least 3 points of shape (N, 3), got {p.shape}")
    centroid = p.mean(axis=0)
    _, s, Vt = np.linalg.svd(p - centroid, full_matrices=False)
    if s[1] <= 1e-9 * max(s[0], 1e-12):
        raise ValueError("fit_plane: points are collinear")
    n = Vt[2]
    return n, float(-n @ centroid)
