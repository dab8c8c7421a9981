"""The frame the written trajectories are poses of, and the ground truth they are evaluated
against (`coplanar run`'s trajectory.txt, keyframes.txt, groundtruth.txt and metrics.json;
the debugger's trajectory downloads).

The engines estimate `T_world_rect0`, poses of the rectified left camera. A dataset's own
ground truth gives poses of another frame (`StereoSource.ground_truth_frame`: EuRoC's IMU
body, KITTI's left camera), and the ATE after an SE(3) alignment is not invariant to a change
of body frame: a trajectory compared with the dataset's file must be in that file's frame.
So by default (`TrajectoryFrame.TRUTH`) the written poses are
`T_world_truth = T_world_rect0 · T_truth_rect0⁻¹`; `TrajectoryFrame.CAMERA` writes
`T_world_rect0` as the engines estimate it. A Monte-Carlo world's ground truth is its camera's
poses: both choices give the camera there.

The ground truth a written pose is evaluated against is, where the source holds a file of
timed samples (:class:`backend.data.source.GroundTruthSamples`), the sample nearest the
pose's time within `MAX_TIME_DIFF_NS`, as evo pairs a trajectory with that file
(`evo_ape euroc data.csv trajectory.txt`: nearest time, `max_diff` 0.01 s), rather than the
pose interpolated at the frame's time; the figures in metrics.json then are evo's from the
dataset's own file as well as from groundtruth.txt. Otherwise (rendered scenes: exact at the
frame times) it is the source's per-frame ground truth.

Units: metres, timestamps in nanoseconds; poses `T_world_x` map x's coordinates to the world's.
"""

from __future__ import annotations

import dataclasses
import enum

import numpy as np

from backend.data.source import GroundTruthSamples, StereoSource
from backend.pipeline.snapshot import Trajectory

MAX_TIME_DIFF_NS = 10_000_000  # evo's default association window (max_diff 0.01 s)


class TrajectoryFrame(enum.StrEnum):
    """`--trajectory-frame`: the dataset's ground-truth frame, or the rectified left camera."""

    TRUTH = "truth"
    CAMERA = "camera"


@dataclasses.dataclass(frozen=True)
class OutputFrame:
    """The frame written poses are of: its `name` ("body", "cam0", "rect0", "camera"), a
    one-sentence `note` for metrics.json and the files' headers, `T_frame_rect0` (4, 4) the
    rectified left camera in it, and `T_truth_frame` (4, 4) taking a ground-truth sample
    `T_world_truth` to `T_world_frame`; metres."""

    name: str
    note: str
    T_frame_rect0: np.ndarray
    T_truth_frame: np.ndarray

    def poses(self, trajectory: Trajectory) -> Trajectory:
        """`trajectory`'s poses `T_world_rect0` as poses of this frame,
        `T_world_frame = T_world_rect0 · T_frame_rect0⁻¹` (NaN rows stay NaN)."""
        return _times(trajectory, np.linalg.inv(self.T_frame_rect0))


def output_frame(source: StereoSource | None, *, choice: TrajectoryFrame) -> OutputFrame:
    """The frame `choice` names for `source` (None: a Monte-Carlo world, whose ground truth
    is camera poses)."""
    identity = np.eye(4)
    if source is None:
        return OutputFrame("camera", "poses T_world_camera of the simulated camera (a Monte-Carlo world's ground truth is camera poses)", identity, identity)
    truth_name = str(source.ground_truth_frame)
    T_truth_rect0 = np.asarray(source.T_truth_rect0, dtype=float)
    if choice is TrajectoryFrame.CAMERA:
        note = (
            "poses T_world_rect0 of the rectified left camera, as the engine estimates them (--trajectory-frame camera); "
            f"the dataset's own ground truth gives poses of its {truth_name} frame: evaluate against groundtruth.txt, which is in the same frame"
        )
        return OutputFrame("rect0", note, identity, T_truth_rect0)
    note = (
        f"poses T_world_{truth_name} of the {_describe(truth_name)}, the frame the dataset's own ground truth gives poses of "
        f"(evo against the dataset's file compares like with like); metrics.json's T_frame_rect0 is the rectified left camera in it"
    )
    return OutputFrame(truth_name, note, T_truth_rect0, identity)


def ground_truth_in(frame: OutputFrame, source: StereoSource | None, per_frame: Trajectory) -> Trajectory:
    """The ground truth of poses at `per_frame.timestamp_ns`, as poses of `frame`.

    `per_frame`: the source's own ground truth of those poses, `T_world_rect0` (NaN rows:
    none), used where `source` holds no timed samples. Where it does, each pose gets the
    sample nearest in time (module docstring; NaN where none is within `MAX_TIME_DIFF_NS`)."""
    if not isinstance(source, GroundTruthSamples):
        return frame.poses(per_frame)
    sample_ns, T_world_truth = source.ground_truth_samples()
    stamps = np.asarray(per_frame.timestamp_ns, dtype=np.int64)
    nearest = nearest_samples(stamps, np.asarray(sample_ns, dtype=np.int64), max_diff_ns=MAX_TIME_DIFF_NS)
    T = np.full((len(stamps), 4, 4), np.nan)
    found = nearest >= 0
    T[found] = np.asarray(T_world_truth)[nearest[found]] @ frame.T_truth_frame
    return Trajectory.of(stamps, T[:, :3, :3], T[:, :3, 3])


def nearest_samples(stamps_ns: np.ndarray, sample_ns: np.ndarray, *, max_diff_ns: int) -> np.ndarray:
    """For each of `stamps_ns` (N,), the index of the sample in `sample_ns` (M,), increasing,
    nearest in time (the earlier one on a tie, as evo's `matching_time_indices`); -1 where
    none is within `max_diff_ns`. Nanoseconds."""
    if len(sample_ns) == 0:
        return np.full(len(stamps_ns), -1, dtype=np.int64)
    upper = np.clip(np.searchsorted(sample_ns, stamps_ns, side="right"), 1, len(sample_ns) - 1) if len(sample_ns) > 1 else np.zeros(len(stamps_ns), np.int64)
    lower = np.maximum(upper - 1, 0)
    d_upper = np.abs(sample_ns[upper] - stamps_ns)
    d_lower = np.abs(stamps_ns - sample_ns[lower])
    best = np.where(d_upper < d_lower, upper, lower)
    return np.where(np.minimum(d_upper, d_lower) <= max_diff_ns, best, -1).astype(np.int64)


def _times(trajectory: Trajectory, T_right: np.ndarray) -> Trajectory:
    """`trajectory`'s poses right-multiplied by `T_right` (4, 4): `T_world_a · T_a_b`."""
    R = np.asarray(trajectory.R_world_camera)
    t = np.asarray(trajectory.t_world_camera)
    return Trajectory.of(np.asarray(trajectory.timestamp_ns), R @ T_right[:3, :3], R @ T_right[:3, 3] + t)


def _describe(name: str) -> str:
    """Words for a ground-truth frame's name."""
    return {"body": "IMU body", "cam0": "left camera (cam0)"}.get(name, f"{name} frame")
