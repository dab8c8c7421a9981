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
