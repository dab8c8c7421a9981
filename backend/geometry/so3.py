"""Rotations: vectorized SO(3) helpers on numpy arrays.

Conventions: rotation vectors (axis * angle, radians) map to matrices by the
exponential map; perturbations are applied on the right, `R <- R Exp(δθ)`.
Every function accepts a single vector/matrix or a stack with leading axes.
"""

from __future__ import annotations

import numpy as np

_SMALL_ANGLE = 1e-8


def cross(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """`a × b` over the last axis, broadcasting (faster than np.cross for stacks of 3-vectors)."""
    a0, a1, a2 = a[..., 0], a[..., 1], a[..., 2]
    b0, b1, b2 = b[..., 0], b[..., 1], b[..., 2]
    return np.stack([a1 * b2 - a2 * b1, a2 * b0 - a0 * b2, a0 * b1 - a1 * b0], axis=-1)


def hat(w: np.ndarray) -> np.ndarray:
    """Skew-symmetric matrix `[w]_x` of (..., 3) vectors, shape (..., 3, 3)."""
    w = np.asarray(w, dtype=float)
    out = np.zeros(w.shape[:-1] + (3, 3))
    out[..., 0, 1] = -w[..., 2]
    out[..., 0, 2] = w[..., 1]
    out[..., 1, 0] = w[..., 2]
    out[..., 1, 2] = -w[..., 0]
    out[..., 2, 0] = -w[..., 1]
    out[..., 2, 1] = w[..., 0]
    return out


def exp(w: np.ndarray) -> np.ndarray:
    """Rodrigues: rotation vectors (..., 3) in radians to matrices (..., 3, 3)."""
    w = np.asarray(w, dtype=float)
    theta = np.linalg.norm(w, axis=-1)[..., None, None]
    K = hat(w)
    K2 = K @ K
    small = theta < _SMALL_ANGLE
    safe = np.where(small, 1.0, theta)
    a = np.where(small, 1.0 - theta**2 / 6.0, np.sin(safe) / safe)
    b = np.where(small, 0.5 - theta**2 / 24.0, (1.0 - np.cos(safe)) / safe**2)
    return np.eye(3) + a * K + b * K2


def log(R: np.ndarray) -> np.ndarray:
    """Rotation matrices (..., 3, 3) to rotation vectors (..., 3) in radians.

    Accurate near 0 and near π (the axis is then taken from the symmetric part).
    """
    R = np.asarray(R, dtype=float)
    cos = np.clip((np.trace(R, axis1=-2, axis2=-1) - 1.0) / 2.0, -1.0, 1.0)
    theta = np.arccos(cos)
    vee = np.stack(
        [R[..., 2, 1] - R[..., 1, 2], R[..., 0, 2] - R[..., 2, 0], R[..., 1, 0] - R[..., 0, 1]],
        axis=-1,
    )
    sin = np.sin(theta)
    small = theta < 1e-6
    near_pi = theta > np.pi - 1e-4
    scale = np.where(small, 0.5 + theta**2 / 12.0, theta / (2.0 * np.where(small, 1.0, sin + 1e-300)))
    w = scale[..., None] * vee
    if np.any(near_pi):
        # Axis from the largest column of (R + I) / 2 = a a^T for θ = π.
        B = (R + np.swapaxes(R, -1, -2)) / 4.0 + np.eye(3) / 2.0  # symmetric part: a aᵀ at θ = π
        diag = np.diagonal(B, axis1=-2, axis2=-1)
        idx = np.argmax(diag, axis=-1)
        col = np.take_along_axis(B, idx[..., None, None].repeat(3, axis=-1), axis=-2)[..., 0, :]
        axis = col / np.linalg.norm(col, axis=-1, keepdims=True)
        # Choose the sign consistent with the (tiny) antisymmetric part.
        sign = np.where(np.sum(axis * vee, axis=-1) < 0.0, -1.0, 1.0)
        w_pi = (sign * theta)[..., None] * axis
        w = np.where(near_pi[..., None], w_pi, w)
    return w


def right_jacobian_inv(w: np.ndarray) -> np.ndarray:
    """Inverse right Jacobian `J_r⁻¹(w)` of SO(3), (..., 3) -> (..., 3, 3).

    For `Log(Exp(w) Exp(δ)) ≈ w + J_r⁻¹(w) δ`.
    """
    w = np.asarray(w, dtype=float)
    theta = np.linalg.norm(w, axis=-1)[..., None, None]
    K = hat(w)
    small = theta < 1e-5
    safe = np.where(small, 1.0, theta)
    c = np.where(
        small,
        1.0 / 12.0 + theta**2 / 720.0,
        1.0 / safe**2 - (1.0 + np.cos(safe)) / (2.0 * safe * np.sin(safe) + 1e-300),
    )
    return np.eye(3) + 0.5 * K + c * (K @ K)


def right_jacobian(w: np.ndarray) -> np.ndarray:
    """Right Jacobian `J_r(w)` of SO(3): `Exp(w + δ) ≈ Exp(w) Exp(J_r(w) δ)`."""
    w = np.asarray(w, dtype=float)
    theta = np.linalg.norm(w, axis=-1)[..., None, None]
    K = hat(w)
    small = theta < 1e-5
    safe = np.where(small, 1.0, theta)
    a = np.where(small, 0.5 - theta**2 / 24.0, (1.0 - np.cos(safe)) / safe**2)
    b = np.where(small, 1.0 / 6.0 - theta**2 / 120.0, (safe - np.sin(safe)) / safe**3)
    return np.eye(3) - a * K + b * (K @ K)


def project_to_so3(M: np.ndarray) -> np.ndarray:
    """Nearest rotation (Frobenius) to (..., 3, 3) matrices."""
    U, _, Vt = np.linalg.svd(M)
    D = np.ones(M.shape[:-1])
    D[..., 2] = np.sign(np.linalg.det(U @ Vt))
    return (U * D[..., None, :]) @ Vt
