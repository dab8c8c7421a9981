"""The road loop and the car's drive around it: the loop closes, the drive is smooth (its
derivatives are right, C2) and drives like a car, and its simulated IMU reproduces it."""

from __future__ import annotations

import gtsam
import numpy as np
import pytest

from backend.data.motion import GRAVITY_WORLD, imu_samples
from backend.data.road import DriveTrajectory, RoadLoop, drive_trajectory

DT = 0.005


@pytest.fixture(scope="module")
def road() -> RoadLoop:
    return RoadLoop(straights_m=(160.0, 100.0), corner_m=56.0, origin=(-80.0, -80.0), speed_mps=(8.5, 14.0), height_m=0.85)


@pytest.fixture(scope="module")
def drive(road: RoadLoop) -> DriveTrajectory:
    return drive_trajectory(road, np.random.default_rng(5))


def test_the_loop_closes_and_turns_four_quarters(road: RoadLoop) -> None:
    L = road.length_m
    assert L == pytest.approx(2 * 160 + 2 * 100 + 4 * 56)
    np.testing.assert_allclose(road.point(np.array([0.0, L, 3 * L])), np.tile([[-80.0, -80.0]], (3, 1)), atol=1e-9)
    assert road.heading(np.array([L]))[0] == pytest.approx(2 * np.pi)
    s = np.linspace(0.0, L, 20001)
    step = np.linalg.norm(np.diff(road.point(s), axis=0), axis=1)
    np.testing.assert_allclose(step, L / 20000, rtol=1e-6)  # parametrized by arc length, no jumps
    kappa = road.curvature(s)
    assert np.max(np.abs(np.diff(kappa))) < 1e-3  # continuous curvature
    assert kappa.max() == pytest.approx(np.pi / 56.0, rel=1e-3) and kappa.min() == 0.0


def test_derivatives_match_finite_differences(drive: DriveTrajectory) -> None:
    t = np.linspace(0.0, 120.0, 97)  # more than a lap
    h = 1e-5
    np.testing.assert_allclose(drive.velocity(t), (drive.position(t + h) - drive.position(t - h)) / (2 * h), atol=1e-6)
    np.testing.assert_allclose(drive.acceleration(t), (drive.velocity(t + h) - drive.velocity(t - h)) / (2 * h), atol=1e-6)
    R = drive.rotation(t)
    np.testing.assert_allclose(R @ np.swapaxes(R, 1, 2), np.broadcast_to(np.eye(3), R.shape), atol=1e-12)


def test_the_drive_is_a_cars(drive: DriveTrajectory) -> None:
    """Forward along the road at 8.5–14 m/s, no sideways slip, small pitch and roll, smooth
    (C2: the acceleration has no jumps between 200 Hz samples beyond its rate of change)."""
    t = np.arange(0.0, 150.0, DT)
    v = drive.velocity(t)
    speed = np.linalg.norm(v, axis=1)
    assert 8.4 < speed.min() and speed.max() < 14.1
    R = drive.rotation(t)
    v_body = np.einsum("nji,nj->ni", R, v)
    assert np.all(v_body[:, 0] > 0.99 * speed) and np.max(np.abs(v_body[:, 1]) / speed) < 0.01
    up_body = R[:, 2, :]  # world z in body axes
    assert np.degrees(np.arccos(np.min(up_body[:, 2]))) < 4.0  # pitch and roll within a few degrees
    a = drive.acceleration(t)
    assert np.max(np.linalg.norm(a[:, :2], axis=1)) < 5.0  # a car's lateral and braking accelerations
    assert np.max(np.abs(np.diff(a, axis=0))) < 0.2  # m/s² per 5 ms: no jumps


def test_speed_scales_the_drive(road: RoadLoop) -> None:
    slow, fast = drive_trajectory(road, np.random.default_rng(2)), drive_trajectory(road, np.random.default_rng(2), speed=1.5)
    t = np.linspace(0.0, 40.0, 11)
    np.testing.assert_allclose(fast.position(t), slow.position(1.5 * t), atol=1e-9)
    yaw = lambda R: np.unwrap(np.arctan2(R[:, 1, 0], R[:, 0, 0]))  # noqa: E731
    np.testing.assert_allclose(yaw(fast.rotation(t)), yaw(slow.rotation(1.5 * t)), atol=1e-12)  # the same heading; roll and pitch lean more
    assert np.max(np.abs(fast.rotation(t)[:, 2, 1])) > np.max(np.abs(slow.rotation(1.5 * t)[:, 2, 1]))


def test_noise_free_imu_reproduces_the_drive_after_10_s(drive: DriveTrajectory) -> None:
    imu = imu_samples(drive, start_ns=0, end_ns=int(10e9))
    assert np.max(np.abs(imu.gyro[:, 2])) > 0.2  # it turns within these 10 s
    params = gtsam.PreintegrationParams.MakeSharedU(-GRAVITY_WORLD[2])
    params.setAccelerometerCovariance(1e-6 * np.eye(3))
    params.setGyroscopeCovariance(1e-6 * np.eye(3))
    params.setIntegrationCovariance(1e-8 * np.eye(3))
    pim = gtsam.PreintegratedImuMeasurementsManifold(params, gtsam.imuBias.ConstantBias())
    for a, w in zip(imu.accel, imu.gyro):
        pim.integrateMeasurement(a, w, DT)
    t = np.array([0.0, 10.0])
    R, p, v = drive.rotation(t), drive.position(t), drive.velocity(t)
    end = pim.predict(gtsam.NavState(gtsam.Rot3(R[0]), p[0], v[0]), gtsam.imuBias.ConstantBias())
    assert np.linalg.norm(end.position() - p[1]) < 1e-4  # over about 120 m driven
    assert np.linalg.norm(end.velocity() - v[1]) < 1e-6
    assert np.linalg.norm(gtsam.Rot3.Logmap(gtsam.Rot3(R[1]).between(end.attitude()))) < 1e-9


@pytest.mark.parametrize(
    ("field", "value", "words"),
    [
        ("straights_m", (-1.0, 10.0), "straights_m"),
        ("corner_m", 0.5, "corner_m"),
        ("speed_mps", (15.0, 10.0), "speed_mps"),
        ("height_m", float("nan"), "height_m"),
    ],
)
def test_bad_loops_are_refused(field: str, value: object, words: str) -> None:
    with pytest.raises(ValueError, match=words):
        RoadLoop(**{field: value})  # type: ignore[arg-type]
