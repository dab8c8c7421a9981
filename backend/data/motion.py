"""Smooth body trajectories and IMU measurements consistent with them.

A trajectory (`Trajectory`) is `T_world_body(t)` (world z up, gravity -z, metres, seconds)
with analytic position derivatives. `SmoothTrajectory`: positions and yaw/pitch/roll are
sums of sinusoids, so speed and turn rate vary smoothly, like a hand-held or MAV camera.
Two wrappers change any trajectory: `ShakenTrajectory` adds a hand-held shake (`Shake`: a
few centimetre-and-degree sinusoids at 2–6 Hz), `WarpedTrajectory` runs its time slowly at
first (`SlowStart`: a near-still creep, then the usual pace). A car's trajectory around a
road loop is `backend.data.road.DriveTrajectory`.

IMU samples follow the discrete model of preintegration (gtsam's): sample k, at time t_k,
holds the gyro and accelerometer readings taken as constant over [t_k, t_{k+1}]. They are
built so that this model reproduces the trajectory at every sample time:

- gyro `ω_k = Log(R_kᵀ R_{k+1}) / Δt`, the exact rotation increment;
- accelerometer `a_k = R_kᵀ ((v_{k+1} - v_k) / Δt - g)`: the world acceleration that
  carries the true velocity from v_k to v_{k+1}, rotated by the attitude at t_k (the
  model rotates the whole interval's acceleration by R_k). Positions then follow the
  trapezoid rule, whose error is O(Δt²) of the jerk: micrometres over 10 s at 200 Hz.

Noise (EuRoC's `imu0/sensor.yaml` convention): white noise densities (per √Hz) become
per-sample standard deviations `σ·√rate`; biases follow a random walk with densities per
√Hz, `σ_b·√Δt` per sample.
"""

from __future__ import annotations

import dataclasses
import math
from typing import Protocol

import numpy as np

from backend.geometry import so3

GRAVITY_WORLD = np.array([0.0, 0.0, -9.81])  # m/s², world z up


class Trajectory(Protocol):
    """`T_world_body(t)` and its derivatives at times t (N,) seconds."""

    def position(self, t: np.ndarray) -> np.ndarray:
        """`p_world_body` (N, 3), metres."""
        ...

    def velocity(self, t: np.ndarray) -> np.ndarray:
        """World velocity (N, 3), m/s."""
        ...

    def acceleration(self, t: np.ndarray) -> np.ndarray:
        """World acceleration (N, 3), m/s² (without gravity)."""
        ...

    def rotation(self, t: np.ndarray) -> np.ndarray:
        """`R_world_body` (N, 3, 3)."""
        ...


def ypr_rotation(ypr: np.ndarray) -> np.ndarray:
    """`R = Rz(yaw) Ry(pitch) Rx(roll)` (N, 3, 3) of angles (N, 3) in radians."""
    z = np.array([0.0, 0.0, 1.0])
    y = np.array([0.0, 1.0, 0.0])
    x = np.array([1.0, 0.0, 0.0])
    return so3.exp(ypr[:, :1] * z) @ so3.exp(ypr[:, 1:2] * y) @ so3.exp(ypr[:, 2:3] * x)


@dataclasses.dataclass(frozen=True)
class SmoothTrajectory:
    """`x(t) = offset + Σ_i amplitude_i sin(2π frequency_i t + phase_i)` for each of the six
    channels: position x, y, z (m) and yaw, pitch, roll (rad). Arrays are (6, H)
    (H harmonics); `offset` is (6,). `R = Rz(yaw) Ry(pitch) Rx(roll)` is `R_world_body`."""

    offset: np.ndarray
    amplitude: np.ndarray
    frequency_hz: np.ndarray
    phase: np.ndarray

    def _channels(self, t: np.ndarray, derivative: int = 0) -> np.ndarray:
        """Channel values (or their time derivatives) at times t (N,): (N, 6)."""
        t = np.asarray(t, dtype=float)[:, None, None]
        w = 2.0 * np.pi * self.frequency_hz[None]
        arg = w * t + self.phase[None]
        if derivative == 0:
            return self.offset[None] + np.sum(self.amplitude[None] * np.sin(arg), axis=2)
        if derivative == 1:
            return np.sum(self.amplitude[None] * w * np.cos(arg), axis=2)
        if derivative == 2:
            return np.sum(-self.amplitude[None] * w**2 * np.sin(arg), axis=2)
        raise ValueError("derivative must be 0, 1 or 2")

    def position(self, t: np.ndarray) -> np.ndarray:
        """`p_world_body` (N, 3), metres."""
        return self._channels(t)[:, :3]

    def velocity(self, t: np.ndarray) -> np.ndarray:
        """World velocity (N, 3), m/s."""
        return self._channels(t, 1)[:, :3]

    def acceleration(self, t: np.ndarray) -> np.ndarray:
        """World acceleration (N, 3), m/s² (without gravity)."""
        return self._channels(t, 2)[:, :3]

    def rotation(self, t: np.ndarray) -> np.ndarray:
        """`R_world_body` (N, 3, 3)."""
        return ypr_rotation(self._channels(t)[:, 3:])


def random_trajectory(
    rng: np.random.Generator,
    *,
    centre: np.ndarray = np.zeros(3),
    half_extent: np.ndarray = np.array([1.5, 1.5, 0.3]),
    height: float = 1.4,
    yaw_range: float = np.pi,
    tilt: float = np.deg2rad(8.0),
    harmonics: int = 3,
    base_frequency_hz: float = 0.04,
) -> SmoothTrajectory:
    """A smooth random trajectory inside `centre ± half_extent` (z around `height`): three
    harmonics per channel at incommensurate frequencies (base, ×≈1.7, ×≈2.9) so that speed
    and turn rate vary; yaw sweeps ±`yaw_range`, pitch and roll stay within ±`tilt`."""
    ratios = np.array([1.0, 1.71, 2.93])[:harmonics]
    frequency = base_frequency_hz * ratios[None, :] * rng.uniform(0.8, 1.25, (6, harmonics))
    weights = rng.uniform(0.5, 1.0, (6, harmonics)) / ratios[None, :]
    weights /= weights.sum(axis=1, keepdims=True)
    scale = np.concatenate([half_extent, [yaw_range, tilt, tilt]])
    amplitude = weights * scale[:, None]
    phase = rng.uniform(0.0, 2.0 * np.pi, (6, harmonics))
    offset = np.concatenate([centre + np.array([0.0, 0.0, height]), rng.uniform(-np.pi, np.pi, 1), [0.0, 0.0]])
    return SmoothTrajectory(offset=offset, amplitude=amplitude, frequency_hz=frequency, phase=phase)


MAX_SHAKE_M = 1.0
MAX_SHAKE_DEG = 30.0
MAX_SHAKE_HZ = 50.0


@dataclasses.dataclass(frozen=True)
class Shake:
    """A hand-held shake: each position axis moves within ±`amplitude_m` metres and each
    angle (yaw, pitch, roll) within ±`amplitude_deg` degrees, as sums of three sinusoids at
    random frequencies in `band_hz` (Hz), the faster ones smaller."""

    amplitude_m: float = 0.008
    amplitude_deg: float = 1.5
    band_hz: tuple[float, float] = (2.0, 6.0)

    def __post_init__(self) -> None:
        if not (math.isfinite(self.amplitude_m) and 0 <= self.amplitude_m <= MAX_SHAKE_M):
            raise ValueError(f"amplitude_m: must be in [0, {MAX_SHAKE_M:g}] metres")
        if not (math.isfinite(self.amplitude_deg) and 0 <= self.amplitude_deg <= MAX_SHAKE_DEG):
            raise ValueError(f"amplitude_deg: must be in [0, {MAX_SHAKE_DEG:g}] degrees")
        low, high = self.band_hz
        if not (math.isfinite(low) and math.isfinite(high) and 0 < low <= high <= MAX_SHAKE_HZ):
            raise ValueError(f"band_hz: expected [low, high] with 0 < low <= high <= {MAX_SHAKE_HZ:g} Hz")

    def trajectory(self, rng: np.random.Generator, *, harmonics: int = 3) -> SmoothTrajectory:
        """The shake alone: a `SmoothTrajectory` about zero (position and angles), drawn from `rng`."""
        low, high = self.band_hz
        frequency = rng.uniform(low, high, (6, harmonics))
        weights = rng.uniform(0.5, 1.0, (6, harmonics)) * low / frequency
        weights /= weights.sum(axis=1, keepdims=True)
        scale = np.array([self.amplitude_m] * 3 + [np.deg2rad(self.amplitude_deg)] * 3)
        phase = rng.uniform(0.0, 2.0 * np.pi, (6, harmonics))
        return SmoothTrajectory(offset=np.zeros(6), amplitude=weights * scale[:, None], frequency_hz=frequency, phase=phase)


@dataclasses.dataclass(frozen=True)
class ShakenTrajectory:
    """`base` with `shake` (a `SmoothTrajectory` about zero) added: its positions in the world
    frame, its angles as a rotation in the body frame (`R = R_base R_shake`)."""

    base: Trajectory
    shake: SmoothTrajectory

    def position(self, t: np.ndarray) -> np.ndarray:
        return self.base.position(t) + self.shake.position(t)

    def velocity(self, t: np.ndarray) -> np.ndarray:
        return self.base.velocity(t) + self.shake.velocity(t)

    def acceleration(self, t: np.ndarray) -> np.ndarray:
        return self.base.acceleration(t) + self.shake.acceleration(t)

    def rotation(self, t: np.ndarray) -> np.ndarray:
        return self.base.rotation(t) @ self.shake.rotation(t)


MAX_SLOW_START_S = 3600.0


@dataclasses.dataclass(frozen=True)
class SlowStart:
    """A start that waits: for the first `still_s` seconds the path's own time runs at
    `creep` times the usual pace (a creep of millimetres per second where the path moves
    decimetres per second), then the pace rises to the usual one over `ramp_s` seconds along
    a quintic step, so that velocity and acceleration stay continuous."""

    still_s: float = 3.0
    ramp_s: float = 2.0
    creep: float = 0.01

    def __post_init__(self) -> None:
        if not (math.isfinite(self.still_s) and 0 <= self.still_s <= MAX_SLOW_START_S):
            raise ValueError(f"still_s: must be in [0, {MAX_SLOW_START_S:g}] seconds")
        if not (math.isfinite(self.ramp_s) and 0 < self.ramp_s <= MAX_SLOW_START_S):
            raise ValueError(f"ramp_s: must be in (0, {MAX_SLOW_START_S:g}] seconds")
        if not (math.isfinite(self.creep) and 0 <= self.creep <= 1):
            raise ValueError("creep: must be a fraction in [0, 1]")

    def warp(self, t: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The path's time `τ(t)` at times t (N,) seconds, its rate `dτ/dt` and `d²τ/dt²`."""
        t = np.asarray(t, dtype=float)
        x = np.clip((t - self.still_s) / self.ramp_s, 0.0, 1.0)
        rise = 1.0 - self.creep
        step = x**3 * (10.0 - 15.0 * x + 6.0 * x**2)  # 0 -> 1, flat at both ends
        step_integral = x**4 * (2.5 - 3.0 * x + x**2)  # ∫₀ˣ step, 1/2 at x = 1
        tau = self.creep * t + rise * (self.ramp_s * step_integral + np.maximum(t - self.still_s - self.ramp_s, 0.0))
        rate = self.creep + rise * step
        rate_dot = rise * 30.0 * x**2 * (1.0 - x) ** 2 / self.ramp_s
        return tau, rate, rate_dot


@dataclasses.dataclass(frozen=True)
class WarpedTrajectory:
    """`base` along its own path, its time warped by `slow_start`: the pose at t is base's at τ(t)."""

    base: Trajectory
    slow_start: SlowStart

    def position(self, t: np.ndarray) -> np.ndarray:
        return self.base.position(self.slow_start.warp(t)[0])

    def velocity(self, t: np.ndarray) -> np.ndarray:
        tau, rate, _ = self.slow_start.warp(t)
        return self.base.velocity(tau) * rate[:, None]

    def acceleration(self, t: np.ndarray) -> np.ndarray:
        tau, rate, rate_dot = self.slow_start.warp(t)
        return self.base.acceleration(tau) * (rate**2)[:, None] + self.base.velocity(tau) * rate_dot[:, None]

    def rotation(self, t: np.ndarray) -> np.ndarray:
        return self.base.rotation(self.slow_start.warp(t)[0])


@dataclasses.dataclass(frozen=True)
class ImuData:
    """IMU samples: timestamps (N,) int64 ns; gyro (N, 3) rad/s and accelerometer (N, 3)
    m/s² in the body frame; each held constant until the next sample."""

    timestamp_ns: np.ndarray
    gyro: np.ndarray
    accel: np.ndarray

    def __len__(self) -> int:
        return int(self.timestamp_ns.shape[0])

    def between(self, t0_ns: int, t1_ns: int) -> ImuData:
        """The samples with `t0_ns < t <= t1_ns`."""
        if t1_ns < t0_ns:
            raise ValueError(f"t1_ns {t1_ns} is before t0_ns {t0_ns}")
        begin, end = np.searchsorted(self.timestamp_ns, [t0_ns, t1_ns], side="right")
        return ImuData(self.timestamp_ns[begin:end], self.gyro[begin:end], self.accel[begin:end])


@dataclasses.dataclass(frozen=True)
class ImuNoise:
    """Continuous-time noise densities, EuRoC `imu0/sensor.yaml` values by default."""

    gyroscope_noise_density: float = 1.6968e-04  # rad / s / √Hz
    gyroscope_random_walk: float = 1.9393e-05  # rad / s² / √Hz
    accelerometer_noise_density: float = 2.0000e-3  # m / s² / √Hz
    accelerometer_random_walk: float = 3.0000e-3  # m / s³ / √Hz


def imu_samples(trajectory: Trajectory, *, start_ns: int, end_ns: int, rate_hz: float = 200.0) -> ImuData:
    """Noise-free IMU samples at `rate_hz` from `start_ns` up to `end_ns` (the last sample's
    interval ends at or before `end_ns`), consistent with the discrete preintegration model
    (module docstring)."""
    period_ns = int(round(1e9 / rate_hz))
    stamps = np.arange(start_ns, end_ns + 1, period_ns, dtype=np.int64)
    t = stamps.astype(np.float64) * 1e-9
    dt = period_ns * 1e-9
    R = trajectory.rotation(t)
    v = trajectory.velocity(t)
    gyro = so3.log(np.swapaxes(R[:-1], 1, 2) @ R[1:]) / dt
    a_world = (v[1:] - v[:-1]) / dt - GRAVITY_WORLD
    accel = np.einsum("nji,nj->ni", R[:-1], a_world)
    return ImuData(timestamp_ns=stamps[:-1], gyro=gyro, accel=accel)


def add_imu_noise(
    imu: ImuData, rng: np.random.Generator, *, noise: ImuNoise = ImuNoise(), bias_gyro: np.ndarray | None = None, bias_accel: np.ndarray | None = None
) -> tuple[ImuData, np.ndarray, np.ndarray]:
    """White noise plus random-walk biases (starting at the given biases, zero by default).
    Returns the noisy samples and the true biases per sample, gyro (N, 3) and accel (N, 3)."""
    n = len(imu)
    if n == 0:
        return imu, np.zeros((0, 3)), np.zeros((0, 3))
    dt = float(np.median(np.diff(imu.timestamp_ns))) * 1e-9 if n > 1 else 0.005
    sqrt_rate = np.sqrt(1.0 / dt)
    b_g0 = np.zeros(3) if bias_gyro is None else np.asarray(bias_gyro, dtype=float)
    b_a0 = np.zeros(3) if bias_accel is None else np.asarray(bias_accel, dtype=float)
    walk_g = noise.gyroscope_random_walk * np.sqrt(dt) * rng.standard_normal((n, 3))
    walk_a = noise.accelerometer_random_walk * np.sqrt(dt) * rng.standard_normal((n, 3))
    b_g = b_g0 + np.cumsum(walk_g, axis=0) - walk_g[0]
    b_a = b_a0 + np.cumsum(walk_a, axis=0) - walk_a[0]
    gyro = imu.gyro + b_g + noise.gyroscope_noise_density * sqrt_rate * rng.standard_normal((n, 3))
    accel = imu.accel + b_a + noise.accelerometer_noise_density * sqrt_rate * rng.standard_normal((n, 3))
    return ImuData(imu.timestamp_ns, gyro, accel), b_g, b_a
