"""A car driving around a closed road loop: the `street` scene's motion.

The loop (`RoadLoop`) is a rectangle of four straights with rounded corners, driven
counter-clockwise in the world's xy plane (z = 0 is the road). Each corner turns 90° left
over `corner_m` metres of arc, its curvature a raised cosine that is 0 where it meets the
straights, so curvature and its rate are continuous. By the loop's half-turn symmetry it
closes exactly, and any duration stays on it, lap after lap.

The car (`DriveTrajectory`) follows the loop's centre line (its right lane) with a speed
that is a function of the arc length s: `speed_mps[1]` on the straights, falling smoothly
(a Gaussian dip of the slowness 1/v around each corner's middle) to `speed_mps[0]` in the
corners. Its time-of-arc `T(s) = ∫ ds / v(s)` has a closed form (error functions), so the
arc length at time t is found by Newton's method to machine precision, and then

- position `p(s)` (the corners' by Gauss-Legendre quadrature of the heading, exact to
  ~1e-13 m), velocity `p'(s) ṡ`, acceleration `p''(s) ṡ² + p'(s) s̈`: C2, so the simulated
  IMU is consistent with it;
- yaw is the road's heading (no sideways slip: the velocity lies along the body's x axis
  up to the small pitch and roll); roll leans out of a turn in proportion to the lateral
  acceleration (`ROLL_PER_MPS2`), pitch dives when braking and squats when accelerating
  (`PITCH_PER_MPS2`), plus a suspension bounce: height, pitch and roll wander by about a
  centimetre and a few tenths of a degree over wavelengths of 5–25 m of road.
"""

from __future__ import annotations

import dataclasses
import functools
import math

import numpy as np
from scipy.special import erf

from backend.data.motion import ypr_rotation

ROLL_PER_MPS2 = np.deg2rad(0.5)  # rad of roll per m/s² of lateral acceleration (a car's roll gradient)
PITCH_PER_MPS2 = np.deg2rad(0.3)  # rad of pitch per m/s² of longitudinal acceleration
BOUNCE_HEIGHT_M = 0.012  # the suspension's height excursion bound (m)
BOUNCE_PITCH_RAD = np.deg2rad(0.3)
BOUNCE_ROLL_RAD = np.deg2rad(0.15)
MAX_LOOP_M = 1e4
MAX_SPEED_MPS = 100.0
_GAUSS_NODES, _GAUSS_WEIGHTS = np.polynomial.legendre.leggauss(24)


@dataclasses.dataclass(frozen=True)
class RoadLoop:
    """The loop: from `origin` (world xy, metres) a straight of `straights_m[0]` heading +x,
    a corner, `straights_m[1]` heading +y, a corner, `straights_m[0]` heading -x, a corner,
    `straights_m[1]` heading -y and the last corner back to `origin`; corners `corner_m`
    metres of arc. The body drives it at `height_m` above the road at `speed_mps` = (in the
    corners, on the straights) metres per second."""

    straights_m: tuple[float, float] = (160.0, 100.0)
    corner_m: float = 56.0
    origin: tuple[float, float] = (0.0, 0.0)
    speed_mps: tuple[float, float] = (8.5, 14.0)
    height_m: float = 0.85

    def __post_init__(self) -> None:
        if not (len(self.straights_m) == 2 and all(math.isfinite(a) and 0 <= a <= MAX_LOOP_M for a in self.straights_m)):
            raise ValueError(f"straights_m: expected two lengths in [0, {MAX_LOOP_M:g}] metres")
        if not (math.isfinite(self.corner_m) and 1.0 <= self.corner_m <= MAX_LOOP_M):
            raise ValueError(f"corner_m: must be in [1, {MAX_LOOP_M:g}] metres")
        if not (len(self.origin) == 2 and all(math.isfinite(x) and abs(x) <= MAX_LOOP_M for x in self.origin)):
            raise ValueError(f"origin: expected two coordinates within ±{MAX_LOOP_M:g} metres")
        slow, fast = self.speed_mps
        if not (math.isfinite(slow) and math.isfinite(fast) and 0.1 <= slow <= fast <= MAX_SPEED_MPS):
            raise ValueError(f"speed_mps: expected [in corners, on straights] with 0.1 <= corners <= straights <= {MAX_SPEED_MPS:g} m/s")
        if not (math.isfinite(self.height_m) and 0 <= self.height_m <= 100.0):
            raise ValueError("height_m: must be in [0, 100] metres")

    # ------------------------------------------------------------------ geometry by arc length

    @functools.cached_property
    def corner_offset_m(self) -> float:
        """How far a corner carries the car along and across its entry heading (equal, by symmetry)."""
        return float(self._corner_displacement(np.array([self.corner_m]))[0, 0])

    @functools.cached_property
    def _segments(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """start s (8,), length (8,), start point (8, 2), start heading (8,), is corner (8,)."""
        a, b = self.straights_m
        c, d = self.corner_m, self.corner_offset_m
        lengths = np.array([a, c, b, c, a, c, b, c])
        starts = np.concatenate([[0.0], np.cumsum(lengths)[:-1]])
        heading = np.repeat(np.arange(4) * (np.pi / 2.0), 2)
        is_corner = np.arange(8) % 2 == 1
        points = [np.asarray(self.origin, dtype=float)]
        for k in range(7):
            h = heading[k]
            step = np.array([lengths[k], 0.0]) if not is_corner[k] else np.array([d, d])
            points.append(points[-1] + _rotate(step, h))
        return starts, lengths, np.array(points), heading, is_corner

    @property
    def length_m(self) -> float:
        """The loop's length (m)."""
        return float(2.0 * sum(self.straights_m) + 4.0 * self.corner_m)

    def straights(self) -> list[tuple[np.ndarray, float, float]]:
        """The four straights in driving order: start point (2,) world xy, heading (rad),
        length (m)."""
        _, lengths, points, heading, _ = self._segments
        return [(points[k].copy(), float(heading[k]), float(lengths[k])) for k in range(0, 8, 2)]

    @property
    def corner_starts_m(self) -> np.ndarray:
        """Arc length (m) where each of the four corners begins."""
        return self._segments[0][1::2]

    def _locate(self, s: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Segment index, distance into it (m) and completed laps of arc lengths s (N,)."""
        s = np.asarray(s, dtype=float)
        laps = np.floor(s / self.length_m)
        r = s - laps * self.length_m
        starts = self._segments[0]
        k = np.clip(np.searchsorted(starts, r, side="right") - 1, 0, 7)
        return k, r - starts[k], laps

    def _corner_heading(self, x: np.ndarray) -> np.ndarray:
        """Heading gained x metres into a corner (rad)."""
        c = self.corner_m
        return (np.pi / 2.0) * (x / c - np.sin(2.0 * np.pi * x / c) / (2.0 * np.pi))

    def _corner_displacement(self, x: np.ndarray) -> np.ndarray:
        """Displacement (N, 2) x metres into a corner entered heading +x (Gauss-Legendre)."""
        xi = 0.5 * x[:, None] * (_GAUSS_NODES[None, :] + 1.0)
        psi = self._corner_heading(xi)
        w = 0.5 * x[:, None] * _GAUSS_WEIGHTS[None, :]
        return np.stack([np.sum(w * np.cos(psi), axis=1), np.sum(w * np.sin(psi), axis=1)], axis=1)

    def heading(self, s: np.ndarray) -> np.ndarray:
        """Heading (N,) rad at arc lengths s, continuous over laps (2π more per lap)."""
        k, x, laps = self._locate(s)
        _, _, _, h0, corner = self._segments
        return h0[k] + np.where(corner[k], self._corner_heading(x), 0.0) + 2.0 * np.pi * laps

    def curvature(self, s: np.ndarray) -> np.ndarray:
        """Curvature (N,) 1/m at arc lengths s (positive: turning left)."""
        k, x, _ = self._locate(s)
        c = self.corner_m
        return np.where(self._segments[4][k], (np.pi / (2.0 * c)) * (1.0 - np.cos(2.0 * np.pi * x / c)), 0.0)

    def curvature_rate(self, s: np.ndarray) -> np.ndarray:
        """d curvature / ds (N,), 1/m²."""
        k, x, _ = self._locate(s)
        c = self.corner_m
        return np.where(self._segments[4][k], (np.pi / c) ** 2 * np.sin(2.0 * np.pi * x / c), 0.0)

    def point(self, s: np.ndarray) -> np.ndarray:
        """World xy (N, 2) of the centre line at arc lengths s."""
        k, x, _ = self._locate(s)
        _, _, p0, h0, corner = self._segments
        local = np.stack([x, np.zeros_like(x)], axis=1)
        if np.any(corner[k]):
            local[corner[k]] = self._corner_displacement(x[corner[k]])
        return p0[k] + _rotate_many(local, h0[k])


def _rotate(v: np.ndarray, angle: float) -> np.ndarray:
    c, s = math.cos(angle), math.sin(angle)
    return np.array([c * v[0] - s * v[1], s * v[0] + c * v[1]])


def _rotate_many(v: np.ndarray, angle: np.ndarray) -> np.ndarray:
    c, s = np.cos(angle), np.sin(angle)
    return np.stack([c * v[:, 0] - s * v[:, 1], s * v[:, 0] + c * v[:, 1]], axis=1)


@dataclasses.dataclass(frozen=True, eq=False)
class DriveTrajectory:
    """A car on `road`, at arc length `start_s` (m) at t = 0, `speed_scale` times the road's
    speeds; `bounce_*` (3, H) are the suspension's sinusoids of arc length for height (m),
    pitch and roll (rad): amplitudes, wavelengths (m) and phases (rad). A `Trajectory`."""

    road: RoadLoop
    start_s: float
    speed_scale: float
    bounce_amplitude: np.ndarray
    bounce_wavelength_m: np.ndarray
    bounce_phase: np.ndarray

    # ------------------------------------------------------------------ speed along the road

    @functools.cached_property
    def _dips(self) -> np.ndarray:
        """Centres (M,) of the slowness dips: each corner's middle, on the neighbouring laps too."""
        middles = self.road.corner_starts_m + 0.5 * self.road.corner_m
        return (middles[None, :] + self.road.length_m * np.arange(-2, 3)[:, None]).ravel()

    @property
    def _sigma_m(self) -> float:
        return 0.5 * self.road.corner_m

    def _slowness(self, s: np.ndarray, derivative: int = 0) -> np.ndarray:
        """1/v (s/m) at arc lengths s in [0, L) or its derivative in s."""
        slow, fast = self.road.speed_mps
        base, dip = 1.0 / (fast * self.speed_scale), 1.0 / (slow * self.speed_scale) - 1.0 / (fast * self.speed_scale)
        z = (s[:, None] - self._dips[None, :]) / self._sigma_m
        g = np.exp(-0.5 * z**2)
        if derivative == 0:
            return base + dip * g.sum(axis=1)
        return dip * np.sum(-z / self._sigma_m * g, axis=1)

    def _time_within_lap(self, r: np.ndarray) -> np.ndarray:
        """Seconds from arc length 0 to r (N,) in [0, L]: ∫₀ʳ slowness, in closed form."""
        slow, fast = self.road.speed_mps
        base, dip = 1.0 / (fast * self.speed_scale), 1.0 / (slow * self.speed_scale) - 1.0 / (fast * self.speed_scale)
        k = self._sigma_m * math.sqrt(2.0)
        return base * r + dip * self._sigma_m * math.sqrt(np.pi / 2.0) * np.sum(erf((r[:, None] - self._dips) / k) - erf(-self._dips / k), axis=1)

    @functools.cached_property
    def _lap_s(self) -> float:
        """Seconds per lap."""
        return float(self._time_within_lap(np.array([self.road.length_m]))[0])

    @functools.cached_property
    def _table(self) -> tuple[np.ndarray, np.ndarray]:
        r = np.linspace(0.0, self.road.length_m, int(self.road.length_m) + 2)
        return self._time_within_lap(r), r

    def _time_of(self, s: np.ndarray) -> np.ndarray:
        laps = np.floor(s / self.road.length_m)
        return laps * self._lap_s + self._time_within_lap(s - laps * self.road.length_m)

    def arc_length(self, t: np.ndarray) -> np.ndarray:
        """Arc length s (N,) metres along the road at times t (N,) seconds."""
        target = np.asarray(t, dtype=float) + self._time_of(np.array([self.start_s]))[0]
        laps = np.floor(target / self._lap_s)
        rest = target - laps * self._lap_s
        times, table = self._table
        r = np.interp(rest, times, table)
        for _ in range(6):  # Newton: T(r) = rest, T' = slowness > 0
            r = np.clip(r - (self._time_within_lap(r) - rest) / self._slowness(r), 0.0, self.road.length_m)
        return laps * self.road.length_m + r

    def _kinematics(self, t: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """s, ṡ (m/s), s̈ (m/s²) at times t, and s within its lap."""
        s = self.arc_length(t)
        r = s - np.floor(s / self.road.length_m) * self.road.length_m
        w = self._slowness(r)
        return s, 1.0 / w, -self._slowness(r, 1) / w**3, r

    def speed(self, t: np.ndarray) -> np.ndarray:
        """Speed along the road (N,) m/s."""
        return self._kinematics(t)[1]

    # ------------------------------------------------------------------ the suspension

    def _bounce(self, s: np.ndarray, derivative: int = 0) -> np.ndarray:
        """Height (m), pitch, roll (rad) offsets (N, 3) at arc lengths s, or d/ds, d²/ds²."""
        k = 2.0 * np.pi / self.bounce_wavelength_m
        arg = k[None] * s[:, None, None] + self.bounce_phase[None]
        a = self.bounce_amplitude[None]
        if derivative == 0:
            return np.sum(a * np.sin(arg), axis=2)
        if derivative == 1:
            return np.sum(a * k[None] * np.cos(arg), axis=2)
        return np.sum(-a * k[None] ** 2 * np.sin(arg), axis=2)

    # ------------------------------------------------------------------ Trajectory

    def position(self, t: np.ndarray) -> np.ndarray:
        s = self.arc_length(t)
        return np.column_stack([self.road.point(s), self.road.height_m + self._bounce(s)[:, 0]])

    def velocity(self, t: np.ndarray) -> np.ndarray:
        s, v, _, _ = self._kinematics(t)
        h = self.road.heading(s)
        return np.column_stack([np.cos(h) * v, np.sin(h) * v, self._bounce(s, 1)[:, 0] * v])

    def acceleration(self, t: np.ndarray) -> np.ndarray:
        s, v, a, _ = self._kinematics(t)
        h, kappa = self.road.heading(s), self.road.curvature(s)
        tangent, normal = np.column_stack([np.cos(h), np.sin(h)]), np.column_stack([-np.sin(h), np.cos(h)])
        xy = normal * (kappa * v**2)[:, None] + tangent * a[:, None]
        z = self._bounce(s, 2)[:, 0] * v**2 + self._bounce(s, 1)[:, 0] * a
        return np.column_stack([xy, z])

    def rotation(self, t: np.ndarray) -> np.ndarray:
        s, v, a, _ = self._kinematics(t)
        bounce = self._bounce(s)
        yaw = self.road.heading(s)
        pitch = -PITCH_PER_MPS2 * a + bounce[:, 1]
        roll = ROLL_PER_MPS2 * self.road.curvature(s) * v**2 + bounce[:, 2]
        return ypr_rotation(np.column_stack([yaw, pitch, roll]))


def drive_trajectory(road: RoadLoop, rng: np.random.Generator, *, speed: float = 1.0, harmonics: int = 3) -> DriveTrajectory:
    """A drive around `road` drawn from `rng`: it starts 30–60 m before one of the four
    corners (so a turn comes within seconds), with a random suspension bounce; `speed`
    scales the road's speeds."""
    corner = int(rng.integers(4))
    lead = rng.uniform(30.0, 60.0)
    start = float((road.corner_starts_m[corner] - lead) % road.length_m)
    wavelength = np.stack([rng.uniform(6.0, 25.0, harmonics), rng.uniform(5.0, 20.0, harmonics), rng.uniform(5.0, 20.0, harmonics)])
    weights = rng.uniform(0.5, 1.0, (3, harmonics))
    weights /= weights.sum(axis=1, keepdims=True)
    amplitude = weights * np.array([BOUNCE_HEIGHT_M, BOUNCE_PITCH_RAD, BOUNCE_ROLL_RAD])[:, None]
    phase = rng.uniform(0.0, 2.0 * np.pi, (3, harmonics))
    return DriveTrajectory(road=road, start_s=start, speed_scale=speed, bounce_amplitude=amplitude, bounce_wavelength_m=wavelength, bounce_phase=phase)
