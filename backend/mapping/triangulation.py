"""Linear (DLT) triangulation of points and lines from several calibrated views.

Views are given by poses `T_world_camera` (R (N, 3, 3), t (N, 3)) and normalized image
coordinates `x̂ = K⁻¹ [u v 1]ᵀ`. Results are in the world frame, metres.
"""

from __future__ import annotations

import numpy as np

from backend.geometry import so3


def triangulate_points(x_norm: list[np.ndarray], poses: list[np.ndarray], R: np.ndarray, t: np.ndarray) -> np.ndarray:
    """World point (P, 3) of each landmark i from its normalized observations `x_norm[i]`
    (n_i, 2) in poses `poses[i]` (n_i,); NaN where the solution is at infinity."""
    out = np.empty((len(x_norm), 3))
    for i, (x, k) in enumerate(zip(x_norm, poses)):
        Rt = np.swapaxes(R[k], 1, 2)
        P = np.concatenate([Rt, -np.einsum("nij,nj->ni", Rt, t[k])[:, :, None]], axis=2)  # (n, 3, 4)
        A = np.concatenate([x[:, 0:1] * P[:, 2] - P[:, 0], x[:, 1:2] * P[:, 2] - P[:, 1]], axis=0)
        _, _, Vt = np.linalg.svd(A)
        X = Vt[-1]
        out[i] = X[:3] / X[3] if abs(X[3]) > 1e-12 else np.full(3, np.nan)
    return out


def triangulate_two_views(x0: np.ndarray, x1: np.ndarray, R0: np.ndarray, t0: np.ndarray, R1: np.ndarray, t1: np.ndarray) -> np.ndarray:
    """World points (P, 3) from normalized observations x0, x1 (P, 2) in two poses
    `T_world_camera` (R (3, 3), t (3,)): the DLT of :func:`triangulate_points`, vectorized
    over the points (one batched SVD); NaN where the solution is at infinity."""
    rows = []
    for x, R, t in ((x0, R0, t0), (x1, R1, t1)):
        P = np.concatenate([R.T, (-R.T @ t)[:, None]], axis=1)  # (3, 4)
        rows += [x[:, 0:1] * P[2] - P[0], x[:, 1:2] * P[2] - P[1]]
    A = np.stack(rows, axis=1)  # (P, 4, 4)
    if len(A) == 0:
        return np.zeros((0, 3))
    _, _, Vt = np.linalg.svd(A)
    X = Vt[:, -1]
    w = X[:, 3]
    with np.errstate(divide="ignore", invalid="ignore"):
        out = X[:, :3] / w[:, None]
    out[np.abs(w) <= 1e-12] = np.nan
    return out


def backprojection_planes(x_start: np.ndarray, x_end: np.ndarray, R: np.ndarray, t: np.ndarray) -> np.ndarray:
    """World planes (M, 4) `(N, -N·t)` through each camera centre and its observed segment
    (normalized endpoints (M, 2)), N a unit normal; R, t the observing poses (M, ...)."""
    N = so3.cross(x_start, x_end)
    N = np.einsum("mij,mj->mi", R, N / np.linalg.norm(N, axis=1, keepdims=True))
    return np.concatenate([N, -np.sum(N * t, axis=1, keepdims=True)], axis=1)


def triangulate_lines(x_start: np.ndarray, x_end: np.ndarray, landmark: np.ndarray, pose: np.ndarray, n_lines: int, R: np.ndarray, t: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Plücker `(m, v)` of each line from all its views, and the sine of the largest angle
    between its back-projection planes (0: degenerate). Every observation gives a world
    back-projection plane `π_k`; the homogeneous points X with `π_k·X ≈ 0` for all k form
    the near-null space of the stacked planes, spanned by two points A, B of the line (the
    DLT of lines): `v = a₄ b - b₄ a`, `m = a × b`."""
    planes = backprojection_planes(x_start, x_end, R[pose], t[pose])
    m = np.empty((n_lines, 3))
    v = np.empty((n_lines, 3))
    spread = np.zeros(n_lines)
    for i in range(n_lines):
        P = planes[landmark == i]
        _, _, Vt = np.linalg.svd(P)
        A, B = Vt[-1], Vt[-2]
        v[i] = A[3] * B[:3] - B[3] * A[:3]
        m[i] = so3.cross(A[:3], B[:3])
        if len(P) >= 2:
            spread[i] = np.max(np.linalg.norm(so3.cross(P[:1, :3], P[:, :3]), axis=1))
    return m, v, spread
