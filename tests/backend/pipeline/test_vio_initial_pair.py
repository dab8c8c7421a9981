"""The VIO's monocular start on a slow creep: the initial pair spans at most
`init_max_pair_interval_s`, holds `init_min_matches` points, and its translation points
where the camera moved.

`slow-start` (seed 1, speed 1) creeps for its first seconds. Before, features were followed
from frame 0 for 4.1 s until a pair passed its checks with 61 essential-matrix inliers: the
gyroscope's rotation, its bias not yet known, could then be 24° off and still agree, and
the pair's translation came out 97° from the true one. The map grew from it at a shrinking
scale until tracking was lost (10 frames, a new map segment; ATE 20.9 cm over 30 s). The
2 s cap alone moved the pair (2.05-4.05 s, 61 inliers) and left it 88° off; ORB-SLAM's 100
points for a monocular start refuse such a pair. Good pairs on the rendered scenes hold
168-889."""

from __future__ import annotations

import numpy as np

from backend.frontend.segmenters import SegmenterKind
from backend.pipeline.factory import EngineConfig, Mode, make_engine
from backend.pipeline.vio_engine import VioEngine


def _camera_pose(engine: VioEngine, stamp_ns: int) -> tuple[np.ndarray, np.ndarray]:
    """The true `R_world_camera`, `t_world_camera` (m) of the rectified left camera at `stamp_ns`."""
    trajectory = engine.data_source.trajectory
    t = np.array([stamp_ns * 1e-9])
    R_wb, p_wb = trajectory.rotation(t)[0], trajectory.position(t)[0]
    T_bc = engine.T_body_camera
    return R_wb @ T_bc[:3, :3], p_wb + R_wb @ T_bc[:3, 3]


def test_a_creeping_start_pairs_frames_at_most_the_cap_apart_and_gets_the_direction() -> None:
    engine = make_engine(EngineConfig(scene="slow-start", seed=1, speed=1.0, duration_s=12.0, mode=Mode.VIO, segmenter=SegmenterKind.ORACLE, variant="P-wo"))
    assert isinstance(engine, VioEngine)
    cap_s = engine.settings.init_max_pair_interval_s
    assert cap_s == 2.0 and engine.settings.init_min_matches == 100
    messages: list[str] = []
    for _ in range(40):
        snapshot = engine.step()
        messages += engine.core.messages
        if snapshot.tracking is not None and snapshot.tracking.keyframe_reason == "initial pair":
            break
    else:
        raise AssertionError(f"no initial pair in 40 keyframes: {engine.start.status}")
    assert any("no initial pair within 2 s of the first keyframe; starting again" in m for m in messages)
    k1 = engine.keyframes - 1
    k0 = engine.map.segment_start
    stamps = engine.map.keyframe_stamp_ns
    assert k1 == k0 + 1 and 0 < (int(stamps[k1]) - int(stamps[k0])) * 1e-9 <= cap_s
    # the pair's translation, in the first camera's frame, against the truth's
    R_w0, t_w0 = engine.map.R_world_keyframe[k0], engine.map.t_world_keyframe[k0]
    estimated = R_w0.T @ (engine.map.t_world_keyframe[k1] - t_w0)
    R_true0, t_true0 = _camera_pose(engine, int(stamps[k0]))
    _, t_true1 = _camera_pose(engine, int(stamps[k1]))
    true = R_true0.T @ (t_true1 - t_true0)
    cosine = estimated @ true / (np.linalg.norm(estimated) * np.linalg.norm(true))
    assert np.degrees(np.arccos(np.clip(cosine, -1.0, 1.0))) < 20.0
