"""Trajectories in the TUM format: `t x y z qx qy qz qw` per line, t in seconds, the pose
`T_world_camera` (position in metres, Hamilton unit quaternion)."""

from __future__ import annotations

import os
import pathlib
import typing

import numpy as np
from scipy.spatial.transform import Rotation

from backend.common.atomic import atomic_path
from backend.pipeline.snapshot import Trajectory


def write_tum(path: pathlib.Path | str | typing.TextIO, trajectory: Trajectory) -> None:
    """Write `trajectory` to `path` (TUM format, one pose per line; a file complete or not
    at all), or to an open text stream."""
    q_xyzw = Rotation.from_matrix(trajectory.R_world_camera).as_quat() if len(trajectory) else np.zeros((0, 4))
    t = trajectory.timestamp_ns.astype(np.float64) * 1e-9
    rows = np.concatenate([t[:, None], trajectory.t_world_camera, q_xyzw], axis=1)

    def save(target) -> None:
        np.savetxt(target, rows, fmt=["%.9f"] + ["%.9f"] * 7, header="t x y z qx qy qz qw", comments="# ")

    if not isinstance(path, (str, os.PathLike)):  # an open text stream (the debugger's download)
        save(path)
        return
    with atomic_path(path) as tmp:
        save(tmp)
