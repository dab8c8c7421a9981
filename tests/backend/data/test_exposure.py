"""Exposure schedules: the gain holds, steps and ramps as the changes say, repeating."""

from __future__ import annotations

import pytest

from backend.data.exposure import ExposureSchedule, GainChange


def test_gain_holds_steps_and_ramps_and_repeats() -> None:
    schedule = ExposureSchedule(period_s=10.0, changes=(GainChange(at_s=2.0, gain=1.5), GainChange(at_s=5.0, gain=0.5, ramp_s=2.0)))
    # before the first change of a period: the last change's gain (the previous period's)
    assert schedule.gain(0.0) == schedule.gain(1.999) == 0.5
    assert schedule.gain(2.0) == schedule.gain(4.9) == 1.5  # a step
    assert schedule.gain(6.0) == pytest.approx(1.0)  # halfway down the ramp
    assert schedule.gain(7.0) == schedule.gain(9.9) == 0.5
    assert schedule.gain(16.0) == schedule.gain(6.0) and schedule.gain(-4.0) == schedule.gain(6.0)  # repeats, also before 0
    assert ExposureSchedule(period_s=3.0, changes=(GainChange(at_s=1.0, gain=0.7, ramp_s=3.0),)).gain(0.5) == 0.7  # one change: constant


@pytest.mark.parametrize(
    ("changes", "words"),
    [
        ((), "at least one"),
        ((GainChange(3.0, 1.2), GainChange(1.0, 0.8)), "increasing"),
        ((GainChange(1.0, 1.2, ramp_s=5.0), GainChange(3.0, 0.8)), "ramp_s"),
        ((GainChange(12.0, 1.2),), "at_s"),
        ((GainChange(1.0, 0.0),), "gain"),
    ],
)
def test_bad_schedules_are_refused(changes: tuple[GainChange, ...], words: str) -> None:
    with pytest.raises(ValueError, match=words):
        ExposureSchedule(period_s=10.0, changes=changes)
