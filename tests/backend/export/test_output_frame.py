"""The written trajectories' frame and the ground truth they are evaluated against
(backend/export/output_frame.py)."""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

from backend.eval.trajectory import ate_rmse
from backend.export.output_frame import MAX_TIME_DIFF_NS, TrajectoryFrame, ground_truth_in, nearest_samples, output_frame
from backend.pipeline.snapshot import Trajectory


def _pose(rotvec: np.ndarray, t: np.ndarray) -> np.ndarray:
    T = np.eye(4)
    T[:3, :3] = Rotation.from_rotvec(rotvec).as_matrix()
    T[:3, 3] = t
    return T


T_BODY_RECT0 = _pose(np.array([1.2, -0.3, 0.4]), np.array([0.05, -0.2, 0.1]))


class _Source:
    """A source with a file of body samples at 200 Hz, 4.4 µs off its frames (as MH_01)."""

    ground_truth_frame = "body"
    T_truth_rect0 = T_BODY_RECT0

    def __init__(self, n: int = 40) -> None:
        rng = np.random.default_rng(1)
        self.sample_ns = 5_000_000 * np.arange(10 * n, dtype=np.int64) + 10_000
        self.T_world_body = np.stack([_pose(0.3 * rng.normal(size=3), rng.normal(size=3)) for _ in self.sample_ns])
        self.timestamps_ns = 50_000_000 * np.arange(n, dtype=np.int64) + 14_400

    def ground_truth_samples(self) -> tuple[np.ndarray, np.ndarray]:
        return self.sample_ns, self.T_world_body


def _trajectory(stamps: np.ndarray, T: np.ndarray) -> Trajectory:
    return Trajectory.of(stamps, T[:, :3, :3], T[:, :3, 3])


def test_nearest_samples_pair_as_evo_does() -> None:
    samples = np.array([100, 200, 300], dtype=np.int64)
    stamps = np.array([0, 90, 149, 150, 151, 310, 311, 400], dtype=np.int64)
    # Nearest in time, the earlier one on a tie, none further than max_diff (inclusive).
    np.testing.assert_array_equal(nearest_samples(stamps, samples, max_diff_ns=10), [-1, 0, -1, -1, -1, 2, -1, -1])
    np.testing.assert_array_equal(nearest_samples(stamps, samples, max_diff_ns=100), [0, 0, 0, 0, 1, 2, 2, 2])
    np.testing.assert_array_equal(nearest_samples(stamps, samples[:1], max_diff_ns=10), [-1, 0, -1, -1, -1, -1, -1, -1])
    np.testing.assert_array_equal(nearest_samples(stamps, samples[:0], max_diff_ns=10), np.full(8, -1))


def test_the_truth_frame_is_the_body_and_the_camera_frame_the_estimate() -> None:
    source = _Source()
    body = output_frame(source, choice=TrajectoryFrame.TRUTH)  # type: ignore[arg-type]
    camera = output_frame(source, choice=TrajectoryFrame.CAMERA)  # type: ignore[arg-type]
    assert (body.name, camera.name) == ("body", "rect0") and "T_world_body" in body.note and "rectified left camera" in camera.note
    np.testing.assert_array_equal(body.T_frame_rect0, T_BODY_RECT0)
    np.testing.assert_array_equal(camera.T_frame_rect0, np.eye(4))
    # An estimate of the camera, written as the body: T_world_body = T_world_rect0 · T_body_rect0⁻¹.
    T_world_rect0 = source.T_world_body[::10] @ T_BODY_RECT0
    written = body.poses(_trajectory(source.timestamps_ns, T_world_rect0))
    np.testing.assert_allclose(written.t_world_camera, source.T_world_body[::10, :3, 3], atol=1e-12)
    np.testing.assert_allclose(written.R_world_camera, source.T_world_body[::10, :3, :3], atol=1e-12)
    same = camera.poses(_trajectory(source.timestamps_ns, T_world_rect0))
    np.testing.assert_array_equal(same.t_world_camera, T_world_rect0[:, :3, 3])  # the identity is exact


def test_ground_truth_is_the_file_sample_nearest_each_pose_in_the_written_frame() -> None:
    source = _Source()
    n = len(source.timestamps_ns)
    no_truth = np.full((n, 4, 4), np.nan)  # ignored where the source has samples
    per_frame = _trajectory(source.timestamps_ns, no_truth)
    body = ground_truth_in(output_frame(source, choice=TrajectoryFrame.TRUTH), source, per_frame)  # type: ignore[arg-type]
    # The samples as the file gives them, exactly (bit for bit: evo reads the same numbers).
    np.testing.assert_array_equal(body.t_world_camera, source.T_world_body[::10, :3, 3])
    camera = ground_truth_in(output_frame(source, choice=TrajectoryFrame.CAMERA), source, per_frame)  # type: ignore[arg-type]
    np.testing.assert_allclose(camera.t_world_camera, (source.T_world_body[::10] @ T_BODY_RECT0)[:, :3, 3], atol=1e-12)
    # A pose further than 10 ms from every sample has none.
    late = _trajectory(np.array([source.sample_ns[-1] + MAX_TIME_DIFF_NS + 1]), no_truth[:1])
    assert np.isnan(ground_truth_in(output_frame(source, choice=TrajectoryFrame.TRUTH), source, late).t_world_camera).all()  # type: ignore[arg-type]


class _PerFrame:
    """A source whose ground truth is one pose per frame (a rendered scene)."""

    ground_truth_frame = "body"
    T_truth_rect0 = T_BODY_RECT0


def test_without_samples_the_per_frame_truth_is_moved_to_the_frame() -> None:
    samples = _Source()
    T_world_rect0 = samples.T_world_body[::10] @ T_BODY_RECT0
    T_world_rect0[3] = np.nan  # no ground truth there
    source = _PerFrame()
    frame = output_frame(source, choice=TrajectoryFrame.TRUTH)  # type: ignore[arg-type]
    truth = ground_truth_in(frame, source, _trajectory(samples.timestamps_ns, T_world_rect0))  # type: ignore[arg-type]
    expected = samples.T_world_body[::10, :3, 3].copy()
    expected[3] = np.nan
    np.testing.assert_allclose(truth.t_world_camera, expected, atol=1e-12)


def test_the_aligned_error_depends_on_the_frame() -> None:
    """Why the written frame matters: the same estimate, as the camera or as the body, has a
    different ATE after SE(3) alignment (a rotation error moves an offset point)."""
    source = _Source()
    rng = np.random.default_rng(2)
    T_true = source.T_world_body[::10] @ T_BODY_RECT0
    T_est = np.stack([T @ _pose(0.02 * rng.normal(size=3), 0.002 * rng.normal(size=3)) for T in T_true])
    ate = {}
    for choice in TrajectoryFrame:
        frame = output_frame(source, choice=choice)  # type: ignore[arg-type]
        est = frame.poses(_trajectory(source.timestamps_ns, T_est))
        gt = ground_truth_in(frame, source, _trajectory(source.timestamps_ns, T_true))  # type: ignore[arg-type]
        ate[choice] = ate_rmse(np.asarray(est.t_world_camera), np.asarray(gt.t_world_camera), align="se3")
    assert abs(ate[TrajectoryFrame.TRUTH] - ate[TrajectoryFrame.CAMERA]) > 0.1 * ate[TrajectoryFrame.CAMERA]
