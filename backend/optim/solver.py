"""Gauss-Newton on a :class:`~backend.optim.problem.Problem` with the Schur complement.

The landmark variables (inverse depths, orthonormal lines) form a block-diagonal part of
H = JᵀJ (no factor joins two landmarks); they are eliminated first and the reduced system
over cameras and planes is solved by dense Cholesky. This is the structure the paper's
efficiency argument rests on: -w has no landmark variables and a smaller reduced system.
"""

from __future__ import annotations

import dataclasses
import time

import numpy as np
import scipy.linalg
import scipy.linalg.lapack

from backend.optim.problem import Layout, Linearization, NormalBlocks, Problem, State


@dataclasses.dataclass(frozen=True)
class SolveReport:
    """What one optimization did. Times in milliseconds (wall clock)."""

    variant: str
    method: str
    iterations: int
    initial_cost: float
    final_cost: float
    costs: tuple[float, ...]
    time_ms: float
    linearize_ms: float
    solve_ms: float
    other_ms: float
    converged: bool
    items: int
    params: int


def _dense_solve(S: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Solve S x = b for symmetric positive (semi)definite S by Cholesky; least squares
    where S is singular (degenerate geometry).

    S (C order, both triangles filled) is factored in place, without a copy: LAPACK sees
    `S.T` in Fortran order and overwrites one triangle of it, which is S's upper triangle,
    so S's strict lower triangle and the saved diagonal still hold S for the least-squares
    fallback. S's contents are undefined afterwards.
    """
    if S.shape[0] == 0:
        return np.zeros(0)
    diagonal = np.diagonal(S).copy()
    c, info = scipy.linalg.lapack.dpotrf(S.T, lower=1, clean=0, overwrite_a=1)
    if info == 0:
        x, info = scipy.linalg.lapack.dpotrs(c, b, lower=1)
        if info == 0:
            return x
    lower = np.tril(S, -1)
    return np.linalg.lstsq(lower + lower.T + np.diag(diagonal), b, rcond=None)[0]


def _invert_blocks(blocks: np.ndarray) -> np.ndarray:
    """Inverse of a stack of small symmetric blocks (pseudo-inverse where singular)."""
    try:
        return np.linalg.inv(blocks)
    except np.linalg.LinAlgError:
        return np.linalg.pinv(blocks, hermitian=True)


def solve_schur(H: np.ndarray, g: np.ndarray, layout: Layout) -> np.ndarray:
    """Solve `H δ = g` (dense H, both triangles) by eliminating the landmark columns
    (:func:`solve_schur_blocks`)."""
    n = layout.n_params
    lo, mid, hi = layout.group_start["points"], layout.group_start["lines"], layout.group_start["planes"]
    reduced = np.r_[0:lo, hi:n]
    n_lines = (hi - mid) // 4
    blocks = H[mid:hi, mid:hi].reshape(n_lines, 4, n_lines, 4)[np.arange(n_lines), :, np.arange(n_lines), :] if n_lines else np.zeros((0, 4, 4))
    return solve_schur_blocks(NormalBlocks(reduced, H[np.ix_(reduced, reduced)], H[reduced, lo:hi], np.diagonal(H)[lo:mid].copy(), blocks, g), layout)


def solve_schur_blocks(ne: NormalBlocks, layout: Layout) -> np.ndarray:
    """Solve the normal equations by eliminating the landmark columns (points: 1×1 blocks,
    lines: 4×4 blocks, block-diagonal in H) and solving the reduced camera|plane system by
    Cholesky. `ne.H_rr` is used as workspace: its contents are undefined afterwards."""
    n = layout.n_params
    lo, mid, hi = layout.group_start["points"], layout.group_start["lines"], layout.group_start["planes"]
    g = ne.g
    if hi == lo:  # no landmark variables (-w with every feature on a plane)
        return _dense_solve(ne.H_rr, g.copy())
    reduced = ne.reduced
    delta = np.zeros(n)
    g_r = g[reduced]
    H_rl = ne.H_rl
    g_l = g[lo:hi]
    # W = H_rl H_ll⁻¹ and H_ll⁻¹ g_l, blockwise.
    W = np.empty_like(H_rl)
    Hinv_g = np.empty(hi - lo)
    n_pts = mid - lo
    if n_pts:
        d_inv = 1.0 / ne.d_points
        W[:, :n_pts] = H_rl[:, :n_pts] * d_inv
        Hinv_g[:n_pts] = g_l[:n_pts] * d_inv
    n_lines = (hi - mid) // 4
    if n_lines:
        inv = _invert_blocks(ne.B_lines)
        W[:, n_pts:] = np.einsum("rli,lij->rlj", H_rl[:, n_pts:].reshape(-1, n_lines, 4), inv).reshape(len(reduced), -1)
        Hinv_g[n_pts:] = np.einsum("lij,lj->li", inv, g_l[n_pts:].reshape(n_lines, 4)).ravel()
    S = ne.H_rr
    S -= W @ H_rl.T
    delta_r = _dense_solve(S, g_r - H_rl @ Hinv_g)
    delta[reduced] = delta_r
    # δ_l = H_ll⁻¹ (g_l - H_lr δ_r) = H_ll⁻¹ g_l - Wᵀ δ_r (H_ll⁻¹ is symmetric).
    delta[lo:hi] = Hinv_g - W.T @ delta_r
    return delta


def solve_normal_equations(lin: Linearization, layout: Layout) -> np.ndarray:
    """Gauss-Newton step δ (n_params,) solving `JᵀJ δ = -Jᵀ r` by the Schur complement."""
    return solve_schur_blocks(lin.normal_blocks(layout), layout)


METHODS: tuple[str, ...] = ("gn", "lm")


def optimize(
    problem: Problem,
    state: State | None = None,
    *,
    method: str = "gn",
    max_iterations: int = 10,
    relative_tolerance: float = 1e-10,
    step_tolerance: float = 1e-10,
    max_step_halvings: int = 4,
    initial_lambda: float = 1e-4,
) -> tuple[State, SolveReport]:
    """Minimize the problem's cost from `state` (its initial values by default).

    `method="gn"`: Gauss-Newton; if a full step raises the cost it is halved, at most
    `max_step_halvings` times (the last is taken anyway). `method="lm"`: Levenberg-Marquardt
    with Marquardt's scaling `H + λ diag(H)`, λ divided by 10 after a successful step and
    multiplied by 10 (re-solving the same linearization) after a failed one.

    An iteration is one linearization and its accepted step; at most `max_iterations`. Stops
    early when the cost decreases by less than `relative_tolerance` (relative) or the largest
    step component is below `step_tolerance`. The report splits the loop's wall time into
    linearization (residuals, Jacobians), solve (normal equations, Schur complement,
    Cholesky) and other (retraction, bookkeeping).
    """
    if method not in METHODS:
        raise ValueError(f"unknown method {method!r}; expected one of {', '.join(METHODS)}")
    t_start = time.perf_counter()
    state = problem.initial_state() if state is None else state
    t_lin = t_solve = 0.0
    t0 = time.perf_counter()
    lin = problem.linearize(state)
    t_lin += time.perf_counter() - t0
    costs = [lin.cost]
    iterations = 0
    converged = False
    lam = initial_lambda
    for _ in range(max_iterations):
        t0 = time.perf_counter()
        blocks = lin.normal_blocks(problem.layout)
        t_solve += time.perf_counter() - t0
        step = 1.0
        for attempt in range(max_step_halvings + 1 if method == "gn" else 12):
            t0 = time.perf_counter()
            if method == "lm":
                delta = solve_schur_blocks(blocks.damped(lam), problem.layout)
            elif attempt == 0:
                delta = solve_schur_blocks(blocks, problem.layout)
            t_solve += time.perf_counter() - t0
            if not np.all(np.isfinite(delta)):
                delta = np.zeros_like(delta)
            candidate = problem.retract(state, step * delta)
            t0 = time.perf_counter()
            lin_candidate = problem.linearize(candidate)
            t_lin += time.perf_counter() - t0
            if np.isfinite(lin_candidate.cost) and lin_candidate.cost <= costs[-1]:
                lam = max(lam / 10.0, 1e-10)
                break
            if method == "gn":
                step *= 0.5
            else:
                lam *= 10.0
        else:
            if method == "lm":  # no damping helped: keep the current state
                candidate, lin_candidate, delta, step = state, lin, np.zeros_like(delta), 0.0
        state, lin = candidate, lin_candidate
        iterations += 1
        costs.append(lin.cost)
        if abs(costs[-2] - costs[-1]) <= relative_tolerance * max(costs[-2], 1e-300) or np.max(np.abs(step * delta), initial=0.0) < step_tolerance:
            converged = True
            break
    total = time.perf_counter() - t_start
    report = SolveReport(
        variant=problem.variant,
        method=method,
        iterations=iterations,
        initial_cost=costs[0],
        final_cost=costs[-1],
        costs=tuple(costs),
        time_ms=1e3 * total,
        linearize_ms=1e3 * t_lin,
        solve_ms=1e3 * t_solve,
        other_ms=1e3 * (total - t_lin - t_solve),
        converged=converged,
        items=problem.layout.n_items,
        params=problem.layout.n_params,
    )
    return state, report


def gauss_newton(problem: Problem, state: State | None = None, **options) -> tuple[State, SolveReport]:
    """:func:`optimize` with `method="gn"` (the Monte-Carlo study's solver)."""
    return optimize(problem, state, method="gn", **options)
