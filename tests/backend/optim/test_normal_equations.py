"""The normal equations the solver factors equal JᵀJ and -Jᵀr of the stored Jacobian."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from backend.optim.problem import build_problem
from backend.optim.variant import VARIANTS
from tests.backend.optim.test_jacobians import _stereo_data


@pytest.mark.parametrize("robust", [None, 2.0])
@pytest.mark.parametrize("variant", VARIANTS)
def test_normal_equations_match_the_jacobian(variant: str, robust: float | None) -> None:
    problem = build_problem(_stereo_data(), variant, robust_px=robust)
    rng = np.random.default_rng(2)
    state = problem.retract(problem.initial_state(), 1e-3 * rng.standard_normal(problem.layout.n_params))
    lin = problem.linearize(state)
    J = lin.jacobian.toarray()
    H, g = lin.normal_equations()
    np.testing.assert_allclose(H, J.T @ J, rtol=1e-10, atol=1e-8 * np.abs(J.T @ J).max())
    np.testing.assert_allclose(g, -J.T @ lin.residual, rtol=1e-10, atol=1e-8 * np.abs(g).max())
    np.testing.assert_array_equal(H, H.T)


def test_robust_kernel_downweights_an_outlier() -> None:
    data = _stereo_data()
    uv = data.point_obs.uv.copy()
    uv[5] += 200.0  # a gross outlier
    data = dataclasses.replace(data, point_obs=dataclasses.replace(data.point_obs, uv=uv))
    plain = build_problem(data, "P-wo")
    robust = build_problem(data, "P-wo", robust_px=2.0)
    state = plain.initial_state()
    plain_costs, robust_costs = plain.linearize(state).costs, robust.linearize(state).costs
    assert robust_costs["points"] < 0.2 * plain_costs["points"]
    assert robust_costs["prior"] == pytest.approx(plain_costs["prior"])  # only reprojections are robust


@pytest.mark.parametrize("variant", ["P-wo", "PL-r", "PL-w"])
def test_schur_solve_matches_a_dense_solve_and_survives_singularity(variant: str) -> None:
    from backend.optim.solver import solve_schur

    problem = build_problem(_stereo_data(), variant)
    H, g = problem.linearize(problem.initial_state()).normal_equations()
    expected = np.linalg.solve(H, g)
    np.testing.assert_allclose(solve_schur(H.copy(), g, problem.layout), expected, rtol=1e-6, atol=1e-9 * np.abs(expected).max())
    # A variable no factor constrains (a zero row and column) must not crash the solve.
    singular = H.copy()
    singular[:, 0] = singular[0, :] = 0.0
    delta = solve_schur(singular, g * (np.arange(len(g)) > 0), problem.layout)
    assert np.all(np.isfinite(delta))


@pytest.mark.parametrize("robust", [None, 2.0])
@pytest.mark.parametrize("variant", VARIANTS)
def test_schur_blocks_equal_the_dense_normal_equations(variant: str, robust: float | None) -> None:
    """The solver accumulates only the blocks the Schur complement needs; they must be the
    dense H's (stereo observations included: the right image of the anchor touches the
    anchor pose twice)."""
    from backend.optim.solver import solve_schur, solve_schur_blocks

    problem = build_problem(_stereo_data(), variant, robust_px=robust)
    lin = problem.linearize(problem.initial_state())
    H, g = lin.normal_equations()
    blocks = lin.normal_blocks(problem.layout)
    L = problem.layout
    lo, mid, hi = L.group_start["points"], L.group_start["lines"], L.group_start["planes"]
    r = blocks.reduced
    np.testing.assert_allclose(blocks.H_rr, H[np.ix_(r, r)], rtol=1e-12, atol=1e-10 * np.abs(H).max())
    np.testing.assert_allclose(blocks.H_rl, H[r, lo:hi], rtol=1e-12, atol=1e-10 * np.abs(H).max())
    np.testing.assert_allclose(blocks.d_points, np.diagonal(H)[lo:mid], rtol=1e-12)
    for k in range(len(blocks.B_lines)):
        s = mid + 4 * k
        np.testing.assert_allclose(blocks.B_lines[k], H[s : s + 4, s : s + 4], rtol=1e-12, atol=1e-10 * np.abs(H).max())
    # Only the diagonal blocks of the landmark part are non-zero.
    off = H[lo:hi, lo:hi].copy()
    off[np.arange(lo, mid) - lo, np.arange(lo, mid) - lo] = 0.0
    for k in range(len(blocks.B_lines)):
        s = mid - lo + 4 * k
        off[s : s + 4, s : s + 4] = 0.0
    assert not off.any()
    np.testing.assert_allclose(blocks.g, g)
    damped = blocks.damped(0.5)
    np.testing.assert_allclose(np.diagonal(damped.H_rr), 1.5 * np.diagonal(H)[r])
    np.testing.assert_allclose(damped.d_points, 1.5 * np.diagonal(H)[lo:mid])
    np.testing.assert_allclose(solve_schur_blocks(blocks, problem.layout).delta, solve_schur(H.copy(), g, problem.layout), rtol=1e-8, atol=1e-12)
