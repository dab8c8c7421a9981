"""Rotations: vectorized SO(3) helpers on numpy arrays.

Conventions: rotation vectors (axis * angle, radians) map to matrices by the
exponential map; perturbations are applied on the right, `R <- R Exp(δθ)`.
Every function accepts a single vector/matrix or a stack with leading axes. exp, log and
the inverse right Jacobian run as compiled loops (numba): they sit on the solver's hot path.
"""

from __future__ import annotations

import numba
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


@numba.njit(cache=True, nogil=True)
def _exp_kernel(w, out):
    for n in range(w.shape[0]):
        x, y, z = w[n, 0], w[n, 1], w[n, 2]
        t2 = x * x + y * y + z * z
        theta = np.sqrt(t2)
        if theta < _SMALL_ANGLE:
            a = 1.0 - t2 / 6.0
            b = 0.5 - t2 / 24.0
        else:
            a = np.sin(theta) / theta
            b = (1.0 - np.cos(theta)) / t2
        _identity_plus(x, y, z, a, b, out[n])


@numba.njit(cache=True, nogil=True)
def _identity_plus(x, y, z, a, b, out):
    """out (3, 3) = I + a K + b K² for K = [w]_×, w = (x, y, z); K² = w wᵀ - |w|² I."""
    t2 = x * x + y * y + z * z
    out[0, 0] = 1.0 + b * (x * x - t2)
    out[1, 1] = 1.0 + b * (y * y - t2)
    out[2, 2] = 1.0 + b * (z * z - t2)
    out[0, 1] = -a * z + b * x * y
    out[1, 0] = a * z + b * x * y
    out[0, 2] = a * y + b * x * z
    out[2, 0] = -a * y + b * x * z
    out[1, 2] = -a * x + b * y * z
    out[2, 1] = a * x + b * y * z


def exp(w: np.ndarray) -> np.ndarray:
    """Rodrigues: rotation vectors (..., 3) in radians to matrices (..., 3, 3)."""
    w = np.asarray(w, dtype=float)
    flat = np.ascontiguousarray(w.reshape(-1, 3))
    out = np.empty((flat.shape[0], 3, 3))
    _exp_kernel(flat, out)
    return out.reshape(w.shape[:-1] + (3, 3))


@numba.njit(cache=True, nogil=True)
def _log_kernel(R, out):
    for n in range(R.shape[0]):
        log_one(R[n], out[n])


@numba.njit(cache=True, nogil=True)
def log_one(M, out):
    """Compiled `log` of one rotation matrix M (3, 3) into out (3,) (for other kernels)."""
    c = min(1.0, max(-1.0, (M[0, 0] + M[1, 1] + M[2, 2] - 1.0) / 2.0))
    theta = np.arccos(c)
    v0 = M[2, 1] - M[1, 2]
    v1 = M[0, 2] - M[2, 0]
    v2 = M[1, 0] - M[0, 1]
    if theta < 1e-6:
        scale = 0.5 + theta * theta / 12.0
        out[0], out[1], out[2] = scale * v0, scale * v1, scale * v2
    elif theta > np.pi - 1e-4:
        # Axis from the symmetric part: (R + Rᵀ)/4 + I/2 = a aᵀ at θ = π.
        best = 0
        for i in range(1, 3):
            if M[i, i] > M[best, best]:
                best = i
        a0 = (M[best, 0] + M[0, best]) / 4.0
        a1 = (M[best, 1] + M[1, best]) / 4.0
        a2 = (M[best, 2] + M[2, best]) / 4.0
        if best == 0:
            a0 += 0.5
        elif best == 1:
            a1 += 0.5
        else:
            a2 += 0.5
        norm = np.sqrt(a0 * a0 + a1 * a1 + a2 * a2)
        sign = -1.0 if a0 * v0 + a1 * v1 + a2 * v2 < 0.0 else 1.0
        k = sign * theta / norm
        out[0], out[1], out[2] = k * a0, k * a1, k * a2
    else:
        scale = theta / (2.0 * np.sin(theta))
        out[0], out[1], out[2] = scale * v0, scale * v1, scale * v2


def log(R: np.ndarray) -> np.ndarray:
    """Rotation matrices (..., 3, 3) to rotation vectors (..., 3) in radians.

    Accurate near 0 and near π (the axis is then taken from the symmetric part).
    """
    R = np.asarray(R, dtype=float)
    flat = np.ascontiguousarray(R.reshape(-1, 3, 3))
    out = np.empty((flat.shape[0], 3))
    _log_kernel(flat, out)
    return out.reshape(R.shape[:-2] + (3,))


@numba.njit(cache=True, nogil=True)
def _right_jacobian_inv_kernel(w, out):
    for n in range(w.shape[0]):
        right_jacobian_inv_one(w[n], out[n])


@numba.njit(cache=True, nogil=True)
def right_jacobian_inv_one(w, out):
    """Compiled `right_jacobian_inv` of one rotation vector w (3,) into out (3, 3)."""
    x, y, z = w[0], w[1], w[2]
    t2 = x * x + y * y + z * z
    theta = np.sqrt(t2)
    if theta < 1e-5:
        c = 1.0 / 12.0 + t2 / 720.0
    else:
        c = 1.0 / t2 - (1.0 + np.cos(theta)) / (2.0 * theta * np.sin(theta))
    _identity_plus(x, y, z, 0.5, c, out)


def right_jacobian_inv(w: np.ndarray) -> np.ndarray:
    """Inverse right Jacobian `J_r⁻¹(w)` of SO(3), (..., 3) -> (..., 3, 3).

    For `Log(Exp(w) Exp(δ)) ≈ w + J_r⁻¹(w) δ`.
    """
    w = np.asarray(w, dtype=float)
    flat = np.ascontiguousarray(w.reshape(-1, 3))
    out = np.empty((flat.shape[0], 3, 3))
    _right_jacobian_inv_kernel(flat, out)
    return out.reshape(w.shape[:-1] + (3, 3))


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
