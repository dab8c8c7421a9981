"""Rigid transforms `T_world_camera = (R, t)`: `X_world = R X_camera + t`.

The optimizer's pose retraction is decoupled: `R <- R Exp(δθ)`, `t <- t + δt`, with the
6-vector ordered `(δθ, δt)` (radians, metres; δt in the world frame). gtsam `Pose3` objects
convert through :func:`from_gtsam` / :func:`to_gtsam` at the boundaries.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from backend.geometry import so3


@dataclasses.dataclass(frozen=True)
class Poses:
    """A stack of N poses `T_world_camera`: rotations (N, 3, 3) and positions (N, 3) in metres."""

    R_world_camera: np.ndarray
    t_world_camera: np.ndarray

    def __len__(self) -> int:
        return int(self.t_world_camera.shape[0])

    def retract(self, delta: np.ndarray) -> Poses:
        """Apply (N, 6) increments `(δθ, δt)`: `R Exp(δθ)`, `t + δt`."""
        delta = np.asarray(delta, dtype=float).reshape(-1, 6)
        return Poses(
            R_world_camera=self.R_world_camera @ so3.exp(delta[:, :3]),
            t_world_camera=self.t_world_camera + delta[:, 3:],
        )

    def inverse_transform_points(self, idx: np.ndarray, p_world: np.ndarray) -> np.ndarray:
        """`R_iᵀ (p_world - t_i)` for pose indices `idx` and (M, 3) world points."""
        R = self.R_world_camera[idx]
        return np.einsum("mji,mj->mi", R, p_world - self.t_world_camera[idx])

    def copy(self) -> Poses:
        return Poses(self.R_world_camera.copy(), self.t_world_camera.copy())


def from_gtsam(poses: list) -> Poses:
    """Stack gtsam `Pose3` objects (camera to world) into :class:`Poses`."""
    R = np.stack([p.rotation().matrix() for p in poses])
    t = np.stack([np.asarray(p.translation(), dtype=float) for p in poses])
    return Poses(R, t)


def to_gtsam(poses: Poses) -> list:
    """Convert :class:`Poses` to a list of gtsam `Pose3` (camera to world)."""
    import gtsam

    return [gtsam.Pose3(gtsam.Rot3(R), t) for R, t in zip(poses.R_world_camera, poses.t_world_camera)]
