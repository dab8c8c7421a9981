"""Trajectories in the TUM format: `t x y z qx qy qz qw` per line, t in seconds, the pose
`T_world_x` of whatever frame x the trajectory is of (position in metres, Hamilton unit
quaternion), under `#` comment lines that may say which frame that is."""

from __future__ import annotations

import os
import pathlib
import textwrap
import typing

import numpy as np
from scipy.spatial.transform import Rotation

from backend.common.atomic import atomic_path
from backend.pipeline.snapshot import Trajectory


def write_tum(path: pathlib.Path | str | typing.TextIO, trajectory: Trajectory, *, comment: str = "") -> None:
    """Write `trajectory` to `path` (TUM format, one pose per line; a file complete or not
    at all), or to an open text stream. `comment` (e.g. which frame the poses are of) goes
    into the `#` header above the column names, wrapped at 100 characters."""
    q_xyzw = Rotation.from_matrix(trajectory.R_world_camera).as_quat() if len(trajectory) else np.zeros((0, 4))
    t = trajectory.timestamp_ns.astype(np.float64) * 1e-9
    rows = np.concatenate([t[:, None], trajectory.t_world_camera, q_xyzw], axis=1)
    header = "\n".join([*textwrap.wrap(comment, 98), "t x y z qx qy qz qw"])

    def save(target) -> None:
        np.savetxt(target, rows, fmt=["%.9f"] + ["%.9f"] * 7, header=header, comments="# ")

    if not isinstance(path, (str, os.PathLike)):  # an open text stream (the debugger's download)
        save(path)
        return
    with atomic_path(path) as tmp:
        save(tmp)
