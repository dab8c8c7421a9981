"""The reduced camera | plane system of the Schur complement, formed and factored sparsely.

After the landmark variables are eliminated, the reduced matrix
`S = H_rr - Σ_l H_rl[:, l] H_ll⁻¹ H_rl[:, l]ᵀ` couples two cameras only where they see a
common landmark (or share an odometry factor): in a sequence that moves along, such as the
paper's circle of sequence a, S is a band (with a wrap-around where the path closes), and
only the few plane columns couple everything. Two things follow:

- each landmark's outer product touches only the rows of the cameras (and planes) that see
  it, so S is formed landmark by landmark over those rows (:func:`subtract_landmarks`)
  instead of by one dense product over all rows and all landmarks;
- the camera block, reordered by reverse Cuthill-McKee, is a band: it is factored by
  LAPACK's banded Cholesky and the plane columns are eliminated as a dense border
  (:func:`solve_bordered_band`). Where the band is not narrow enough to pay (every camera
  sees every landmark, as in sequence b or a short window), the caller uses dense Cholesky.
"""

from __future__ import annotations

import numba
import numpy as np
import scipy.linalg.lapack
import scipy.sparse
from scipy.sparse.csgraph import reverse_cuthill_mckee

# The band pays when its half-width is below this fraction of the camera block's size:
# banded Cholesky costs about n·kd² flops against n³/3 for the dense one, and LAPACK's band
# kernels run at a lower rate than the dense ones.
BAND_FRACTION = 0.45


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


@numba.njit(cache=True, nogil=True)
def _to_upper_band(S: np.ndarray, perm: np.ndarray, kd: int, abT: np.ndarray) -> None:
    """LAPACK upper band storage of `S' = S[perm][:, perm]`, transposed: `abT[j, kd + i - j]
    = S'[i, j]` (abT (n, kd + 1) in C order is LAPACK's column-major (kd + 1, n) array).
    S is symmetric, so S'[i, j] is read along row perm[j]."""
    n = perm.shape[0]
    for j in range(n):
        Sj = S[perm[j]]
        for i in range(max(0, j - kd), j + 1):
            abT[j, kd + i - j] = Sj[perm[i]]


def camera_band_order(S_cameras: np.ndarray) -> tuple[np.ndarray, int]:
    """Reverse Cuthill-McKee order of the camera block (6×6 blocks) of S and the half
    bandwidth (in scalar rows) it gives. Returns the scalar permutation and kd."""
    n = S_cameras.shape[0]
    nb = n // 6
    pattern = np.abs(S_cameras).reshape(nb, 6, nb, 6).sum(axis=(1, 3)) > 0
    order = reverse_cuthill_mckee(scipy.sparse.csr_matrix(pattern), symmetric_mode=True)
    perm = (6 * order[:, None] + np.arange(6)).ravel()
    position = np.empty(nb, np.int64)
    position[order] = np.arange(nb)
    i, j = np.nonzero(pattern)
    kd_blocks = int(np.max(np.abs(position[i] - position[j]), initial=0))
    return perm, 6 * kd_blocks + 5


def solve_bordered_band(S: np.ndarray, b: np.ndarray, n_cameras: int, perm: np.ndarray, kd: int) -> np.ndarray | None:
    """Solve `S x = b` for symmetric positive definite S whose first `n_cameras` rows form a
    band of half-width kd under the permutation `perm` and whose remaining rows (planes) are
    a dense border. Returns None when a factorization fails (not positive definite): the
    caller falls back to the dense path.

    With `S = [A B; Bᵀ C]`: A = UᵀU (banded Cholesky), X = A⁻¹B, the border's Schur
    complement `C - BᵀX` is factored densely, and the camera part is back-substituted."""
    nc = n_cameras
    abT = np.zeros((nc, kd + 1))
    _to_upper_band(S, perm.astype(np.int64), kd, abT)
    U, info = scipy.linalg.lapack.dpbtrf(abT.T, lower=0, overwrite_ab=1)
    if info != 0:
        return None
    B = S[perm, nc:]
    b_a = b[perm]
    rhs = np.concatenate([b_a[:, None], B], axis=1)
    sol, info = scipy.linalg.lapack.dpbtrs(U, rhs, lower=0)
    if info != 0:
        return None
    y_a, X = sol[:, 0], sol[:, 1:]
    x = np.empty_like(b)
    if S.shape[0] > nc:
        C = S[nc:, nc:] - B.T @ X
        c, info = scipy.linalg.lapack.dpotrf(C, lower=1, clean=1)
        if info != 0:
            return None
        x_c, info = scipy.linalg.lapack.dpotrs(c, b[nc:] - B.T @ y_a, lower=1)
        if info != 0:
            return None
        x[nc:] = x_c
        x_a = y_a - X @ x_c
    else:
        x_a = y_a
    x[perm] = x_a
    return x
