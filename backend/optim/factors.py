"""Residuals and analytic Jacobians of every factor type, vectorized over observations.

Each function takes stacked inputs (leading axis M = observations or landmarks) and returns
*unwhitened* values with their Jacobians, either as a dict of blocks (M, r, dim) keyed by
slot or, where the docstring says so, as one array with the slots concatenated. Slots:
`"anchor"`/`"pose"` (6: `(δθ, δt)`, see :mod:`backend.geometry.se3`), `"rho"` (1),
`"line"` (4: `(δθ, δφ)`, see :mod:`backend.geometry.line`), `"plane"` (3: `(δn, δd)`, see
:mod:`backend.geometry.plane`). The per-observation loops run compiled
(:mod:`backend.optim.kernels`). Frames: poses are `T_world_camera`; an observation from a
camera whose centre sits at `offset` (metres, in the left camera frame; `(b, 0, 0)` for the
right camera of a rectified stereo pair) is projected through that camera.
"""

from __future__ import annotations

import numpy as np

from backend.geometry import so3
from backend.geometry.camera import PinholeCamera
from backend.optim import kernels

Blocks = dict[str, np.ndarray]

_E1 = np.array([1.0, 0.0, 0.0])
_E2 = np.array([0.0, 1.0, 0.0])


def _mv(A: np.ndarray, x: np.ndarray) -> np.ndarray:
    return np.einsum("...ij,...j->...i", A, x)


def _outer(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    return a[..., :, None] * b[..., None, :]


def _transpose(A: np.ndarray) -> np.ndarray:
    return np.swapaxes(A, -1, -2)


# --------------------------------------------------------------------------- points in 3D


def point_world_inverse_depth(x_anchor: np.ndarray, rho: np.ndarray, R_world_anchor: np.ndarray, t_world_anchor: np.ndarray) -> tuple[np.ndarray, Blocks]:
    """`X_w = R_a x̂_a / ρ + t_a` and its Jacobians w.r.t. the anchor pose and ρ.

    x_anchor: (M, 3) normalized anchor observation; rho (M,) in 1/m.
    Returns X_w (M, 3) and blocks {"anchor": (M, 3, 6), "rho": (M, 3, 1)}.
    """
    p_anchor = x_anchor / rho[:, None]
    p_world = _mv(R_world_anchor, p_anchor) + t_world_anchor
    J_anchor = np.empty(p_world.shape + (6,))
    J_anchor[..., :3] = -R_world_anchor @ so3.hat(p_anchor)
    J_anchor[..., 3:] = np.eye(3)
    J_rho = (-_mv(R_world_anchor, x_anchor) / (rho**2)[:, None])[..., None]
    return p_world, {"anchor": J_anchor, "rho": J_rho}


def point_world_on_plane(
    x_anchor: np.ndarray,
    n_world: np.ndarray,
    d_world: np.ndarray,
    B_plane: np.ndarray,
    R_world_anchor: np.ndarray,
    t_world_anchor: np.ndarray,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Co-planar (-w) point: the anchor ray `t_a + h R_a x̂_a` meets the plane (n, d).

    `h = -(n·t_a + d) / (n·R_a x̂_a)` is the depth along x̂_a (paper Eq. 3 in the anchor
    frame). B_plane (P, 3, 2) is the tangent basis of n. With `ray = R_a x̂_a`, `s = n·ray`,
    `q = n·t_a + d`: `∂X/∂δθ_a = (h I + ray (q/s²) nᵀ)(-R_a [x̂_a]_×)`,
    `∂X/∂δt_a = I - ray nᵀ/s`, `∂X/∂n = ray (-t_a/s + (q/s²) ray)ᵀ`, `∂X/∂d = -ray/s`.
    Returns X_w (P, 3), the Jacobian (P, 3, 9) w.r.t. [anchor (6) | plane (3)] and h (P,)
    (the caller rejects h <= 0).
    """
    P = len(x_anchor)
    p_world = np.empty((P, 3))
    J = np.empty((P, 3, 9))
    h = np.empty(P)
    kernels.point_on_plane(
        np.ascontiguousarray(x_anchor, dtype=float),
        np.ascontiguousarray(n_world, dtype=float),
        np.ascontiguousarray(d_world, dtype=float),
        np.ascontiguousarray(B_plane, dtype=float),
        np.ascontiguousarray(R_world_anchor, dtype=float),
        np.ascontiguousarray(t_world_anchor, dtype=float),
        p_world,
        J,
        h,
    )
    return p_world, J, h


# --------------------------------------------------------------------------- projection


def point_reprojection(
    camera: PinholeCamera,
    p_world: np.ndarray,
    J_world: np.ndarray,
    landmark: np.ndarray,
    R_world_camera: np.ndarray,
    t_world_camera: np.ndarray,
    pose: np.ndarray,
    offset_camera: np.ndarray,
    uv_observed: np.ndarray,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Pixel reprojection residual `π_K(R_kᵀ (X_w - t_k) - o) - u_k`, (M, 2).

    p_world (L, 3) and J_world (L, 3, D) are the landmarks' world positions and Jacobians
    w.r.t. their own variables; observation m sees landmark `landmark[m]` from pose
    `pose[m]` of the (N, 3, 3) / (N, 3) pose arrays. With G = ∂π/∂p_cam, the Jacobian is
    `[G R_kᵀ J_world, G [p_rel]_×, -G R_kᵀ]` (M, 2, D + 6), the last 6 columns for the
    observing pose's `(δθ, δt)`. Also returns the depth (M,).
    """
    M = len(landmark)
    D = J_world.shape[2]
    residual = np.empty((M, 2))
    J = np.empty((M, 2, D + 6))
    depth = np.empty(M)
    kernels.point_reprojection(
        camera.fx,
        camera.fy,
        camera.cx,
        camera.cy,
        p_world,
        J_world,
        landmark,
        R_world_camera,
        t_world_camera,
        pose,
        np.ascontiguousarray(offset_camera, dtype=float),
        np.ascontiguousarray(uv_observed, dtype=float),
        residual,
        J,
        depth,
    )
    return residual, J, depth


# --------------------------------------------------------------------------- lines in 3D


def line_world_orthonormal(U: np.ndarray, phi: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """World Plücker (m, v) of orthonormal lines and their (M, 3, 4) Jacobians w.r.t. `(δθ, δφ)`."""
    c, s = np.cos(phi), np.sin(phi)
    m = c[:, None] * U[..., 0]
    v = s[:, None] * U[..., 1]
    J_m = np.empty(m.shape + (4,))
    J_v = np.empty(m.shape + (4,))
    J_m[..., :3] = -c[:, None, None] * (U @ so3.hat(_E1))
    J_v[..., :3] = -s[:, None, None] * (U @ so3.hat(_E2))
    J_m[..., 3] = -s[:, None] * U[..., 0]
    J_v[..., 3] = c[:, None] * U[..., 1]
    return m, v, J_m, J_v


def line_world_on_plane(
    n_backprojection_anchor: np.ndarray,
    n_world: np.ndarray,
    d_world: np.ndarray,
    B_plane: np.ndarray,
    R_world_anchor: np.ndarray,
    t_world_anchor: np.ndarray,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Co-planar (-w) line: the anchor back-projection plane `(n_l, 0)` meets (n, d).

    In the anchor frame `v_a = n_l × n_a`, `m_a = -d_a n_l`; in the world with
    `N = R_a n_l`, `q = n·t_a + d`: `v_w = N × n_w`, `m_w = -q N + t_a × v_w`. Jacobians:
    `∂N/∂δθ_a = -R_a [n_l]_×`, `∂v/∂N = -[n]_×`, `∂v/∂n = [N]_×`,
    `∂m/∂N = -q I - [t_a]_× [n]_×`, `∂m/∂n = -N t_aᵀ + [t_a]_× [N]_×`,
    `∂m/∂δt_a = -N nᵀ - [v]_×`, `∂m/∂d = -N`.
    Returns m_w, v_w (L, 3), the Jacobian (L, 6, 9) of the stacked (m, v) w.r.t. [anchor (6)
    | plane (3)] and `|N × n_w|` (L,) (small when the back-projection plane is parallel to
    the plane).
    """
    L = len(n_backprojection_anchor)
    m = np.empty((L, 3))
    v = np.empty((L, 3))
    J = np.empty((L, 6, 9))
    kernels.line_on_plane(
        np.ascontiguousarray(n_backprojection_anchor, dtype=float),
        np.ascontiguousarray(n_world, dtype=float),
        np.ascontiguousarray(d_world, dtype=float),
        np.ascontiguousarray(B_plane, dtype=float),
        np.ascontiguousarray(R_world_anchor, dtype=float),
        np.ascontiguousarray(t_world_anchor, dtype=float),
        m,
        v,
        J,
    )
    return m, v, J, np.linalg.norm(v, axis=-1)


def line_reprojection(
    camera: PinholeCamera,
    m_world: np.ndarray,
    v_world: np.ndarray,
    J_mv: np.ndarray,
    landmark: np.ndarray,
    R_world_camera: np.ndarray,
    t_world_camera: np.ndarray,
    pose: np.ndarray,
    offset_camera: np.ndarray,
    x_start: np.ndarray,
    x_end: np.ndarray,
) -> tuple[np.ndarray, np.ndarray]:
    """Endpoint-to-line residual (paper Eq. error-line) in pixels, (M, 2).

    With `l = m_c` the image line of the world line in the observing camera (moved by the
    camera offset: `m_o = m_c - o × v_c`), `r = f [x̂_s·l, x̂_e·l] / sqrt(l₁² + l₂²)`
    for the observed normalized endpoints x̂_s, x̂_e (M, 3). m_world, v_world (L, 3) are
    the lines' world Plücker coordinates and J_mv (L, 6, D) the Jacobian of the stacked
    (m, v) w.r.t. their own variables; `landmark` and `pose` index them per observation.
    Returns the residual and the Jacobian (M, 2, D + 6), the last 6 columns for the pose:
    `∂l/∂δθ = [m_rel]_× - [o]_× [v_c]_×`, `∂l/∂δt = R_kᵀ [v_w]_×`.
    """
    M = len(landmark)
    D = J_mv.shape[2]
    residual = np.empty((M, 2))
    J = np.empty((M, 2, D + 6))
    kernels.line_reprojection(
        camera.fx,
        np.ascontiguousarray(m_world),
        np.ascontiguousarray(v_world),
        np.ascontiguousarray(J_mv),
        landmark,
        R_world_camera,
        t_world_camera,
        pose,
        np.ascontiguousarray(offset_camera, dtype=float),
        np.ascontiguousarray(x_start),
        np.ascontiguousarray(x_end),
        residual,
        J,
    )
    return residual, J


# --------------------------------------------------------------------------- -r residuals


def point_plane_relative(
    x_anchor: np.ndarray,
    rho: np.ndarray,
    R_world_anchor: np.ndarray,
    t_world_anchor: np.ndarray,
    n_world: np.ndarray,
    d_world: np.ndarray,
    B_plane: np.ndarray,
) -> tuple[np.ndarray, np.ndarray]:
    """Scale-safe point-to-plane residual (DESIGN §3, -r), (K, 1), dimensionless:
    `r = (n·X_w + d) / |n·t_a + d|`, the signed distance of `X_w = R_a x̂_a / ρ + t_a` to the
    world plane (n, d) as a fraction of the anchor camera's distance to it (the caller
    whitens by 1/σ_rel). Invariant to scaling the map (t, 1/ρ, d all times s > 0).

    x_anchor (K, 3) normalized anchor ray, rho (K,) 1/m, anchor pose (K, 3, 3) / (K, 3),
    plane (K, 3) / (K,) with tangent basis B_plane (K, 3, 2). With `e = n·X_w + d`,
    `q = n·t_a + d`, `p = x̂_a / ρ`, `n_a = R_aᵀ n`: `dr = (de - r sign(q) dq) / |q|`,
    `∂e/∂δθ_a = (p × n_a)ᵀ`, `∂e/∂δt_a = ∂q/∂δt_a = nᵀ` (q does not depend on δθ_a),
    `∂e/∂ρ = -(n_a·x̂_a)/ρ²`, `∂e/∂δn = X_wᵀ B`, `∂q/∂δn = t_aᵀ B`, `∂e/∂δd = ∂q/∂δd = 1`.
    Returns the residual and its Jacobian (K, 1, 10) w.r.t. [anchor (6) | ρ (1) | plane (3)].
    """
    K = len(x_anchor)
    residual = np.empty((K, 1))
    J = np.empty((K, 1, 10))
    kernels.point_plane_relative(
        np.ascontiguousarray(x_anchor, dtype=float),
        np.ascontiguousarray(rho, dtype=float),
        np.ascontiguousarray(R_world_anchor, dtype=float),
        np.ascontiguousarray(t_world_anchor, dtype=float),
        np.ascontiguousarray(n_world, dtype=float),
        np.ascontiguousarray(d_world, dtype=float),
        np.ascontiguousarray(B_plane, dtype=float),
        residual,
        J,
    )
    return residual, J


def line_plane_relative(
    m_world: np.ndarray,
    v_world: np.ndarray,
    J_mv: np.ndarray,
    landmark: np.ndarray,
    x_start: np.ndarray,
    x_end: np.ndarray,
    R_world_anchor: np.ndarray,
    t_world_anchor: np.ndarray,
    n_world: np.ndarray,
    d_world: np.ndarray,
    B_plane: np.ndarray,
) -> tuple[np.ndarray, np.ndarray]:
    """Scale-safe line-to-plane residuals (DESIGN §3, -r), (K, 2), dimensionless:
    `r_j = (n·P_j + d) / |n·t_a + d|` for P_start, P_end the points of the line nearest to
    the anchor endpoint rays `t_a + λ w`, `w = R_a x̂` (:func:`line_point_nearest_ray`).

    m_world, v_world (L, 3) are the lines' world Plücker coordinates, J_mv (L, 6, D) the
    Jacobian of the stacked (m, v) w.r.t. the line's own variables (orthonormal:
    :func:`line_world_orthonormal`, D = 4); pair k uses line `landmark[k]`, its anchor
    pose (K, 3, 3) / (K, 3), normalized anchor endpoints x_start, x_end (K, 3) and the
    world plane (K, 3) / (K,) with tangent basis B_plane (K, 3, 2). Chain rule as in
    :func:`point_plane_relative` with `de = nᵀ dP` (+ the plane terms `P_jᵀ B δn + δd`):
    `∂P/∂δθ_a = ∂P/∂w (-R_a [x̂]_×)`, `∂P/∂δt_a = ∂P/∂c`, `∂P/∂line = [∂P/∂m, ∂P/∂v] J_mv`,
    and `∂q/∂δt_a = nᵀ`, `∂q/∂δn = t_aᵀ B`, `∂q/∂δd = 1`.
    Returns the residual and its Jacobian (K, 2, 6 + D + 3) w.r.t. [anchor | line | plane].
    """
    K = len(landmark)
    D = J_mv.shape[2]
    residual = np.empty((K, 2))
    J = np.empty((K, 2, 6 + D + 3))
    kernels.line_plane_relative(
        np.ascontiguousarray(m_world, dtype=float),
        np.ascontiguousarray(v_world, dtype=float),
        np.ascontiguousarray(J_mv, dtype=float),
        np.ascontiguousarray(landmark, dtype=np.int64),
        np.ascontiguousarray(x_start, dtype=float),
        np.ascontiguousarray(x_end, dtype=float),
        np.ascontiguousarray(R_world_anchor, dtype=float),
        np.ascontiguousarray(t_world_anchor, dtype=float),
        np.ascontiguousarray(n_world, dtype=float),
        np.ascontiguousarray(d_world, dtype=float),
        np.ascontiguousarray(B_plane, dtype=float),
        residual,
        J,
    )
    return residual, J


def line_point_nearest_ray(m_world: np.ndarray, v: np.ndarray, c_world: np.ndarray, w_world: np.ndarray) -> tuple[np.ndarray, dict[str, np.ndarray], np.ndarray]:
    """The point of the line (m, v) closest to the ray `c + λ w`.

    Returns P (M, 3), its Jacobians {"m", "v", "c", "w"} (M, 3, 3) and the conditioning
    `D = |v|²|w|² - (v·w)²` (M,) (zero when the ray is parallel to the line).
    """
    a = np.sum(v * v, axis=-1)
    vxm = so3.cross(v, m_world)
    p0 = vxm / a[:, None]
    r0 = p0 - c_world
    b = np.sum(v * w_world, axis=-1)
    cc = np.sum(w_world * w_world, axis=-1)
    dd = np.sum(v * r0, axis=-1)
    e = np.sum(w_world * r0, axis=-1)
    D = a * cc - b**2
    mu = (b * e - cc * dd) / D
    P = p0 + mu[:, None] * v
    inv_D = (1.0 / D)[:, None]
    dmu_dv = (e[:, None] * w_world - cc[:, None] * r0 - mu[:, None] * (2.0 * cc[:, None] * v - 2.0 * b[:, None] * w_world)) * inv_D
    dmu_dw = (e[:, None] * v + b[:, None] * r0 - 2.0 * dd[:, None] * w_world - mu[:, None] * (2.0 * a[:, None] * w_world - 2.0 * b[:, None] * v)) * inv_D
    dmu_dr0 = (b[:, None] * w_world - cc[:, None] * v) * inv_D
    dp0_dm = so3.hat(v) / a[:, None, None]
    dp0_dv = -so3.hat(m_world) / a[:, None, None] - _outer(vxm, 2.0 * v) / (a**2)[:, None, None]
    A = np.eye(3) + _outer(v, dmu_dr0)
    J = {
        "m": A @ dp0_dm,
        "v": A @ dp0_dv + mu[:, None, None] * np.eye(3) + _outer(v, dmu_dv),
        "c": -_outer(v, dmu_dr0),
        "w": _outer(v, dmu_dw),
    }
    return P, J, D


# --------------------------------------------------------------------------- poses


def relative_pose_error(R_world_camera: np.ndarray, t_world_camera: np.ndarray, i: np.ndarray, j: np.ndarray, R_i_j: np.ndarray, t_i_j: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Odometry residual (M, 6): `[Log(R_ijᵀ R_iᵀ R_j), R_iᵀ (t_j - t_i) - t_ij]` for pose
    pairs (i, j) of the (N, 3, 3) / (N, 3) pose arrays; (R_ij, t_ij) is the measured pose of
    j in i's frame. Jacobian (M, 6, 12) w.r.t. [pose i | pose j]: rotation rows
    `[-J_r⁻¹ R_jᵀ R_i, 0 | J_r⁻¹, 0]`, position rows `[[R_iᵀ (t_j - t_i)]_×, -R_iᵀ | 0, R_iᵀ]`.
    """
    M = len(i)
    residual = np.empty((M, 6))
    J = np.empty((M, 6, 12))
    kernels.relative_pose(R_world_camera, t_world_camera, np.asarray(i), np.asarray(j), np.ascontiguousarray(R_i_j), np.ascontiguousarray(t_i_j), residual, J)
    return residual, J


def pose_distance_error(t_world_camera: np.ndarray, i: np.ndarray, j: np.ndarray, distance: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Distance prior residual (M, 1): `|t_j - t_i| - distance` (metres) for pose pairs
    (i, j) of the (N, 3) positions. Jacobian (M, 1, 12) w.r.t. [pose i | pose j] with
    `u = (t_j - t_i) / |t_j - t_i|`: `[0, -uᵀ | 0, uᵀ]` (rotations do not enter)."""
    diff = t_world_camera[j] - t_world_camera[i]
    norm = np.linalg.norm(diff, axis=-1)
    u = diff / np.maximum(norm, 1e-12)[:, None]
    J = np.zeros((len(i), 1, 12))
    J[:, 0, 3:6] = -u
    J[:, 0, 9:12] = u
    return (norm - distance)[:, None], J


def pose_prior_error(R: np.ndarray, t: np.ndarray, R_prior: np.ndarray, t_prior: np.ndarray) -> tuple[np.ndarray, Blocks]:
    """Prior residual (M, 6): `[Log(R_priorᵀ R), t - t_prior]`, block "pose"."""
    r_rot = so3.log(_transpose(R_prior) @ R)
    J = np.zeros((r_rot.shape[0], 6, 6))
    J[:, :3, :3] = so3.right_jacobian_inv(r_rot)
    J[:, 3:, 3:] = np.eye(3)
    return np.concatenate([r_rot, t - t_prior], axis=-1), {"pose": J}
