"""Pinhole camera (OpenCV convention: x right, y down, z forward) with an optional
rectified stereo partner whose centre lies `baseline` metres along +x of the left camera.
"""

from __future__ import annotations

import dataclasses

import numpy as np


@dataclasses.dataclass(frozen=True)
class PinholeCamera:
    """Intrinsics in pixels; `baseline` in metres (0 for a monocular camera)."""

    fx: float
    fy: float
    cx: float
    cy: float
    width: int
    height: int
    baseline: float = 0.0

    @property
    def K(self) -> np.ndarray:
        return np.array([[self.fx, 0.0, self.cx], [0.0, self.fy, self.cy], [0.0, 0.0, 1.0]])

    def normalize(self, uv: np.ndarray) -> np.ndarray:
        """Pixels (..., 2) to normalized homogeneous coordinates `x̂ = K⁻¹[u v 1]ᵀ`, (..., 3)."""
        uv = np.asarray(uv, dtype=float)
        x = (uv[..., 0] - self.cx) / self.fx
        y = (uv[..., 1] - self.cy) / self.fy
        return np.stack([x, y, np.ones_like(x)], axis=-1)

    def project(self, p_camera: np.ndarray) -> np.ndarray:
        """Camera-frame points (..., 3) in metres to pixels (..., 2)."""
        p = np.asarray(p_camera, dtype=float)
        z = p[..., 2]
        return np.stack([self.fx * p[..., 0] / z + self.cx, self.fy * p[..., 1] / z + self.cy], axis=-1)

    def project_jacobian(self, p_camera: np.ndarray) -> np.ndarray:
        """`∂ project / ∂ p_camera`, (..., 2, 3), pixels per metre."""
        p = np.asarray(p_camera, dtype=float)
        inv_z = 1.0 / p[..., 2]
        J = np.zeros(p.shape[:-1] + (2, 3))
        J[..., 0, 0] = self.fx * inv_z
        J[..., 0, 2] = -self.fx * p[..., 0] * inv_z**2
        J[..., 1, 1] = self.fy * inv_z
        J[..., 1, 2] = -self.fy * p[..., 1] * inv_z**2
        return J

    def in_image(self, uv: np.ndarray) -> np.ndarray:
        """Boolean mask of pixels (..., 2) inside the image rectangle."""
        uv = np.asarray(uv, dtype=float)
        return (uv[..., 0] >= 0) & (uv[..., 0] <= self.width - 1) & (uv[..., 1] >= 0) & (uv[..., 1] <= self.height - 1)

    @property
    def offset_right(self) -> np.ndarray:
        """Position of the right camera in the left camera frame, metres."""
        return np.array([self.baseline, 0.0, 0.0])
