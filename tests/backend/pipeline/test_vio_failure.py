"""The VIO's failure detection and restart (VioSettings' failure checks): an implausible
inertial state after a window solve starts a new map segment from the last good keyframe's
pose, and the start that follows goes on from there instead of taking the ground truth."""

from __future__ import annotations

import numpy as np
import pytest

from backend.frontend.segmenters import SegmenterKind
from backend.pipeline.factory import EngineConfig, Mode, make_engine
from backend.pipeline.vio_engine import VioEngine


def _initialized_engine() -> VioEngine:
    """`room` at twice the speed with the oracle planes, stepped until the IMU is aligned."""
    engine = make_engine(EngineConfig(scene="room", mode=Mode.VIO, speed=2.0, duration_s=8.0, segmenter=SegmenterKind.ORACLE, variant="P-wo"))
    assert isinstance(engine, VioEngine)
    for _ in range(60):
        engine.step()
        if engine.inertial.initialized:
            return engine
    pytest.fail("the VIO did not initialize within 60 keyframes")


def test_an_implausible_bias_or_jump_is_a_failure() -> None:
    engine = _initialized_engine()
    engine.step()
    k = engine.keyframes - 1
    assert engine._failure(k) == ""
    bias = engine.inertial.bias[k].copy()
    engine.inertial.bias[k][:3] = [3.0, 0.0, 0.0]
    assert "accelerometer bias" in engine._failure(k)
    engine.inertial.bias[k] = bias.copy()
    engine.inertial.bias[k][3:] = [0.0, 0.0, 2.0]
    assert "gyroscope bias" in engine._failure(k)
    engine.inertial.bias[k] = bias
    t = engine.map.t_world_keyframe[k].copy()
    engine.map.t_world_keyframe[k] = t + np.array([100.0, 0.0, 0.0])
    assert "speed" in engine._failure(k) or "jump" in engine._failure(k)
    engine.map.t_world_keyframe[k] = t
    engine.inertial.velocity[k] = np.array([np.nan, 0.0, 0.0])
    assert engine._failure(k) == "non-finite state"


def test_a_failure_restarts_from_the_last_keyframe_and_not_from_the_truth(monkeypatch: pytest.MonkeyPatch) -> None:
    engine = _initialized_engine()
    engine.step()
    fail_once = iter(["a test failure"])
    monkeypatch.setattr(engine, "_failure", lambda k: next(fail_once, ""))
    snapshot = engine.step()
    k = engine.keyframes - 1
    assert snapshot.tracking is not None and snapshot.tracking.reinitializations == 1
    assert "VIO failure (a test failure)" in snapshot.message
    assert not engine.inertial.initialized and engine.map.segment_start == k + 1
    R_before, t_before = engine.map.R_world_keyframe[k - 1].copy(), engine.map.t_world_keyframe[k - 1].copy()
    snapshot = engine.step()
    s0 = engine.map.segment_start
    assert snapshot.tracking is not None and snapshot.tracking.keyframe_reason == "restart after a failure"
    assert np.allclose(engine.map.R_world_keyframe[s0], R_before) and np.allclose(engine.map.t_world_keyframe[s0], t_before)
    for _ in range(60):
        engine.step()
        if engine.inertial.initialized:
            break
    assert engine.inertial.initialized, engine.start.status
    # The new segment's start kept its first keyframe where the failure left it (yaw and
    # position; roll and pitch come from the aligned gravity).
    assert np.linalg.norm(engine.map.t_world_keyframe[s0] - t_before) < 1e-6
