"""Inertial variables and factors in the project's own solver (VIO, DESIGN §5).

A keyframe with inertial state has, next to its camera pose, a velocity and the IMU biases:
9 columns `(δv, δb_a, δb_g)` (m/s in the world frame, m/s², rad/s), placed in the camera
group after the pose columns, so the Schur complement keeps them in the reduced system with
the poses. The solver's poses are `T_world_camera`; the IMU factors are stated for
`T_world_body = T_world_camera · T_camera_body` and chained through the extrinsic here.

Factors, each whitened:
- IMU preintegration between consecutive inertial keyframes (gtsam's `ImuFactor`, evaluated
  with its analytic Jacobians by :func:`backend.imu.preintegration.imu_factor_error`;
  the bias is re-linearized by the preintegration's first-order correction);
- the bias random walk between them;
- a linear prior (:class:`LinearPrior`): the marginalization prior of a sliding window
  (:mod:`backend.optim.marginalization`), or any Gaussian prior on poses, inertial states and
  planes.
"""

from __future__ import annotations

import dataclasses
from typing import Any

import numpy as np

from backend.data.motion import ImuNoise
from backend.geometry import plane as plane_geo
from backend.geometry import so3

INERTIAL_DIM = 9  # (δv, δb_a, δb_g)


@dataclasses.dataclass(frozen=True)
class LinearPrior:
    """A Gaussian prior in square-root form, `r = A · (x ⊟ x̄) + b` (whitened), over the
    camera poses `pose_index` (6 columns each, `(δθ, δt)` with `x ⊟ x̄ = (Log(R̄ᵀR), t - t̄)`),
    the inertial states `inertial_index` (9 each, additive) and the planes `plane_index`
    (3 each, in the tangent coordinates of :func:`backend.geometry.plane.retract` at n̄).
    Columns of `A` (r, D) are in that order. `x̄`: `R`, `t`, `inertial` (Q, 9), `plane_n`,
    `plane_d` at the linearization point. Indices are the problem's pose and plane indices."""

    pose_index: np.ndarray
    inertial_index: np.ndarray
    plane_index: np.ndarray
    R: np.ndarray
    t: np.ndarray
    inertial: np.ndarray
    plane_n: np.ndarray
    plane_d: np.ndarray
    A: np.ndarray
    b: np.ndarray

    @property
    def dim(self) -> int:
        return 6 * len(self.pose_index) + INERTIAL_DIM * len(self.inertial_index) + 3 * len(self.plane_index)


@dataclasses.dataclass(frozen=True)
class InertialData:
    """The inertial part of a problem. `T_body_camera` (4, 4): the camera in the IMU (body)
    frame. `velocity` (N, 3) m/s (world) and `bias` (N, 6) `(b_a, b_g)` initial values per
    pose; `free` (N,) bool: poses whose inertial state is optimized (the others are held).
    `imu_i`, `imu_j` (M,): pose indices of each preintegration `imu[m]` (gtsam
    `PreintegratedImuMeasurements`, or :class:`backend.imu.preintegration.PreparedImuFactor`, from
    keyframe i to j). `noise`: the sensor's densities (sensor.yaml), whose random walks
    weigh the bias factor over each interval `dt_s[m]`. `prior`: a :class:`LinearPrior` or
    None."""

    T_body_camera: np.ndarray
    velocity: np.ndarray
    bias: np.ndarray
    free: np.ndarray
    imu_i: np.ndarray
    imu_j: np.ndarray
    imu: tuple[Any, ...]
    dt_s: np.ndarray
    noise: ImuNoise
    prior: LinearPrior | None = None


def body_poses(R_world_camera: np.ndarray, t_world_camera: np.ndarray, T_body_camera: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """`T_world_body = T_world_camera · T_camera_body` for (N, 3, 3), (N, 3) camera poses, and
    the Jacobian (N, 6, 6) of the body pose's `(δθ, δt)` w.r.t. the camera pose's (both in the
    project's retraction `R Exp(δθ)`, `t + δt`)."""
    R_bc, t_bc = T_body_camera[:3, :3], T_body_camera[:3, 3]
    R_cb = R_bc.T
    t_cb = -R_cb @ t_bc
    R_wb = R_world_camera @ R_cb
    t_wb = t_world_camera + R_world_camera @ t_cb
    J = np.zeros((len(R_world_camera), 6, 6))
    J[:, :3, :3] = R_bc  # R_wc Exp(δθ) R_cb = R_wb Exp(R_bc δθ)
    J[:, 3:, :3] = -R_world_camera @ so3.hat(t_cb)
    J[:, 3:, 3:] = np.eye(3)
    return R_wb, t_wb, J


def imu_residuals(R_world_camera: np.ndarray, t_world_camera: np.ndarray, velocity: np.ndarray, bias: np.ndarray, data: InertialData) -> tuple[np.ndarray, np.ndarray]:
    """Whitened IMU residuals (M, 9) and Jacobians (M, 9, 30) over the slots
    `pose_i (6) | inertial_i (9) | pose_j (6) | inertial_j (9)` (inertial_j has no entries:
    the factor depends on the bias at i only)."""
    from backend.imu.preintegration import imu_factor_error

    M = len(data.imu_i)
    res = np.zeros((M, 9))
    J = np.zeros((M, 9, 30))
    if M == 0:
        return res, J
    R_wb, t_wb, J_bc = body_poses(R_world_camera, t_world_camera, data.T_body_camera)
    for m in range(M):
        i, j = int(data.imu_i[m]), int(data.imu_j[m])
        e = imu_factor_error(data.imu[m], R_wb[i], t_wb[i], velocity[i], R_wb[j], t_wb[j], velocity[j], bias[i])
        res[m] = e.residual
        J[m, :, 0:6] = e.J_pose_i @ J_bc[i]
        J[m, :, 6:9] = e.J_v_i
        J[m, :, 9:15] = e.J_bias_i
        J[m, :, 15:21] = e.J_pose_j @ J_bc[j]
        J[m, :, 21:24] = e.J_v_j
    return res, J


def bias_walk_residuals(bias: np.ndarray, data: InertialData) -> tuple[np.ndarray, np.ndarray]:
    """Whitened bias random-walk residuals (M, 6) and Jacobians (M, 6, 18) over
    `inertial_i (9) | inertial_j (9)` (:func:`backend.imu.preintegration.bias_random_walk_error`)."""
    from backend.imu.preintegration import bias_random_walk_error

    M = len(data.imu_i)
    res = np.zeros((M, 6))
    J = np.zeros((M, 6, 18))
    if M:
        e = bias_random_walk_error(bias[data.imu_i], bias[data.imu_j], data.dt_s, data.noise)
        res[:] = e.residual
        J[:, :, 3:9] = e.J_bias_i
        J[:, :, 12:18] = e.J_bias_j
    return res, J


def prior_residual(prior: LinearPrior, R: np.ndarray, t: np.ndarray, inertial: np.ndarray, plane_n: np.ndarray, plane_d: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The prior's whitened residual (r,) and Jacobian (r, D) at the current values of its
    variables (`R`, `t` of its poses, `inertial` (Q, 9), `plane_n`, `plane_d` of its planes).
    The rotation's local coordinates `Log(R̄ᵀR)` are differentiated exactly (`J_r⁻¹`), the
    planes' through :func:`plane_local`."""
    P, Q, K = len(prior.pose_index), len(prior.inertial_index), len(prior.plane_index)
    A = prior.A
    r = A.shape[0]
    parts = []
    J = A.copy()
    if P:
        w = so3.log(np.einsum("nji,njk->nik", prior.R, R))
        parts.append(np.concatenate([w, t - prior.t], axis=1).ravel())
        A_p = A[:, : 6 * P].reshape(r, P, 6)
        J[:, : 6 * P].reshape(r, P, 6)[:, :, :3] = _times_blocks(A_p[:, :, :3], so3.right_jacobian_inv(w))
    if Q:
        parts.append((inertial - prior.inertial).ravel())
    if K:
        local, J_plane = plane_local(prior.plane_n, prior.plane_d, plane_n, plane_d)
        parts.append(local.ravel())
        c = 6 * P + INERTIAL_DIM * Q
        J[:, c:] = _times_blocks(A[:, c:].reshape(r, K, 3), J_plane).reshape(r, 3 * K)
    dx = np.concatenate(parts) if parts else np.zeros(0)
    return A @ dx + prior.b, J


def _times_blocks(A: np.ndarray, B: np.ndarray) -> np.ndarray:
    """`A[:, k] @ B[k]` for every k: (r, K, 3) times K blocks (K, 3, 3), summed term by term
    in the order of `einsum("rki,kij->rkj")` (the same values, twice as fast here)."""
    return A[:, :, 0, None] * B[None, :, 0, :] + A[:, :, 1, None] * B[None, :, 1, :] + A[:, :, 2, None] * B[None, :, 2, :]


def plane_local(n_ref: np.ndarray, d_ref: np.ndarray, n: np.ndarray, d: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Tangent coordinates (K, 3) of planes (n, d) around (n_ref, d_ref), the exact inverse
    of :func:`backend.geometry.plane.retract`: `retract(n_ref, d_ref, δ)` with
    `δ = (Bᵀn / (n_ref·n), d - d_ref)` gives back (n, d) (B: the tangent basis at n_ref;
    normals on the same side as n_ref). Also the Jacobian (K, 3, 3) of δ w.r.t. a
    retraction of (n, d) at (n, d)."""
    B = plane_geo.tangent_basis(n_ref)  # (K, 3, 2)
    sign = np.where(np.einsum("ki,ki->k", n, n_ref) < 0, -1.0, 1.0)
    n_s = n * sign[:, None]
    c = np.einsum("ki,ki->k", n_ref, n_s)
    Btn = np.einsum("kij,ki->kj", B, n_s)
    local = np.concatenate([Btn / c[:, None], (d * sign - d_ref)[:, None]], axis=1)
    df_dn = np.swapaxes(B, 1, 2) / c[:, None, None] - Btn[:, :, None] * n_ref[:, None, :] / (c**2)[:, None, None]  # (K, 2, 3)
    J = np.zeros((len(n), 3, 3))
    J[:, :2, :2] = np.einsum("kij,kjl->kil", df_dn, sign[:, None, None] * plane_geo.tangent_basis(n))
    J[:, 2, 2] = sign
    return local, J
