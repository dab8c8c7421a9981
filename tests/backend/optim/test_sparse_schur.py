"""The envelope Cholesky of the reduced camera | plane system solves it exactly: on sequence
a's reduced systems, on a random cyclic band with a border, and it declines (None) a matrix
that is not positive definite."""

from __future__ import annotations

import numpy as np
import pytest

from backend.eval import montecarlo, sequences
from backend.optim import sparse_schur
from backend.optim.problem import ProblemData, build_problem


@pytest.fixture(scope="module")
def data_a() -> ProblemData:
    return montecarlo.make_problem_data(sequences.make_world("a"), np.random.default_rng([0, 0]))


def _reduced_system(data: ProblemData, variant: str) -> tuple[np.ndarray, np.ndarray, int]:
    """S = H_rr − H_rl H_ll⁻¹ H_lr and b = g_r − H_rl H_ll⁻¹ g_l, densely, from the normal
    equations at the initial state, and the number of camera columns."""
    problem = build_problem(data, variant)
    H, g = problem.linearize(problem.initial_state()).normal_equations()
    layout = problem.layout
    lo, hi = layout.group_start["points"], layout.group_start["planes"]
    r = np.r_[0:lo, hi : layout.n_params]
    l_ = np.arange(lo, hi)
    H_rl = H[np.ix_(r, l_)]
    if len(l_):
        X = np.linalg.solve(H[np.ix_(l_, l_)], np.column_stack([H_rl.T, g[l_]]))
        S = H[np.ix_(r, r)] - H_rl @ X[:, :-1]
        b = g[r] - H_rl @ X[:, -1]
    else:
        S, b = H[np.ix_(r, r)], g[r]
    S = 0.5 * (S + S.T)
    return np.ascontiguousarray(S), b, layout.group_size["cameras"]


@pytest.mark.parametrize("variant", ["P-wo", "P-w", "PL-r", "PL-w"])
def test_envelope_solve_equals_the_dense_solution_on_sequence_a(data_a: ProblemData, variant: str) -> None:
    S, b, nc = _reduced_system(data_a, variant)
    plan = sparse_schur.envelope_plan(S[:nc, :nc], S.shape[0] - nc)
    assert sparse_schur.envelope_pays(plan, S.shape[0])
    assert plan.flops < 0.4 * S.shape[0] ** 3 / 3  # the ring folds: far less than dense
    expected = np.linalg.solve(S, b)
    # S's condition number is ~1e10 (-w: ~5e10), so small components carry an absolute error
    # near 1e-10 of the largest one in any backward-stable solver (dense Cholesky included).
    atol = 1e-8 * np.abs(expected).max()
    S_before = S.copy()
    for _ in range(2):  # the plan (and its workspace) serves repeated solves
        x = sparse_schur.solve_bordered_envelope(S, b, nc, plan)
        assert x is not None
        np.testing.assert_allclose(x, expected, rtol=1e-8, atol=atol)
    np.testing.assert_array_equal(S, S_before)  # S is only read


def _cyclic_band(n_blocks: int, width: int, n_border: int, rng: np.random.Generator) -> np.ndarray:
    """A random symmetric positive definite matrix of 6×6 blocks coupled within `width`
    blocks around a ring (sparsely), two long links, and a dense border of `n_border` rows."""
    n = 6 * n_blocks + n_border
    rows = []
    for i in range(n_blocks):
        for d in range(1, width + 1):
            if rng.random() < 0.7:
                j = (i + d) % n_blocks
                rows.append((i, j))
    rows += [(0, n_blocks // 2), (3, n_blocks // 3)]
    J = []
    for i, j in rows:
        Jk = np.zeros((4, n))
        Jk[:, 6 * i : 6 * i + 6] = rng.standard_normal((4, 6))
        Jk[:, 6 * j : 6 * j + 6] = rng.standard_normal((4, 6))
        if n_border and rng.random() < 0.4:
            Jk[:, 6 * n_blocks :] = rng.standard_normal((4, n_border))
        J.append(Jk)
    J = np.vstack(J)
    S = J.T @ J + 0.1 * np.eye(n)
    return np.ascontiguousarray(0.5 * (S + S.T))


@pytest.mark.parametrize("n_border", [0, 9])
def test_envelope_solve_on_a_random_cyclic_band_with_a_border(n_border: int) -> None:
    rng = np.random.default_rng(3)
    S = _cyclic_band(100, 8, n_border, rng)
    b = rng.standard_normal(S.shape[0])
    nc = 600
    plan = sparse_schur.envelope_plan(S[:nc, :nc], n_border, panel=30)
    assert sparse_schur.envelope_pays(plan, S.shape[0])
    x = sparse_schur.solve_bordered_envelope(S, b, nc, plan)
    assert x is not None
    expected = np.linalg.solve(S, b)
    np.testing.assert_allclose(x, expected, rtol=1e-8, atol=1e-10 * np.abs(expected).max())


def test_a_dense_pattern_does_not_pay() -> None:
    """Every camera coupled to every other (sequence b): the dense factorization is used."""
    rng = np.random.default_rng(4)
    A = rng.standard_normal((400, 303))
    S = np.ascontiguousarray(A.T @ A)
    plan = sparse_schur.envelope_plan(S[:300, :300], 3)
    assert not sparse_schur.envelope_pays(plan, 303)
    x = sparse_schur.solve_bordered_envelope(S, np.ones(303), 300, plan)  # still correct
    assert x is not None
    np.testing.assert_allclose(x, np.linalg.solve(S, np.ones(303)), rtol=1e-6)


@pytest.mark.parametrize("where", ["cameras", "border"])
def test_not_positive_definite_returns_none(where: str) -> None:
    rng = np.random.default_rng(5)
    S = _cyclic_band(60, 6, 6, rng)
    nc = 360
    plan = sparse_schur.envelope_plan(S[:nc, :nc], 6)
    i = 200 if where == "cameras" else nc + 2
    S[i, i] = -1.0
    assert sparse_schur.solve_bordered_envelope(S, rng.standard_normal(S.shape[0]), nc, plan) is None
