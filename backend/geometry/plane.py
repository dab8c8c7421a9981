"""Infinite planes `π = (n, d)` with `|n| = 1`: points satisfy `n·X + d = 0` (d in metres).

In optimization a plane has 3 degrees of freedom: the normal moves on S² in its tangent
space, `n <- normalize(n + B(n) δn)` with `B(n)` a fixed 3×2 orthonormal tangent basis,
and `d <- d + δd`. The 3-vector is ordered `(δn, δd)`.
"""

from __future__ import annotations

import numba
import numpy as np


@numba.njit(cache=True, nogil=True)
def _tangent_basis_kernel(n, out):
    for k in range(n.shape[0]):
        n0, n1, n2 = n[k, 0], n[k, 1], n[k, 2]
        a0, a1, a2 = abs(n0), abs(n1), abs(n2)
        if a0 <= a1 and a0 <= a2:  # a × n for the least aligned axis a
            b0, b1, b2 = 0.0, -n2, n1
        elif a1 <= a2:
            b0, b1, b2 = n2, 0.0, -n0
        else:
            b0, b1, b2 = -n1, n0, 0.0
        inv = 1.0 / np.sqrt(b0 * b0 + b1 * b1 + b2 * b2)
        b0, b1, b2 = b0 * inv, b1 * inv, b2 * inv
        out[k, 0, 0], out[k, 1, 0], out[k, 2, 0] = b0, b1, b2
        out[k, 0, 1] = n1 * b2 - n2 * b1  # n × b1
        out[k, 1, 1] = n2 * b0 - n0 * b2
        out[k, 2, 1] = n0 * b1 - n1 * b0


def tangent_basis(n: np.ndarray) -> np.ndarray:
    """Orthonormal basis (..., 3, 2) of the tangent space of unit normals n (..., 3).

    Deterministic: the first axis is `normalize(a × n)` with `a` the coordinate axis least
    aligned with n (as gtsam's Unit3 does), the second `n × b1`.
    """
    n = np.asarray(n, dtype=float)
    flat = np.ascontiguousarray(n.reshape(-1, 3))
    out = np.empty((flat.shape[0], 3, 2))
    _tangent_basis_kernel(flat, out)
    return out.reshape(n.shape[:-1] + (3, 2))


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
