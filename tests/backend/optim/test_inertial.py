"""Inertial states, IMU factors and the marginalization prior in the project's solver."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from backend.data.motion import ImuNoise, add_imu_noise, imu_samples, random_trajectory
from backend.data.synthetic import CAMERA, T_BODY_CAM0
from backend.geometry import so3
from backend.geometry.camera import PinholeCamera
from backend.geometry.se3 import Poses
from backend.imu.preintegration import imu_factor, preintegrate, preintegration_params
from backend.optim import inertial
from backend.optim.marginalization import marginalize, remap
from backend.optim.problem import Observations, ProblemData, build_problem
from backend.optim.solver import optimize
from tests.backend.optim.test_jacobians import linearize_against_numeric

MONO = PinholeCamera(fx=CAMERA.fx, fy=CAMERA.fy, cx=CAMERA.cx, cy=CAMERA.cy, width=CAMERA.width, height=CAMERA.height)
KEYFRAME_NS = 100_000_000  # 10 Hz


def _vio_data(*, seed: int = 0, n_kf: int = 6, n_points: int = 160, pixel_noise: float = 0.3) -> tuple[ProblemData, dict]:
    """A small monocular VIO window: keyframes every 0.1 s on a smooth random trajectory,
    points (half on the floor z = 0, a plane) seen by every keyframe with pixel noise, the
    noisy IMU between keyframes. Initial values are the truth; returns the data and the truth."""
    rng = np.random.default_rng(seed)
    traj = random_trajectory(rng, centre=np.zeros(3), half_extent=np.array([1.0, 1.0, 0.2]), height=1.4, base_frequency_hz=0.15)
    stamps = np.arange(n_kf) * KEYFRAME_NS
    imu, b_g, b_a = add_imu_noise(imu_samples(traj, start_ns=0, end_ns=int(stamps[-1])), rng, noise=ImuNoise())
    t = stamps * 1e-9
    R_wb, t_wb, v_w = traj.rotation(t), traj.position(t), traj.velocity(t)
    R_wc = R_wb @ T_BODY_CAM0[:3, :3]
    t_wc = t_wb + R_wb @ T_BODY_CAM0[:3, 3]
    # Points in front of the first camera, 2-6 m away; half of them dropped onto the floor.
    ray = MONO.normalize(np.c_[rng.uniform(60, 690, n_points), rng.uniform(60, 420, n_points)])
    p_w = (ray * rng.uniform(2.0, 6.0, n_points)[:, None]) @ R_wc[0].T + t_wc[0]
    floor = np.arange(n_points) % 2 == 0
    p_w[floor, 2] = 0.0
    seen_by_all = np.ones(n_points, bool)
    for k in range(n_kf):  # keep the points every keyframe sees (any of them can anchor them)
        p_c = (p_w - t_wc[k]) @ R_wc[k]
        seen_by_all &= (p_c[:, 2] > 0.3) & MONO.in_image(MONO.project(p_c))
    p_w, floor = p_w[seen_by_all], floor[seen_by_all]
    n_points = len(p_w)
    obs_l, obs_k, obs_uv = [], [], []
    for k in range(n_kf):
        p_c = (p_w - t_wc[k]) @ R_wc[k]
        uv = MONO.project(p_c) + pixel_noise * rng.standard_normal((n_points, 2))
        ok = (p_c[:, 2] > 0.3) & MONO.in_image(uv)
        obs_l.append(np.flatnonzero(ok))
        obs_k.append(np.full(int(ok.sum()), k))
        obs_uv.append(uv[ok])
    landmark, pose, uv = np.concatenate(obs_l), np.concatenate(obs_k), np.concatenate(obs_uv)
    anchor_uv = MONO.project((p_w - t_wc[0]) @ R_wc[0])
    rho = 1.0 / ((p_w - t_wc[0]) @ R_wc[0])[:, 2]
    params = preintegration_params(ImuNoise())
    bias0 = np.zeros(6)
    pims = tuple(imu_factor(preintegrate(imu, int(stamps[k]), int(stamps[k + 1]), bias_accel=bias0[:3], bias_gyro=bias0[3:], params=params)) for k in range(n_kf - 1))
    ine = inertial.InertialData(
        T_body_camera=T_BODY_CAM0.copy(),
        velocity=v_w.copy(),
        bias=np.zeros((n_kf, 6)),
        free=np.ones(n_kf, bool),
        imu_i=np.arange(n_kf - 1),
        imu_j=np.arange(1, n_kf),
        imu=pims,
        dt_s=np.diff(t),
        noise=ImuNoise(),
        prior=_pose_prior(R_wc[0], t_wc[0], v_w[0]),
    )
    data = ProblemData(
        camera=MONO,
        poses=Poses(R_wc.copy(), t_wc.copy()),
        point_anchor=np.zeros(n_points, np.int64),
        point_anchor_uv=anchor_uv,
        point_rho=rho,
        point_plane=np.where(floor, 0, -1),
        point_obs=Observations(landmark, pose, uv, np.zeros((len(landmark), 3))),
        line_anchor=np.zeros(0, np.int64),
        line_anchor_uv=np.zeros((0, 4)),
        line_U=np.zeros((0, 3, 3)),
        line_phi=np.zeros((0, 2)),
        line_plane=np.zeros(0, np.int64),
        line_obs=Observations.empty(4),
        plane_n=np.array([[0.0, 0.0, 1.0]]),
        plane_d=np.array([0.0]),
        odometry=None,
        prior=None,
        inertial=ine,
    )
    return data, {"R_wc": R_wc, "t_wc": t_wc, "v": v_w, "b_g": b_g, "b_a": b_a, "p_w": p_w}


def _pose_prior(R: np.ndarray, t: np.ndarray, v: np.ndarray, sigma: float = 1e-3) -> inertial.LinearPrior:
    """The gauge and what a VIO start knows: pose 0 (σ = `sigma` in rad and m), its velocity
    loosely (1 m/s) and its biases (0.1 m/s², 0.01 rad/s) around zero."""
    A = np.diag(np.r_[np.full(6, 1.0 / sigma), np.full(3, 1.0), np.full(3, 10.0), np.full(3, 100.0)])
    return inertial.LinearPrior(
        pose_index=np.array([0]),
        inertial_index=np.array([0]),
        plane_index=np.zeros(0, np.int64),
        R=R[None].copy(),
        t=t[None].copy(),
        inertial=np.r_[v, np.zeros(6)][None],
        plane_n=np.zeros((0, 3)),
        plane_d=np.zeros(0),
        A=A,
        b=np.zeros(15),
    )


@pytest.mark.parametrize("variant", ["P-wo", "P-w", "P-r"])
def test_inertial_problem_jacobian_matches_numeric(variant: str) -> None:
    """IMU, bias random walk and a dense prior over poses, inertial states and the plane:
    the assembled Jacobian against central differences in the solver's own retraction."""
    data, _ = _vio_data(n_kf=4, n_points=16)
    rng = np.random.default_rng(3)
    prior = inertial.LinearPrior(
        pose_index=np.array([0, 2]),
        inertial_index=np.array([1]),
        plane_index=np.array([0]),
        R=data.poses.R_world_camera[[0, 2]] @ so3.exp(0.01 * rng.standard_normal((2, 3))),
        t=data.poses.t_world_camera[[0, 2]] + 0.01,
        inertial=np.concatenate([data.inertial.velocity[[1]], np.zeros((1, 6))], axis=1) + 0.01,
        plane_n=np.array([[0.05, -0.03, 1.0]]) / np.linalg.norm([0.05, -0.03, 1.0]),
        plane_d=np.array([0.02]),
        A=rng.standard_normal((10, 24)),
        b=rng.standard_normal(10),
    )
    data = dataclasses.replace(data, inertial=dataclasses.replace(data.inertial, prior=prior))
    problem = build_problem(data, variant)
    assert problem.layout.inertial_col is not None and problem.layout.group_size["cameras"] == 4 * 15
    state = problem.retract(problem.initial_state(), 1e-2 * rng.standard_normal(problem.layout.n_params))
    lin = linearize_against_numeric(problem, state, variant)
    assert {"imu", "bias_walk", "marginalization"} <= set(lin.costs)


def test_plane_local_inverts_the_retraction() -> None:
    rng = np.random.default_rng(0)
    from backend.geometry import plane as plane_geo

    n_ref = rng.standard_normal((5, 3))
    n_ref /= np.linalg.norm(n_ref, axis=1, keepdims=True)
    d_ref = rng.standard_normal(5)
    delta = 0.2 * rng.standard_normal((5, 3))
    n, d = plane_geo.retract(n_ref, d_ref, delta)
    local, _ = inertial.plane_local(n_ref, d_ref, n, d)
    np.testing.assert_allclose(local, delta, atol=1e-12)
    local_flipped, _ = inertial.plane_local(n_ref, d_ref, -n, -d)  # the same planes, normals flipped
    np.testing.assert_allclose(local_flipped, delta, atol=1e-12)


def test_the_window_recovers_velocity_and_the_gyro_bias() -> None:
    """From velocities and biases started at zero and poses perturbed, the VIO window
    solve (P-w: the floor points through their plane) returns to the truth: poses within a
    few mm, velocities within a few cm/s."""
    data, truth = _vio_data(seed=2, n_kf=6)
    rng = np.random.default_rng(1)
    R0 = data.poses.R_world_camera @ so3.exp(0.01 * rng.standard_normal((6, 3)))
    t0 = data.poses.t_world_camera + 0.02 * rng.standard_normal((6, 3))
    R0[0], t0[0] = data.poses.R_world_camera[0], data.poses.t_world_camera[0]
    data = dataclasses.replace(data, poses=Poses(R0, t0), inertial=dataclasses.replace(data.inertial, velocity=np.zeros((6, 3))))
    problem = build_problem(data, "P-w")
    state, report = optimize(problem, method="lm", max_iterations=30)
    assert report.final_cost < report.initial_cost
    assert np.max(np.abs(state.poses.t_world_camera - truth["t_wc"])) < 0.01
    assert np.max(np.abs(state.velocity - truth["v"])) < 0.05


def test_marginalizing_at_the_optimum_keeps_the_solution_and_the_marginal_covariance() -> None:
    """Solve the whole window, marginalize keyframe 0 and the points it anchors into a prior
    at the optimum: the rest of the window with that prior has the same optimum (solved from
    a perturbed start) and the same Gauss-Newton information for what stays (the Schur
    complement of the full information)."""
    data, _ = _vio_data(seed=4, n_kf=6)
    # Anchor half of the points in keyframe 1 so that some landmarks stay.
    n_points = len(data.point_anchor)
    stays = np.arange(n_points) >= n_points // 2
    p_c0 = data.camera.normalize(data.point_anchor_uv) / data.point_rho[:, None]
    R, t = data.poses.R_world_camera, data.poses.t_world_camera
    p_w = p_c0 @ R[0].T + t[0]
    p_c1 = (p_w - t[1]) @ R[1]
    anchor = np.where(stays, 1, 0)
    anchor_uv = np.where(stays[:, None], data.camera.project(p_c1), data.point_anchor_uv)
    rho = np.where(stays, 1.0 / p_c1[:, 2], data.point_rho)
    obs = data.point_obs
    keep_obs = ~(stays[obs.landmark] & (obs.pose == 0))  # a landmark is first seen by its anchor
    data = dataclasses.replace(data, point_anchor=anchor, point_anchor_uv=anchor_uv, point_rho=rho, point_obs=obs.select(keep_obs))
    full = build_problem(data, "P-wo")
    state, _ = optimize(full, method="lm", max_iterations=50)
    prior = marginalize(full, state, poses=np.array([0]), points=np.flatnonzero(~stays))
    assert prior is not None
    assert set(prior.pose_index.tolist()) == {1, 2, 3, 4, 5}  # every keyframe saw keyframe 0's points
    assert prior.inertial_index.tolist() == [1]  # the IMU factor 0 -> 1
    # The reduced window: keyframes 1..5, the points anchored in 1, the prior.
    keep_kf = np.arange(1, 6)
    pose_map = np.full(6, -1)
    pose_map[keep_kf] = np.arange(5)
    pts = np.flatnonzero(stays)
    pt_map = np.full(n_points, -1)
    pt_map[pts] = np.arange(len(pts))
    o = data.point_obs
    sel = stays[o.landmark]
    ine = data.inertial
    reduced = dataclasses.replace(
        data,
        poses=Poses(state.poses.R_world_camera[keep_kf].copy(), state.poses.t_world_camera[keep_kf].copy()),
        point_anchor=pose_map[anchor[pts]],
        point_anchor_uv=anchor_uv[pts],
        point_rho=state.rho[pts],
        point_plane=data.point_plane[pts],
        point_obs=Observations(pt_map[o.landmark[sel]], pose_map[o.pose[sel]], o.uv[sel], o.offset[sel]),
        inertial=dataclasses.replace(
            ine,
            velocity=state.velocity[keep_kf].copy(),
            bias=state.bias[keep_kf].copy(),
            free=np.ones(5, bool),
            imu_i=np.arange(4),
            imu_j=np.arange(1, 5),
            imu=ine.imu[1:],
            dt_s=ine.dt_s[1:],
            prior=remap(prior, pose_map=pose_map),
        ),
    )
    problem = build_problem(reduced, "P-wo")
    # Same information: the reduced Hessian at the optimum is the Schur complement of the full one.
    H_full, _ = full.linearize(state).normal_equations()
    st_reduced = problem.initial_state()
    H_red, g_red = problem.linearize(st_reduced).normal_equations()
    assert np.max(np.abs(g_red)) < 1e-6 * max(1.0, np.max(np.abs(H_red)))
    cov_full = np.linalg.inv(H_full)
    cov_red = np.linalg.inv(H_red)
    Lf, Lr = full.layout, problem.layout
    for k in keep_kf:
        cf = np.r_[Lf.pose_col[k] : Lf.pose_col[k] + 6, Lf.inertial_col[k] : Lf.inertial_col[k] + 9]
        cr = np.r_[Lr.pose_col[pose_map[k]] : Lr.pose_col[pose_map[k]] + 6, Lr.inertial_col[pose_map[k]] : Lr.inertial_col[pose_map[k]] + 9]
        np.testing.assert_allclose(cov_red[np.ix_(cr, cr)], cov_full[np.ix_(cf, cf)], rtol=1e-5, atol=1e-12)
    # Same optimum from a perturbed start.
    rng = np.random.default_rng(0)
    start = problem.retract(st_reduced, 1e-3 * rng.standard_normal(Lr.n_params))
    solved, _ = optimize(problem, start, method="lm", max_iterations=50)
    np.testing.assert_allclose(solved.poses.t_world_camera, state.poses.t_world_camera[keep_kf], atol=1e-6)
    np.testing.assert_allclose(solved.velocity, state.velocity[keep_kf], atol=1e-5)


def test_marginalizing_leaves_out_a_landmark_with_a_non_finite_estimate() -> None:
    """A point whose estimate a solve left non-finite (degenerate geometry) must not make
    the marginalization fail or poison the prior: its factors are left out, so the prior is
    the one of the same window without that point's observations."""
    data, _ = _vio_data(seed=4, n_kf=6)
    full = build_problem(data, "P-wo")
    state, _ = optimize(full, method="lm", max_iterations=50)
    all_points = np.arange(len(data.point_anchor))
    broken = dataclasses.replace(state, rho=np.where(all_points == 3, np.nan, state.rho))
    prior = marginalize(full, broken, poses=np.array([0]), points=all_points)
    assert prior is not None and np.all(np.isfinite(prior.A)) and np.all(np.isfinite(prior.b))
    without = build_problem(dataclasses.replace(data, point_obs=data.point_obs.select(data.point_obs.landmark != 3)), "P-wo")
    reference = marginalize(without, state, poses=np.array([0]), points=all_points)
    np.testing.assert_allclose(prior.A.T @ prior.A, reference.A.T @ reference.A, rtol=1e-9, atol=1e-9)
    np.testing.assert_allclose(prior.A.T @ prior.b, reference.A.T @ reference.b, rtol=1e-9, atol=1e-9)
