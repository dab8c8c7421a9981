"""Gauss-Newton on a :class:`~backend.optim.problem.Problem` with the Schur complement.

The landmark variables (inverse depths, orthonormal lines) form a block-diagonal part of
H = JᵀJ (no factor joins two landmarks); they are eliminated first and the reduced system
over cameras and planes is formed over each landmark's own rows and solved by Cholesky:
an envelope (profile) Cholesky of the reordered camera block with the planes as a dense
border where the cameras see only their neighbours (sequence a's circle), dense otherwise
(:mod:`backend.optim.sparse_schur`). This is the
structure the paper's efficiency argument rests on: -w has no landmark variables and a
smaller reduced system.

The solver never accepts a step that raises the cost and reports `converged` only when a
convergence test held (:func:`optimize`).
"""

from __future__ import annotations

import dataclasses
import enum
import time

import numpy as np
import scipy.linalg
import scipy.linalg.lapack

from backend.common.blas import single_threaded_blas
from backend.optim import sparse_schur
from backend.optim.problem import Layout, Linearization, NormalBlocks, Problem, State


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


def _invert_blocks(blocks: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Inverse of a stack of small symmetric blocks (L, k, k) and a mask (L,) of those that
    are positive definite and finite; the others get a zero inverse (left out of the step)."""
    L, k, _ = blocks.shape
    good = np.all(np.isfinite(blocks.reshape(L, k * k)), axis=1)
    inv = np.zeros_like(blocks)
    if np.any(good):
        eig = np.linalg.eigvalsh(blocks[good])
        scale = np.maximum(eig[:, -1], 1e-300)
        ok = eig[:, 0] > 1e-12 * scale
        idx = np.flatnonzero(good)
        good[idx[~ok]] = False
        if np.any(good):
            inv[good] = np.linalg.inv(blocks[good])
    return inv, good


def solve_schur(H: np.ndarray, g: np.ndarray, layout: Layout) -> np.ndarray:
    """Solve `H δ = g` (dense H, both triangles) by eliminating the landmark columns
    (:func:`solve_schur_blocks`)."""
    n = layout.n_params
    lo, mid, hi = layout.group_start["points"], layout.group_start["lines"], layout.group_start["planes"]
    reduced = np.r_[0:lo, hi:n]
    n_lines = (hi - mid) // 4
    blocks = H[mid:hi, mid:hi].reshape(n_lines, 4, n_lines, 4)[np.arange(n_lines), :, np.arange(n_lines), :] if n_lines else np.zeros((0, 4, 4))
    return solve_schur_blocks(NormalBlocks(reduced, H[np.ix_(reduced, reduced)], H[reduced, lo:hi], np.diagonal(H)[lo:mid].copy(), blocks, g), layout).delta


@dataclasses.dataclass(frozen=True)
class SchurSolution:
    """A step δ (n_params,) and the landmarks left out of it: points (indices into the
    layout's point columns) and lines whose own block of H is singular or not finite (not
    observed enough in this linearization), held at their value (δ = 0) for this step.
    `linear_solver`: "dense" or "envelope" (the reduced system's factorization)."""

    delta: np.ndarray
    dropped_points: np.ndarray
    dropped_lines: np.ndarray
    linear_solver: str

    @property
    def n_dropped(self) -> int:
        return int(len(self.dropped_points) + len(self.dropped_lines))


def _solve_reduced(S: np.ndarray, b: np.ndarray, n_cameras: int, cache: dict | None) -> tuple[np.ndarray, str]:
    """Solve the reduced camera | plane system: envelope Cholesky of the reordered camera
    block with a dense plane border where its estimated work is well below the dense
    factorization's (:func:`sparse_schur.envelope_pays`), dense Cholesky otherwise. The
    plan (order, panels, workspace) depends on the structure only and is kept in `cache`."""
    if n_cameras >= 60:  # below ten cameras the dense factorization is as fast
        key = ("envelope_plan", S.shape[0], n_cameras)
        plan = cache.get(key) if cache is not None else None
        if plan is None:
            plan = sparse_schur.envelope_plan(S[:n_cameras, :n_cameras], S.shape[0] - n_cameras)
            if cache is not None:
                cache[key] = plan
        if sparse_schur.envelope_pays(plan, S.shape[0]):
            x = sparse_schur.solve_bordered_envelope(S, b, n_cameras, plan)
            if x is not None:
                return x, "envelope"
    return _dense_solve(S, b), "dense"


def solve_schur_blocks(ne: NormalBlocks, layout: Layout, *, cache: dict | None = None) -> SchurSolution:
    """Solve the normal equations by eliminating the landmark columns (points: 1×1 blocks,
    lines: 4×4 blocks, block-diagonal in H) and solving the reduced camera|plane system by
    Cholesky. A landmark whose own block is singular or not finite is left out of the step
    (δ = 0, no contribution to the reduced system) and reported, so that one degenerate
    landmark cannot spoil the step of all others. `ne.H_rr` is used as workspace: its
    contents are undefined afterwards. `cache` (the problem's) keeps the reduced system's
    envelope plan (order, panels, workspace) between iterations."""
    n = layout.n_params
    lo, mid, hi = layout.group_start["points"], layout.group_start["lines"], layout.group_start["planes"]
    n_cameras = layout.n_pose_params  # VIO's inertial columns join the dense border with the planes
    g = ne.g
    none = np.zeros(0, np.int64)
    if hi == lo:  # no landmark variables (-w with every feature on a plane)
        x, how = _solve_reduced(ne.H_rr, g.copy(), n_cameras, cache)
        return SchurSolution(x, none, none, how)
    reduced = ne.reduced
    delta = np.zeros(n)
    g_r = g[reduced]
    H_rl = ne.H_rl
    g_l = g[lo:hi]
    # W = H_rl H_ll⁻¹ and H_ll⁻¹ g_l, blockwise; zero for the landmarks left out.
    n_pts = mid - lo
    n_lines = (hi - mid) // 4
    W = np.zeros_like(H_rl)
    Hinv_g = np.zeros(hi - lo)
    col_ok = ne.shared.get("col_ok")
    if col_ok is None:  # the same for every damping of these blocks
        col_ok = ne.shared["col_ok"] = np.isfinite(g_l) & np.isfinite(H_rl.sum(axis=0))
    point_ok = np.zeros(0, bool)
    line_ok = np.zeros(0, bool)
    inv = np.zeros((0, 4, 4))
    if n_pts:
        dp = ne.d_points
        scale = max(float(np.max(np.abs(dp), initial=0.0)), 1e-300)
        point_ok = np.isfinite(dp) & (dp > 1e-12 * scale) & col_ok[:n_pts]
    if n_lines:
        inv, line_ok = _invert_blocks(ne.B_lines)
        line_ok &= np.all(col_ok[n_pts:].reshape(n_lines, 4), axis=1)
        inv[~line_ok] = 0.0
    used = np.concatenate([point_ok, np.repeat(line_ok, 4)])
    kept = ne.shared.get("landmark_rows")
    if kept is not None and np.array_equal(kept[0], used):  # another damping, the same landmarks
        H_used, indptr, rows = kept[1:]
    else:
        H_used = H_rl if np.all(used) else np.where(used, H_rl, 0.0)
        indptr, rows = sparse_schur.landmark_rows(H_used, n_pts, n_lines)
        ne.shared["landmark_rows"] = (used, H_used, indptr, rows)
    if n_pts:
        d_inv = np.where(point_ok, 1.0 / np.where(point_ok, ne.d_points, 1.0), 0.0)
        sparse_schur.point_columns_times_inverse(H_used, d_inv, indptr, rows, W)
        Hinv_g[:n_pts] = np.where(point_ok, g_l[:n_pts], 0.0) * d_inv
    if n_lines:
        sparse_schur.line_columns_times_inverse(H_used, inv, indptr, rows, n_pts, W)
        Hinv_g[n_pts:] = np.einsum("lij,lj->li", inv, np.where(np.repeat(line_ok, 4), g_l[n_pts:], 0.0).reshape(n_lines, 4)).ravel()
    S = ne.H_rr
    sparse_schur.subtract_landmarks(S, H_used, W, indptr, rows, n_pts, n_lines)
    delta_r, how = _solve_reduced(S, g_r - H_used @ Hinv_g, n_cameras, cache)
    delta[reduced] = delta_r
    # δ_l = H_ll⁻¹ (g_l - H_lr δ_r) = H_ll⁻¹ g_l - Wᵀ δ_r (H_ll⁻¹ is symmetric).
    delta[lo:hi] = Hinv_g - W.T @ delta_r
    return SchurSolution(delta, np.flatnonzero(~point_ok), np.flatnonzero(~line_ok), how)


def solve_normal_equations(lin: Linearization, layout: Layout) -> np.ndarray:
    """Gauss-Newton step δ (n_params,) solving `JᵀJ δ = -Jᵀ r` by the Schur complement."""
    return solve_schur_blocks(lin.normal_blocks(layout), layout).delta


METHODS: tuple[str, ...] = ("gn", "lm")


class Damping(enum.Enum):
    """How Levenberg-Marquardt changes λ: MARQUARDT divides it by 10 after an accepted step
    and multiplies it by 10 after a rejected one; NIELSEN (Madsen, Nielsen & Tingleff, as
    g2o and Ceres) scales it by max(1/3, 1 - (2ρ - 1)³) after an accepted step, ρ the gain
    ratio against the damped model, and by ν = 2, 4, 8, ... after rejected ones in a row."""

    MARQUARDT = "marquardt"
    NIELSEN = "nielsen"


# How a solve ended (SolveReport.termination); only the first two count as converged.
CONVERGED_COST = "converged: relative cost change below tolerance"
CONVERGED_STEP = "converged: step below tolerance"
CONVERGED_MODEL = "converged: no decrease left to gain (predicted decrease below tolerance)"
CONVERGED_ROUNDING = "converged: the full step changes the cost only at rounding level"
# A full step whose cost change is below this (relative) is at the minimum to rounding: the
# cost cannot be lowered meaningfully, and shortening or damping it would only spend time.
ROUNDING_RELATIVE = 1e-12
MAX_ITERATIONS = "maximum iterations reached"
STALLED = "stalled: no step lowers the cost"
NOT_FINITE = "failed: the cost at the initial state is not finite"


@dataclasses.dataclass(frozen=True)
class SolveReport:
    """What one optimization did. Times in milliseconds (wall clock).

    `costs` are the costs of the accepted states (the first is the initial cost), so they
    never increase. `converged` is true only when a convergence test held (`termination`
    says which); a solve that ran out of iterations or found no step that lowers the cost
    is not converged. `linearizations` counts every evaluation of residuals and Jacobians
    (a rejected trial step costs one), `rejected_steps` the trial steps that raised the cost
    (then shortened or damped), `dropped_landmarks` the largest number of landmarks left
    out of one step because their own block of H was singular (see
    :class:`SchurSolution`), `linear_solver` how the last reduced system was factored."""

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
    termination: str = ""
    linearizations: int = 0
    rejected_steps: int = 0
    dropped_landmarks: int = 0
    linear_solver: str = ""


@single_threaded_blas
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
    max_damping_increases: int = 6,
    damping: Damping = Damping.MARQUARDT,
) -> tuple[State, SolveReport]:
    """Minimize the problem's cost from `state` (its initial values by default). A step
    that raises the cost is never accepted.

    `method="gn"`: Gauss-Newton. If the full step raises the cost it is halved, at most
    `max_step_halvings` times (backtracking along the Gauss-Newton direction); if no
    shortened step lowers the cost either, the iteration falls back to Levenberg-Marquardt
    damping on the same linearization (`H + λ diag(H)`, λ from `initial_lambda`, ×10 per
    failure, at most `max_damping_increases` times). `method="lm"`: Levenberg-Marquardt with
    Marquardt's scaling, λ changed by `damping` (:class:`Damping`: by default divided by 10
    after a successful step and multiplied by 10, re-solving the same linearization, after
    a failed one), at most `max_damping_increases` failures in a row.

    An iteration is one linearization and its accepted step; at most `max_iterations`. The
    solve has converged when the accepted step changed the cost by less than
    `relative_tolerance` (relative), when the largest component of the step actually
    applied is below `step_tolerance`, or when the linear model predicts a decrease below
    `relative_tolerance` (relative; the cost is at its minimum to working precision: no
    trial step is made), or when the full step is rejected but changes the cost only at
    rounding level (`ROUNDING_RELATIVE`; no shortened or damped step is tried). If no step lowers the cost although the model predicts a
    decrease, the solve stops at the current state and reports itself stalled (not
    converged). Landmarks whose own block of H is singular are left out of the step
    (:func:`solve_schur_blocks`) and counted in the report.

    The report splits the loop's wall time into linearization (residuals, Jacobians), solve
    (normal equations, Schur complement, Cholesky) and other (retraction, bookkeeping).
    """
    if method not in METHODS:
        raise ValueError(f"unknown method {method!r}; expected one of {', '.join(METHODS)}")
    t_start = time.perf_counter()
    layout = problem.layout
    state = problem.initial_state() if state is None else state
    t_lin = t_solve = 0.0
    n_lin = 0

    def linearize(s: State) -> Linearization:
        nonlocal t_lin, n_lin
        t0 = time.perf_counter()
        out = problem.linearize(s)
        t_lin += time.perf_counter() - t0
        n_lin += 1
        return out

    def solve(blocks: NormalBlocks) -> SchurSolution:
        nonlocal t_solve
        t0 = time.perf_counter()
        out = solve_schur_blocks(blocks, layout, cache=problem.cache)
        t_solve += time.perf_counter() - t0
        return out

    lin = linearize(state)
    costs = [lin.cost]
    iterations = rejected = dropped = 0
    how = ""
    termination = MAX_ITERATIONS
    lam = initial_lambda
    if not np.isfinite(lin.cost):
        termination = NOT_FINITE
        max_iterations = 0
    for _ in range(max_iterations):
        t0 = time.perf_counter()
        blocks = lin.normal_blocks(layout)
        t_solve += time.perf_counter() - t0
        accepted: tuple[State, Linearization, np.ndarray] | None = None
        last_trial_cost = np.inf
        predicted = 0.0  # decrease of the cost the linear model predicts for the last step tried

        def trial(delta: np.ndarray) -> bool:
            nonlocal accepted, rejected, last_trial_cost
            last_trial_cost = np.inf
            if not np.all(np.isfinite(delta)):
                rejected += 1
                return False
            candidate = problem.retract(state, delta)  # type: ignore[arg-type]  # noqa: B023 - runs within this iteration, where state is set
            lin_candidate = linearize(candidate)
            last_trial_cost = lin_candidate.cost
            if np.isfinite(lin_candidate.cost) and lin_candidate.cost <= costs[-1]:
                accepted = (candidate, lin_candidate, delta)
                return True
            rejected += 1
            return False

        if method == "gn":
            sol = solve(blocks)
            dropped, how = max(dropped, sol.n_dropped), sol.linear_solver
            # For the Gauss-Newton step H δ = g the model predicts a decrease of ½ δ·g.
            predicted = 0.5 * float(sol.delta @ blocks.g) if np.all(np.isfinite(sol.delta)) else np.inf
            if 0.0 <= predicted <= relative_tolerance * max(costs[-1], 1e-300):
                termination = CONVERGED_MODEL  # nothing left to gain: no trial steps
                break
            step = 1.0
            for halving in range(max_step_halvings + 1):
                if trial(step * sol.delta):
                    break
                if halving == 0 and abs(last_trial_cost - costs[-1]) <= ROUNDING_RELATIVE * max(costs[-1], 1e-300):
                    termination = CONVERGED_ROUNDING
                    break
                step *= 0.5
            if termination == CONVERGED_ROUNDING:
                break
        if accepted is None:  # LM, or Gauss-Newton's fallback: damp the same linearization
            if method == "gn":  # the Gauss-Newton solve used H_rr as workspace
                t0 = time.perf_counter()
                blocks = lin.normal_blocks(layout)
                t_solve += time.perf_counter() - t0
            nu = 2.0
            for _increase in range(max_damping_increases + 1):
                sol = solve(blocks.damped(lam))
                dropped, how = max(dropped, sol.n_dropped), sol.linear_solver
                if method == "lm" and np.all(np.isfinite(sol.delta)):
                    predicted = 0.5 * float(sol.delta @ blocks.g)
                if trial(sol.delta):
                    if damping is Damping.NIELSEN:
                        # The damped model's decrease: ½ δ·g + ½ λ δ·diag(H) δ.
                        model = 0.5 * float(sol.delta @ blocks.g) + 0.5 * lam * float(sol.delta @ (blocks.diagonal() * sol.delta))
                        rho = (costs[-1] - last_trial_cost) / model if model > 0 else 0.0
                        lam = max(lam * max(1.0 / 3.0, 1.0 - (2.0 * rho - 1.0) ** 3), 1e-10)
                    else:
                        lam = max(lam / 10.0, 1e-10)
                    break
                if damping is Damping.NIELSEN:
                    lam *= nu
                    nu *= 2.0
                else:
                    lam *= 10.0
        if accepted is None:
            termination = CONVERGED_MODEL if 0.0 <= predicted <= relative_tolerance * max(costs[-1], 1e-300) else STALLED
            break
        state, lin, applied = accepted
        iterations += 1
        costs.append(lin.cost)
        if abs(costs[-2] - costs[-1]) <= relative_tolerance * max(costs[-2], 1e-300):
            termination = CONVERGED_COST
            break
        if np.max(np.abs(applied), initial=0.0) < step_tolerance:
            termination = CONVERGED_STEP
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
        converged=termination.startswith("converged"),
        items=layout.n_items,
        params=layout.n_params,
        termination=termination,
        linearizations=n_lin,
        rejected_steps=rejected,
        dropped_landmarks=dropped,
        linear_solver=how,
    )
    return state, report


def gauss_newton(problem: Problem, state: State | None = None, **options) -> tuple[State, SolveReport]:
    """:func:`optimize` with `method="gn"` (the Monte-Carlo study's solver)."""
    return optimize(problem, state, method="gn", **options)
