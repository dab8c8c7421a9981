"""The normal equations the solver factors equal JᵀJ and -Jᵀr of the stored Jacobian."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from backend.optim.problem import VARIANTS, build_problem
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
