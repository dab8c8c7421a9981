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

from backend.geometry.so3 import log_one, right_jacobian_inv_one


@numba.njit(cache=True, nogil=True)
def point_reprojection(fx, fy, cx, cy, p_world_l, J_world_l, landmark, R_world_camera, t_world_camera, pose, offset, uv, residual, J, depth):
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
def _cross3(a0, a1, a2, b0, b1, b2):
    return a1 * b2 - a2 * b1, a2 * b0 - a0 * b2, a0 * b1 - a1 * b0


@numba.njit(cache=True, nogil=True)
def line_reprojection(f, m_world_l, v_world_l, J_mv_l, landmark, R_world_camera, t_world_camera, pose, offset, x_start, x_end, residual, J):
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
def accumulate_normal_equations(J, residual, cols, H, g):
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
        if R == 2:  # the common case (reprojection): both rows in one pass over A
            J0 = Jm[0]
            J1 = Jm[1]
            r0 = residual[m, 0]
            r1 = residual[m, 1]
            for i in range(D):
                a0 = J0[i]
                a1 = J1[i]
                b[i] += a0 * r0 + a1 * r1
                Ai = A[i]
                for j in range(D):
                    Ai[j] += a0 * J0[j] + a1 * J1[j]
        else:
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


@numba.njit(cache=True, nogil=True, fastmath=True)
def accumulate_normal_blocks(J, residual, cols, rmap, lo, mid, hi, H_rr, H_rl, d_points, B_lines, g):
    """As :func:`accumulate_normal_equations`, into the blocks the Schur complement needs
    instead of a dense H: `H_rr` (r, r) over the reduced columns (cameras, planes; `rmap`
    maps a global column to its reduced index or -1), `H_rl` (r, hi - lo) between reduced
    and landmark columns [lo, hi), the points' diagonal `d_points` (mid - lo,) and the
    lines' 4×4 blocks `B_lines` ((hi - mid) / 4, 4, 4). Both triangles of `H_rr` and of the
    line blocks are filled. A factor touches one landmark at most."""
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
        if last:
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
                    ri = rmap[ci]
                    rj = rmap[cj]
                    if ri >= 0 and rj >= 0:
                        H_rr[ri, rj] += v
                        if i != j:
                            H_rr[rj, ri] += v
                    elif ri >= 0:
                        H_rl[ri, cj - lo] += v
                    elif rj >= 0:
                        H_rl[rj, ci - lo] += v
                    elif ci < mid:  # a point: its own 1×1 block
                        d_points[ci - lo] += v if i == j else 2.0 * v
                    else:
                        k = (ci - mid) // 4
                        a = (ci - mid) % 4
                        c = (cj - mid) % 4
                        B_lines[k, a, c] += v
                        if i != j:
                            B_lines[k, c, a] += v
            A[:, :] = 0.0
            b[:] = 0.0


@numba.njit(cache=True, nogil=True)
def mirror_upper(H):
    """Copy the upper triangle of the square H into its lower triangle, in place."""
    n = H.shape[0]
    for i in range(n):
        for j in range(i + 1, n):
            H[j, i] = H[i, j]


@numba.njit(cache=True, nogil=True)
def point_on_plane(x_anchor, n_world, d_world, B_plane, R_world_anchor, t_world_anchor, p_world, J, h_out):
    """Co-planar point per landmark: p_world (P, 3), J (P, 3, 9) w.r.t. [anchor (δθ, δt) |
    plane (δn, δd)], depth h (P,). Formulas in :func:`backend.optim.factors.point_world_on_plane`."""
    for p in range(x_anchor.shape[0]):
        R = R_world_anchor[p]
        x0, x1, x2 = x_anchor[p, 0], x_anchor[p, 1], x_anchor[p, 2]
        n0, n1, n2 = n_world[p, 0], n_world[p, 1], n_world[p, 2]
        t0, t1, t2 = t_world_anchor[p, 0], t_world_anchor[p, 1], t_world_anchor[p, 2]
        r0 = R[0, 0] * x0 + R[0, 1] * x1 + R[0, 2] * x2
        r1 = R[1, 0] * x0 + R[1, 1] * x1 + R[1, 2] * x2
        r2 = R[2, 0] * x0 + R[2, 1] * x1 + R[2, 2] * x2
        s = n0 * r0 + n1 * r1 + n2 * r2
        q = n0 * t0 + n1 * t1 + n2 * t2 + d_world[p]
        h = -q / s
        h_out[p] = h
        p_world[p, 0] = t0 + h * r0
        p_world[p, 1] = t1 + h * r1
        p_world[p, 2] = t2 + h * r2
        ray = (r0, r1, r2)
        k = q / (s * s)  # ∂h/∂ray = k n
        for c in range(3):
            # column c of ∂ray/∂δθ = -R (x̂ × e_c)
            e0, e1, e2 = 0.0, 0.0, 0.0
            if c == 0:
                e1, e2 = x2, -x1
            elif c == 1:
                e0, e2 = -x2, x0
            else:
                e0, e1 = x1, -x0
            d0 = -(R[0, 0] * e0 + R[0, 1] * e1 + R[0, 2] * e2)
            d1 = -(R[1, 0] * e0 + R[1, 1] * e1 + R[1, 2] * e2)
            d2 = -(R[2, 0] * e0 + R[2, 1] * e1 + R[2, 2] * e2)
            dh = k * (n0 * d0 + n1 * d1 + n2 * d2)
            J[p, 0, c] = h * d0 + r0 * dh
            J[p, 1, c] = h * d1 + r1 * dh
            J[p, 2, c] = h * d2 + r2 * dh
        nn = (n0, n1, n2)
        for i in range(3):
            for c in range(3):
                J[p, i, 3 + c] = (1.0 if i == c else 0.0) - ray[i] * nn[c] / s
        # ∂h/∂n = -t/s + k ray, then through the tangent basis; ∂h/∂d = -1/s.
        g0 = -t0 / s + k * r0
        g1 = -t1 / s + k * r1
        g2 = -t2 / s + k * r2
        for b in range(2):
            gb = g0 * B_plane[p, 0, b] + g1 * B_plane[p, 1, b] + g2 * B_plane[p, 2, b]
            for i in range(3):
                J[p, i, 6 + b] = ray[i] * gb
        for i in range(3):
            J[p, i, 8] = -ray[i] / s


@numba.njit(cache=True, nogil=True)
def line_on_plane(n_backprojection, n_world, d_world, B_plane, R_world_anchor, t_world_anchor, m_out, v_out, J):
    """Co-planar line per landmark: Plücker m, v (L, 3) and J (L, 6, 9), rows (m, v), columns
    [anchor (δθ, δt) | plane (δn, δd)]. Formulas in :func:`backend.optim.factors.line_world_on_plane`."""
    dN = np.empty((3, 3))
    dv_dN = np.empty((3, 3))
    dm_dN = np.empty((3, 3))
    dv_dn = np.empty((3, 3))
    dm_dn = np.empty((3, 3))
    for p in range(n_backprojection.shape[0]):
        R = R_world_anchor[p]
        l0, l1, l2 = n_backprojection[p, 0], n_backprojection[p, 1], n_backprojection[p, 2]
        n0, n1, n2 = n_world[p, 0], n_world[p, 1], n_world[p, 2]
        t0, t1, t2 = t_world_anchor[p, 0], t_world_anchor[p, 1], t_world_anchor[p, 2]
        N0 = R[0, 0] * l0 + R[0, 1] * l1 + R[0, 2] * l2
        N1 = R[1, 0] * l0 + R[1, 1] * l1 + R[1, 2] * l2
        N2 = R[2, 0] * l0 + R[2, 1] * l1 + R[2, 2] * l2
        v0, v1, v2 = _cross3(N0, N1, N2, n0, n1, n2)
        q = n0 * t0 + n1 * t1 + n2 * t2 + d_world[p]
        c0, c1, c2 = _cross3(t0, t1, t2, v0, v1, v2)
        m_out[p, 0], m_out[p, 1], m_out[p, 2] = -q * N0 + c0, -q * N1 + c1, -q * N2 + c2
        v_out[p, 0], v_out[p, 1], v_out[p, 2] = v0, v1, v2
        for c in range(3):  # ∂N/∂δθ = -R [n_l]_×, column c = -R (n_l × e_c)
            e0, e1, e2 = 0.0, 0.0, 0.0
            if c == 0:
                e1, e2 = l2, -l1
            elif c == 1:
                e0, e2 = -l2, l0
            else:
                e0, e1 = l1, -l0
            for i in range(3):
                dN[i, c] = -(R[i, 0] * e0 + R[i, 1] * e1 + R[i, 2] * e2)
        # dv/dN = -[n]_×, dv/dn = [N]_×; dm/dN = -q I + [t]_× dv/dN; dm/dn = -N tᵀ + [t]_× [N]_×.
        hn = ((0.0, -n2, n1), (n2, 0.0, -n0), (-n1, n0, 0.0))
        hN = ((0.0, -N2, N1), (N2, 0.0, -N0), (-N1, N0, 0.0))
        ht = ((0.0, -t2, t1), (t2, 0.0, -t0), (-t1, t0, 0.0))
        NN = (N0, N1, N2)
        tt = (t0, t1, t2)
        for i in range(3):
            for j in range(3):
                dv_dN[i, j] = -hn[i][j]
                dv_dn[i, j] = hN[i][j]
        for i in range(3):
            for j in range(3):
                acc_N = 0.0
                acc_n = 0.0
                for k in range(3):
                    acc_N += ht[i][k] * dv_dN[k, j]
                    acc_n += ht[i][k] * hN[k][j]
                dm_dN[i, j] = acc_N - (q if i == j else 0.0)
                dm_dn[i, j] = acc_n - NN[i] * tt[j]
        nn = (n0, n1, n2)
        hv = ((0.0, -v2, v1), (v2, 0.0, -v0), (-v1, v0, 0.0))
        for i in range(3):
            for c in range(3):
                am = 0.0
                av = 0.0
                for k in range(3):
                    am += dm_dN[i, k] * dN[k, c]
                    av += dv_dN[i, k] * dN[k, c]
                J[p, i, c] = am
                J[p, 3 + i, c] = av
                J[p, i, 3 + c] = -NN[i] * nn[c] - hv[i][c]
                J[p, 3 + i, 3 + c] = 0.0
            for b in range(2):
                am = 0.0
                av = 0.0
                for k in range(3):
                    am += dm_dn[i, k] * B_plane[p, k, b]
                    av += dv_dn[i, k] * B_plane[p, k, b]
                J[p, i, 6 + b] = am
                J[p, 3 + i, 6 + b] = av
            J[p, i, 8] = -NN[i]
            J[p, 3 + i, 8] = 0.0


@numba.njit(cache=True, nogil=True)
def relative_pose(R_world_camera, t_world_camera, i_index, j_index, R_i_j, t_i_j, residual, J):
    """Odometry residual (M, 6) and Jacobian (M, 6, 12) w.r.t. [pose i | pose j]; formulas in
    :func:`backend.optim.factors.relative_pose_error`."""
    E = np.empty((3, 3))
    W = np.empty((3, 3))
    Jr = np.empty((3, 3))
    r = np.empty(3)
    for m in range(i_index.shape[0]):
        Ri = R_world_camera[i_index[m]]
        Rj = R_world_camera[j_index[m]]
        Rm = R_i_j[m]
        for a in range(3):  # W = R_iᵀ R_j, E = R_ijᵀ W
            for b in range(3):
                W[a, b] = Ri[0, a] * Rj[0, b] + Ri[1, a] * Rj[1, b] + Ri[2, a] * Rj[2, b]
        for a in range(3):
            for b in range(3):
                E[a, b] = Rm[0, a] * W[0, b] + Rm[1, a] * W[1, b] + Rm[2, a] * W[2, b]
        log_one(E, r)
        right_jacobian_inv_one(r, Jr)
        d0 = t_world_camera[j_index[m], 0] - t_world_camera[i_index[m], 0]
        d1 = t_world_camera[j_index[m], 1] - t_world_camera[i_index[m], 1]
        d2 = t_world_camera[j_index[m], 2] - t_world_camera[i_index[m], 2]
        p0 = Ri[0, 0] * d0 + Ri[1, 0] * d1 + Ri[2, 0] * d2  # R_iᵀ (t_j - t_i)
        p1 = Ri[0, 1] * d0 + Ri[1, 1] * d1 + Ri[2, 1] * d2
        p2 = Ri[0, 2] * d0 + Ri[1, 2] * d1 + Ri[2, 2] * d2
        residual[m, 0], residual[m, 1], residual[m, 2] = r[0], r[1], r[2]
        residual[m, 3] = p0 - t_i_j[m, 0]
        residual[m, 4] = p1 - t_i_j[m, 1]
        residual[m, 5] = p2 - t_i_j[m, 2]
        J[m, :, :] = 0.0
        for a in range(3):
            for b in range(3):
                J[m, a, 6 + b] = Jr[a, b]
                # -J_r⁻¹ R_jᵀ R_i = -J_r⁻¹ Wᵀ
                J[m, a, b] = -(Jr[a, 0] * W[b, 0] + Jr[a, 1] * W[b, 1] + Jr[a, 2] * W[b, 2])
                J[m, 3 + a, 3 + b] = -Ri[b, a]
                J[m, 3 + a, 9 + b] = Ri[b, a]
        # [R_iᵀ (t_j - t_i)]_×
        J[m, 3, 1], J[m, 3, 2] = -p2, p1
        J[m, 4, 0], J[m, 4, 2] = p2, -p0
        J[m, 5, 0], J[m, 5, 1] = -p1, p0


@numba.njit(cache=True, nogil=True)
def point_plane_relative(x_anchor, rho, R_world_anchor, t_world_anchor, n_world, d_world, B_plane, residual, J):
    """Scale-safe point-to-plane residual per (point, plane) pair: residual (K, 1) =
    `(n·X_w + d) / |n·t_a + d|` with `X_w = R_a x̂_a / ρ + t_a`, J (K, 1, 10) w.r.t.
    [anchor (δθ, δt) | ρ | plane (δn, δd)]. Formulas in
    :func:`backend.optim.factors.point_plane_relative`."""
    for k in range(x_anchor.shape[0]):
        R = R_world_anchor[k]
        x0, x1, x2 = x_anchor[k, 0], x_anchor[k, 1], x_anchor[k, 2]
        n0, n1, n2 = n_world[k, 0], n_world[k, 1], n_world[k, 2]
        t0, t1, t2 = t_world_anchor[k, 0], t_world_anchor[k, 1], t_world_anchor[k, 2]
        ir = 1.0 / rho[k]
        # The normal in the anchor frame, nc = R_aᵀ n, and the anchor-frame point p = x̂ / ρ.
        c0 = R[0, 0] * n0 + R[1, 0] * n1 + R[2, 0] * n2
        c1 = R[0, 1] * n0 + R[1, 1] * n1 + R[2, 1] * n2
        c2 = R[0, 2] * n0 + R[1, 2] * n1 + R[2, 2] * n2
        p0, p1, p2 = x0 * ir, x1 * ir, x2 * ir
        q = n0 * t0 + n1 * t1 + n2 * t2 + d_world[k]
        e = c0 * p0 + c1 * p1 + c2 * p2 + q  # n·X_w + d = n·R_a p + q
        sq = 1.0 if q >= 0.0 else -1.0
        iq = 1.0 / (sq * q)
        r = e * iq
        residual[k, 0] = r
        rs = r * sq  # dr = (de - r sign(q) dq) / |q|
        # ∂e/∂δθ = -nᵀ R_a [p]_× = (p × nc)ᵀ; q does not depend on the rotation.
        a0, a1, a2 = _cross3(p0, p1, p2, c0, c1, c2)
        J[k, 0, 0] = a0 * iq
        J[k, 0, 1] = a1 * iq
        J[k, 0, 2] = a2 * iq
        # ∂e/∂δt = ∂q/∂δt = nᵀ.
        f = (1.0 - rs) * iq
        J[k, 0, 3] = n0 * f
        J[k, 0, 4] = n1 * f
        J[k, 0, 5] = n2 * f
        # ∂e/∂ρ = -(nc·x̂) / ρ².
        J[k, 0, 6] = -(c0 * x0 + c1 * x1 + c2 * x2) * ir * ir * iq
        # Plane: ∂e/∂δn = X_wᵀ B, ∂q/∂δn = t_aᵀ B, ∂e/∂δd = ∂q/∂δd = 1.
        X0 = R[0, 0] * p0 + R[0, 1] * p1 + R[0, 2] * p2 + t0
        X1 = R[1, 0] * p0 + R[1, 1] * p1 + R[1, 2] * p2 + t1
        X2 = R[2, 0] * p0 + R[2, 1] * p1 + R[2, 2] * p2 + t2
        for b in range(2):
            B0, B1, B2 = B_plane[k, 0, b], B_plane[k, 1, b], B_plane[k, 2, b]
            J[k, 0, 7 + b] = ((X0 - rs * t0) * B0 + (X1 - rs * t1) * B1 + (X2 - rs * t2) * B2) * iq
        J[k, 0, 9] = f


@numba.njit(cache=True, nogil=True)
def line_plane_relative(m_world_l, v_world_l, J_mv_l, landmark, x_start, x_end, R_world_anchor, t_world_anchor, n_world, d_world, B_plane, residual, J):
    """Scale-safe line-to-plane residuals per (line, plane) pair: residual (K, 2) =
    `(n·P + d) / |n·t_a + d|` for P the points of line `landmark[k]` (world Plücker (m, v)
    (L, 3), J_mv_l (L, 6, D) the Jacobian of the stacked (m, v)) nearest to the anchor rays
    `t_a + λ R_a x̂` of the segment's start and end; J (K, 2, 6 + D + 3) w.r.t. [anchor
    (δθ, δt) | line | plane (δn, δd)]. Formulas in :func:`backend.optim.factors.line_plane_relative`."""
    D = J_mv_l.shape[2]
    g = np.empty(6)  # ∂(n·P)/∂(m, v)
    for k in range(landmark.shape[0]):
        lm = landmark[k]
        R = R_world_anchor[k]
        n0, n1, n2 = n_world[k, 0], n_world[k, 1], n_world[k, 2]
        t0, t1, t2 = t_world_anchor[k, 0], t_world_anchor[k, 1], t_world_anchor[k, 2]
        m0, m1, m2 = m_world_l[lm, 0], m_world_l[lm, 1], m_world_l[lm, 2]
        v0, v1, v2 = v_world_l[lm, 0], v_world_l[lm, 1], v_world_l[lm, 2]
        q = n0 * t0 + n1 * t1 + n2 * t2 + d_world[k]
        sq = 1.0 if q >= 0.0 else -1.0
        iq = 1.0 / (sq * q)
        a = v0 * v0 + v1 * v1 + v2 * v2
        ia = 1.0 / a
        vm0, vm1, vm2 = _cross3(v0, v1, v2, m0, m1, m2)
        P00, P01, P02 = vm0 * ia, vm1 * ia, vm2 * ia  # the line's point nearest the origin
        r00, r01, r02 = P00 - t0, P01 - t1, P02 - t2
        nv = n0 * v0 + n1 * v1 + n2 * v2
        dd = v0 * r00 + v1 * r01 + v2 * r02
        for s in range(2):
            if s == 0:
                x0, x1, x2 = x_start[k, 0], x_start[k, 1], x_start[k, 2]
            else:
                x0, x1, x2 = x_end[k, 0], x_end[k, 1], x_end[k, 2]
            w0 = R[0, 0] * x0 + R[0, 1] * x1 + R[0, 2] * x2  # ray direction R_a x̂
            w1 = R[1, 0] * x0 + R[1, 1] * x1 + R[1, 2] * x2
            w2 = R[2, 0] * x0 + R[2, 1] * x1 + R[2, 2] * x2
            b = v0 * w0 + v1 * w1 + v2 * w2
            cc = w0 * w0 + w1 * w1 + w2 * w2
            e = w0 * r00 + w1 * r01 + w2 * r02
            iD = 1.0 / (a * cc - b * b)
            mu = (b * e - cc * dd) * iD
            P0, P1, P2 = P00 + mu * v0, P01 + mu * v1, P02 + mu * v2
            r = (n0 * P0 + n1 * P1 + n2 * P2 + d_world[k]) * iq
            residual[k, s] = r
            rs = r * sq
            # ∂μ/∂r0, ∂μ/∂v, ∂μ/∂w (see factors.line_point_nearest_ray).
            u0, u1, u2 = (b * w0 - cc * v0) * iD, (b * w1 - cc * v1) * iD, (b * w2 - cc * v2) * iD
            f1 = 2.0 * mu * cc
            f2 = 2.0 * mu * b
            dv0 = (e * w0 - cc * r00 - f1 * v0 + f2 * w0) * iD
            dv1 = (e * w1 - cc * r01 - f1 * v1 + f2 * w1) * iD
            dv2 = (e * w2 - cc * r02 - f1 * v2 + f2 * w2) * iD
            h1 = 2.0 * mu * a
            dw0 = (e * v0 + b * r00 - 2.0 * dd * w0 - h1 * w0 + f2 * v0) * iD
            dw1 = (e * v1 + b * r01 - 2.0 * dd * w1 - h1 * w1 + f2 * v1) * iD
            dw2 = (e * v2 + b * r02 - 2.0 * dd * w2 - h1 * w2 + f2 * v2) * iD
            # y = nᵀ (I + v ∂μ/∂r0ᵀ): the gradient of n·P w.r.t. p0.
            y0, y1, y2 = n0 + nv * u0, n1 + nv * u1, n2 + nv * u2
            # ∂(n·P)/∂m = (y × v)ᵀ / |v|².
            gm0, gm1, gm2 = _cross3(y0, y1, y2, v0, v1, v2)
            g[0], g[1], g[2] = gm0 * ia, gm1 * ia, gm2 * ia
            # ∂(n·P)/∂v = -(y × m)/|v|² - 2 (y·(v × m)) v/|v|⁴ + μ n + (n·v) ∂μ/∂v.
            ym0, ym1, ym2 = _cross3(y0, y1, y2, m0, m1, m2)
            yv = 2.0 * (y0 * vm0 + y1 * vm1 + y2 * vm2) * ia * ia
            g[3] = -ym0 * ia - yv * v0 + mu * n0 + nv * dv0
            g[4] = -ym1 * ia - yv * v1 + mu * n1 + nv * dv1
            g[5] = -ym2 * ia - yv * v2 + mu * n2 + nv * dv2
            # Anchor rotation through w = R_a x̂: (x̂ × R_aᵀ g_w)ᵀ with g_w = (n·v) ∂μ/∂w.
            gw0, gw1, gw2 = nv * dw0, nv * dw1, nv * dw2
            h0 = R[0, 0] * gw0 + R[1, 0] * gw1 + R[2, 0] * gw2
            h1_ = R[0, 1] * gw0 + R[1, 1] * gw1 + R[2, 1] * gw2
            h2 = R[0, 2] * gw0 + R[1, 2] * gw1 + R[2, 2] * gw2
            a0, a1, a2 = _cross3(x0, x1, x2, h0, h1_, h2)
            J[k, s, 0] = a0 * iq
            J[k, s, 1] = a1 * iq
            J[k, s, 2] = a2 * iq
            # Anchor position: through the ray origin c = t_a, ∂(n·P)/∂c = -(n·v) ∂μ/∂r0,
            # and through q (∂q/∂δt = nᵀ).
            J[k, s, 3] = (-nv * u0 - rs * n0) * iq
            J[k, s, 4] = (-nv * u1 - rs * n1) * iq
            J[k, s, 5] = (-nv * u2 - rs * n2) * iq
            for c in range(D):
                acc = 0.0
                for j in range(6):
                    acc += g[j] * J_mv_l[lm, j, c]
                J[k, s, 6 + c] = acc * iq
            for bb in range(2):
                B0, B1, B2 = B_plane[k, 0, bb], B_plane[k, 1, bb], B_plane[k, 2, bb]
                J[k, s, 6 + D + bb] = ((P0 - rs * t0) * B0 + (P1 - rs * t1) * B1 + (P2 - rs * t2) * B2) * iq
            J[k, s, 6 + D + 2] = (1.0 - rs) * iq
