"""Trajectories in the TUM format: `t x y z qx qy qz qw` per line, t in seconds, the pose
`T_world_camera` (position in metres, Hamilton unit quaternion)."""

from __future__ import annotations

import pathlib

import numpy as np
from scipy.spatial.transform import Rotation

from backend.export.atomic import atomic_path
from backend.pipeline.snapshot import Trajectory


def write_tum(path: pathlib.Path | str, trajectory: Trajectory) -> None:
    """Write `trajectory` to `path` (TUM format, one pose per line)."""
    q_xyzw = Rotation.from_matrix(trajectory.R_world_camera).as_quat() if len(trajectory) else np.zeros((0, 4))
    t = trajectory.timestamp_ns.astype(np.float64) * 1e-9
    rows = np.concatenate([t[:, None], trajectory.t_world_camera, q_xyzw], axis=1)
    with atomic_path(path) as tmp:
        np.savetxt(tmp, rows, fmt=["%.9f"] + ["%.9f"] * 7, header="t x y z qx qy qz qw", comments="# ")
