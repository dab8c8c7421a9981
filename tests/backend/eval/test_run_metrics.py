"""The figures of metrics.json (backend/eval/run_metrics.py); the whole files are checked
by tests/app/test_run_command.py."""

from __future__ import annotations

import math

from backend.eval.run_metrics import stereo_timing


def test_stereo_timing_means() -> None:
    """Per-frame stages weighted by frames, per-keyframe stages over the keyframes where
    they ran (0: did not run), null where they never ran."""
    steps = [
        (1, {"point_dm": 10.0, "tracking": 0.0, "load": 1.0, "line_dm": 0.0, "optimization": 0.0, "total": 30.0, "total_per_frame": 30.0}),
        (3, {"point_dm": 6.0, "tracking": 4.0, "load": 1.0, "line_dm": 0.0, "optimization": 20.0, "total": 60.0, "total_per_frame": 20.0}),
        (4, {"point_dm": 5.0, "tracking": 6.0, "load": 1.0, "line_dm": 0.0, "optimization": 40.0, "total": 90.0, "total_per_frame": 22.5}),
    ]
    timing = stereo_timing(steps)
    assert math.isclose(timing["point_dm"], (10 + 18 + 20) / 8)
    assert math.isclose(timing["tracking"], (0 + 12 + 24) / 8)
    assert math.isclose(timing["optimization"], 30.0)  # not the first keyframe's 0
    assert timing["line_dm"] is None and timing["plane_seg"] is None
    assert math.isclose(timing["total_per_frame"], 180.0 / 8)
    assert math.isclose(timing["all_stages"]["total"], 60.0) and math.isclose(timing["all_stages"]["load"], 1.0)
