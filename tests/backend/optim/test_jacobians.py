"""Every analytic Jacobian against central differences through the variables' retractions."""

from __future__ import annotations

import numpy as np
import pytest

from backend.eval import montecarlo, sequences
from backend.geometry import so3
from backend.geometry.se3 import Poses
from backend.optim import factors
from backend.optim.problem import Observations, ProblemData, build_problem
from backend.optim.variant import VARIANTS


def _stereo_data(seed: int = 1) -> ProblemData:
    """A small sequence-b problem with stereo (right-camera) observations added and a fixed pose."""
    world = sequences.make_world("b", seed=seed)
    data = montecarlo.make_problem_data(world, np.random.default_rng(seed))
    keep_poses = 6
    po = data.point_obs
    lo = data.line_obs
    # Right-image observations: the same points seen from a camera 0.11 m to the right.
    b = np.array([0.11, 0.0, 0.0])
    right = po.select(po.pose < keep_poses)
    right = Observations(right.landmark, right.pose, right.uv + np.array([-12.0, 0.3]), np.tile(b, (len(right), 1)))
    lright = lo.select(lo.pose < keep_poses)
    lright = Observations(lright.landmark, lright.pose, lright.uv + np.array([-10.0, 0.2, -11.0, -0.1]), np.tile(b, (len(lright), 1)))

    def both(a: Observations, c: Observations) -> Observations:
        return Observations(*(np.concatenate([x, y]) for x, y in zip((a.landmark, a.pose, a.uv, a.offset), (c.landmark, c.pose, c.uv, c.offset))))

    fixed = np.zeros(len(data.poses), bool)
    fixed[3] = True
    return ProblemData(**{**data.__dict__, "point_obs": both(po, right), "line_obs": both(lo, lright), "fixed_poses": fixed})


def _numeric_jacobian(problem, state, eps: float = 1e-6) -> np.ndarray:
    n = problem.layout.n_params
    cols = []
    for c in range(n):
        d = np.zeros(n)
        d[c] = eps
        rp = problem.linearize(problem.retract(state, d)).residual
        rm = problem.linearize(problem.retract(state, -d)).residual
        cols.append((rp - rm) / (2 * eps))
    return np.stack(cols, axis=1)


def linearize_against_numeric(problem, state, label: str):
    """`problem.linearize(state)`, after asserting that its analytic Jacobian matches central
    differences (relative to each column's scale, at least 1) to 1e-5."""
    lin = problem.linearize(state)
    J = lin.jacobian.toarray()
    J_num = _numeric_jacobian(problem, state)
    scale = np.maximum(np.abs(J_num).max(axis=0, keepdims=True), 1.0)
    err = np.abs(J - J_num) / scale
    worst = np.unravel_index(np.argmax(err), err.shape)
    assert err.max() < 1e-5, f"{label}: worst column {worst[1]} row {worst[0]}: {J[worst]} vs {J_num[worst]}"
    return lin


@pytest.mark.parametrize("variant", VARIANTS)
def test_problem_jacobian_matches_numeric(variant: str) -> None:
    data = _stereo_data()
    problem = build_problem(data, variant)
    # Evaluate away from the initial values so that no residual is trivially zero.
    rng = np.random.default_rng(5)
    state = problem.retract(problem.initial_state(), 1e-3 * rng.standard_normal(problem.layout.n_params))
    lin = linearize_against_numeric(problem, state, variant)
    # Every factor type of the variant is present in the check.
    assert {"points", "odometry", "prior"} <= set(lin.costs)
    if variant.startswith("PL"):
        assert "lines" in lin.costs
    if variant.endswith("-r"):
        assert "point_plane" in lin.costs
        assert ("line_plane" in lin.costs) == variant.startswith("PL")


def test_line_point_nearest_ray_jacobians() -> None:
    rng = np.random.default_rng(0)
    M = 20
    p, q = rng.standard_normal((M, 3)), rng.standard_normal((M, 3))
    m, v = np.cross(p, q - p), q - p
    c, w = rng.standard_normal((M, 3)), rng.standard_normal((M, 3))
    P, J, _ = factors.line_point_nearest_ray(m, v, c, w)
    args = {"m": m, "v": v, "c": c, "w": w}
    for name in args:
        num = np.zeros((M, 3, 3))
        for k in range(3):
            e = np.zeros(3)
            e[k] = 1e-6
            hi = factors.line_point_nearest_ray(**{**{"m_world": m, "v": v, "c_world": c, "w_world": w}, _argname(name): args[name] + e})[0]
            lo = factors.line_point_nearest_ray(**{**{"m_world": m, "v": v, "c_world": c, "w_world": w}, _argname(name): args[name] - e})[0]
            num[:, :, k] = (hi - lo) / 2e-6
        np.testing.assert_allclose(J[name], num, atol=1e-5, rtol=1e-5)
    # P lies on the line: (P × v) equals m.
    np.testing.assert_allclose(np.cross(P, v), m, atol=1e-9)


def _argname(short: str) -> str:
    return {"m": "m_world", "v": "v", "c": "c_world", "w": "w_world"}[short]


def test_relative_pose_jacobians_at_large_rotation() -> None:
    rng = np.random.default_rng(3)
    M = 5
    R = so3.exp(2.0 * rng.standard_normal((2 * M, 3)))
    t = rng.standard_normal((2 * M, 3))
    i, j = np.arange(M), np.arange(M, 2 * M)
    R_m, t_m = so3.exp(2.0 * rng.standard_normal((M, 3))), rng.standard_normal((M, 3))
    _, J = factors.relative_pose_error(R, t, i, j, R_m, t_m)
    for slot, idx in ((0, i), (1, j)):
        num = np.zeros((M, 6, 6))
        for k in range(6):
            res = []
            for sgn in (1, -1):
                d = np.zeros((2 * M, 6))
                d[idx, k] = sgn * 1e-6
                moved = Poses(R, t).retract(d)
                res.append(factors.relative_pose_error(moved.R_world_camera, moved.t_world_camera, i, j, R_m, t_m)[0])
            num[:, :, k] = (res[0] - res[1]) / 2e-6
        np.testing.assert_allclose(J[:, :, 6 * slot : 6 * slot + 6], num, atol=1e-6)
