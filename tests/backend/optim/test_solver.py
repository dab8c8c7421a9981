"""The solver tells the truth: it never accepts a cost increase, a degenerate landmark cannot
spoil a step, `converged` means converged, and the sparse reduced solve equals the dense one."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from backend.eval import montecarlo, sequences
from backend.optim import solver
from backend.optim.problem import Linearization, Problem, ProblemData, build_problem
from backend.optim.solver import Damping, optimize, solve_schur_blocks


@pytest.fixture(scope="module")
def data_b() -> ProblemData:
    return montecarlo.make_problem_data(sequences.make_world("b"), np.random.default_rng([0, 0]))


@pytest.fixture(scope="module")
def data_a() -> ProblemData:
    return montecarlo.make_problem_data(sequences.make_world("a"), np.random.default_rng([0, 0]))


@pytest.mark.parametrize("variant", ["P-wo", "PL-r", "PL-w"])
def test_banded_reduced_solve_equals_the_dense_solution(data_a: ProblemData, variant: str) -> None:
    """Sequence a's cameras see only their neighbours: the reduced system is solved as a band
    (with the planes as a dense border) and gives the dense normal equations' solution."""
    problem = build_problem(data_a, variant)
    lin = problem.linearize(problem.initial_state())
    H, g = lin.normal_equations()
    sol = solve_schur_blocks(lin.normal_blocks(problem.layout), problem.layout, cache={})
    assert sol.linear_solver == "envelope"
    expected = np.linalg.solve(H, g)
    np.testing.assert_allclose(sol.delta, expected, rtol=1e-6, atol=1e-8 * np.abs(expected).max())
    assert sol.n_dropped == 0


def test_sequence_b_uses_the_dense_path(data_b: ProblemData) -> None:
    problem = build_problem(data_b, "P-wo")
    lin = problem.linearize(problem.initial_state())
    assert solve_schur_blocks(lin.normal_blocks(problem.layout), problem.layout, cache={}).linear_solver == "dense"


def _without_observations_of(data: ProblemData, point: int) -> ProblemData:
    """The same data with every observation of one point removed but its anchor's: its
    inverse depth then has a zero column in J (a zero diagonal in H)."""
    po = data.point_obs
    keep = (po.landmark != point) | (po.pose == data.point_anchor[po.landmark])
    return dataclasses.replace(data, point_obs=po.select(keep))


def test_a_degenerate_landmark_is_left_out_and_reported(data_b: ProblemData) -> None:
    problem = build_problem(_without_observations_of(data_b, 7), "P-wo")
    lin = problem.linearize(problem.initial_state())
    blocks = lin.normal_blocks(problem.layout)
    assert blocks.d_points[7] == 0.0
    sol = solve_schur_blocks(blocks, problem.layout)
    assert np.all(np.isfinite(sol.delta))
    assert list(sol.dropped_points) == [7] and sol.n_dropped == 1
    assert sol.delta[problem.layout.point_col[7]] == 0.0
    state, report = optimize(problem)
    assert report.dropped_landmarks == 1
    assert report.final_cost < 1e-3 * report.initial_cost  # the other landmarks and poses moved
    assert state.rho[7] == problem.initial_state().rho[7]
    assert all(b <= a for a, b in zip(report.costs, report.costs[1:]))
    assert report.converged == report.termination.startswith("converged")


def test_gauss_newton_never_accepts_a_cost_increase() -> None:
    """Sequence b with initial poses off by 5° and 50 cm per axis, PL-wo: plain Gauss-Newton
    (every full step taken) raises the cost on the way (2.4e4 -> 4.3e4 at its fifth step);
    the solver shortens or damps that step instead and its costs never increase."""
    noise = montecarlo.NoiseModel(pixel=1.0, rotation_rad=np.deg2rad(5.0), position_m=0.5)
    data = montecarlo.make_problem_data(sequences.make_world("b"), np.random.default_rng([0, 3]), noise=noise)
    problem = build_problem(data, "PL-wo")
    state = problem.initial_state()
    plain = [problem.linearize(state).cost]
    for _ in range(10):
        lin = problem.linearize(state)
        state = problem.retract(state, solve_schur_blocks(lin.normal_blocks(problem.layout), problem.layout).delta)
        plain.append(problem.linearize(state).cost)
    assert any(b > 1.5 * a for a, b in zip(plain, plain[1:])), "plain GN should overshoot here"
    state, report = optimize(problem)
    assert report.rejected_steps >= 1
    assert report.linearizations > report.iterations + 1
    assert all(b <= a for a, b in zip(report.costs, report.costs[1:]))
    assert report.final_cost < 1e-6 * report.initial_cost
    assert report.final_cost < 1.01 * min(plain)
    assert problem.linearize(state).cost == pytest.approx(report.final_cost)


@pytest.mark.parametrize("method", ["gn", "lm"])
def test_a_solve_cut_short_is_not_converged(data_b: ProblemData, method: str) -> None:
    problem = build_problem(data_b, "PL-w")
    _, report = optimize(problem, method=method, max_iterations=1)
    assert report.iterations == 1
    assert not report.converged
    assert report.termination == solver.MAX_ITERATIONS


def test_a_converged_solve_says_why(data_b: ProblemData) -> None:
    _, report = optimize(build_problem(data_b, "PL-w"), max_iterations=50)
    assert report.converged
    assert report.termination in (solver.CONVERGED_COST, solver.CONVERGED_STEP, solver.CONVERGED_MODEL)
    assert report.final_cost <= report.initial_cost


@dataclasses.dataclass(frozen=True)
class _WrongJacobian(Problem):
    """A problem whose Jacobian has the wrong sign: every Gauss-Newton or damped step goes
    uphill, so no step lowers the cost although the linear model promises a decrease."""

    def linearize(self, state):
        lin = super().linearize(state)
        batches = tuple(dataclasses.replace(b, jacobian=-b.jacobian) for b in lin.batches)
        return Linearization(batches, lin.costs, lin.n_params)


@pytest.mark.parametrize(("method", "damping"), [("gn", Damping.MARQUARDT), ("lm", Damping.MARQUARDT), ("lm", Damping.NIELSEN)])
def test_no_descent_is_reported_as_stalled_not_converged(data_b: ProblemData, method: str, damping: Damping) -> None:
    problem = build_problem(data_b, "P-w")
    wrong = _WrongJacobian(**{f.name: getattr(problem, f.name) for f in dataclasses.fields(Problem)})
    state, report = optimize(wrong, method=method, damping=damping)
    assert report.termination == solver.STALLED
    assert not report.converged
    assert report.iterations == 0
    assert report.final_cost == report.initial_cost
    assert state.poses.t_world_camera is wrong.initial_state().poses.t_world_camera or np.array_equal(state.poses.t_world_camera, wrong.data.poses.t_world_camera)


def test_a_non_finite_start_is_reported() -> None:
    data = montecarlo.make_problem_data(sequences.make_world("b"), np.random.default_rng([0, 1]))
    rho = data.point_rho.copy()
    rho[0] = np.nan
    _, report = optimize(build_problem(dataclasses.replace(data, point_rho=rho), "P-wo"))
    assert report.termination == solver.NOT_FINITE and not report.converged


def test_at_the_minimum_it_stops_without_spending_trial_steps(data_b: ProblemData) -> None:
    """With the convergence tests off, a converged solve's next full step changes the cost only
    at rounding level: the solver says converged instead of halving and damping that step."""
    _, report = optimize(build_problem(data_b, "PL-w"), max_iterations=30, relative_tolerance=0.0, step_tolerance=0.0)
    assert report.converged, report.termination
    assert report.iterations < 30
    assert report.linearizations <= report.iterations + 2


@pytest.mark.parametrize("seed", [3, 4])
def test_nielsens_damping_reaches_the_same_minimum_and_never_climbs(seed: int) -> None:
    """Levenberg-Marquardt with Nielsen's λ rule (the stereo windows' default) on sequence b
    started 5° and 50 cm off, PL-wo: the costs never rise and it converges to Marquardt's
    minimum (÷10 / ×10), with no more linearizations."""
    noise = montecarlo.NoiseModel(pixel=1.0, rotation_rad=np.deg2rad(5.0), position_m=0.5)
    problem = build_problem(montecarlo.make_problem_data(sequences.make_world("b"), np.random.default_rng([0, seed]), noise=noise), "PL-wo")
    _, marquardt = optimize(problem, method="lm", max_iterations=50)
    _, nielsen = optimize(problem, method="lm", damping=Damping.NIELSEN, max_iterations=50)
    assert marquardt.converged and nielsen.converged
    assert all(b <= a for a, b in zip(nielsen.costs, nielsen.costs[1:]))
    assert nielsen.final_cost == pytest.approx(marquardt.final_cost, rel=1e-8)
    assert nielsen.linearizations <= marquardt.linearizations


def test_the_damping_scales_the_diagonal_of_the_normal_equations(data_b: ProblemData) -> None:
    """`NormalBlocks.diagonal` (Nielsen's gain ratio) is diag(JᵀJ) in the problem's columns,
    landmarks included."""
    problem = build_problem(data_b, "PL-wo")
    lin = problem.linearize(problem.initial_state())
    H, _ = lin.normal_equations()
    np.testing.assert_allclose(lin.normal_blocks(problem.layout).diagonal(), np.diag(H), rtol=1e-12, atol=1e-9)


@pytest.mark.parametrize("variant", ["P-wo", "PL-wo"])
def test_each_damping_of_one_linearization_solves_its_own_normal_equations(data_b: ProblemData, variant: str) -> None:
    """The damped copies of one linearization share what the damping does not change (the
    finite columns, the rows each landmark touches); each damped step is still the solution
    of `(H + λ diag(H)) δ = g`, and equals the same damping solved from fresh blocks, also
    with a landmark left out of the step."""
    problem = build_problem(data_b, variant)
    lin = problem.linearize(problem.initial_state())
    H, g = lin.normal_equations()
    blocks = lin.normal_blocks(problem.layout)
    for lam in (1e-4, 1e-3, 1e-2):
        sol = solve_schur_blocks(blocks.damped(lam), problem.layout)
        expected = np.linalg.solve(H + lam * np.diag(np.diag(H)), g)
        np.testing.assert_allclose(sol.delta, expected, rtol=1e-6, atol=1e-8 * np.abs(expected).max())
    assert "landmark_rows" in blocks.shared
    degenerate = build_problem(_without_observations_of(data_b, 7), variant)
    lin = degenerate.linearize(degenerate.initial_state())
    blocks = lin.normal_blocks(degenerate.layout)
    for lam in (1e-4, 1e-3, 1e-2):
        shared = solve_schur_blocks(blocks.damped(lam), degenerate.layout)
        alone = solve_schur_blocks(lin.normal_blocks(degenerate.layout).damped(lam), degenerate.layout)
        np.testing.assert_array_equal(shared.delta, alone.delta)
        assert list(shared.dropped_points) == list(alone.dropped_points) == [7]
