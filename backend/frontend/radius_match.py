"""Descriptor matching gated by image distance: each query (a map point's projection)
against the keypoints within a radius of it, in one compiled pass.

The keypoints are bucketed on a grid of `radius`-sized cells, so a query looks at the 3×3
(or so) cells around it instead of building two k-d trees and a sparse distance matrix
per frame; the Hamming distance of each candidate is computed in place (64-bit popcount)
and only the closest two per query are kept. The ratio test and the one-to-one check are
:func:`backend.frontend.points.best_matches`'s, whose result does not depend on the order
in which candidates are seen, so this gives the same matches as listing every pair within
the radius and calling it.
"""

from __future__ import annotations

import numba
import numpy as np

from backend.frontend.points import keep_closest, resolve_matches

_M1 = np.uint64(0x5555555555555555)
_M2 = np.uint64(0x3333333333333333)
_M4 = np.uint64(0x0F0F0F0F0F0F0F0F)
_H01 = np.uint64(0x0101010101010101)


def match_in_radius(
    query_uv: np.ndarray,
    query_descriptors: np.ndarray,
    keypoints_uv: np.ndarray,
    keypoint_descriptors: np.ndarray,
    *,
    radius_px: float,
    max_hamming: int,
    ratio: float,
) -> np.ndarray:
    """Keypoint index (Q,) matched to each query (-1: none). Queries at `query_uv` (Q, 2)
    px with binary descriptors (Q, B) uint8, keypoints at `keypoints_uv` (N, 2) px with
    (N, B) uint8, B a multiple of 8. A query's candidates are the keypoints at Euclidean
    image distance `<= radius_px`; the closest by Hamming distance wins if it is
    `<= max_hamming` and `< ratio` times the second closest, and a keypoint keeps only its
    closest query (ties: the lower query index)."""
    n_query, n_keypoints = len(query_uv), len(keypoints_uv)
    if n_query == 0 or n_keypoints == 0:
        return np.full(n_query, -1, np.int64)
    a = np.ascontiguousarray(query_descriptors, np.uint8).view(np.uint64)
    b = np.ascontiguousarray(keypoint_descriptors, np.uint8).view(np.uint64)
    if a.shape[1] != b.shape[1]:
        raise ValueError(f"descriptor lengths differ: {query_descriptors.shape[1]} and {keypoint_descriptors.shape[1]} bytes")
    q = np.ascontiguousarray(query_uv, np.float64)
    k = np.ascontiguousarray(keypoints_uv, np.float64)
    return _match_kernel(q, a, k, b, float(radius_px), float(max_hamming), float(ratio))


@numba.njit(cache=True, nogil=True, inline="always")
def _popcount(x):  # pragma: no cover - compiled
    x = x - ((x >> np.uint64(1)) & _M1)
    x = (x & _M2) + ((x >> np.uint64(2)) & _M2)
    x = (x + (x >> np.uint64(4))) & _M4
    return (x * _H01) >> np.uint64(56)


@numba.njit(cache=True, nogil=True)
def _match_kernel(query_uv, query_words, kp_uv, kp_words, radius, max_distance, ratio):  # pragma: no cover - compiled
    n_query = query_uv.shape[0]
    n_kp = kp_uv.shape[0]
    n_words = kp_words.shape[1]
    # Bucket the keypoints: cell (cx, cy) of side `radius` from the keypoints' lower bound.
    cell = max(radius, 1e-9)
    u0 = kp_uv[:, 0].min()
    v0 = kp_uv[:, 1].min()
    nx = int((kp_uv[:, 0].max() - u0) / cell) + 1
    ny = int((kp_uv[:, 1].max() - v0) / cell) + 1
    cell_of = np.empty(n_kp, np.int64)
    for j in range(n_kp):
        cell_of[j] = int((kp_uv[j, 1] - v0) / cell) * nx + int((kp_uv[j, 0] - u0) / cell)
    order = np.argsort(cell_of, kind="mergesort")
    start = np.zeros(nx * ny + 1, np.int64)
    for j in range(n_kp):
        start[cell_of[j] + 1] += 1
    for c in range(nx * ny):
        start[c + 1] += start[c]

    best = np.full(n_query, np.inf)
    second = np.full(n_query, np.inf)
    best_col = np.full(n_query, -1, np.int64)
    finite = np.zeros(n_query, np.int64)
    has_nan = np.zeros(n_query, np.bool_)
    r2 = radius * radius
    for i in range(n_query):
        u = query_uv[i, 0]
        v = query_uv[i, 1]
        x_lo = max(int(np.floor((u - radius - u0) / cell)), 0)
        x_hi = min(int(np.floor((u + radius - u0) / cell)), nx - 1)
        y_lo = max(int(np.floor((v - radius - v0) / cell)), 0)
        y_hi = min(int(np.floor((v + radius - v0) / cell)), ny - 1)
        for cy in range(y_lo, y_hi + 1):
            for cx in range(x_lo, x_hi + 1):
                c = cy * nx + cx
                for s in range(start[c], start[c + 1]):
                    j = order[s]
                    du = u - kp_uv[j, 0]
                    dv = v - kp_uv[j, 1]
                    if du * du + dv * dv > r2:
                        continue
                    d = 0
                    for w in range(n_words):
                        d += int(_popcount(query_words[i, w] ^ kp_words[j, w]))
                    finite[i] += 1
                    keep_closest(i, float(d), j, best, second, best_col)
    return resolve_matches(best, second, best_col, finite, has_nan, n_kp, max_distance, ratio)
