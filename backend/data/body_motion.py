"""How a rendered scene's body moves (`Motion`, part of a `Scene`), and the trajectory that
a seed draws from it (`body_trajectory`).

A scene's body either drives around a road loop (`road`, `backend.data.road`: the `street`
scene's car) or, by default, moves along a smooth random path inside the scene's camera
region (`backend.data.motion.random_trajectory`, as every scene before `street`). Either
can be shaken by hand (`shake`) and start with a near-still creep (`slow_start`). The
sequence's `speed` runs the path that many times faster (the random path's frequencies, the
road's speeds); the shake's frequencies and the slow start's seconds stay as they are.
"""

from __future__ import annotations

import dataclasses
from typing import Any

import numpy as np

from backend.data.json_fields import bounded, optional_object, vector
from backend.data.motion import Shake, ShakenTrajectory, SlowStart, Trajectory, WarpedTrajectory, random_trajectory
from backend.data.road import MAX_LOOP_M, MAX_SPEED_MPS, RoadLoop, drive_trajectory

# The random paths' lowest motion frequency at speed 1 (motion.random_trajectory's default).
BASE_FREQUENCY_HZ = 0.04
DEFAULT_REGION = (np.array([0.0, 0.0, 1.4]), np.array([1.0, 1.0, 0.2]))  # where a scene without a camera region moves
_SHAKE_STREAM = 0x5EA4E  # the shake's random stream, apart from the path's and the IMU noise's


@dataclasses.dataclass(frozen=True)
class Motion:
    """The body drives around `road` or (None) wanders along a random path in the scene's
    camera region; `shake` adds a hand-held shake, `slow_start` a near-still start."""

    road: RoadLoop | None = None
    shake: Shake | None = None
    slow_start: SlowStart | None = None


def body_trajectory(motion: Motion, *, rng: np.random.Generator, seed: int, region: tuple[np.ndarray, np.ndarray] | None, speed: float = 1.0) -> Trajectory:
    """`T_world_body(t)` of `motion`: the path drawn from `rng` (the random path's draws come
    first, as they always have, so that the IMU noise drawn after them is unchanged), the
    shake from its own stream of `seed`. `region`: the scene's camera region (centre,
    half extent; metres), where a random path moves."""
    if motion.road is None:
        centre, half = region if region is not None else DEFAULT_REGION
        path: Trajectory = random_trajectory(rng, centre=np.asarray(centre, float), half_extent=np.asarray(half, float), height=0.0, base_frequency_hz=BASE_FREQUENCY_HZ * speed)
    else:
        path = drive_trajectory(motion.road, rng, speed=speed)
    if motion.slow_start is not None:
        path = WarpedTrajectory(path, motion.slow_start)
    if motion.shake is not None:
        path = ShakenTrajectory(path, motion.shake.trajectory(np.random.default_rng([seed, _SHAKE_STREAM])))
    return path


# ----------------------------------------------------------------------------- JSON


def motion_to_dict(motion: Motion) -> dict[str, Any]:
    """{"road": null | {"straights_m": [a, b], "corner_m", "origin": [x, y], "speed_mps":
    [in corners, on straights], "height_m"}, "shake": null | {"amplitude_m", "amplitude_deg",
    "band_hz": [low, high]}, "slow_start": null | {"still_s", "ramp_s", "creep"}}."""
    road, shake, slow = motion.road, motion.shake, motion.slow_start
    return {
        "road": None if road is None else {"straights_m": list(road.straights_m), "corner_m": road.corner_m, "origin": list(road.origin), "speed_mps": list(road.speed_mps), "height_m": road.height_m},
        "shake": None if shake is None else {"amplitude_m": shake.amplitude_m, "amplitude_deg": shake.amplitude_deg, "band_hz": list(shake.band_hz)},
        "slow_start": None if slow is None else {"still_s": slow.still_s, "ramp_s": slow.ramp_s, "creep": slow.creep},
    }


def _pair(obj: dict[str, Any], key: str, where: str, *, high: float) -> tuple[float, float]:
    a, b = vector(obj, key, 2, where)
    if not (np.isfinite(a) and np.isfinite(b) and abs(a) <= high and abs(b) <= high):
        raise ValueError(f"{where}.{key}: expected 2 numbers within ±{high:g}")
    return float(a), float(b)


def motion_from_dict(data: Any, where: str = "motion") -> Motion:
    """A motion from `motion_to_dict`'s form (keys may be left out: no road, no shake, no
    slow start); ValueError naming the field when malformed."""
    if not isinstance(data, dict):
        raise ValueError(f"{where}: expected an object with road, shake and slow_start")
    road = shake = slow = None
    part = ""
    try:
        if (r := optional_object(data, "road", where)) is not None:
            part = f"{where}.road"
            road = RoadLoop(
                straights_m=_pair(r, "straights_m", part, high=MAX_LOOP_M),
                corner_m=bounded(r, "corner_m", part, low=1.0, high=MAX_LOOP_M),
                origin=_pair(r, "origin", part, high=MAX_LOOP_M),
                speed_mps=_pair(r, "speed_mps", part, high=MAX_SPEED_MPS),
                height_m=bounded(r, "height_m", part, low=0.0, high=100.0),
            )
        if (s := optional_object(data, "shake", where)) is not None:
            part = f"{where}.shake"
            shake = Shake(
                amplitude_m=bounded(s, "amplitude_m", part, low=0.0, high=1.0),
                amplitude_deg=bounded(s, "amplitude_deg", part, low=0.0, high=30.0),
                band_hz=_pair(s, "band_hz", part, high=50.0),
            )
        if (w := optional_object(data, "slow_start", where)) is not None:
            part = f"{where}.slow_start"
            slow = SlowStart(
                still_s=bounded(w, "still_s", part, low=0.0, high=3600.0),
                ramp_s=bounded(w, "ramp_s", part, low=0.0, high=3600.0, low_open=True),
                creep=bounded(w, "creep", part, low=0.0, high=1.0),
            )
    except ValueError as e:
        message = str(e)
        raise ValueError(message if message.startswith(where) else f"{part}.{message}") from None
    return Motion(road=road, shake=shake, slow_start=slow)
