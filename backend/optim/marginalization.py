"""Marginalization of a sliding window's oldest states into a linear prior (Schur complement).

When the VIO window slides, the oldest keyframe's pose and inertial state, and the landmarks
it anchors, leave the optimization. Their factors (reprojections of those landmarks, the IMU
and bias factors to the next keyframe, the previous prior) are linearized at the current
estimate and the marginalized columns are eliminated: the information they carried about the
remaining poses, inertial states and planes becomes a :class:`~backend.optim.inertial.LinearPrior`
`r = A (x ⊟ x̄) + b` with `AᵀA = H_kk - H_km H_mm⁺ H_mk` and `Aᵀb = g_k - H_km H_mm⁺ g_m`.

Under -w a feature on a plane has no variable: its factors join (anchor pose, observing pose,
plane), so the prior keeps the plane, which stays a variable of the window while the prior
holds it (:func:`backend.optim.problem.build_problem`).

Consistency: the prior's Jacobian `A` is fixed at the marginalization point x̄ and only its
residual moves with the state (`A (x ⊟ x̄) + b`), as VINS-Mono does; first-estimate
Jacobians for the other factors on the same variables are not used. The directions the
window cannot observe (global position and yaw) get no information from the prior because
eigenvalues below `rank_tolerance` of the largest are dropped from `A`.
"""

from __future__ import annotations

import numpy as np

from backend.optim import inertial
from backend.optim.problem import Problem, State


def marginalize(
    problem: Problem, state: State, *, poses: np.ndarray, points: np.ndarray = np.zeros(0, np.int64), lines: np.ndarray = np.zeros(0, np.int64), rank_tolerance: float = 1e-9
) -> inertial.LinearPrior | None:
    """Marginalize the camera poses `poses` (with their inertial states) and the landmarks
    `points`, `lines` (problem indices; those without a variable under the variant are
    ignored) of `problem` at `state`. Returns the prior on the poses, inertial states and
    planes that shared factors with them, in the problem's indices, or None when nothing is
    left to constrain. Factors that also touch a landmark that stays are left out (their
    information is dropped, not double counted), and so are residual rows that are not
    finite at `state`."""
    L = problem.layout
    lin = problem.linearize(state)
    J = lin.jacobian.tocsc()
    r = lin.residual
    n = L.n_params
    marg = np.zeros(n, bool)
    poses = np.asarray(poses, np.int64)
    for col, dim, idx in ((L.pose_col, 6, poses), (L.point_col, 1, np.asarray(points, np.int64)), (L.line_col, 4, np.asarray(lines, np.int64))):
        c = col[idx]
        c = c[c >= 0]
        marg[(c[:, None] + np.arange(dim)).ravel()] = True
    if L.inertial_col is not None:
        c = L.inertial_col[poses]
        c = c[c >= 0]
        marg[(c[:, None] + np.arange(inertial.INERTIAL_DIM)).ravel()] = True
    if not marg.any():
        return None
    # Rows (residuals) that touch a marginalized column; whole factors are rows of one batch,
    # so a factor touching it has all its rows selected.
    Jr = J.tocsr()
    rows = np.unique(J[:, np.flatnonzero(marg)].tocoo().row)
    # A factor linearized at a non-finite estimate (a degenerate landmark the solve left
    # behind) carries no usable information: its rows are left out rather than poisoning
    # the prior.
    Js = Jr[rows]
    finite = np.isfinite(r[rows])
    coo = Js.tocoo()
    finite[coo.row[~np.isfinite(coo.data)]] = False
    rows, Js = rows[finite], Js[finite]
    touched = np.unique(Js.tocoo().col)
    landmark_lo, landmark_hi = L.group_start["points"], L.group_start["planes"]
    kept_landmark = touched[(touched >= landmark_lo) & (touched < landmark_hi) & ~marg[touched]]
    if len(kept_landmark):
        bad = np.unique(Js[:, kept_landmark].tocoo().row)
        Js = Js[np.setdiff1d(np.arange(Js.shape[0]), bad)]
        rows = np.setdiff1d(rows, rows[bad])
        touched = np.unique(Js.tocoo().col)
    rs = r[rows]
    m_cols = touched[marg[touched]]
    k_cols = _ordered_kept(L, touched[~marg[touched]])
    if len(k_cols) == 0:
        return None
    Jm = Js[:, m_cols].toarray()
    Jk = Js[:, k_cols].toarray()
    H_mm, H_mk, H_kk = Jm.T @ Jm, Jm.T @ Jk, Jk.T @ Jk
    g_m, g_k = Jm.T @ rs, Jk.T @ rs
    w, V = np.linalg.eigh(H_mm)
    keep = w > rank_tolerance * max(float(w[-1]) if len(w) else 0.0, 1e-300)
    H_mm_pinv = (V[:, keep] / w[keep]) @ V[:, keep].T
    H_p = H_kk - H_mk.T @ H_mm_pinv @ H_mk
    g_p = g_k - H_mk.T @ H_mm_pinv @ g_m
    H_p = 0.5 * (H_p + H_p.T)
    s, U = np.linalg.eigh(H_p)
    ok = s > rank_tolerance * max(float(s[-1]) if len(s) else 0.0, 1e-300)
    if not ok.any():
        return None
    sq = np.sqrt(s[ok])
    A = (U[:, ok] * sq).T
    b = (U[:, ok].T @ g_p) / sq
    return _prior(problem, state, k_cols, A, b)


def _ordered_kept(L, cols: np.ndarray) -> np.ndarray:
    """The kept columns in the prior's order (poses, inertial states, planes), whole blocks."""
    out = []
    for col, dim in ((L.pose_col, 6), (L.inertial_col, inertial.INERTIAL_DIM), (L.plane_col, 3)):
        if col is None:
            continue
        starts = col[col >= 0]
        hit = [s for s in np.sort(starts) if np.any((cols >= s) & (cols < s + dim))]
        out += [s + np.arange(dim) for s in hit]
    return np.concatenate(out) if out else np.zeros(0, np.int64)


def _prior(problem: Problem, state: State, k_cols: np.ndarray, A: np.ndarray, b: np.ndarray) -> inertial.LinearPrior:
    L = problem.layout
    starts = set(int(c) for c in k_cols)

    def chosen(col: np.ndarray | None) -> np.ndarray:
        if col is None:
            return np.zeros(0, np.int64)
        idx = np.flatnonzero(col >= 0)
        return idx[[int(col[i]) in starts for i in idx]].astype(np.int64) if len(idx) else np.zeros(0, np.int64)

    pi, ii, qi = chosen(L.pose_col), chosen(L.inertial_col), chosen(L.plane_col)
    vb = np.zeros((len(ii), inertial.INERTIAL_DIM))
    if len(ii):
        assert state.velocity is not None and state.bias is not None  # inertial columns come with inertial states
        vb = np.concatenate([state.velocity[ii], state.bias[ii]], axis=1)
    return inertial.LinearPrior(
        pose_index=pi,
        inertial_index=ii,
        plane_index=qi,
        R=state.poses.R_world_camera[pi].copy(),
        t=state.poses.t_world_camera[pi].copy(),
        inertial=vb,
        plane_n=state.plane_n[qi].copy(),
        plane_d=state.plane_d[qi].copy(),
        A=A,
        b=b,
    )


def remap(prior: inertial.LinearPrior, *, pose_map: np.ndarray, plane_map: np.ndarray | None = None) -> inertial.LinearPrior:
    """The prior with its pose (and inertial) indices renumbered by `pose_map` (old -> new
    index) and plane indices by `plane_map` (identity when None), for the next window's
    problem. A variable mapped to -1 must not occur (it would need marginalizing first)."""
    pi = pose_map[prior.pose_index]
    ii = pose_map[prior.inertial_index]
    qi = prior.plane_index if plane_map is None else plane_map[prior.plane_index]
    if np.any(pi < 0) or np.any(ii < 0) or np.any(qi < 0):
        raise ValueError("the prior holds a variable that is not in the new window")
    return inertial.LinearPrior(pi, ii, qi, prior.R, prior.t, prior.inertial, prior.plane_n, prior.plane_d, prior.A, prior.b)
