"""The debugger's text panels and the TUM export."""

from __future__ import annotations

import numpy as np

from backend.pipeline.sim_engine import SimEngine, SimSettings
from backend.pipeline.snapshot import Tracking
from viewer import images, panels


def test_report_times_are_a_table_and_counts_read_as_words() -> None:
    snap = SimEngine(SimSettings(window=4, max_iterations=2)).step()
    text = panels.report_markdown(snap)
    assert "| stage | ms |" in text
    assert all(f"| {panels.STAGE_LABELS.get(k, k)} | {v:.1f} |" in text for k, v in snap.report.timing_ms.items())
    one = Tracking(frames=1, lost_frames=0, reinitializations=1, tracked_points=1, tracked_lines=2)
    line = images.tracking_markdown(one)
    assert "1 frame ·" in line and "1 re-initialization" in line and "1 point ·" in line and "2 lines" in line
    assert "1 frames" not in line


def test_tum_export_round_trips_the_keyframe_poses() -> None:
    engine = SimEngine(SimSettings(window=4, max_iterations=2))
    for _ in range(5):
        snap = engine.step()
    rows = np.loadtxt(panels.tum_bytes(snap.estimate).decode().splitlines())
    assert rows.shape == (5, 8)
    np.testing.assert_allclose(rows[:, 1:4], snap.estimate.t_world_camera, atol=1e-8)
    np.testing.assert_allclose(rows[:, 0], snap.estimate.timestamp_ns * 1e-9, atol=1e-8)
    np.testing.assert_allclose(np.linalg.norm(rows[:, 4:], axis=1), 1.0, atol=1e-8)


class _Client:
    """What exports.export sends a tab: the downloads, by name."""

    def __init__(self) -> None:
        self.files: dict[str, bytes] = {}

    def send_file_download(self, name: str, data: bytes, *, save_immediately: bool) -> None:
        self.files[name] = data

    def add_notification(self, *args: object, **kwargs: object) -> None:
        pass


def test_trajectory_downloads_are_poses_of_the_ground_truths_frame() -> None:
    """The debugger's TUM downloads are in the frame `coplanar run` writes by default (the
    dataset's ground-truth frame, here a body 10 cm behind the camera), which their header says."""
    from backend.export.output_frame import TrajectoryFrame, output_frame
    from viewer import exports

    class _Source:
        ground_truth_frame = "body"
        T_truth_rect0 = np.eye(4)

    _Source.T_truth_rect0[:3, 3] = [0.1, 0.0, 0.0]
    engine = SimEngine(SimSettings(window=4, max_iterations=2))
    for _ in range(3):
        snap = engine.step()
    client = _Client()
    frame = output_frame(_Source(), choice=TrajectoryFrame.TRUTH)  # type: ignore[arg-type]
    exports.export(client, "keyframes", snap, frame_trajectory=None, is_newest=True, frame=frame)  # type: ignore[arg-type]
    (text,) = (data.decode() for data in client.files.values())
    assert "T_world_body" in text.split("# t x y z")[0]
    rows = np.loadtxt(text.splitlines())
    R, t = np.asarray(snap.estimate.R_world_camera), np.asarray(snap.estimate.t_world_camera)
    np.testing.assert_allclose(rows[:, 1:4], t - R @ np.array([0.1, 0.0, 0.0]), atol=1e-8)  # T_world_rect0 · T_body_rect0⁻¹
