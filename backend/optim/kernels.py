"""Compiled per-observation loops (numba) for the solver's hot path.

numpy evaluates each operation over all observations, but the observations' algebra is a
few dozen flops on 3-vectors and 3×3 matrices, so the cost is dominated by temporaries and
per-call overhead. These loops do the same algebra in one pass; the formulas are those of
:mod:`backend.optim.factors` (which documents them) and are checked against central
differences by the problem-level Jacobian tests. Compiled code is cached on disk
(`cache=True`), so only the first run on a machine pays the compilation.
"""

from __future__ import annotations

import numba
import numpy as np


@numba.njit(cache=True, nogil=True)
def point_reprojection(fx, fy, cx, cy, p_world_l, J_world_l, landmark, R_world_camera, t_world_camera, pose, offset, uv, residual, J, depth):  # noqa: ANN001
    """Fill residual (M, 2), J (M, 2, Dw + 6) and depth (M,) for points with world position
    p_world_l (L, 3) and Jacobian J_world_l (L, 3, Dw) seen from poses (N, 3, 3), (N, 3)."""
    Dw = J_world_l.shape[2]
    jp = np.empty((2, 3))
    for m in range(landmark.shape[0]):
        lm = landmark[m]
        k = pose[m]
        R = R_world_camera[k]
        d0 = p_world_l[lm, 0] - t_world_camera[k, 0]
        d1 = p_world_l[lm, 1] - t_world_camera[k, 1]
        d2 = p_world_l[lm, 2] - t_world_camera[k, 2]
        pr0 = R[0, 0] * d0 + R[1, 0] * d1 + R[2, 0] * d2  # p_rel = Rᵀ (X_w - t)
        pr1 = R[0, 1] * d0 + R[1, 1] * d1 + R[2, 1] * d2
        pr2 = R[0, 2] * d0 + R[1, 2] * d1 + R[2, 2] * d2
        pc0 = pr0 - offset[m, 0]
        pc1 = pr1 - offset[m, 1]
        pc2 = pr2 - offset[m, 2]
        iz = 1.0 / pc2
        xz = pc0 * iz
        yz = pc1 * iz
        residual[m, 0] = fx * xz + cx - uv[m, 0]
        residual[m, 1] = fy * yz + cy - uv[m, 1]
        depth[m] = pc2
        a0 = fx * iz
        c0 = -fx * xz * iz
        a1 = fy * iz
        c1 = -fy * yz * iz
        for i in range(3):  # G Rᵀ with G = [[a0, 0, c0], [0, a1, c1]]
            jp[0, i] = a0 * R[i, 0] + c0 * R[i, 2]
            jp[1, i] = a1 * R[i, 1] + c1 * R[i, 2]
        for r in range(2):
            for c in range(Dw):
                J[m, r, c] = jp[r, 0] * J_world_l[lm, 0, c] + jp[r, 1] * J_world_l[lm, 1, c] + jp[r, 2] * J_world_l[lm, 2, c]
            for i in range(3):
                J[m, r, Dw + 3 + i] = -jp[r, i]
        # Rows of G [p_rel]_× are g_r × p_rel.
        J[m, 0, Dw + 0] = -c0 * pr1
        J[m, 0, Dw + 1] = c0 * pr0 - a0 * pr2
        J[m, 0, Dw + 2] = a0 * pr1
        J[m, 1, Dw + 0] = a1 * pr2 - c1 * pr1
        J[m, 1, Dw + 1] = c1 * pr0
        J[m, 1, Dw + 2] = -a1 * pr0


@numba.njit(cache=True, nogil=True)
def _cross3(a0, a1, a2, b0, b1, b2):  # noqa: ANN001, ANN202
    return a1 * b2 - a2 * b1, a2 * b0 - a0 * b2, a0 * b1 - a1 * b0


@numba.njit(cache=True, nogil=True)
def line_reprojection(f, m_world_l, v_world_l, J_mv_l, landmark, R_world_camera, t_world_camera, pose, offset, x_start, x_end, residual, J):  # noqa: ANN001
    """Fill residual (M, 2) and J (M, 2, D + 6) of the endpoint-to-line error for lines with
    world Plücker (m, v) (L, 3) and Jacobian of the stacked (m, v) J_mv_l (L, 6, D)."""
    D = J_mv_l.shape[2]
    dr_dl = np.empty((2, 3))
    q = np.empty((2, 3))
    dmv = np.empty((2, 6))
    for m in range(landmark.shape[0]):
        lm = landmark[m]
        k = pose[m]
        R = R_world_camera[k]
        t0, t1, t2 = t_world_camera[k, 0], t_world_camera[k, 1], t_world_camera[k, 2]
        vw0, vw1, vw2 = v_world_l[lm, 0], v_world_l[lm, 1], v_world_l[lm, 2]
        c0, c1, c2 = _cross3(t0, t1, t2, vw0, vw1, vw2)
        w0, w1, w2 = m_world_l[lm, 0] - c0, m_world_l[lm, 1] - c1, m_world_l[lm, 2] - c2
        mr0 = R[0, 0] * w0 + R[1, 0] * w1 + R[2, 0] * w2  # m_rel = Rᵀ (m_w - t × v_w)
        mr1 = R[0, 1] * w0 + R[1, 1] * w1 + R[2, 1] * w2
        mr2 = R[0, 2] * w0 + R[1, 2] * w1 + R[2, 2] * w2
        vc0 = R[0, 0] * vw0 + R[1, 0] * vw1 + R[2, 0] * vw2  # v_cam = Rᵀ v_w
        vc1 = R[0, 1] * vw0 + R[1, 1] * vw1 + R[2, 1] * vw2
        vc2 = R[0, 2] * vw0 + R[1, 2] * vw1 + R[2, 2] * vw2
        o0, o1, o2 = offset[m, 0], offset[m, 1], offset[m, 2]
        x0, x1, x2 = _cross3(o0, o1, o2, vc0, vc1, vc2)
        l0, l1, l2 = mr0 - x0, mr1 - x1, mr2 - x2
        inv = 1.0 / np.sqrt(l0 * l0 + l1 * l1)
        e0 = x_start[m, 0] * l0 + x_start[m, 1] * l1 + x_start[m, 2] * l2
        e1 = x_end[m, 0] * l0 + x_end[m, 1] * l1 + x_end[m, 2] * l2
        residual[m, 0] = f * e0 * inv
        residual[m, 1] = f * e1 * inv
        inv3 = inv * inv * inv
        for j in range(3):
            dr_dl[0, j] = f * x_start[m, j] * inv
            dr_dl[1, j] = f * x_end[m, j] * inv
        dr_dl[0, 0] -= f * e0 * inv3 * l0
        dr_dl[0, 1] -= f * e0 * inv3 * l1
        dr_dl[1, 0] -= f * e1 * inv3 * l0
        dr_dl[1, 1] -= f * e1 * inv3 * l1
        for r in range(2):
            g0, g1, g2 = dr_dl[r, 0], dr_dl[r, 1], dr_dl[r, 2]
            for i in range(3):
                q[r, i] = g0 * R[i, 0] + g1 * R[i, 1] + g2 * R[i, 2]  # dr_dl Rᵀ
            wo0, wo1, wo2 = _cross3(g0, g1, g2, o0, o1, o2)
            qt0, qt1, qt2 = _cross3(q[r, 0], q[r, 1], q[r, 2], t0, t1, t2)
            for i in range(3):
                dmv[r, i] = q[r, i]
                dmv[r, 3 + i] = -(qt0, qt1, qt2)[i] - (wo0 * R[i, 0] + wo1 * R[i, 1] + wo2 * R[i, 2])
            for c in range(D):
                acc = 0.0
                for s in range(6):
                    acc += dmv[r, s] * J_mv_l[lm, s, c]
                J[m, r, c] = acc
            a0, a1, a2 = _cross3(g0, g1, g2, mr0, mr1, mr2)
            b0, b1, b2 = _cross3(wo0, wo1, wo2, vc0, vc1, vc2)
            J[m, r, D + 0] = a0 - b0
            J[m, r, D + 1] = a1 - b1
            J[m, r, D + 2] = a2 - b2
            p0, p1, p2 = _cross3(q[r, 0], q[r, 1], q[r, 2], vw0, vw1, vw2)
            J[m, r, D + 3] = p0
            J[m, r, D + 4] = p1
            J[m, r, D + 5] = p2


@numba.njit(cache=True, nogil=True, fastmath=True)
def accumulate_normal_equations(J, residual, cols, H, g):  # noqa: ANN001
    """Add `JᵀJ` into the upper triangle of H (n, n) and `-Jᵀr` into g (n,) for a batch:
    J (M, r, D), residual (M, r), cols (M, D) global column of each Jacobian column or -1.

    Consecutive observations with the same columns are summed in a local D×D buffer first
    (the problem orders observations so that they are adjacent); H is touched once per run.
    """
    M, R, D = J.shape
    A = np.zeros((D, D))
    b = np.zeros(D)
    for m in range(M):
        Jm = J[m]
        for r in range(R):
            rr = residual[m, r]
            Jr = Jm[r]
            for i in range(D):
                jri = Jr[i]
                b[i] += jri * rr
                Ai = A[i]
                for j in range(D):
                    Ai[j] += jri * Jr[j]
        last = m == M - 1
        if not last:
            for i in range(D):
                if cols[m + 1, i] != cols[m, i]:
                    last = True
                    break
        if last:  # flush the run into H and g
            for i in range(D):
                ci = cols[m, i]
                if ci < 0:
                    continue
                g[ci] -= b[i]
                for j in range(i, D):
                    cj = cols[m, j]
                    if cj < 0:
                        continue
                    v = A[i, j]
                    if i == j:
                        H[ci, ci] += v
                    elif ci < cj:
                        H[ci, cj] += v
                    elif ci > cj:
                        H[cj, ci] += v
                    else:
                        H[ci, ci] += 2.0 * v
            A[:, :] = 0.0
            b[:] = 0.0


@numba.njit(cache=True, nogil=True)
def mirror_upper(H):  # noqa: ANN001
    """Copy the upper triangle of the square H into its lower triangle, in place."""
    n = H.shape[0]
    for i in range(n):
        for j in range(i + 1, n):
            H[j, i] = H[i, j]
