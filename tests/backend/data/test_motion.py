"""Smooth trajectories and IMU samples: the derivatives are right, and preintegrating the
noise-free samples with gtsam reproduces the trajectory (issue 4's IMU consistency)."""

from __future__ import annotations

import dataclasses

import gtsam
import numpy as np
import pytest

from backend.data.motion import GRAVITY_WORLD, ImuNoise, Shake, ShakenTrajectory, SlowStart, WarpedTrajectory, add_imu_noise, imu_samples, random_trajectory

DURATION_S = 10.0
DT = 0.005


@pytest.fixture(scope="module")
def trajectory():
    return random_trajectory(np.random.default_rng(3))


def _preintegrate(imu, trajectory, kind: str) -> tuple[float, float, float]:
    """Position (m), velocity (m/s) and rotation (rad) error after predicting over the samples."""
    params = gtsam.PreintegrationParams.MakeSharedU(-GRAVITY_WORLD[2])
    params.setAccelerometerCovariance(1e-6 * np.eye(3))
    params.setGyroscopeCovariance(1e-6 * np.eye(3))
    params.setIntegrationCovariance(1e-8 * np.eye(3))
    pim = getattr(gtsam, kind)(params, gtsam.imuBias.ConstantBias())
    for a, w in zip(imu.accel, imu.gyro):
        pim.integrateMeasurement(a, w, DT)
    t = np.array([imu.timestamp_ns[0], imu.timestamp_ns[-1] + int(DT * 1e9)]) * 1e-9
    R, p, v = trajectory.rotation(t), trajectory.position(t), trajectory.velocity(t)
    end = pim.predict(gtsam.NavState(gtsam.Rot3(R[0]), p[0], v[0]), gtsam.imuBias.ConstantBias())
    rot = np.linalg.norm(gtsam.Rot3.Logmap(gtsam.Rot3(R[1]).between(end.attitude())))
    return float(np.linalg.norm(end.position() - p[1])), float(np.linalg.norm(end.velocity() - v[1])), float(rot)


def test_noise_free_samples_reproduce_the_trajectory_after_10_s(trajectory) -> None:
    imu = imu_samples(trajectory, start_ns=0, end_ns=int(DURATION_S * 1e9))
    assert len(imu) == 2000
    # The motion is not trivial: it moves and turns.
    t = np.linspace(0.0, DURATION_S, 200)
    assert np.max(np.linalg.norm(trajectory.velocity(t), axis=1)) > 0.2
    assert np.max(np.abs(imu.gyro)) > 0.2
    # gtsam's manifold preintegration follows the samples' discrete model exactly.
    dp, dv, dr = _preintegrate(imu, trajectory, "PreintegratedImuMeasurementsManifold")
    assert dp < 1e-5 and dv < 1e-5 and dr < 1e-7, (dp, dv, dr)
    # Its default (tangent-space, first-order) preintegration stays within millimetres.
    dp, dv, dr = _preintegrate(imu, trajectory, "PreintegratedImuMeasurements")
    assert dp < 5e-3 and dv < 5e-3 and dr < np.deg2rad(0.02), (dp, dv, dr)


def test_naive_sampling_would_drift(trajectory) -> None:
    """Sampling the continuous rates at t_k (no discretization care) misses by far more:
    the test above is not passing trivially."""
    imu = imu_samples(trajectory, start_ns=0, end_ns=int(DURATION_S * 1e9))
    t = imu.timestamp_ns * 1e-9
    R = trajectory.rotation(t)
    naive_accel = np.einsum("nji,nj->ni", R, trajectory.acceleration(t) - GRAVITY_WORLD)
    naive = dataclasses.replace(imu, accel=naive_accel)
    dp, _, _ = _preintegrate(naive, trajectory, "PreintegratedImuMeasurementsManifold")
    assert dp > 1e-3, dp  # measured 4.5 mm, against 0.5 µm above


def test_derivatives_match_finite_differences(trajectory) -> None:
    t = np.linspace(0.0, DURATION_S, 37)
    h = 1e-5
    np.testing.assert_allclose(trajectory.velocity(t), (trajectory.position(t + h) - trajectory.position(t - h)) / (2 * h), atol=1e-8)
    np.testing.assert_allclose(trajectory.acceleration(t), (trajectory.velocity(t + h) - trajectory.velocity(t - h)) / (2 * h), atol=1e-8)
    R = trajectory.rotation(t)
    np.testing.assert_allclose(R @ np.swapaxes(R, 1, 2), np.broadcast_to(np.eye(3), R.shape), atol=1e-12)


def test_at_rest_the_accelerometer_reads_gravity_up(trajectory) -> None:
    still = dataclasses.replace(trajectory, amplitude=np.zeros_like(trajectory.amplitude))
    imu = imu_samples(still, start_ns=0, end_ns=int(1e9))
    R0 = still.rotation(np.zeros(1))[0]
    np.testing.assert_allclose(imu.gyro, 0.0, atol=1e-12)
    np.testing.assert_allclose(imu.accel, np.broadcast_to(R0.T @ np.array([0.0, 0.0, 9.81]), imu.accel.shape), atol=1e-9)


def test_noise_levels_follow_the_densities(trajectory) -> None:
    imu = imu_samples(trajectory, start_ns=0, end_ns=int(50e9))
    white = ImuNoise(gyroscope_random_walk=0.0, accelerometer_random_walk=0.0)
    noisy, b_g, b_a = add_imu_noise(imu, np.random.default_rng(0), noise=white)
    assert np.all(b_g == 0.0) and np.all(b_a == 0.0)
    np.testing.assert_allclose(np.std(noisy.gyro - imu.gyro, axis=0), white.gyroscope_noise_density * np.sqrt(200.0), rtol=0.05)
    np.testing.assert_allclose(np.std(noisy.accel - imu.accel, axis=0), white.accelerometer_noise_density * np.sqrt(200.0), rtol=0.05)
    # Bias random walk: Var(b(T)) = σ_b² T, over many independent walks.
    walk = ImuNoise(gyroscope_noise_density=0.0, accelerometer_noise_density=0.0)
    ends = np.array([add_imu_noise(imu, np.random.default_rng(s), noise=walk)[2][-1] for s in range(200)])
    T = len(imu) * DT
    np.testing.assert_allclose(np.std(ends), walk.accelerometer_random_walk * np.sqrt(T), rtol=0.15)


def test_seeded_and_reproducible() -> None:
    a, b = random_trajectory(np.random.default_rng(7)), random_trajectory(np.random.default_rng(7))
    t = np.linspace(0, 5, 11)
    np.testing.assert_array_equal(a.position(t), b.position(t))
    assert not np.allclose(a.position(t), random_trajectory(np.random.default_rng(8)).position(t))


def _wrapped(trajectory):
    """A shaken trajectory and a slow-starting one, both built on `trajectory`."""
    shake = Shake(amplitude_m=0.008, amplitude_deg=1.5, band_hz=(2.0, 6.0)).trajectory(np.random.default_rng(1))
    return ShakenTrajectory(trajectory, shake), WarpedTrajectory(trajectory, SlowStart(still_s=3.0, ramp_s=2.0, creep=0.01))


def test_shaken_and_slow_started_trajectories_keep_their_derivatives(trajectory) -> None:
    t = np.linspace(0.0, DURATION_S, 53)
    h = 1e-5
    for wrapped in _wrapped(trajectory):
        np.testing.assert_allclose(wrapped.velocity(t), (wrapped.position(t + h) - wrapped.position(t - h)) / (2 * h), atol=1e-7)
        np.testing.assert_allclose(wrapped.acceleration(t), (wrapped.velocity(t + h) - wrapped.velocity(t - h)) / (2 * h), atol=1e-6)


def test_noise_free_samples_reproduce_shaken_and_slow_started_trajectories(trajectory) -> None:
    for wrapped in _wrapped(trajectory):
        imu = imu_samples(wrapped, start_ns=0, end_ns=int(DURATION_S * 1e9))
        dp, dv, dr = _preintegrate(imu, wrapped, "PreintegratedImuMeasurementsManifold")
        assert dp < 2e-5 and dv < 1e-5 and dr < 1e-7, (dp, dv, dr)


def test_slow_start_warps_time_smoothly() -> None:
    slow = SlowStart(still_s=3.0, ramp_s=2.0, creep=0.01)
    t = np.array([0.0, 3.0, 4.0, 5.0, 6.0])
    tau, rate, rate_dot = slow.warp(t)
    np.testing.assert_allclose(tau, [0.0, 0.03, 0.04 + 0.99 * 2.0 * 0.5**4 * 1.25, 0.05 + 0.99, 0.05 + 0.99 + 1.0], atol=1e-12)  # ∫ of the quintic step: x⁴(5/2 - 3x + x²)
    np.testing.assert_allclose(rate, [0.01, 0.01, 0.505, 1.0, 1.0], atol=1e-12)
    assert rate_dot[0] == rate_dot[-1] == 0.0 and rate_dot[2] > 0
    with pytest.raises(ValueError, match="creep"):
        SlowStart(creep=1.5)
    with pytest.raises(ValueError, match="band_hz"):
        Shake(band_hz=(6.0, 2.0))
