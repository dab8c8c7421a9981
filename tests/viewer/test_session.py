"""Stepping ahead is invisible except in time: what Step shows after a step computed ahead,
and what a variant switch, the A/B run or Reset give after one was put aside, are the
snapshots of a session that never steps ahead; an export of the newest keyframe leaves out
the frames of the step kept aside; the end of the sequence found ahead comes with Step."""

from __future__ import annotations

import numpy as np
import pytest

from backend.optim.variant import Variant
from backend.pipeline.engine import EndOfSequence
from backend.pipeline.factory import EngineConfig, make_engine
from backend.pipeline.sim_engine import SimEngine, SimSettings
from backend.pipeline.snapshot import Snapshot
from viewer.session import Session


def _same(a: Snapshot, b: Snapshot) -> None:
    assert (a.keyframe, a.variant) == (b.keyframe, b.variant)
    np.testing.assert_array_equal(a.estimate.t_world_camera, b.estimate.t_world_camera)
    np.testing.assert_array_equal(a.estimate.R_world_camera, b.estimate.R_world_camera)
    assert a.report.final_cost == b.report.final_cost


def _busy(_: str) -> None:
    pass


def _sim_session() -> Session:
    return Session(SimEngine(SimSettings(window=4, max_iterations=3)), keep=100)


def test_a_users_session_is_the_same_with_steps_computed_ahead() -> None:
    plain, ahead = _sim_session(), _sim_session()

    def both(action):  # the same action on both; the second session steps ahead after each
        out = action(plain), action(ahead)
        ahead.step_ahead()
        assert ahead.has_ahead
        return out

    for _ in range(4):
        a, b = both(lambda s: s.step().snapshot)
        _same(a, b)
    a, b = both(lambda s: s.switch_variant(Variant.P_WO, busy=_busy))  # the step aside is put back first
    _same(a, b)
    for _ in range(2):
        a, b = both(lambda s: s.step().snapshot)
        _same(a, b)
        assert a.variant == Variant.P_WO
    both(lambda s: s.start_ab(Variant.PL_WO))
    for _ in range(2):
        a, b = both(lambda s: s.step())
        _same(a.snapshot, b.snapshot)
        _same(a.other, b.other)
    a, b = both(lambda s: s.switch_variant(Variant.PL_W, busy=_busy))
    _same(a, b)
    assert plain.keyframes == ahead.keyframes == 8
    both(lambda s: s.reset())
    assert ahead.keyframes == 0
    a, b = both(lambda s: s.step().snapshot)
    _same(a, b)


def test_the_end_of_the_sequence_found_ahead_comes_with_step() -> None:
    session = Session(make_engine(EngineConfig(scene="room", duration_s=3.0)), keep=100)
    steps = 0
    while True:
        session.step_ahead()
        try:
            session.step()
        except EndOfSequence:
            break
        steps += 1
    assert steps >= 2 and session.keyframes == steps
    with pytest.raises(EndOfSequence):
        session.step()  # still the end, whether found ahead or in place


def test_the_export_of_the_newest_keyframe_leaves_out_the_step_aside() -> None:
    session = Session(make_engine(EngineConfig(scene="room", duration_s=4.0)), keep=100)
    for _ in range(2):
        session.step()
    before = session.frame_trajectory()
    assert before is not None
    session.step_ahead()
    assert session.has_ahead
    aside = session.frame_trajectory()
    assert aside is not None
    np.testing.assert_array_equal(aside.frame, before.frame)
    session.cancel_ahead()
    after = session.frame_trajectory()
    assert after is not None
    np.testing.assert_array_equal(after.frame, before.frame)  # put back: the engine is where the step left it
