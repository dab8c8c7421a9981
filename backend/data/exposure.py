"""Auto-exposure-like gain over time for rendered scenes (`exposure`): the image intensities
are multiplied by a gain that holds, jumps (a step) or ramps linearly to a new value, on a
schedule that repeats every `period_s` seconds."""

from __future__ import annotations

import bisect
import dataclasses
import math
from typing import Any

from backend.data.json_fields import bounded

MAX_GAIN = 10.0
MAX_PERIOD_S = 3600.0


@dataclasses.dataclass(frozen=True)
class GainChange:
    """At `at_s` seconds into the schedule's period the gain starts moving to `gain`
    (relative: 1 is the scene's own exposure), linearly over `ramp_s` seconds (0: a step)."""

    at_s: float
    gain: float
    ramp_s: float = 0.0


@dataclasses.dataclass(frozen=True)
class ExposureSchedule:
    """Gain changes (sorted by `at_s`, each in [0, period_s), each ramp over before the next
    change starts) repeating every `period_s` seconds; before the first change of a period
    the gain is the last change's."""

    period_s: float
    changes: tuple[GainChange, ...]

    def __post_init__(self) -> None:
        if not (math.isfinite(self.period_s) and 0 < self.period_s <= MAX_PERIOD_S):
            raise ValueError(f"period_s: must be in (0, {MAX_PERIOD_S:g}] seconds")
        if not self.changes:
            raise ValueError("changes: expected at least one gain change")
        if any(b.at_s <= a.at_s for a, b in zip(self.changes, self.changes[1:])):
            raise ValueError("changes: expected increasing at_s")
        for i, c in enumerate(self.changes):
            if not (math.isfinite(c.at_s) and 0 <= c.at_s < self.period_s):
                raise ValueError(f"changes[{i}].at_s: must be in [0, period_s)")
            if not (math.isfinite(c.gain) and 0 < c.gain <= MAX_GAIN):
                raise ValueError(f"changes[{i}].gain: must be in (0, {MAX_GAIN:g}]")
            following = self.changes[i + 1].at_s if i + 1 < len(self.changes) else self.changes[0].at_s + self.period_s
            if not (math.isfinite(c.ramp_s) and 0 <= c.ramp_s <= following - c.at_s):
                raise ValueError(f"changes[{i}].ramp_s: must be >= 0 and end before the next change starts")

    def gain(self, t_s: float) -> float:
        """The gain at time `t_s` (seconds)."""
        phase = math.fmod(t_s, self.period_s)
        if phase < 0:
            phase += self.period_s
        starts = [c.at_s for c in self.changes]
        i = bisect.bisect_right(starts, phase) - 1  # -1: before the first change, in the last one's
        change = self.changes[i]
        since = phase - change.at_s if i >= 0 else phase + self.period_s - change.at_s
        before = self.changes[(i - 1) % len(self.changes)].gain
        if change.ramp_s > 0 and since < change.ramp_s:
            return before + (change.gain - before) * since / change.ramp_s
        return change.gain


def exposure_to_dict(schedule: ExposureSchedule) -> dict[str, Any]:
    """{"period_s": seconds, "changes": [{"at_s", "gain", "ramp_s"}, ...]}."""
    return {"period_s": schedule.period_s, "changes": [{"at_s": c.at_s, "gain": c.gain, "ramp_s": c.ramp_s} for c in schedule.changes]}


def exposure_from_dict(data: Any, where: str = "exposure") -> ExposureSchedule:
    """A schedule from `exposure_to_dict`'s form; ValueError naming the field when malformed."""
    if not isinstance(data, dict):
        raise ValueError(f"{where}: expected an object with period_s and changes, or null")
    items = data.get("changes")
    if not (isinstance(items, list) and items and all(isinstance(x, dict) for x in items)):
        raise ValueError(f"{where}.changes: expected a list of objects with at_s, gain and ramp_s")
    changes = tuple(
        GainChange(
            at_s=bounded(c, "at_s", f"{where}.changes[{i}]", low=0.0, high=MAX_PERIOD_S),
            gain=bounded(c, "gain", f"{where}.changes[{i}]", low=0.0, high=MAX_GAIN, low_open=True),
            ramp_s=bounded(c, "ramp_s", f"{where}.changes[{i}]", low=0.0, high=MAX_PERIOD_S, default=0.0),
        )
        for i, c in enumerate(items)
    )
    try:
        return ExposureSchedule(period_s=bounded(data, "period_s", where, low=0.0, high=MAX_PERIOD_S, low_open=True), changes=changes)
    except ValueError as e:
        raise ValueError(f"{where}.{e}") from None
