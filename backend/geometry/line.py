"""3D lines in Plücker coordinates `(m, v)`: direction v and moment `m = p × v` for any point
p on the line (any common scale). Orthonormal representation (Bartoli & Sturm 2005):
`U = [m/|m|, v/|v|, (m×v)/|m×v|] ∈ SO(3)` and `W = (cos φ, sin φ)` with
`(cos φ, sin φ) ∝ (|m|, |v|)`, so `m = cos φ · U e₁`, `v = sin φ · U e₂` (unit scale).
The 4-DoF update is `U <- U Exp(δθ)`, `φ <- φ + δφ`, ordered `(δθ, δφ)`.
A line through the origin (m = 0) is degenerate for the camera that sees it edge-on.
"""

from __future__ import annotations

import numpy as np

from backend.geometry import so3


def from_points(p: np.ndarray, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Plücker (m, v) of the lines through points p and q (..., 3); v = q - p."""
    v = np.asarray(q, dtype=float) - np.asarray(p, dtype=float)
    return so3.cross(p, v), v


def to_orthonormal(m: np.ndarray, v: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Plücker (..., 3) pairs to `(U (..., 3, 3), φ (...))`."""
    m = np.asarray(m, dtype=float)
    v = np.asarray(v, dtype=float)
    nm = np.linalg.norm(m, axis=-1)
    nv = np.linalg.norm(v, axis=-1)
    u2 = v / nv[..., None]
    # m ⟂ v always; for a line through the origin pick any unit vector ⟂ v.
    fallback = so3.cross(u2, np.where(np.abs(u2[..., :1]) < 0.9, [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]))
    u1 = np.where((nm > 1e-12 * nv)[..., None], m / np.maximum(nm, 1e-300)[..., None], fallback)
    u1 = u1 / np.linalg.norm(u1, axis=-1, keepdims=True)
    u3 = so3.cross(u1, u2)
    U = np.stack([u1, u2, u3], axis=-1)
    return U, np.arctan2(nv, nm)


def from_orthonormal(U: np.ndarray, phi: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """`(U, φ)` to Plücker `(m, v) = (cos φ U e₁, sin φ U e₂)`."""
    U = np.asarray(U, dtype=float)
    phi = np.asarray(phi, dtype=float)
    return np.cos(phi)[..., None] * U[..., :, 0], np.sin(phi)[..., None] * U[..., :, 1]


def retract(U: np.ndarray, phi: np.ndarray, delta: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Apply (..., 4) increments `(δθ, δφ)`."""
    delta = np.asarray(delta, dtype=float)
    return U @ so3.exp(delta[..., :3]), phi + delta[..., 3]


def to_camera(m_world: np.ndarray, v_world: np.ndarray, R_world_camera: np.ndarray, t_world_camera: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """World Plücker lines into camera frames: `v_c = Rᵀ v_w`, `m_c = Rᵀ (m_w - t × v_w)`."""
    v_c = np.einsum("...ji,...j->...i", R_world_camera, v_world)
    m_c = np.einsum("...ji,...j->...i", R_world_camera, m_world - so3.cross(t_world_camera, v_world))
    return m_c, v_c


def to_world(m_camera: np.ndarray, v_camera: np.ndarray, R_world_camera: np.ndarray, t_world_camera: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Camera Plücker lines into the world: `v_w = R v_c`, `m_w = R m_c + t × v_w`."""
    v_w = np.einsum("...ij,...j->...i", R_world_camera, v_camera)
    m_w = np.einsum("...ij,...j->...i", R_world_camera, m_camera) + so3.cross(t_world_camera, v_w)
    return m_w, v_w


def image_line(m_camera: np.ndarray) -> np.ndarray:
    """The 2D line (normalized image coordinates) of camera-frame lines: `l = m_c`.
    A normalized point x̂ lies on it when `x̂·l = 0`."""
    return np.asarray(m_camera, dtype=float)


def closest_point_to_origin(m: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Point of the line nearest the frame origin: `v × m / |v|²`."""
    return so3.cross(v, m) / np.sum(v * v, axis=-1, keepdims=True)


def from_two_planes(n1: np.ndarray, d1: np.ndarray, n2: np.ndarray, d2: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Intersection of planes `n1·X + d1 = 0` and `n2·X + d2 = 0` as Plücker (m, v):
    `v = n1 × n2`, `m = d1 n2 - d2 n1` (the dual Plücker matrix `π₁π₂ᵀ - π₂π₁ᵀ`)."""
    n1 = np.asarray(n1, dtype=float)
    n2 = np.asarray(n2, dtype=float)
    v = so3.cross(n1, n2)
    m = np.asarray(d1)[..., None] * n2 - np.asarray(d2)[..., None] * n1
    return m, v
