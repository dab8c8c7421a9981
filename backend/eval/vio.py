"""What the VIO initialization is checked with on rendered scenes: an up-to-scale visual
trajectory made from the true camera poses, as a structure from motion would give it."""

from __future__ import annotations

import dataclasses

import numpy as np

from backend.geometry import so3


@dataclasses.dataclass(frozen=True)
class VisualKeyframes:
    """Keyframes `index` (frames of the sequence) at `timestamps_ns`, camera poses in the
    first camera's frame c0 (`R_c0_cam`, `p_c0_cam` metres, before any scaling) with their
    perturbation, and the truth: `R_world_c0`, and the body velocities in c0 (m/s)."""

    index: np.ndarray
    timestamps_ns: np.ndarray
    R_c0_cam: np.ndarray
    p_c0_cam: np.ndarray
    R_world_c0: np.ndarray
    velocity_c0: np.ndarray


def visual_keyframes(seq, duration_s: float, *, rate_hz: float = 10.0, rotation_deg: float = 0.2, position_fraction: float = 0.005, rng: np.random.Generator) -> VisualKeyframes:
    """Keyframes at `rate_hz` over [0, duration_s] of a rendered sequence `seq`, the true
    camera poses in c0 with rotation noise of `rotation_deg` (degrees, 1 σ of the angle) and
    position noise of `position_fraction` of the mean keyframe-to-keyframe distance (1 σ of
    the norm), both drawn from `rng`; the first keyframe is exact (it defines c0)."""
    step = int(round(seq.camera_rate_hz / rate_hz))
    index = np.arange(0, int(round(duration_s * seq.camera_rate_hz)) + 1, step)
    T = seq.T_world_rect0[index]
    R_world_c0, p_world_c0 = T[0, :3, :3], T[0, :3, 3]
    R = R_world_c0.T @ T[:, :3, :3]
    p = (T[:, :3, 3] - p_world_c0) @ R_world_c0
    baseline = float(np.mean(np.linalg.norm(np.diff(p, axis=0), axis=1)))
    R[1:] = R[1:] @ so3.exp(rng.normal(0.0, np.radians(rotation_deg) / np.sqrt(3.0), (len(index) - 1, 3)))
    p[1:] += rng.normal(0.0, position_fraction * baseline / np.sqrt(3.0), (len(index) - 1, 3))
    t = seq.timestamps_ns[index]
    v_c0 = seq.trajectory.velocity(t * 1e-9) @ R_world_c0
    return VisualKeyframes(index, t, R, p, R_world_c0, v_c0)
