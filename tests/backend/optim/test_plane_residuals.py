"""The scale-safe -r residuals (DESIGN §3): invariance to the map's scale, the compiled
kernels against a plain numpy evaluation, and the rejection of anchors on their plane."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from backend.eval import montecarlo, sequences
from backend.geometry import line as line_geo
from backend.geometry import plane as plane_geo
from backend.geometry import so3
from backend.geometry.se3 import Poses
from backend.optim import factors
from backend.optim.problem import MIN_ANCHOR_PLANE_DISTANCE_M, ProblemData, State, _point_plane_valid, build_problem

R_FACTORS = ("point_plane", "line_plane")


def _data(seed: int = 2) -> ProblemData:
    world = sequences.make_world("b", seed=seed)
    return montecarlo.make_problem_data(world, np.random.default_rng(seed))


def _r_residuals(problem, state: State) -> dict[str, np.ndarray]:
    lin = problem.linearize(state)
    return {b.name: b.residual for b in lin.batches if b.name in R_FACTORS}


def _scaled(state: State, s: float) -> State:
    """The whole map scaled by s about the world origin: positions, depths, plane offsets
    and line moments times s (rotations, normals and directions unchanged)."""
    m, v = line_geo.from_orthonormal(state.line_U, state.line_phi)
    U, phi = line_geo.to_orthonormal(s * m, v)
    poses = Poses(state.poses.R_world_camera.copy(), s * state.poses.t_world_camera)
    return State(poses, state.rho / s, U, phi, state.plane_n.copy(), s * state.plane_d)


@pytest.mark.parametrize("variant", ["P-r", "PL-r"])
def test_relative_plane_residuals_are_scale_invariant(variant: str) -> None:
    problem = build_problem(_data(), variant)
    rng = np.random.default_rng(7)
    # Away from the initial values, so that the residuals are clearly non-zero.
    state = problem.retract(problem.initial_state(), 1e-2 * rng.standard_normal(problem.layout.n_params))
    ref = _r_residuals(problem, state)
    assert set(ref) == ({"point_plane", "line_plane"} if variant == "PL-r" else {"point_plane"})
    assert all(np.abs(r).max() > 0.1 for r in ref.values())  # whitened: above 0.1 σ
    for s in (0.1, 0.5, 3.0):
        got = _r_residuals(problem, _scaled(state, s))
        for name, r in ref.items():
            np.testing.assert_allclose(got[name], r, rtol=1e-9, atol=1e-9, err_msg=f"{name} at scale {s}")


def _random_pairs(rng: np.random.Generator, K: int) -> dict[str, np.ndarray]:
    """Random anchors, rays and planes; half of the anchors on the negative side (q < 0)."""
    R = so3.exp(rng.standard_normal((K, 3)))
    t = rng.standard_normal((K, 3))
    n = rng.standard_normal((K, 3))
    n /= np.linalg.norm(n, axis=-1, keepdims=True)
    q = rng.uniform(0.5, 3.0, K) * np.where(np.arange(K) % 2 == 0, 1.0, -1.0)
    d = q - np.sum(n * t, axis=-1)  # n·t + d = q
    x = np.concatenate([rng.uniform(-0.5, 0.5, (K, 2)), np.ones((K, 1))], axis=1)
    return {"R": R, "t": t, "n": n, "d": d, "B": plane_geo.tangent_basis(n), "x": x}


def test_point_plane_kernel_matches_numpy() -> None:
    rng = np.random.default_rng(11)
    K = 40
    g = _random_pairs(rng, K)
    rho = rng.uniform(0.1, 2.0, K)
    res, J = factors.point_plane_relative(g["x"], rho, g["R"], g["t"], g["n"], g["d"], g["B"])
    X = np.einsum("kij,kj->ki", g["R"], g["x"] / rho[:, None]) + g["t"]
    expected = (np.sum(g["n"] * X, axis=-1) + g["d"]) / np.abs(np.sum(g["n"] * g["t"], axis=-1) + g["d"])
    assert res.shape == (K, 1) and J.shape == (K, 1, 10)
    np.testing.assert_allclose(res[:, 0], expected, rtol=1e-12, atol=1e-12)

    # The Jacobian through the retractions, on both sides of the plane.
    def residual(delta: np.ndarray) -> np.ndarray:
        R = g["R"] @ so3.exp(delta[:, :3])
        n, d = plane_geo.retract(g["n"], g["d"], delta[:, 7:])
        return factors.point_plane_relative(g["x"], rho + delta[:, 6], R, g["t"] + delta[:, 3:6], n, d, plane_geo.tangent_basis(n))[0][:, 0]

    np.testing.assert_allclose(J[:, 0, :], _numeric(residual, K, 10), atol=1e-6, rtol=1e-6)


def test_line_plane_kernel_matches_numpy() -> None:
    rng = np.random.default_rng(12)
    K = 40
    g = _random_pairs(rng, K)
    m, v = line_geo.from_points(rng.standard_normal((K, 3)), rng.standard_normal((K, 3)))
    x_s = g["x"]
    x_e = np.concatenate([rng.uniform(-0.5, 0.5, (K, 2)), np.ones((K, 1))], axis=1)
    J_mv = np.broadcast_to(np.eye(6), (K, 6, 6))  # line columns = ∂r/∂(m, v)
    res, J = factors.line_plane_relative(m, v, J_mv, np.arange(K), x_s, x_e, g["R"], g["t"], g["n"], g["d"], g["B"])
    assert res.shape == (K, 2) and J.shape == (K, 2, 15)
    q = np.abs(np.sum(g["n"] * g["t"], axis=-1) + g["d"])
    for col, x in enumerate((x_s, x_e)):
        P, _, _ = factors.line_point_nearest_ray(m, v, g["t"], np.einsum("kij,kj->ki", g["R"], x))
        expected = (np.sum(g["n"] * P, axis=-1) + g["d"]) / q
        np.testing.assert_allclose(res[:, col], expected, rtol=1e-10, atol=1e-10)

    def residual(delta: np.ndarray) -> np.ndarray:
        R = g["R"] @ so3.exp(delta[:, :3])
        n, d = plane_geo.retract(g["n"], g["d"], delta[:, 12:])
        r, _ = factors.line_plane_relative(m + delta[:, 6:9], v + delta[:, 9:12], J_mv, np.arange(K), x_s, x_e, R, g["t"] + delta[:, 3:6], n, d, plane_geo.tangent_basis(n))
        return r

    np.testing.assert_allclose(J, _numeric(residual, K, 15), atol=1e-5, rtol=1e-5)


def _numeric(residual, K: int, D: int, eps: float = 1e-6) -> np.ndarray:
    """Central differences (K, ..., D) of a per-pair residual function of (K, D) increments."""
    cols = []
    for c in range(D):
        delta = np.zeros((K, D))
        delta[:, c] = eps
        cols.append((residual(delta) - residual(-delta)) / (2 * eps))
    return np.stack(cols, axis=-1)


def test_anchor_near_plane_is_not_an_r_pair() -> None:
    world = sequences.make_world("a")  # four walls, anchors spread over the poses
    data = montecarlo.make_problem_data(world, np.random.default_rng(0))
    i = int(np.flatnonzero(data.point_anchor > 0)[0])
    a, p = data.point_anchor[i], data.point_plane[i]
    n, d = data.plane_n[p], data.plane_d[p]
    # Move the anchor camera to half the threshold from the plane, on its side: its ray
    # still meets the plane in front, so only the new -r rule rejects the pair.
    t = data.poses.t_world_camera.copy()
    q = n @ t[a] + d
    t[a] -= (q - np.sign(q) * 0.5 * MIN_ANCHOR_PLANE_DISTANCE_M) * n
    moved = dataclasses.replace(data, poses=Poses(data.poses.R_world_camera, t))
    near = (moved.point_anchor == a) & (moved.point_plane == p)
    near_lines = (moved.line_anchor == a) & (moved.line_plane == p)
    assert _point_plane_valid(moved)[i]
    for variant in ("P-r", "PL-r"):
        problem = build_problem(moved, variant)
        assert not near[problem.point_plane_pairs[:, 0]].any()
        assert not near_lines[problem.line_plane_pairs[:, 0]].any()
        # Moving the anchor moves every point anchored there: those far off their planes now
        # are left out too (MAX_INITIAL_RELATIVE_RESIDUAL); no other pair is.
        assert len(problem.point_plane_pairs) <= np.sum(_point_plane_valid(moved)) - np.sum(near & _point_plane_valid(moved))
        before = build_problem(data, variant).point_plane_pairs[:, 0]
        assert set(before[data.point_anchor[before] != a]) <= set(problem.point_plane_pairs[:, 0])
        assert np.all(np.isfinite(problem.linearize(problem.initial_state()).residual))
    # -w keeps its own rule: the point stays co-planar there (no variable).
    assert build_problem(moved, "P-w").layout.point_col[i] < 0


def test_a_feature_that_starts_far_off_its_plane_is_not_an_r_pair() -> None:
    """A point whose initial depth puts it 1.5 m off its wall (relative residual about 0.5) is
    left out of -r's plane residuals (a local minimum trap), keeps its inverse depth, and
    stays co-planar for -w; one 5 cm off stays an -r pair."""
    from backend.optim.problem import MAX_INITIAL_RELATIVE_RESIDUAL

    data = montecarlo.make_problem_data(sequences.make_world("b"), np.random.default_rng(0))
    rho = data.point_rho.copy()
    far, near = 3, 4
    for i, off in ((far, 1.5), (near, 0.05)):
        depth = 1.0 / rho[i]
        rho[i] = 1.0 / (depth + off)  # along the ray, behind the wall (about 4 m away)
    moved = dataclasses.replace(data, point_rho=rho)
    problem = build_problem(moved, "P-r")
    res = problem.linearize(problem.initial_state())
    assert far not in problem.point_plane_pairs[:, 0]
    assert near in problem.point_plane_pairs[:, 0]
    assert problem.layout.point_col[far] >= 0
    assert build_problem(moved, "P-w").layout.point_col[far] < 0
    assert np.all(np.isfinite(res.residual)) and MAX_INITIAL_RELATIVE_RESIDUAL == 0.3
