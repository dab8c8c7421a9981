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
