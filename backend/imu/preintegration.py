"""IMU preintegration (gtsam) as whitened residuals and Jacobians for the project's solver.

Frames and units: `R_world_body`, `t_world_body` (metres) map body to world,
`X_world = R X_body + t`; `v_world` is the body's velocity in the world frame (m/s); world z
up, gravity `(0, 0, -gravity_m_s2)`. IMU samples are body-frame gyro (rad/s) and accelerometer
(m/s²) readings (`backend.data.motion.ImuData`), sample k held constant over
`[t_k, t_{k+1}]`. A bias is a 6-vector `(accel (m/s²), gyro (rad/s))`, gtsam's
`imuBias.ConstantBias.vector()` order; it is subtracted from the readings.

Residual: gtsam's `ImuFactor.evaluateError`, a 9-vector ordered (rotation, position,
velocity) in gtsam's default IMU error chart (`ImuFactorErrorMode.Logmap` in gtsam 4.3): the
NavState log of actual_j⁻¹ · predicted_j, so to first order `Log(R_jᵀ R_pred)`,
`R_jᵀ (t_pred - t_j)` and `R_jᵀ (v_pred - v_j)` (body frame at j). It is whitened with the
upper-triangular square-root information `S` (`SᵀS = Σ⁻¹`) of the factor's own noise model,
which gtsam 4.3 builds from `pim.residualCovariance()`: the preintegrated covariance
`pim.preintMeasCov()` carried into that error chart (their standard deviations differ by
0.02 % over 0.5 s of hand-held motion, a few per cent at turn rates near 2 rad/s).

Jacobians are in the project's retraction (`backend.geometry.se3`): pose increments
`(δθ, δt)` with `R <- R Exp(δθ)`, `t <- t + δt` (δt in the WORLD frame); velocity and bias
additive. gtsam's Pose3 chart perturbs `(ω, u)` with `T Exp(ω, u) = (R Exp(ω), t + R u + O(|ξ|²))`
(u in the BODY frame), so to first order `ω = δθ`, `u = Rᵀ δt` and
`∂r/∂δt = (∂r/∂u) Rᵀ`; the rotation columns are unchanged. Velocity is a plain world vector
in gtsam too.

Bias re-linearization: a preintegration holds the bias it was integrated with
(`pim.biasHat()`) and the Jacobians of the preintegrated deltas with respect to the bias.
`ImuFactor` evaluated at another bias corrects the deltas to first order
(`biasCorrectedDelta`: `Δ(b) ≈ Δ(b̂) + ∂Δ/∂b (b - b̂)`), so small bias updates need no
re-integration; re-integrate (:func:`preintegrate` with the new bias) once `|b - b̂|` grows
large (the error is second order in it).
"""

from __future__ import annotations

import dataclasses

import gtsam
import numpy as np

from backend.data.motion import ImuData, ImuNoise

DEFAULT_MAX_GAP_NS = 15_000_000  # three sample periods at EuRoC's 200 Hz
INTEGRATION_COVARIANCE_M2_S = 1e-9  # position random walk, m²/s: module docstring of preintegration_params


@dataclasses.dataclass(frozen=True, eq=False)
class ImuResidual:
    """A whitened IMU factor residual (9,) ordered (rotation, position, velocity) and its
    whitened Jacobians in the project's retraction: pose `(δθ, δt_world)` (9, 6), world
    velocity (9, 3), bias `(accel, gyro)` (9, 6)."""

    residual: np.ndarray
    J_pose_i: np.ndarray
    J_v_i: np.ndarray
    J_pose_j: np.ndarray
    J_v_j: np.ndarray
    J_bias_i: np.ndarray

    @property
    def chi2(self) -> float:
        """Squared Mahalanobis norm of the residual."""
        return float(self.residual @ self.residual)


@dataclasses.dataclass(frozen=True, eq=False)
class BiasWalkResidual:
    """A whitened bias random-walk residual (6,) `(b_j - b_i) / σ` ordered (accel, gyro) and
    its Jacobians (6, 6) with respect to `b_i` and `b_j`."""

    residual: np.ndarray
    J_bias_i: np.ndarray
    J_bias_j: np.ndarray


@dataclasses.dataclass(frozen=True, eq=False)
class PreparedImuFactor:
    """A gtsam `ImuFactor` around one preintegration with its square-root information (9, 9),
    built once by :func:`imu_factor` and reused across solver iterations."""

    pim: gtsam.PreintegratedImuMeasurements
    factor: gtsam.ImuFactor
    sqrt_information: np.ndarray


def preintegration_params(noise: ImuNoise, *, gravity_m_s2: float = 9.81, integration_covariance_m2_s: float = INTEGRATION_COVARIANCE_M2_S) -> gtsam.PreintegrationParams:
    """gtsam parameters for a z-up world (gravity `-gravity_m_s2` along z, m/s²).

    Gyroscope and accelerometer covariances are the continuous-time densities squared times
    the identity (`(rad/s)²/Hz`, `(m/s²)²/Hz`); gtsam divides them by each sample's interval.
    The integration covariance (default 1e-9 m²/s, a position random walk of 0.03 mm/√s)
    only keeps the position block well conditioned over very short intervals: over 0.5 s at
    EuRoC's accelerometer density it is 0.3 % of the position variance."""
    params = gtsam.PreintegrationParams.MakeSharedU(float(gravity_m_s2))
    params.setGyroscopeCovariance(noise.gyroscope_noise_density**2 * np.eye(3))
    params.setAccelerometerCovariance(noise.accelerometer_noise_density**2 * np.eye(3))
    params.setIntegrationCovariance(float(integration_covariance_m2_s) * np.eye(3))
    return params


def constant_bias(bias: np.ndarray) -> gtsam.imuBias.ConstantBias:
    """gtsam bias from a 6-vector `(accel m/s², gyro rad/s)`."""
    bias = np.asarray(bias, dtype=float).reshape(6)
    return gtsam.imuBias.ConstantBias(bias[:3], bias[3:])


def preintegrate(
    imu: ImuData,
    t0_ns: int,
    t1_ns: int,
    *,
    bias_accel: np.ndarray,
    bias_gyro: np.ndarray,
    params: gtsam.PreintegrationParams,
    max_gap_ns: int = DEFAULT_MAX_GAP_NS,
) -> gtsam.PreintegratedImuMeasurements:
    """Preintegrate over exactly `[t0_ns, t1_ns]` with the given biases (m/s², rad/s).

    The sample at or before `t0_ns` holds until the next one; the first and last intervals
    are clipped to `[t0_ns, t1_ns]`. The last sample before `t1_ns` holds until its
    successor, or until `t1_ns` when it is the last sample of `imu`. Raises a one-line
    ValueError when `t1_ns <= t0_ns`, when no sample is at or before `t0_ns`, when
    timestamps do not increase, or when a sample used holds for more than `max_gap_ns`
    (the gap to the next sample, or to `t1_ns` for the data's last sample): a dropped
    stretch of IMU data is an error, not something to integrate across."""
    t0_ns, t1_ns = int(t0_ns), int(t1_ns)
    if t1_ns <= t0_ns:
        raise ValueError(f"preintegration interval [{t0_ns}, {t1_ns}] ns is empty")
    stamps = np.asarray(imu.timestamp_ns, dtype=np.int64)
    first = int(np.searchsorted(stamps, t0_ns, side="right")) - 1
    if first < 0:
        start = f"the first sample is at {stamps[0]} ns" if stamps.size else "there are no samples"
        raise ValueError(f"IMU samples do not cover [{t0_ns}, {t1_ns}] ns: {start}, after t0")
    last = int(np.searchsorted(stamps, t1_ns, side="left")) - 1  # the last sample before t1
    used = stamps[first : last + 2]  # with the successor of the last one, when there is one
    ends = np.append(used[1:], t1_ns) if used.shape[0] == last - first + 1 else used[1:]
    begins = used[: last - first + 1]
    spans = ends - begins
    if np.any(spans <= 0):
        k = first + int(np.flatnonzero(spans <= 0)[0])
        raise ValueError(f"IMU timestamps do not increase at sample {k} ({stamps[k]} ns)")
    if np.any(spans > max_gap_ns):
        k = int(np.flatnonzero(spans > max_gap_ns)[0])
        raise ValueError(
            f"IMU samples do not cover [{t0_ns}, {t1_ns}] ns: sample at {begins[k]} ns holds for {spans[k] * 1e-6:.3f} ms, more than the {max_gap_ns * 1e-6:.3f} ms allowed between IMU samples"
        )
    dt_s = (np.minimum(ends, t1_ns) - np.maximum(begins, t0_ns)) * 1e-9
    pim = gtsam.PreintegratedImuMeasurements(params, gtsam.imuBias.ConstantBias(np.asarray(bias_accel, dtype=float), np.asarray(bias_gyro, dtype=float)))
    accel = imu.accel[first : last + 1]
    gyro = imu.gyro[first : last + 1]
    for k in range(dt_s.shape[0]):
        pim.integrateMeasurement(accel[k], gyro[k], float(dt_s[k]))
    return pim


def imu_factor(pim: gtsam.PreintegratedImuMeasurements) -> PreparedImuFactor:
    """The gtsam factor and square-root information of one preintegration (done once per
    preintegration; :func:`imu_factor_error` accepts the result in place of `pim`)."""
    factor = gtsam.ImuFactor(0, 1, 2, 3, 4, pim)
    return PreparedImuFactor(pim=pim, factor=factor, sqrt_information=np.array(factor.noiseModel().R()))  # type: ignore[attr-defined]  # gtsam's stubs: a Gaussian noise model


def imu_factor_error(
    pim: gtsam.PreintegratedImuMeasurements | PreparedImuFactor,
    R_world_body_i: np.ndarray,
    t_world_body_i: np.ndarray,
    v_world_i: np.ndarray,
    R_world_body_j: np.ndarray,
    t_world_body_j: np.ndarray,
    v_world_j: np.ndarray,
    bias_i: np.ndarray,
) -> ImuResidual:
    """Whitened IMU residual between states i and j and its whitened Jacobians (module
    docstring: order, chart, retraction). `bias_i` (6,) is `(accel, gyro)`; when it differs
    from the bias `pim` was integrated with, gtsam corrects the deltas to first order."""
    term = pim if isinstance(pim, PreparedImuFactor) else imu_factor(pim)
    # One Fortran-ordered (9, 24) buffer; gtsam fills its column blocks in place:
    # pose_i 0:6, v_i 6:9, pose_j 9:15, v_j 15:18, bias 18:24.
    H = np.empty((9, 24), order="F")
    R_i = np.asarray(R_world_body_i, dtype=float)
    R_j = np.asarray(R_world_body_j, dtype=float)
    error = term.factor.evaluateError(
        gtsam.Pose3(gtsam.Rot3(R_i), np.asarray(t_world_body_i, dtype=float)),
        np.asarray(v_world_i, dtype=float),
        gtsam.Pose3(gtsam.Rot3(R_j), np.asarray(t_world_body_j, dtype=float)),
        np.asarray(v_world_j, dtype=float),
        constant_bias(bias_i),
        H[:, 0:6],
        H[:, 6:9],
        H[:, 9:15],
        H[:, 15:18],
        H[:, 18:24],
    )
    # gtsam's body-frame translation columns to the project's world-frame δt: ∂r/∂δt = ∂r/∂u Rᵀ.
    H[:, 3:6] = H[:, 3:6] @ R_i.T
    H[:, 12:15] = H[:, 12:15] @ R_j.T
    S = term.sqrt_information
    J = S @ H
    return ImuResidual(
        residual=S @ np.asarray(error, dtype=float).reshape(9),
        J_pose_i=J[:, 0:6],
        J_v_i=J[:, 6:9],
        J_pose_j=J[:, 9:15],
        J_v_j=J[:, 15:18],
        J_bias_i=J[:, 18:24],
    )


def bias_random_walk_error(bias_i: np.ndarray, bias_j: np.ndarray, dt_s: float | np.ndarray, noise: ImuNoise) -> BiasWalkResidual:
    """Whitened `b_j - b_i` (..., 6) of biases `(accel m/s², gyro rad/s)` (..., 6) over `dt_s`
    seconds (a number, or one per bias pair (...)), with standard deviations
    `random_walk · √dt_s` (densities per √Hz, `noise`); Jacobians (..., 6, 6). Pairs of
    biases stacked along leading axes are evaluated at once (the window solve's factors)."""
    dt = np.asarray(dt_s, dtype=float)
    if not np.all(dt > 0.0):
        raise ValueError(f"bias random walk needs dt_s > 0, got {dt_s}")
    sigma = np.sqrt(dt)[..., None] * np.repeat([noise.accelerometer_random_walk, noise.gyroscope_random_walk], 3)
    weight = 1.0 / sigma
    b_i, b_j = np.asarray(bias_i, dtype=float), np.asarray(bias_j, dtype=float)
    residual = weight * (b_j.reshape(b_j.shape[:-1] + (6,)) - b_i.reshape(b_i.shape[:-1] + (6,)))
    J = np.zeros(weight.shape + (6,))
    J[..., np.arange(6), np.arange(6)] = weight
    return BiasWalkResidual(residual=residual, J_bias_i=-J, J_bias_j=J)


def predict_state(
    pim: gtsam.PreintegratedImuMeasurements,
    R_world_body_i: np.ndarray,
    t_world_body_i: np.ndarray,
    v_world_i: np.ndarray,
    *,
    bias: np.ndarray,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """State at the end of the preintegration from state i and `bias` (6,) `(accel, gyro)`:
    `(R_world_body_j (3, 3), t_world_body_j (3,) m, v_world_j (3,) m/s)` (gtsam's predict,
    with the same first-order bias correction)."""
    state = pim.predict(
        gtsam.NavState(gtsam.Rot3(np.asarray(R_world_body_i, dtype=float)), np.asarray(t_world_body_i, dtype=float), np.asarray(v_world_i, dtype=float)),
        constant_bias(bias),
    )
    return np.array(state.attitude().matrix()), np.array(state.position()), np.array(state.velocity())
