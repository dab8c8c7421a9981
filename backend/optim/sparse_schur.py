"""The reduced camera | plane system of the Schur complement, formed and factored sparsely.

After the landmark variables are eliminated, the reduced matrix
`S = H_rr - Σ_l H_rl[:, l] H_ll⁻¹ H_rl[:, l]ᵀ` couples two cameras only where they see a
common landmark (or share an odometry factor): in a sequence that moves along, such as the
paper's circle of sequence a, S is a band (with a wrap-around where the path closes), and
only the few plane columns couple everything. Two things follow:

- each landmark's outer product touches only the rows of the cameras (and planes) that see
  it, so S is formed landmark by landmark over those rows (:func:`subtract_landmarks`)
  instead of by one dense product over all rows and all landmarks;
- the camera block is reordered to a small envelope (profile) and factored by a blocked
  envelope Cholesky, with the plane columns as a dense border
  (:func:`envelope_plan`, :func:`solve_bordered_envelope`). The order is Cuthill-McKee
  (plain or reversed) from the start that gives the least profile: on sequence a's circle
  it folds the ring so that each camera row reaches back about twice the co-visibility
  width (≈ 45 blocks of 150), and a start away from the one long link keeps that link
  inside the envelope. The factorization is left-looking by panels of 48 columns on a
  permuted copy of the lower envelope: each panel's rows are updated by one matrix product
  per chunk of rows with the earlier columns their envelope reaches (a staircase, not the
  rectangle), its diagonal block is factored by LAPACK and the rows below are multiplied
  by the inverse of that block's factor (BLAS's triangular solve is several times slower
  at these sizes). About a quarter of dense Cholesky's flops on sequence a, for every
  variant. Where the envelope's estimated work is not well below dense Cholesky's (every
  camera sees every landmark, as in sequence b, or a short window), the caller uses dense
  Cholesky. The plan (order, panels, workspace) depends on the structure only and is
  computed once per problem.

(LAPACK's banded Cholesky after reverse Cuthill-McKee was tried first: its bandwidth is set
by the widest row, so on sequence a it paid only for P-wo-like patterns, and by less.)
"""

from __future__ import annotations

import dataclasses

import numba
import numpy as np
import scipy.linalg.lapack
import scipy.sparse


@numba.njit(cache=True, nogil=True)
def landmark_rows(H_rl: np.ndarray, n_points: int, n_lines: int) -> tuple[np.ndarray, np.ndarray]:
    """Rows of the reduced system that each landmark touches, as a CSR-like structure:
    landmark k (points first, one column each; then lines, four columns each) touches rows
    `rows[indptr[k]:indptr[k + 1]]` (ascending), those where a column of k in H_rl
    (r, n_points + 4 n_lines) is nonzero."""
    r = H_rl.shape[0]
    n = n_points + n_lines
    counts = np.zeros(n + 1, np.int64)
    for i in range(r):
        for k in range(n_points):
            if H_rl[i, k] != 0.0:
                counts[k + 1] += 1
        for k in range(n_lines):
            c = n_points + 4 * k
            if H_rl[i, c] != 0.0 or H_rl[i, c + 1] != 0.0 or H_rl[i, c + 2] != 0.0 or H_rl[i, c + 3] != 0.0:
                counts[n_points + k + 1] += 1
    indptr = np.cumsum(counts)
    rows = np.empty(indptr[n], np.int64)
    fill = indptr[:-1].copy()
    for i in range(r):
        for k in range(n_points):
            if H_rl[i, k] != 0.0:
                rows[fill[k]] = i
                fill[k] += 1
        for k in range(n_lines):
            c = n_points + 4 * k
            if H_rl[i, c] != 0.0 or H_rl[i, c + 1] != 0.0 or H_rl[i, c + 2] != 0.0 or H_rl[i, c + 3] != 0.0:
                rows[fill[n_points + k]] = i
                fill[n_points + k] += 1
    return indptr, rows


@numba.njit(cache=True, nogil=True)
def point_columns_times_inverse(H_rl: np.ndarray, d_inv: np.ndarray, indptr: np.ndarray, rows: np.ndarray, W: np.ndarray) -> None:
    """`W[:, point k] = H_rl[:, point k] d_inv[k]` (each point's column times the inverse of
    its 1×1 block) on the rows the point touches; W's other rows are left as they are."""
    for k in range(d_inv.shape[0]):
        for a in range(indptr[k], indptr[k + 1]):
            r = rows[a]
            W[r, k] = H_rl[r, k] * d_inv[k]


@numba.njit(cache=True, nogil=True)
def line_columns_times_inverse(H_rl: np.ndarray, inv: np.ndarray, indptr: np.ndarray, rows: np.ndarray, n_points: int, W: np.ndarray) -> None:
    """`W[:, line k] = H_rl[:, line k] inv[k]` (each line's four columns times the inverse
    of its 4×4 block) on the rows the line touches; W's other rows are left as they are."""
    for k in range(inv.shape[0]):
        c0 = n_points + 4 * k
        for a in range(indptr[n_points + k], indptr[n_points + k + 1]):
            r = rows[a]
            for j in range(4):
                v = 0.0
                for i in range(4):
                    v += H_rl[r, c0 + i] * inv[k, i, j]
                W[r, c0 + j] = v


# Above this fraction of rows touched per landmark, one dense product (BLAS) beats the
# landmark-by-landmark update (sequence b: every camera sees every landmark).
DENSE_FRACTION = 0.3


@numba.njit(cache=True, nogil=True, fastmath=True)
def _subtract_landmarks_upper(S: np.ndarray, H_rl: np.ndarray, W: np.ndarray, indptr: np.ndarray, rows: np.ndarray, n_points: int, n_lines: int) -> None:
    w = np.empty((rows.shape[0] if rows.shape[0] else 1, 4))
    for k in range(n_points + n_lines):
        if k < n_points:
            c0 = k
            dim = 1
        else:
            c0 = n_points + 4 * (k - n_points)
            dim = 4
        lo = indptr[k]
        hi = indptr[k + 1]
        for a in range(lo, hi):  # gather the landmark's rows of H_rl once
            for c in range(dim):
                w[a - lo, c] = H_rl[rows[a], c0 + c]
        for a in range(lo, hi):
            ra = rows[a]
            Sa = S[ra]
            if dim == 1:
                wa = W[ra, c0]
                for b in range(a, hi):
                    Sa[rows[b]] -= wa * w[b - lo, 0]
            else:
                w0 = W[ra, c0]
                w1 = W[ra, c0 + 1]
                w2 = W[ra, c0 + 2]
                w3 = W[ra, c0 + 3]
                for b in range(a, hi):
                    j = b - lo
                    Sa[rows[b]] -= w0 * w[j, 0] + w1 * w[j, 1] + w2 * w[j, 2] + w3 * w[j, 3]


@numba.njit(cache=True, nogil=True)
def _mirror_upper(S: np.ndarray) -> None:
    n = S.shape[0]
    for i in range(n):
        for j in range(i + 1, n):
            S[j, i] = S[i, j]


def subtract_landmarks(S: np.ndarray, H_rl: np.ndarray, W: np.ndarray, indptr: np.ndarray, rows: np.ndarray, n_points: int, n_lines: int) -> None:
    """`S -= Σ_k W[:, cols_k] H_rl[:, cols_k]ᵀ = W H_rlᵀ`, in place (both triangles).

    `W = H_rl H_ll⁻¹` blockwise (its columns are zero for a landmark left out of the step).
    Where each landmark touches few rows of S (`rows[indptr[k]:indptr[k + 1]]`, from
    :func:`landmark_rows`), the product is accumulated landmark by landmark over those rows
    (upper triangle, then mirrored: the product is symmetric); where they touch most rows,
    by one dense product."""
    n_landmarks = n_points + n_lines
    if n_landmarks == 0:
        return
    if len(rows) > DENSE_FRACTION * S.shape[0] * n_landmarks:
        S -= W @ H_rl.T
        return
    _subtract_landmarks_upper(S, H_rl, W, indptr, rows, n_points, n_lines)
    _mirror_upper(S)


# ---------------------------------------------------------------------------------------------
# Envelope (profile) Cholesky of the camera block, planes as a dense border.

# Scalar columns per panel of the blocked envelope Cholesky (a multiple of the 6×6 blocks).
ENVELOPE_PANEL = 48

# The envelope pays when its estimated cost (flops plus a per-panel overhead, see
# :func:`envelope_pays`) is below this fraction of dense Cholesky's n³/3: its panels run
# at a lower rate than one dense LAPACK call.
ENVELOPE_FRACTION = 0.6
PANEL_OVERHEAD_FLOPS = 1.5e6

# Start nodes tried by the envelope ordering (:func:`_best_envelope_order`).
ENVELOPE_STARTS = 32


@numba.njit(cache=True, nogil=True)
def _cuthill_mckee(indptr: np.ndarray, indices: np.ndarray, degree: np.ndarray, start: int) -> np.ndarray:
    """Cuthill-McKee order of a graph (CSR adjacency) from `start`: breadth first, each
    node's unvisited neighbours by ascending degree; a disconnected rest restarts from its
    node of least degree."""
    n = degree.shape[0]
    order = np.empty(n, np.int64)
    seen = np.zeros(n, np.bool_)
    head = 0
    tail = 0
    nxt = start
    while tail < n:
        if head == tail:  # next component
            if seen[nxt]:
                best = -1
                for v in range(n):
                    if not seen[v] and (best < 0 or degree[v] < degree[best]):
                        best = v
                nxt = best
            seen[nxt] = True
            order[tail] = nxt
            tail += 1
        u = order[head]
        head += 1
        first = tail
        for a in range(indptr[u], indptr[u + 1]):
            v = indices[a]
            if not seen[v]:
                seen[v] = True
                order[tail] = v
                tail += 1
        # insertion sort of the new level part by degree (stable: few nodes)
        for i in range(first + 1, tail):
            v = order[i]
            j = i - 1
            while j >= first and degree[order[j]] > degree[v]:
                order[j + 1] = order[j]
                j -= 1
            order[j + 1] = v
    return order


@numba.njit(cache=True, nogil=True)
def _row_starts(indptr: np.ndarray, indices: np.ndarray, order: np.ndarray) -> np.ndarray:
    """First block column (under `order`) of each block row's envelope, in the new order."""
    n = order.shape[0]
    position = np.empty(n, np.int64)
    for i in range(n):
        position[order[i]] = i
    first = np.empty(n, np.int64)
    for i in range(n):
        u = order[i]
        f = i
        for a in range(indptr[u], indptr[u + 1]):
            p = position[indices[a]]
            if p < f:
                f = p
        first[i] = f
    return first


@numba.njit(cache=True, nogil=True)
def _envelope_cost(indptr: np.ndarray, indices: np.ndarray, order: np.ndarray) -> float:
    """Σ_i (i − f_i + 1)² over the block rows i of the graph under `order`, f_i the row's
    first neighbour (its envelope's start): proportional to the flops of a Cholesky that
    works inside the envelope (it fills completely)."""
    first = _row_starts(indptr, indices, order)
    cost = 0.0
    for i in range(order.shape[0]):
        cost += float(i - first[i] + 1) ** 2
    return cost


@numba.njit(cache=True, nogil=True)
def _best_envelope_order(indptr: np.ndarray, indices: np.ndarray, degree: np.ndarray, max_starts: int) -> np.ndarray:
    """The Cuthill-McKee order, plain or reversed, from the start node that gives the least
    :func:`_envelope_cost`, trying up to `max_starts` start nodes spread evenly over the
    node numbers (the cameras' own order follows the path, so these spread along it). On a
    cyclic band with a long link the best start lies where the ring folds without the link
    stretching the envelope."""
    n = degree.shape[0]
    best = np.arange(n)
    best_cost = _envelope_cost(indptr, indices, best)
    step = max(1, (n + max_starts - 1) // max_starts)
    for s in range(0, n, step):
        order = _cuthill_mckee(indptr, indices, degree, s)
        c = _envelope_cost(indptr, indices, order)
        if c < best_cost:
            best_cost = c
            best = order
        reverse = order[::-1].copy()
        c = _envelope_cost(indptr, indices, reverse)
        if c < best_cost:
            best_cost = c
            best = reverse
    return best


@dataclasses.dataclass(frozen=True)
class EnvelopePlan:
    """The structure of an envelope Cholesky of the camera block (computed once per
    problem). `perm` (n_cameras,): scalar permutation of the camera rows; `first`
    (n_cameras,): first column of each permuted row's envelope; `fill` (n_cameras,): first
    column from which each row is copied (and read) by the panels; `panels`: for each panel
    of columns `c0:c1`, `(c0, c1, r1, j0, updates)`: the rows `c1:r1` below it inside the
    envelope, the first column `j0` of its own rows' envelopes and the products that update
    it, `(a0, a1, j)`: rows `a0:a1` need the earlier columns `j:c0`; `flops`: the estimated
    factorization flops (with the border); `work` (n_cameras, n_cameras): the workspace
    the factor is formed in, kept between calls (a fresh one of this size costs its page
    faults on every call), so one plan serves one solve at a time."""

    perm: np.ndarray
    first: np.ndarray
    fill: np.ndarray
    panels: tuple[tuple[int, int, int, int, tuple[tuple[int, int, int], ...]], ...]
    flops: float
    work: np.ndarray


def envelope_plan(S_cameras: np.ndarray, n_border: int, panel: int = ENVELOPE_PANEL) -> EnvelopePlan:
    """Plan an envelope Cholesky of the camera block (6×6 blocks) of S with `n_border` dense
    border rows (planes): the block order of least envelope (:func:`_best_envelope_order`),
    the row envelopes, the panels of `panel` scalar columns and, for each, the staircase of
    products over row chunks (a chunk of rows needs only the columns from where its own
    envelope, or the panel's, starts; consecutive chunks with the same start are merged)."""
    n = S_cameras.shape[0]
    nb = n // 6
    pattern = np.abs(S_cameras).reshape(nb, 6, nb, 6).sum(axis=(1, 3)) > 0
    np.fill_diagonal(pattern, False)
    graph = scipy.sparse.csr_matrix(pattern)
    indptr = graph.indptr.astype(np.int64)
    indices = graph.indices.astype(np.int64)
    degree = np.diff(indptr)
    order = _best_envelope_order(indptr, indices, degree, ENVELOPE_STARTS)
    first = 6 * np.repeat(_row_starts(indptr, indices, order), 6)
    perm = (6 * order[:, None] + np.arange(6)).ravel()
    width = max(6, panel - panel % 6)
    starts = list(range(0, n, width))
    ends = [min(c + width, n) for c in starts]
    chunk_start = [int(first[c0:c1].min()) for c0, c1 in zip(starts, ends)]
    fill = np.arange(n)
    panels = []
    flops = 0.0
    for k, (c0, c1) in enumerate(zip(starts, ends)):
        reaching = np.flatnonzero(first < c1)
        r1 = max(int(reaching.max(initial=c1 - 1)) + 1, c1)
        j0 = chunk_start[k]
        fill[c0:r1] = np.minimum(fill[c0:r1], c0)
        updates: list[list[int]] = []
        for i in range(k, len(starts)):
            a0, a1 = starts[i], min(ends[i], r1)
            if a0 >= r1:
                break
            j = max(j0, chunk_start[i])
            if j >= c0:
                continue
            if updates and updates[-1][1] == a0 and updates[-1][2] == j:
                updates[-1][1] = a1
            else:
                updates.append([a0, a1, j])
            fill[a0:a1] = np.minimum(fill[a0:a1], j)
            flops += 2.0 * (a1 - a0) * (c0 - j) * (c1 - c0)
        w = c1 - c0
        panels.append((c0, c1, r1, j0, tuple((int(u[0]), int(u[1]), int(u[2])) for u in updates)))
        flops += 2.0 * n_border * (c0 - j0) * w + w**3 / 3 + (r1 - c1 + n_border) * w * w
    flops += 2.0 * n_border * n_border * n + n_border**3 / 3
    return EnvelopePlan(perm, first, fill, tuple(panels), flops, np.zeros((n, n)))


def envelope_pays(plan: EnvelopePlan, n: int) -> bool:
    """Whether the envelope factorization is estimated cheaper than dense Cholesky of the
    whole (n × n) reduced system: its flops plus a fixed overhead per panel (Python and
    LAPACK call costs) against a fraction of n³/3."""
    return plan.flops + PANEL_OVERHEAD_FLOPS * len(plan.panels) < ENVELOPE_FRACTION * n**3 / 3


@numba.njit(cache=True, nogil=True)
def _gather_envelope(S: np.ndarray, perm: np.ndarray, fill: np.ndarray, M: np.ndarray) -> None:
    """`M[i, fill[i]:i + 1] = S'[i, fill[i]:i + 1]` with `S' = S[perm][:, perm]` (the lower
    envelope of the permuted camera block), copied by 6×6 blocks (perm permutes blocks of
    six and `fill` starts on a block) along rows of S."""
    for bi in range(perm.shape[0] // 6):
        i0 = 6 * bi
        s0 = perm[i0]
        for bj in range(fill[i0] // 6, bi + 1):
            j0 = 6 * bj
            t0 = perm[j0]
            for r in range(6):
                Sr = S[s0 + r]
                Mr = M[i0 + r]
                for c in range(6):
                    Mr[j0 + c] = Sr[t0 + c]


@numba.njit(cache=True, nogil=True)
def _envelope_substitute(M: np.ndarray, first: np.ndarray, Lb: np.ndarray, Lc: np.ndarray, y: np.ndarray, yb: np.ndarray) -> None:
    """Solve `L Lᵀ x = y` in place for `L = [M 0; Lb Lc]` (M lower, zero left of each row's
    `first` column; Lb dense border rows, Lc lower): `y` (camera part) and `yb` (border
    part) are overwritten by x."""
    n = y.shape[0]
    nbord = yb.shape[0]
    for i in range(n):  # forward, cameras
        s = y[i]
        Mi = M[i]
        for j in range(first[i], i):
            s -= Mi[j] * y[j]
        y[i] = s / Mi[i]
    for i in range(nbord):  # forward, border
        s = yb[i]
        for j in range(n):
            s -= Lb[i, j] * y[j]
        for j in range(i):
            s -= Lc[i, j] * yb[j]
        yb[i] = s / Lc[i, i]
    for i in range(nbord - 1, -1, -1):  # backward, border
        v = yb[i] / Lc[i, i]
        yb[i] = v
        for j in range(i):
            yb[j] -= Lc[i, j] * v
        for j in range(n):
            y[j] -= Lb[i, j] * v
    for i in range(n - 1, -1, -1):  # backward, cameras
        Mi = M[i]
        v = y[i] / Mi[i]
        y[i] = v
        for j in range(first[i], i):
            y[j] -= Mi[j] * v


def solve_bordered_envelope(S: np.ndarray, b: np.ndarray, n_cameras: int, plan: EnvelopePlan) -> np.ndarray | None:
    """Solve `S x = b` for symmetric positive definite S whose first `n_cameras` rows have,
    under `plan.perm`, the envelope of `plan` and whose remaining rows (planes) are a dense
    border. Returns None when a factorization fails (not positive definite): the caller
    falls back to the dense path.

    Left-looking blocked Cholesky `S' = L Lᵀ` on a permuted copy of the envelope: for each
    panel of columns `c0:c1`, its rows inside the envelope (`c0:r1`) and the border rows are
    updated by one product with the panel's earlier envelope columns `j0:c0`, its diagonal
    block is factored (LAPACK dpotrf) and the rows below it are multiplied by the inverse
    of that factor (LAPACK dtrtri, then one product); the border's own block is factored last, and the system is solved by
    substitution over the envelope."""
    nc = n_cameras
    perm = plan.perm
    M = plan.work
    _gather_envelope(S, perm, plan.fill, M)
    Lb = S[nc:, perm]  # border rows (C order)
    dpotrf = scipy.linalg.lapack.dpotrf
    dtrtri = scipy.linalg.lapack.dtrtri
    for c0, c1, r1, j0, updates in plan.panels:
        w = c1 - c0
        T = M[c0:r1, c0:c1]
        Tb = Lb[:, c0:c1]
        if c0 > j0:
            Lt = M[c0:c1, j0:c0].T
            for a0, a1, j in updates:
                M[a0:a1, c0:c1] -= M[a0:a1, j:c0] @ Lt[j - j0 :]
            Tb -= Lb[:, j0:c0] @ Lt
        L, info = dpotrf(T[:w], lower=1, clean=1)
        if info != 0:
            return None
        M[c0:c1, c0:c1] = L
        L_inv, info = dtrtri(L, lower=1)
        if info != 0:
            return None
        # the rows below times L⁻ᵀ: one product (BLAS dtrsm is several times slower here)
        if r1 > c1:
            T[w:] = T[w:] @ L_inv.T
        Tb[:] = Tb @ L_inv.T
    y = b[perm]
    yb = b[nc:].copy()
    if S.shape[0] > nc:
        Lc, info = dpotrf(S[nc:, nc:] - Lb @ Lb.T, lower=1, clean=1)
        if info != 0:
            return None
    else:
        Lc = np.zeros((0, 0))
    _envelope_substitute(M, plan.first, Lb, Lc, y, yb)
    x = np.empty_like(b)
    x[perm] = y
    x[nc:] = yb
    return x
