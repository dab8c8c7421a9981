"""IMU preintegration residuals: Jacobians in the project's retraction against central
differences, zero residual on noise-free samples (with and without a constant bias), gtsam's
first-order bias correction, and the coverage / gap errors."""

from __future__ import annotations

import numpy as np
import pytest

from backend.data.motion import ImuData, ImuNoise, imu_samples, random_trajectory
from backend.geometry import so3
from backend.imu.preintegration import (
    bias_random_walk_error,
    imu_factor,
    imu_factor_error,
    predict_state,
    preintegrate,
    preintegration_params,
)

NOISE = ImuNoise()
PARAMS = preintegration_params(NOISE)
T0_NS = 1_000_000_000
T1_NS = 1_500_000_000
BIAS_TRUE = np.array([0.08, -0.05, 0.12, 0.004, -0.006, 0.003])  # accel m/s², gyro rad/s


@pytest.fixture(scope="module")
def trajectory():
    """Hand-held-like motion (turn rates up to ~0.2 rad/s): there the samples' own position
    discretization (trapezoid rule, `backend.data.motion`) stays under a micrometre per 0.5 s."""
    return random_trajectory(np.random.default_rng(7))


@pytest.fixture(scope="module")
def fast_trajectory():
    """Faster motion (turn rates up to ~1.8 rad/s) for the Jacobians."""
    return random_trajectory(np.random.default_rng(7), base_frequency_hz=0.15)


@pytest.fixture(scope="module")
def imu(trajectory) -> ImuData:
    return imu_samples(trajectory, start_ns=0, end_ns=3_000_000_000)


def _truth(trajectory, *stamps_ns: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    t = np.array(stamps_ns, dtype=float) * 1e-9
    return trajectory.rotation(t), trajectory.position(t), trajectory.velocity(t)


def _unwhitened(pim, residual: np.ndarray) -> np.ndarray:
    return np.linalg.solve(imu_factor(pim).sqrt_information, residual)


def _numeric_jacobian(f, x0: np.ndarray, *, step: float) -> np.ndarray:
    columns = []
    for k in range(x0.shape[0]):
        dx = np.zeros_like(x0)
        dx[k] = step
        columns.append((f(x0 + dx) - f(x0 - dx)) / (2.0 * step))
    return np.stack(columns, axis=1)


def test_jacobians_match_central_differences_in_the_project_retraction(fast_trajectory) -> None:
    """Away from the truth (non-zero residual) and at a bias other than the integration's:
    every block, pose columns in `(δθ, δt_world)` with `R Exp(δθ)`, `t + δt`."""
    rng = np.random.default_rng(0)
    imu = imu_samples(fast_trajectory, start_ns=0, end_ns=2_000_000_000)
    pim = preintegrate(imu, T0_NS, T1_NS, bias_accel=np.zeros(3), bias_gyro=np.zeros(3), params=PARAMS)
    term = imu_factor(pim)
    R, p, v = _truth(fast_trajectory, T0_NS, T1_NS)
    R_i, R_j = R[0] @ so3.exp(rng.normal(0, 0.02, 3)), R[1] @ so3.exp(rng.normal(0, 0.02, 3))
    t_i, t_j = p[0] + rng.normal(0, 0.02, 3), p[1] + rng.normal(0, 0.02, 3)
    v_i, v_j = v[0] + rng.normal(0, 0.05, 3), v[1] + rng.normal(0, 0.05, 3)
    bias = rng.normal(0, 0.01, 6)

    def residual(R_i=R_i, t_i=t_i, v_i=v_i, R_j=R_j, t_j=t_j, v_j=v_j, bias=bias) -> np.ndarray:
        return imu_factor_error(term, R_i, t_i, v_i, R_j, t_j, v_j, bias).residual

    result = imu_factor_error(term, R_i, t_i, v_i, R_j, t_j, v_j, bias)
    assert np.linalg.norm(result.residual) > 10.0  # far from zero: the test exercises the chart
    numeric = {
        "J_pose_i": _numeric_jacobian(lambda d: residual(R_i=R_i @ so3.exp(d[:3]), t_i=t_i + d[3:]), np.zeros(6), step=1e-6),
        "J_v_i": _numeric_jacobian(lambda x: residual(v_i=x), v_i, step=1e-6),
        "J_pose_j": _numeric_jacobian(lambda d: residual(R_j=R_j @ so3.exp(d[:3]), t_j=t_j + d[3:]), np.zeros(6), step=1e-6),
        "J_v_j": _numeric_jacobian(lambda x: residual(v_j=x), v_j, step=1e-6),
        "J_bias_i": _numeric_jacobian(lambda x: residual(bias=x), bias, step=1e-6),
    }
    for name, J_numeric in numeric.items():
        J = getattr(result, name)
        scale = np.max(np.abs(J_numeric))
        assert scale > 0.0, name
        assert np.max(np.abs(J - J_numeric)) <= 1e-6 * scale, (name, np.max(np.abs(J - J_numeric)) / scale)
    # The world-frame translation columns differ from gtsam's body-frame ones unless R = I.
    H_t_body = result.J_pose_i[:, 3:] @ R_i
    assert np.max(np.abs(H_t_body - result.J_pose_i[:, 3:])) > 1e-3 * np.max(np.abs(H_t_body))


def test_zero_residual_on_noise_free_samples(trajectory, imu) -> None:
    R, p, v = _truth(trajectory, T0_NS, T1_NS)
    pim = preintegrate(imu, T0_NS, T1_NS, bias_accel=np.zeros(3), bias_gyro=np.zeros(3), params=PARAMS)
    assert pim.deltaTij() == pytest.approx(0.5, abs=1e-12)
    result = imu_factor_error(pim, R[0], p[0], v[0], R[1], p[1], v[1], np.zeros(6))
    assert np.max(np.abs(_unwhitened(pim, result.residual))) < 1e-6
    assert np.linalg.norm(result.residual) < 0.05  # far below one sigma of the sensor noise
    R_j, p_j, v_j = predict_state(pim, R[0], p[0], v[0], bias=np.zeros(6))
    assert np.linalg.norm(so3.log(R[1].T @ R_j)) < 1e-6
    assert np.linalg.norm(p_j - p[1]) < 1e-6 and np.linalg.norm(v_j - v[1]) < 1e-6


def test_residual_blocks_are_prediction_minus_state_in_body_j(trajectory, imu) -> None:
    """The documented chart, to first order: (Log(R_jᵀ R_pred), R_jᵀ (t_pred - t_j), R_jᵀ (v_pred - v_j))."""
    R, p, v = _truth(trajectory, T0_NS, T1_NS)
    pim = preintegrate(imu, T0_NS, T1_NS, bias_accel=np.zeros(3), bias_gyro=np.zeros(3), params=PARAMS)
    phi, dt, dv = np.array([1e-4, -2e-4, 3e-4]), np.array([1e-3, 2e-3, -1e-3]), np.array([-2e-3, 1e-3, 1e-3])
    result = imu_factor_error(pim, R[0], p[0], v[0], R[1] @ so3.exp(phi), p[1] + dt, v[1] + dv, np.zeros(6))
    e = _unwhitened(pim, result.residual)
    R_j = R[1] @ so3.exp(phi)
    np.testing.assert_allclose(e[:3], -phi, atol=1e-6)
    np.testing.assert_allclose(e[3:6], -R_j.T @ dt, atol=1e-5)
    np.testing.assert_allclose(e[6:], -R_j.T @ dv, atol=1e-5)


def test_zero_residual_with_a_known_constant_bias(trajectory, imu) -> None:
    biased = ImuData(imu.timestamp_ns, imu.gyro + BIAS_TRUE[3:], imu.accel + BIAS_TRUE[:3])
    R, p, v = _truth(trajectory, T0_NS, T1_NS)
    pim = preintegrate(biased, T0_NS, T1_NS, bias_accel=BIAS_TRUE[:3], bias_gyro=BIAS_TRUE[3:], params=PARAMS)
    result = imu_factor_error(pim, R[0], p[0], v[0], R[1], p[1], v[1], BIAS_TRUE)
    assert np.max(np.abs(_unwhitened(pim, result.residual))) < 1e-6
    # Ignoring the bias is far off.
    wrong = imu_factor_error(pim, R[0], p[0], v[0], R[1], p[1], v[1], np.zeros(6))
    assert np.max(np.abs(_unwhitened(pim, wrong.residual))) > 1e-3


def test_first_order_bias_correction_matches_reintegration(trajectory, imu) -> None:
    """Evaluating a preintegration at a bias b̂ + δ equals re-integrating with b̂ + δ up to
    O(|δ|²): the gap shrinks fourfold when δ halves, and is tiny against the first-order
    effect of δ itself."""
    biased = ImuData(imu.timestamp_ns, imu.gyro + BIAS_TRUE[3:], imu.accel + BIAS_TRUE[:3])
    R, p, v = _truth(trajectory, T0_NS, T1_NS)
    states = (R[0], p[0], v[0], R[1], p[1], v[1])
    pim = preintegrate(biased, T0_NS, T1_NS, bias_accel=np.zeros(3), bias_gyro=np.zeros(3), params=PARAMS)
    at_zero = _unwhitened(pim, imu_factor_error(pim, *states, np.zeros(6)).residual)
    gaps = []
    for scale in (1.0, 0.5):
        delta = scale * BIAS_TRUE
        corrected = _unwhitened(pim, imu_factor_error(pim, *states, delta).residual)
        pim_new = preintegrate(biased, T0_NS, T1_NS, bias_accel=delta[:3], bias_gyro=delta[3:], params=PARAMS)
        reintegrated = _unwhitened(pim_new, imu_factor_error(pim_new, *states, delta).residual)
        gap = np.linalg.norm(corrected - reintegrated)
        assert gap < 1e-2 * np.linalg.norm(reintegrated - at_zero), (scale, gap)
        gaps.append(gap)
    assert 3.0 < gaps[0] / gaps[1] < 5.0, gaps
    # At the true bias, the corrected residual is near zero as well (second-order small).
    corrected = _unwhitened(pim, imu_factor_error(pim, *states, BIAS_TRUE).residual)
    assert np.max(np.abs(corrected)) < 1e-4


def test_clipped_intervals_cover_exactly_the_requested_span(trajectory, imu) -> None:
    t0, t1 = T0_NS + 1_234_567, T1_NS + 2_345_678  # off the 5 ms sample grid
    pim = preintegrate(imu, t0, t1, bias_accel=np.zeros(3), bias_gyro=np.zeros(3), params=PARAMS)
    assert pim.deltaTij() == pytest.approx((t1 - t0) * 1e-9, abs=1e-12)
    R, p, v = _truth(trajectory, t0, t1)
    result = imu_factor_error(pim, R[0], p[0], v[0], R[1], p[1], v[1], np.zeros(6))
    assert np.max(np.abs(_unwhitened(pim, result.residual))) < 2e-6  # held readings inside a sample


def test_the_data_s_last_sample_holds_until_t1(imu) -> None:
    end = int(imu.timestamp_ns[-1])
    pim = preintegrate(imu, end - 100_000_000, end + 5_000_000, bias_accel=np.zeros(3), bias_gyro=np.zeros(3), params=PARAMS)
    assert pim.deltaTij() == pytest.approx(0.105, abs=1e-12)


@pytest.mark.parametrize(
    ("t0_ns", "t1_ns", "drop", "message"),
    [
        (-1, 500_000_000, None, "do not cover"),  # before the first sample
        (2_900_000_000, 3_100_000_000, None, "holds for"),  # past the data's end
        (T0_NS, T1_NS, slice(250, 254), "holds for"),  # 25 ms gap inside
        (T1_NS, T0_NS, None, "is empty"),
        (T0_NS, T0_NS, None, "is empty"),
    ],
)
def test_coverage_and_gap_errors_are_one_line(imu, t0_ns: int, t1_ns: int, drop: slice | None, message: str) -> None:
    if drop is not None:
        keep = np.ones(len(imu), dtype=bool)
        keep[drop] = False
        imu = ImuData(imu.timestamp_ns[keep], imu.gyro[keep], imu.accel[keep])
    with pytest.raises(ValueError, match=message) as error:
        preintegrate(imu, t0_ns, t1_ns, bias_accel=np.zeros(3), bias_gyro=np.zeros(3), params=PARAMS)
    assert "\n" not in str(error.value)


def test_a_gap_within_max_gap_ns_is_integrated_across(trajectory, imu) -> None:
    keep = np.ones(len(imu), dtype=bool)
    keep[250] = False  # one dropped sample: 10 ms held reading
    holed = ImuData(imu.timestamp_ns[keep], imu.gyro[keep], imu.accel[keep])
    pim = preintegrate(holed, T0_NS, T1_NS, bias_accel=np.zeros(3), bias_gyro=np.zeros(3), params=PARAMS)
    assert pim.deltaTij() == pytest.approx(0.5, abs=1e-12)
    with pytest.raises(ValueError, match="holds for"):
        preintegrate(holed, T0_NS, T1_NS, bias_accel=np.zeros(3), bias_gyro=np.zeros(3), params=PARAMS, max_gap_ns=6_000_000)


def test_bias_random_walk_residual_and_jacobians() -> None:
    rng = np.random.default_rng(1)
    b_i, b_j = rng.normal(0, 0.1, 6), rng.normal(0, 0.1, 6)
    result = bias_random_walk_error(b_i, b_j, 0.25, NOISE)
    sigma = np.sqrt(0.25) * np.repeat([NOISE.accelerometer_random_walk, NOISE.gyroscope_random_walk], 3)
    np.testing.assert_allclose(result.residual, (b_j - b_i) / sigma, rtol=1e-12)
    np.testing.assert_allclose(result.J_bias_i, _numeric_jacobian(lambda x: bias_random_walk_error(x, b_j, 0.25, NOISE).residual, b_i, step=1e-4), rtol=1e-8)
    np.testing.assert_allclose(result.J_bias_j, _numeric_jacobian(lambda x: bias_random_walk_error(b_i, x, 0.25, NOISE).residual, b_j, step=1e-4), rtol=1e-8)
    with pytest.raises(ValueError, match="dt_s > 0"):
        bias_random_walk_error(b_i, b_j, 0.0, NOISE)


def test_bias_random_walk_of_many_pairs_at_once_equals_each_pair() -> None:
    """The window solve evaluates all its bias factors in one call: the same residuals and
    Jacobians, value for value, as one call per pair."""
    rng = np.random.default_rng(2)
    b_i, b_j, dt_s = rng.normal(0, 0.1, (5, 6)), rng.normal(0, 0.1, (5, 6)), rng.uniform(0.05, 0.5, 5)
    batch = bias_random_walk_error(b_i, b_j, dt_s, NOISE)
    for m in range(5):
        one = bias_random_walk_error(b_i[m], b_j[m], float(dt_s[m]), NOISE)
        np.testing.assert_array_equal(batch.residual[m], one.residual)
        np.testing.assert_array_equal(batch.J_bias_i[m], one.J_bias_i)
        np.testing.assert_array_equal(batch.J_bias_j[m], one.J_bias_j)
    with pytest.raises(ValueError, match="dt_s > 0"):
        bias_random_walk_error(b_i, b_j, np.array([0.1, 0.1, 0.0, 0.1, 0.1]), NOISE)
