"""Visual-inertial alignment for VIO initialization (VINS-Mono, Qin et al. 2018, §V-B).

A loosely coupled initialization: an up-to-scale visual structure-from-motion gives K
keyframe poses of the camera in the first camera's frame c0, `R_c0_cam[k]`, `p_c0_cam[k]`,
with an unknown scale `s` (metric position = `s · p_c0_cam`); the IMU samples between
consecutive keyframes give preintegrated deltas (gtsam's `PreintegratedImuMeasurements`).
The alignment recovers, in four linear steps:

1. the gyroscope bias, by least squares on the relative rotations (visual vs preintegrated);
   the intervals are then re-preintegrated with it;
2. every keyframe's velocity (body origin, c0 frame), gravity in c0 and the scale, from one
   linear system in which the camera-IMU extrinsic's translation enters the positions;
3. gravity refined with its magnitude fixed (9.81 m/s²) on its 2-D tangent space, a few
   Gauss-Newton iterations (the velocities and the scale re-solved with it, and optionally
   the accelerometer bias under a prior);
4. the rotation `R_world_c0` taking the refined gravity to (0, 0, -9.81).

Frames and units: `c0` is the first keyframe's camera frame (the SfM's frame); `body` is
the IMU frame; `T_body_cam0 = (R_body_cam, p_body_cam)` maps camera to body coordinates
(`X_body = R_body_cam X_cam + p_body_cam`); world is z up with gravity (0, 0, -9.81) m/s²
(`backend.data.motion.GRAVITY_WORLD`). Rotations in radians, rates in rad/s, accelerations
in m/s², velocities in m/s, timestamps in ns.

Choices, documented:

- Gyro bias Jacobian. gtsam 4.3's Python `PreintegratedImuMeasurements` does not expose
  `delRdelBiasOmega`. It is taken from gtsam's own first-order bias correction instead:
  `pim.predict(NavState(), bias)` applies exactly that correction, so central differences of
  `Log(ΔR̂ᵀ ΔR(b̂ + δ))` in δ (steps of 1e-4 rad/s, the correction is linear in δ in the
  tangent space) give `∂ΔR/∂b_g` as gtsam holds it. Each Gauss-Newton step is followed by a
  re-preintegration at the new bias (a few iterations, until the step is below 1e-7 rad/s),
  so the linearization point is always the current estimate and the deltas of steps 2-3 carry
  no first-order bias correction at all.
- Weights (a deviation from VINS-Mono, which solves with unit weights). The rows are
  expressed in each interval's body frame b_k, as in VINS-Mono, and solved by generalized
  least squares with the covariance of their right-hand sides: the preintegration's
  (gtsam's `preintMeasCov`), the visual rotations' (`visual_rotation_sigma_deg` per keyframe,
  through the gravity terms) and the visual positions' (`visual_position_sigma` times the
  mean keyframe-to-keyframe distance, made metric by the current scale, hence a first solve
  with unit weights and two re-weighted ones; consecutive intervals share a keyframe, so
  their position rows are correlated). Unit weights mix m and m/s rows: on the synthetic
  check (scripts/vio_alignment_check.py) the weighted solve is only modestly more accurate
  (90th percentile of the scale error 4.7 vs 6.1 % over 3 s at speed 1, 0.46 vs 0.63 % at
  speed 2), but it makes the scale's standard deviation meaningful (91 % of the runs within
  1σ, all within 2σ), and that is the rejection criterion for an unobservable scale.
  Columns are scaled to unit norm before solving (the scale column is small where the
  SfM's units are small), which also makes the reported condition number unit-free.
- The accelerometer bias. VINS-Mono does not estimate it (assumed small); with
  `accel_bias_sigma` set (the VIO's default, 0.2 m/s²) it joins step 3's unknowns under a
  zero-mean prior of that σ, as ORB-SLAM3's inertial-only initialization estimates it, its
  Jacobians `∂Δp/∂b_a`, `∂Δv/∂b_a` taken from gtsam's first-order bias correction the same
  way as the gyro's. Why: at the rendered scenes' slow pace (accelerations ~0.2 m/s²) a
  EuRoC-like bias of 0.15 m/s² is as large as the motion's accelerations, and ignoring it
  put the scale 10-37 % off over 3-6 s of true keyframes, accepted with a relative σ of
  5-12 %; estimated, the errors fall to 0-6 % and the σ grows where the bias and the
  scale cannot be told apart (scripts in the CHANGELOG, issue 26). Step 2 (the gravity
  magnitude check) still ignores it. The visual rotations (not the gyro-integrated ones)
  enter steps 2-3, as in VINS-Mono.
- Velocities are unknowns in c0 (not in each body frame as in VINS-Mono): the same model,
  and the world velocities follow by `R_world_c0`.
- Yaw. Gravity fixes roll and pitch only. `R_world_c0` is chosen so that the first
  keyframe's body x axis (the forward axis of the synthetic rig) has zero yaw: its
  horizontal projection points along world +x (VINS-Mono zeroes the first IMU frame's yaw the
  same way). When that axis is within ~6° of vertical, the smallest rotation taking gravity
  to -z is kept instead.
- Rejection (success False, one-line reason; the caller retries with later keyframes):
  fewer than `min_keyframes` keyframes; IMU samples not covering the keyframes; too little
  accelerometer excitation (`min_accel_excitation`, VINS-Mono's measure: the standard
  deviation over intervals of the mean specific force Δv/Δt in the interval's body frame; a
  static or constant-velocity, level rig gives only noise, ~0.01 m/s² at EuRoC's densities);
  gravity magnitude before refinement off by more than `gravity_norm_tolerance` (10 %,
  VINS-Mono's 1 m/s²); scale not positive, outside `scale_range`, or poorly determined
  (relative standard deviation from the least-squares covariance above
  `max_scale_rel_std`: motion without enough translation, e.g. pure rotation); where
  `max_chi2_per_dof` is set, a final system whose weighted residual's χ² per degree of
  freedom exceeds it (the visual poses do not fit the IMU's motion within the noise model,
  which is pessimistic: consistent data give well below 1); a gyro bias
  above `max_gyro_bias`; a non-finite solution. Rotation alone is not a rejection criterion:
  the gyro bias is observable without rotation, and gravity and scale are judged by the
  checks above; the rotation span is reported in the quality figures.
"""

from __future__ import annotations

import dataclasses
from typing import Any

import gtsam
import numpy as np
import scipy.linalg

from backend.data.motion import ImuData, ImuNoise
from backend.geometry import so3
from backend.imu.preintegration import preintegrate, preintegration_params

GRAVITY_MAGNITUDE = 9.81  # m/s², backend.data.motion.GRAVITY_WORLD's norm
_BIAS_STEP = 1e-4  # rad/s, central-difference step for the rotation's gyro-bias Jacobian
_MAX_GAP_PERIODS = 5  # consecutive IMU samples further apart than this many median periods: a gap


@dataclasses.dataclass(frozen=True)
class AlignmentSettings:
    """Options of :func:`align_visual_inertial` (see the module docstring for each check)."""

    min_keyframes: int = 4
    gyro_bias_iterations: int = 4  # Gauss-Newton + re-preintegration rounds (step 1)
    gravity_refine_iterations: int = 4  # tangent-space iterations (step 3)
    gravity_magnitude: float = GRAVITY_MAGNITUDE  # m/s²
    gravity_norm_tolerance: float = 0.10  # relative, |g| of step 2 vs gravity_magnitude
    min_accel_excitation: float = 0.05  # m/s², std of Δv/Δt over intervals (body frames)
    max_scale_rel_std: float = 0.03  # σ_s / s from the least-squares covariance
    scale_range: tuple[float, float] = (1e-3, 1e3)  # accepted metric / visual ratio
    max_gyro_bias: float = 0.5  # rad/s, any axis
    max_chi2_per_dof: float | None = None  # the final system's χ²/dof above this: the visual motion does not fit the IMU's (None: not checked)
    accel_bias_sigma: float | None = None  # m/s², prior σ of the accelerometer bias in step 3 (None: not estimated, as VINS-Mono)
    # Noise of the visual poses, for the weights (and so the scale's standard deviation):
    visual_rotation_sigma_deg: float = 0.2  # degrees, per keyframe and axis
    visual_position_sigma: float = 0.01  # per keyframe and axis, fraction of the mean keyframe-to-keyframe distance

    def __post_init__(self) -> None:
        if self.min_keyframes < 3:
            raise ValueError("min_keyframes must be >= 3 (two intervals)")
        if self.gyro_bias_iterations < 1 or self.gravity_refine_iterations < 1:
            raise ValueError("iteration counts must be >= 1")
        if not (0 < self.scale_range[0] < self.scale_range[1]):
            raise ValueError("scale_range must be 0 < low < high")
        if self.accel_bias_sigma is not None and not self.accel_bias_sigma > 0:
            raise ValueError("accel_bias_sigma must be positive (or None)")


@dataclasses.dataclass(frozen=True)
class AlignmentQuality:
    """Quality figures of one alignment (NaN where the step that computes them was not reached).

    - `rotation_residual_rms_deg`: RMS angle of `Log(ΔR_visualᵀ ΔR_imu)` after the gyro bias;
    - `position_residual_rms_m`, `velocity_residual_rms_mps`: RMS of the final linear
      system's position rows (m) and velocity rows (m/s), body frames, unweighted;
    - `chi2_per_dof`: the weighted residual's χ² per degree of freedom (≈ 1 when the noise
      settings match the data, below 1 when they are pessimistic);
    - `condition_number`: 2-norm condition number of the final weighted system, columns at
      unit norm;
    - `scale_rel_std`: σ_s / s from the final system's covariance `(AᵀC⁻¹A)⁻¹`, inflated by
      χ²/dof when that exceeds 1 (optimistic where errors are systematic, e.g. the
      accelerometer bias, which is not modelled);
    - `accel_excitation_mps2`: VINS-Mono's excitation, std over intervals of Δv/Δt (body);
    - `rotation_span_deg`: largest rotation angle between the first keyframe and any other;
    - `gravity_norm_unrefined`: |g| from step 2 (m/s²), before the magnitude is fixed;
    - `gyro_bias_iterations`: re-preintegration rounds run in step 1.
    """

    rotation_residual_rms_deg: float = float("nan")
    position_residual_rms_m: float = float("nan")
    velocity_residual_rms_mps: float = float("nan")
    chi2_per_dof: float = float("nan")
    condition_number: float = float("nan")
    scale_rel_std: float = float("nan")
    accel_excitation_mps2: float = float("nan")
    rotation_span_deg: float = float("nan")
    gravity_norm_unrefined: float = float("nan")
    gyro_bias_iterations: int = 0


def _nan(*shape: int) -> np.ndarray:
    return np.full(shape, np.nan)


@dataclasses.dataclass(frozen=True, eq=False)
class Alignment:
    """Result of :func:`align_visual_inertial`.

    `success` False comes with a one-line `reason` (empty on success); the other fields hold
    whatever was estimated before the check that failed (NaN otherwise). `bias_gyro` (3,)
    rad/s, body frame; `scale` = metric / visual (metric position = scale · p_c0_cam);
    `gravity_c0` (3,) m/s² in c0 (refined, |g| = 9.81 on success); `R_world_c0` (3, 3);
    `velocity_c0` and `velocity_world` (K, 3) m/s, the body origin's velocity at each
    keyframe, in c0 and in the world frame; `bias_accel` (3,) m/s², body frame (zero unless
    `accel_bias_sigma` is set).
    """

    success: bool
    reason: str
    bias_gyro: np.ndarray
    scale: float
    gravity_c0: np.ndarray
    R_world_c0: np.ndarray
    velocity_c0: np.ndarray
    velocity_world: np.ndarray
    quality: AlignmentQuality
    bias_accel: np.ndarray = dataclasses.field(default_factory=lambda: np.zeros(3))

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready dict (lists and floats; NaN stays NaN)."""
        return {
            "success": self.success,
            "reason": self.reason,
            "bias_gyro": self.bias_gyro.tolist(),
            "scale": float(self.scale),
            "gravity_c0": self.gravity_c0.tolist(),
            "R_world_c0": self.R_world_c0.tolist(),
            "velocity_c0": self.velocity_c0.tolist(),
            "velocity_world": self.velocity_world.tolist(),
            "quality": dataclasses.asdict(self.quality),
            "bias_accel": self.bias_accel.tolist(),
        }


class _ImuGap(Exception):
    """The IMU samples do not cover an interval between two keyframes."""


def _imu_params(noise: ImuNoise) -> gtsam.PreintegrationParams:
    """gtsam parameters, world z up with 9.81 m/s² gravity, the densities of `noise` and an
    integration covariance of 1e-8 m²/s (`backend.imu.preintegration.preintegration_params`)."""
    return preintegration_params(noise, gravity_m_s2=GRAVITY_MAGNITUDE, integration_covariance_m2_s=1e-8)


def _preintegrate(imu: ImuData, t0_ns: int, t1_ns: int, *, params: gtsam.PreintegrationParams, bias_gyro: np.ndarray) -> gtsam.PreintegratedImuMeasurements:
    """Preintegrate over [t0_ns, t1_ns] at gyro bias `bias_gyro` (accelerometer bias zero)
    with `backend.imu.preintegration.preintegrate`; a sample holding for more than
    `_MAX_GAP_PERIODS` median periods, or samples not covering the interval, raise _ImuGap."""
    stamps = imu.timestamp_ns
    period_ns = int(np.median(np.diff(stamps))) if len(stamps) > 1 else 0
    try:
        return preintegrate(imu, int(t0_ns), int(t1_ns), bias_accel=np.zeros(3), bias_gyro=np.asarray(bias_gyro, dtype=float), params=params, max_gap_ns=_MAX_GAP_PERIODS * period_ns)
    except ValueError as error:
        raise _ImuGap(str(error)) from None


def _rotation_jacobian_bias_gyro(pim: gtsam.PreintegratedImuMeasurements) -> np.ndarray:
    """`∂ Log(ΔR̂ᵀ ΔR(b̂_g + δ)) / ∂δ` (3, 3) at δ = 0, from gtsam's own first-order bias
    correction (`predict`), by central differences (see the module docstring)."""
    bias_hat = pim.biasHat()
    b_a, b_g = bias_hat.accelerometer(), bias_hat.gyroscope()
    R_hat_T = pim.deltaRij().matrix().T
    start = gtsam.NavState()
    J = np.empty((3, 3))
    for axis in range(3):
        step = np.zeros(3)
        step[axis] = _BIAS_STEP
        plus = pim.predict(start, gtsam.imuBias.ConstantBias(b_a, b_g + step)).attitude().matrix()
        minus = pim.predict(start, gtsam.imuBias.ConstantBias(b_a, b_g - step)).attitude().matrix()
        J[:, axis] = (so3.log(R_hat_T @ plus) - so3.log(R_hat_T @ minus)) / (2.0 * _BIAS_STEP)
    return J


def _jacobians_bias_accel(pim: gtsam.PreintegratedImuMeasurements) -> tuple[np.ndarray, np.ndarray]:
    """`∂Δp/∂b_a` and `∂Δv/∂b_a` (3, 3 each; body frame b_k, s², s) at the preintegration's
    bias, from gtsam's own first-order bias correction (`predict` from the identity state; the
    gravity terms cancel in the differences), by central differences (linear in b_a)."""
    bias_hat = pim.biasHat()
    b_a, b_g = bias_hat.accelerometer(), bias_hat.gyroscope()
    start = gtsam.NavState()
    J_p, J_v = np.empty((3, 3)), np.empty((3, 3))
    for axis in range(3):
        step = np.zeros(3)
        step[axis] = _BIAS_STEP
        plus = pim.predict(start, gtsam.imuBias.ConstantBias(b_a + step, b_g))
        minus = pim.predict(start, gtsam.imuBias.ConstantBias(b_a - step, b_g))
        J_p[:, axis] = (np.asarray(plus.position()) - np.asarray(minus.position())) / (2.0 * _BIAS_STEP)
        J_v[:, axis] = (np.asarray(plus.velocity()) - np.asarray(minus.velocity())) / (2.0 * _BIAS_STEP)
    return J_p, J_v


def _with_bias_accel(A: np.ndarray, b: np.ndarray, C: np.ndarray, J_p: np.ndarray, J_v: np.ndarray, sigma: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """:func:`_linear_system`'s rows with the accelerometer bias as three more unknowns
    (before the scale, which stays last): the corrected deltas `Δp̂ + J_p b_a`, `Δv̂ + J_v b_a`
    move `J_p` into the position rows and `-J_v` into the velocity rows; and three prior rows
    `b_a = 0` with σ `sigma` m/s² (covariance `C` extended block-diagonally)."""
    n_rows, n = A.shape
    K1 = n_rows // 6
    cols = np.zeros((n_rows, 3))
    for k in range(K1):
        cols[6 * k : 6 * k + 3] = J_p[k]
        cols[6 * k + 3 : 6 * k + 6] = -J_v[k]
    A_aug = np.zeros((n_rows + 3, n + 3))
    A_aug[:n_rows, : n - 1] = A[:, :-1]
    A_aug[:n_rows, n - 1 : n + 2] = cols
    A_aug[:n_rows, -1] = A[:, -1]
    A_aug[n_rows:, n - 1 : n + 2] = np.eye(3)
    b_aug = np.concatenate([b, np.zeros(3)])
    C_aug = np.zeros((n_rows + 3, n_rows + 3))
    C_aug[:n_rows, :n_rows] = C
    C_aug[n_rows:, n_rows:] = np.eye(3) * sigma**2
    return A_aug, b_aug, C_aug


def _tangent_basis(direction: np.ndarray) -> np.ndarray:
    """Two orthonormal vectors (3, 2) perpendicular to the unit vector `direction`."""
    helper = np.array([1.0, 0.0, 0.0]) if abs(direction[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    b1 = np.cross(direction, helper)
    b1 /= np.linalg.norm(b1)
    b2 = np.cross(direction, b1)
    return np.stack([b1, b2], axis=1)


def _rotation_between(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Smallest rotation R with `R a = b` for unit vectors a, b."""
    axis = np.cross(a, b)
    s, c = np.linalg.norm(axis), float(np.dot(a, b))
    if s < 1e-12:
        if c > 0:
            return np.eye(3)
        perp = _tangent_basis(a)[:, 0]  # antiparallel: half a turn about any perpendicular axis
        return 2.0 * np.outer(perp, perp) - np.eye(3)
    return so3.exp(axis / s * np.arctan2(s, c))


def _R_world_c0(gravity_c0: np.ndarray, R_c0_body0: np.ndarray) -> np.ndarray:
    """Rotation taking `gravity_c0` to -z, with the first body's x axis at zero yaw."""
    R = _rotation_between(gravity_c0 / np.linalg.norm(gravity_c0), np.array([0.0, 0.0, -1.0]))
    forward_world = R @ R_c0_body0[:, 0]
    if np.hypot(forward_world[0], forward_world[1]) > 0.1:
        yaw = np.arctan2(forward_world[1], forward_world[0])
        R = so3.exp(np.array([0.0, 0.0, -yaw])) @ R
    return R


def _noise_covariance(
    pims: list[gtsam.PreintegratedImuMeasurements], R_c0_body: np.ndarray, dts: np.ndarray, *, rotation_sigma: float, position_sigma_metric: float, gravity_magnitude: float
) -> np.ndarray:
    """Covariance (6(K-1), 6(K-1)) of the right-hand sides of :func:`_linear_system`.

    Three sources: the preintegration (gtsam's `preintMeasCov`, position and velocity blocks,
    body frame b_k); the visual rotations, whose error δθ of R_k turns `R_kᵀ g Δt` in the
    velocity rows and `R_kᵀ g Δt²/2` in the position rows (isotropic approximation, σ
    `rotation_sigma` rad per axis); the visual positions, error σ `position_sigma_metric` m per
    keyframe and axis (already multiplied by the scale), which enters position row k as
    `R_kᵀ (n_{k+1} - n_k)`, so consecutive intervals are correlated through their shared
    keyframe."""
    K = len(R_c0_body)
    C = np.zeros((6 * (K - 1), 6 * (K - 1)))
    sp2 = position_sigma_metric**2
    for k, pim in enumerate(pims):
        rp, rv = slice(6 * k, 6 * k + 3), slice(6 * k + 3, 6 * k + 6)
        cov = pim.preintMeasCov()
        C[6 * k : 6 * k + 6, 6 * k : 6 * k + 6] += cov[3:9, 3:9]
        dt = dts[k]
        C[rp, rp] += np.eye(3) * ((0.5 * gravity_magnitude * dt**2 * rotation_sigma) ** 2 + 2.0 * sp2)
        C[rv, rv] += np.eye(3) * (gravity_magnitude * dt * rotation_sigma) ** 2
        if k + 1 < K - 1:
            rq = slice(6 * k + 6, 6 * k + 9)  # the next position rows share keyframe k + 1
            block = -sp2 * R_c0_body[k].T @ R_c0_body[k + 1]
            C[rp, rq] += block
            C[rq, rp] += block.T
    return C


def _solve(A: np.ndarray, b: np.ndarray, C: np.ndarray) -> tuple[np.ndarray, np.ndarray, float, float]:
    """Generalized least squares `min (Ax - b)ᵀ C⁻¹ (Ax - b)`, whitened by C's Cholesky factor,
    columns then scaled to unit norm. Returns the solution, its covariance ((AᵀC⁻¹A)⁻¹
    inflated by χ²/dof when that exceeds 1), χ²/dof and the whitened, column-scaled system's
    condition number."""
    try:
        L = np.linalg.cholesky(C)
    except np.linalg.LinAlgError:  # numerically singular (noise-free settings): regularize
        L = np.linalg.cholesky(C + np.eye(len(C)) * max(1e-12 * np.trace(C) / len(C), 1e-18))
    Aw = scipy.linalg.solve_triangular(L, A, lower=True)
    bw = scipy.linalg.solve_triangular(L, b, lower=True)
    norms = np.linalg.norm(Aw, axis=0)
    norms[norms == 0] = 1.0
    An = Aw / norms
    xn, *_ = np.linalg.lstsq(An, bw, rcond=None)
    x = xn / norms
    singular = np.linalg.svd(An, compute_uv=False)
    condition = float(singular[0] / singular[-1]) if singular[-1] > 0 else float("inf")
    chi2_dof = float(np.sum((An @ xn - bw) ** 2)) / max(A.shape[0] - A.shape[1], 1)
    try:
        cov_n = np.linalg.inv(An.T @ An)
    except np.linalg.LinAlgError:
        cov_n = np.full((A.shape[1], A.shape[1]), np.inf)
    cov = max(chi2_dof, 1.0) * cov_n / np.outer(norms, norms)
    return x, cov, chi2_dof, condition


def _linear_system(
    R_c0_body: np.ndarray, p_c0_cam: np.ndarray, p_body_cam: np.ndarray, dts: np.ndarray, dps: np.ndarray, dvs: np.ndarray, gravity_dir: np.ndarray | None, gravity_magnitude: float
) -> tuple[np.ndarray, np.ndarray]:
    """Rows of the VINS-Mono alignment in each interval's body frame b_k.

    Unknowns `[v_c0_0 .. v_c0_{K-1}, g-part, s]`: g-part is g_c0 (3) when `gravity_dir` is
    None, else the tangent coordinates w (2) of `g = gravity_magnitude·gravity_dir + B w`.
    Per interval k (Δt, Δp, Δv preintegrated in b_k, R_k = R_c0_body[k]):

      position: R_kᵀ (v_k Δt + ½ g Δt² - s (p̄_{k+1} - p̄_k)) = -Δp - (R_kᵀ R_{k+1} - I) p_body_cam
      velocity: R_kᵀ (v_{k+1} - v_k - g Δt)                 = Δv
    """
    K = len(R_c0_body)
    ng = 3 if gravity_dir is None else 2
    n = 3 * K + ng + 1
    A = np.zeros((6 * (K - 1), n))
    b = np.zeros(6 * (K - 1))
    if gravity_dir is None:
        G, g_fixed = np.eye(3), np.zeros(3)
    else:
        G, g_fixed = _tangent_basis(gravity_dir), gravity_magnitude * gravity_dir
    for k in range(K - 1):
        Rt = R_c0_body[k].T
        dt = dts[k]
        rp, rv = slice(6 * k, 6 * k + 3), slice(6 * k + 3, 6 * k + 6)
        A[rp, 3 * k : 3 * k + 3] = Rt * dt
        A[rp, 3 * K : 3 * K + ng] = 0.5 * dt**2 * Rt @ G
        A[rp, -1] = -Rt @ (p_c0_cam[k + 1] - p_c0_cam[k])
        b[rp] = -dps[k] - (Rt @ R_c0_body[k + 1] - np.eye(3)) @ p_body_cam - 0.5 * dt**2 * Rt @ g_fixed
        A[rv, 3 * k : 3 * k + 3] = -Rt
        A[rv, 3 * k + 3 : 3 * k + 6] = Rt
        A[rv, 3 * K : 3 * K + ng] = -dt * Rt @ G
        b[rv] = dvs[k] + dt * Rt @ g_fixed
    return A, b


def align_visual_inertial(
    timestamps_ns: np.ndarray,
    R_c0_cam: np.ndarray,
    p_c0_cam: np.ndarray,
    imu: ImuData,
    *,
    T_body_cam0: np.ndarray,
    noise: ImuNoise = ImuNoise(),
    settings: AlignmentSettings = AlignmentSettings(),
    bias_gyro_prior: np.ndarray | None = None,
) -> Alignment:
    """Align an up-to-scale visual trajectory with the IMU (module docstring).

    `timestamps_ns` (K,) increasing keyframe times; `R_c0_cam` (K, 3, 3) and `p_c0_cam`
    (K, 3) the camera poses in c0 from SfM, up to scale (`X_c0 = R X_cam + p`); `imu` the
    samples (body frame) covering [t_0, t_{K-1}]; `T_body_cam0` (4, 4) the camera-IMU
    extrinsic (metres); `noise` the densities for gtsam's preintegration covariances;
    `bias_gyro_prior` (3,) rad/s the starting gyro bias (zero by default). Returns an
    :class:`Alignment`; a rejected alignment has `success` False and a reason. Raises
    ValueError on inconsistent shapes or non-increasing timestamps.
    """
    timestamps_ns = np.asarray(timestamps_ns, dtype=np.int64)
    R_c0_cam = np.asarray(R_c0_cam, dtype=float)
    p_c0_cam = np.asarray(p_c0_cam, dtype=float)
    T_body_cam0 = np.asarray(T_body_cam0, dtype=float)
    K = int(timestamps_ns.shape[0])
    if R_c0_cam.shape != (K, 3, 3) or p_c0_cam.shape != (K, 3):
        raise ValueError(f"expected R_c0_cam ({K}, 3, 3) and p_c0_cam ({K}, 3), got {R_c0_cam.shape} and {p_c0_cam.shape}")
    if T_body_cam0.shape != (4, 4):
        raise ValueError(f"T_body_cam0 must be (4, 4), got {T_body_cam0.shape}")
    if K > 1 and np.any(np.diff(timestamps_ns) <= 0):
        raise ValueError("keyframe timestamps must be strictly increasing")

    bias_gyro = np.zeros(3) if bias_gyro_prior is None else np.asarray(bias_gyro_prior, dtype=float).copy()
    state: dict[str, Any] = {"bias_gyro": bias_gyro, "scale": float("nan"), "gravity_c0": _nan(3), "R_world_c0": _nan(3, 3), "velocity_c0": _nan(K, 3), "velocity_world": _nan(K, 3)}
    quality: dict[str, Any] = {}

    def result(reason: str = "") -> Alignment:
        return Alignment(success=not reason, reason=reason, quality=AlignmentQuality(**quality), **state)

    if K < settings.min_keyframes:
        return result(f"too few keyframes: {K} < {settings.min_keyframes}")
    if not (np.all(np.isfinite(R_c0_cam)) and np.all(np.isfinite(p_c0_cam))):
        return result("non-finite visual poses")

    R_body_cam, p_body_cam = T_body_cam0[:3, :3], T_body_cam0[:3, 3]
    R_c0_body = R_c0_cam @ R_body_cam.T
    R_vis = np.swapaxes(R_c0_body[:-1], 1, 2) @ R_c0_body[1:]  # R_b_k b_{k+1}
    quality["rotation_span_deg"] = float(np.degrees(np.max(np.linalg.norm(so3.log(R_c0_body[0].T @ R_c0_body[1:]), axis=1))))
    params = _imu_params(noise)

    def preintegrate_all(bias: np.ndarray) -> list[gtsam.PreintegratedImuMeasurements]:
        return [_preintegrate(imu, int(timestamps_ns[k]), int(timestamps_ns[k + 1]), params=params, bias_gyro=bias) for k in range(K - 1)]

    # Step 1: gyroscope bias (Gauss-Newton, re-preintegrating at every new estimate).
    try:
        pims = preintegrate_all(bias_gyro)
    except _ImuGap as gap:
        return result(f"IMU does not cover the keyframes: {gap}")
    for iteration in range(settings.gyro_bias_iterations):
        J = np.concatenate([_rotation_jacobian_bias_gyro(p) for p in pims])
        r = np.concatenate([so3.log(R_vis[k].T @ pims[k].deltaRij().matrix()) for k in range(K - 1)])
        step, *_ = np.linalg.lstsq(J, -r, rcond=None)
        bias_gyro = bias_gyro + step
        pims = preintegrate_all(bias_gyro)
        quality["gyro_bias_iterations"] = iteration + 1
        if np.linalg.norm(step) < 1e-7:
            break
    state["bias_gyro"] = bias_gyro
    angles = np.linalg.norm([so3.log(R_vis[k].T @ pims[k].deltaRij().matrix()) for k in range(K - 1)], axis=1)
    quality["rotation_residual_rms_deg"] = float(np.degrees(np.sqrt(np.mean(angles**2))))
    if not np.all(np.isfinite(bias_gyro)) or np.max(np.abs(bias_gyro)) > settings.max_gyro_bias:
        return result(f"implausible gyro bias {np.array2string(bias_gyro, precision=4)} rad/s (limit {settings.max_gyro_bias})")

    dts = np.array([p.deltaTij() for p in pims])
    dps = np.array([p.deltaPij() for p in pims])
    dvs = np.array([p.deltaVij() for p in pims])
    specific_force = dvs / dts[:, None]
    excitation = float(np.sqrt(np.sum((specific_force - specific_force.mean(axis=0)) ** 2) / max(K - 2, 1)))
    quality["accel_excitation_mps2"] = excitation
    if excitation < settings.min_accel_excitation:
        return result(f"too little accelerometer excitation: {excitation:.3f} < {settings.min_accel_excitation} m/s²")

    # Step 2: velocities, gravity and scale. The visual position noise is metric only once the
    # scale is known: a first solve with unit weights (VINS-Mono's), then two weighted ones.
    rotation_sigma = np.radians(settings.visual_rotation_sigma_deg)
    baseline_visual = float(np.mean(np.linalg.norm(np.diff(p_c0_cam, axis=0), axis=1)))

    def covariance(scale: float) -> np.ndarray:
        sigma_p = settings.visual_position_sigma * baseline_visual * abs(scale) if np.isfinite(scale) else 0.0
        return _noise_covariance(pims, R_c0_body, dts, rotation_sigma=rotation_sigma, position_sigma_metric=sigma_p, gravity_magnitude=settings.gravity_magnitude)

    A, b = _linear_system(R_c0_body, p_c0_cam, p_body_cam, dts, dps, dvs, None, settings.gravity_magnitude)
    x, *_ = _solve(A, b, np.eye(len(b)))  # unit weights (VINS-Mono) for a first scale
    for _ in range(2):
        x, *_ = _solve(A, b, covariance(float(x[-1])))
    scale = float(x[-1])
    gravity_c0 = x[3 * K : 3 * K + 3]
    g_norm = float(np.linalg.norm(gravity_c0))
    quality["gravity_norm_unrefined"] = g_norm
    state.update(scale=scale, gravity_c0=gravity_c0, velocity_c0=x[: 3 * K].reshape(K, 3))
    if not np.all(np.isfinite(x)):
        return result("non-finite linear solution")
    if abs(g_norm - settings.gravity_magnitude) > settings.gravity_norm_tolerance * settings.gravity_magnitude:
        return result(f"gravity magnitude {g_norm:.2f} m/s² off {settings.gravity_magnitude} by more than {100 * settings.gravity_norm_tolerance:.0f} %")

    # Step 3: gravity refinement with |g| fixed, on the tangent space; the last solve, at the
    # final direction, gives the velocities and the scale.
    # With `accel_bias_sigma`, the accelerometer bias joins the unknowns here (under a prior):
    # at a slow start the unmodelled bias is as large as the motion's accelerations and drags
    # the scale (tens of per cent at 0.2 m/s² of excitation with EuRoC's 0.1 m/s² of bias).
    gravity_dir = gravity_c0 / g_norm
    bias_accel = np.zeros(3)
    if settings.accel_bias_sigma is not None:
        J_ba = [_jacobians_bias_accel(p) for p in pims]
        J_p, J_v = np.array([j[0] for j in J_ba]), np.array([j[1] for j in J_ba])
    for iteration in range(settings.gravity_refine_iterations + 1):
        A, b = _linear_system(R_c0_body, p_c0_cam, p_body_cam, dts, dps, dvs, gravity_dir, settings.gravity_magnitude)
        C = covariance(scale)
        n_rows = len(b)
        if settings.accel_bias_sigma is not None:
            A, b, C = _with_bias_accel(A, b, C, J_p, J_v, settings.accel_bias_sigma)
            x, cov, chi2_dof, condition = _solve(A, b, C)
            bias_accel = x[3 * K + 2 : 3 * K + 5]
        else:
            x, cov, chi2_dof, condition = _solve(A, b, C)
        scale = float(x[-1])
        if iteration < settings.gravity_refine_iterations:
            g = settings.gravity_magnitude * gravity_dir + _tangent_basis(gravity_dir) @ x[3 * K : 3 * K + 2]
            gravity_dir = g / np.linalg.norm(g)
    residual = (A @ x - b)[:n_rows].reshape(K - 1, 2, 3)
    gravity_c0 = settings.gravity_magnitude * gravity_dir
    velocity_c0 = x[: 3 * K].reshape(K, 3)
    scale_rel_std = float(np.sqrt(max(cov[-1, -1], 0.0)) / abs(scale)) if scale != 0 else float("inf")
    quality.update(
        position_residual_rms_m=float(np.sqrt(np.mean(residual[:, 0] ** 2))),
        velocity_residual_rms_mps=float(np.sqrt(np.mean(residual[:, 1] ** 2))),
        chi2_per_dof=chi2_dof,
        condition_number=condition,
        scale_rel_std=scale_rel_std,
    )
    state.update(scale=scale, gravity_c0=gravity_c0, velocity_c0=velocity_c0, bias_accel=bias_accel)
    if not np.all(np.isfinite(x)):
        return result("non-finite refined solution")
    if scale <= 0:
        return result(f"scale {scale:.4g} is not positive")
    if not settings.scale_range[0] <= scale <= settings.scale_range[1]:
        return result(f"implausible scale {scale:.4g} outside [{settings.scale_range[0]:g}, {settings.scale_range[1]:g}]")
    if not scale_rel_std <= settings.max_scale_rel_std:
        return result(f"scale poorly determined: relative std {scale_rel_std:.3f} > {settings.max_scale_rel_std} (too little translation)")
    if settings.max_chi2_per_dof is not None and not chi2_dof <= settings.max_chi2_per_dof:
        return result(f"visual and inertial motion disagree: chi2/dof {chi2_dof:.3g} > {settings.max_chi2_per_dof:g}")

    # Step 4: the world frame.
    R_world_c0 = _R_world_c0(gravity_c0, R_c0_body[0])
    state.update(R_world_c0=R_world_c0, velocity_world=velocity_c0 @ R_world_c0.T)
    return result()
