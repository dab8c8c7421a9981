"""ORB points spread over the image and matched between rectified left and right images.

Detection keeps the strongest ORB keypoints per cell of a grid (a per-cell budget), so
features cover the whole image instead of piling up on the most textured region. Stereo
matching searches the right keypoints on the same row (`|Δv|` small, the images are
rectified) within a disparity range, by Hamming distance with a ratio test and a one-to-one
check, then refines the disparity to sub-pixel by SAD block matching along the row with a
parabola fit (as ORB-SLAM does). Depth `z = fx·b / disparity`; the 3D point is `x̂·z` in the
left rectified camera frame, metres.
"""

from __future__ import annotations

import dataclasses

import cv2
import numba
import numpy as np

from backend.common.workers import per_thread
from backend.geometry.camera import PinholeCamera


@dataclasses.dataclass(frozen=True)
class PointSettings:
    """ORB detection on a `grid_cols`×`grid_rows` grid keeping at most `n_features` points
    (an equal budget per cell; FAST threshold `fast_threshold` in grey levels, `n_levels`
    pyramid levels of ratio `scale_factor`; ORB is asked for `oversample` times as many
    before the grid selection). A bare image, fewer than `sparse_below` keypoints at that
    threshold, is searched again at `sparse_fast_threshold` (as ORB-SLAM's lower FAST
    threshold where a cell finds none: the corners of faint marks on a plain wall; a
    textured image never reaches it, so its keypoints do not change); stereo matches need `|v_l - v_r| <= max_row_diff_px`,
    disparity `u_l - u_r` in [`min_disparity_px`, `max_disparity_px`], Hamming distance
    `<= max_hamming` (of 256 bits) and best / second best distance `< ratio`; the disparity is
    refined by SAD over a `block_px`-wide square in ±`refine_radius_px` pixels."""

    n_features: int = 1000
    oversample: float = 1.5
    grid_cols: int = 8
    grid_rows: int = 6
    fast_threshold: int = 10
    sparse_below: int = 150
    sparse_fast_threshold: int = 5
    n_levels: int = 4
    scale_factor: float = 1.2
    max_row_diff_px: float = 1.5
    min_disparity_px: float = 0.5
    max_disparity_px: float = 150.0
    max_hamming: int = 60
    ratio: float = 0.85
    block_px: int = 11
    refine_radius_px: int = 2


@dataclasses.dataclass(frozen=True, eq=False)
class StereoPoints:
    """Left keypoints of one rectified stereo frame and their stereo matches.

    `uv_left` (N, 2) pixels; `descriptors` (N, 32) uint8 ORB; `octave` (N,) pyramid level;
    `u_right` (N,) right-image column of the match, NaN where unmatched; `p_cam` (N, 3)
    triangulated points in the left rectified camera frame (metres), NaN where unmatched.
    """

    uv_left: np.ndarray
    descriptors: np.ndarray
    octave: np.ndarray
    u_right: np.ndarray
    p_cam: np.ndarray

    @property
    def matched(self) -> np.ndarray:
        """(N,) bool: the keypoint has a stereo match and a 3D point."""
        return np.isfinite(self.u_right)

    def __len__(self) -> int:
        return int(self.uv_left.shape[0])


@dataclasses.dataclass(frozen=True, eq=False)
class Keypoints:
    """Keypoints of one image: `uv` (N, 2) pixels, `descriptors` (N, 32) uint8, `octave` (N,)."""

    uv: np.ndarray
    descriptors: np.ndarray
    octave: np.ndarray


def _orb(*, n_features: int, fast_threshold: int, scale_factor: float, n_levels: int) -> cv2.ORB:
    """The detector for these settings, one per thread (the next frames are detected on a
    worker while the keyframe's right image is detected on the pipeline's thread)."""

    def make() -> cv2.ORB:
        return cv2.ORB_create(nfeatures=n_features, scaleFactor=scale_factor, nlevels=n_levels, fastThreshold=fast_threshold, edgeThreshold=19, patchSize=31)  # type: ignore[attr-defined]  # not in OpenCV's stubs

    return per_thread(("orb", n_features, fast_threshold, scale_factor, n_levels), make)


def detect_points(image: np.ndarray, *, settings: PointSettings = PointSettings()) -> Keypoints:
    """ORB keypoints of a uint8 grey image (H, W), at most `settings.n_features`, spread over
    a grid: each cell keeps its strongest keypoints up to an equal share of the budget, and
    the budget left by sparse cells goes to the strongest remaining keypoints anywhere."""
    s = settings
    orb = _orb(n_features=int(s.oversample * s.n_features), fast_threshold=s.fast_threshold, scale_factor=s.scale_factor, n_levels=s.n_levels)
    kps, desc = orb.detectAndCompute(image, None)
    if len(kps) < s.sparse_below and s.sparse_fast_threshold < s.fast_threshold:
        orb = _orb(n_features=int(s.oversample * s.n_features), fast_threshold=s.sparse_fast_threshold, scale_factor=s.scale_factor, n_levels=s.n_levels)
        kps, desc = orb.detectAndCompute(image, None)
    if desc is None or len(kps) == 0:
        return Keypoints(uv=np.zeros((0, 2)), descriptors=np.zeros((0, 32), np.uint8), octave=np.zeros(0, np.int32))
    uv = cv2.KeyPoint_convert(kps).astype(float)  # type: ignore[attr-defined]  # not in OpenCV's stubs; float32 positions, as kp.pt holds them
    response = np.fromiter((kp.response for kp in kps), dtype=float, count=len(kps))
    octave = np.fromiter((kp.octave for kp in kps), dtype=np.int32, count=len(kps))
    h, w = image.shape[:2]
    cell = np.minimum((uv[:, 1] * s.grid_rows / h).astype(int), s.grid_rows - 1) * s.grid_cols + np.minimum((uv[:, 0] * s.grid_cols / w).astype(int), s.grid_cols - 1)
    order = np.lexsort((-response, cell))  # by cell, strongest first
    sorted_cell = cell[order]
    rank = np.arange(order.size) - np.searchsorted(sorted_cell, sorted_cell, side="left")
    per_cell = max(1, s.n_features // (s.grid_cols * s.grid_rows))
    keep = np.zeros(order.size, bool)
    keep[order[rank < per_cell]] = True
    spare = s.n_features - int(keep.sum())
    if spare > 0:
        rest = np.flatnonzero(~keep)
        keep[rest[np.argsort(-response[rest])[:spare]]] = True
    idx = np.flatnonzero(keep)
    return Keypoints(uv=uv[idx], descriptors=desc[idx], octave=octave[idx])


def pair_hamming(desc_a: np.ndarray, desc_b: np.ndarray) -> np.ndarray:
    """Hamming distances (P,) between paired binary descriptors (P, B) uint8, B a multiple of 8."""
    a = np.ascontiguousarray(desc_a).view(np.uint64)
    b = np.ascontiguousarray(desc_b).view(np.uint64)
    return np.bitwise_count(a ^ b).sum(axis=-1, dtype=np.int32)


def hamming_distances(desc_a: np.ndarray, desc_b: np.ndarray) -> np.ndarray:
    """All Hamming distances (Na, Nb) between binary descriptors (Na, B), (Nb, B) uint8."""
    return pair_hamming(desc_a[:, None, :], desc_b[None, :, :]) if len(desc_a) and len(desc_b) else np.zeros((len(desc_a), len(desc_b)), np.int32)


def nearest_hamming(desc_a: np.ndarray, desc_b: np.ndarray, *, k: int = 2) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The `k` nearest descriptors of `desc_b` (Nb, B) for each of `desc_a` (Na, B) uint8
    by Hamming distance (OpenCV's brute-force search, `cv2.batchDistance`: the same distances as
    :func:`hamming_distances`, about ten times faster for a map against a frame).
    Returns candidate pairs `(rows, cols, dist)` (P,) each, nearest first within a row."""
    if len(desc_a) == 0 or len(desc_b) == 0:
        return np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros(0, np.int32)
    k_found = min(k, len(desc_b))
    # cv2.batchDistance is what the brute-force matcher's knnMatch runs, returning arrays
    # instead of one DMatch object per pair (whose conversion cost a third of the search).
    dist, index = cv2.batchDistance(np.ascontiguousarray(desc_a, np.uint8), np.ascontiguousarray(desc_b, np.uint8), cv2.CV_32S, normType=cv2.NORM_HAMMING, K=k_found)
    rows = np.repeat(np.arange(len(desc_a), dtype=np.int64), k_found)
    return rows, index.reshape(-1).astype(np.int64), dist.reshape(-1).astype(np.int32)


def best_matches(rows: np.ndarray, cols: np.ndarray, dist: np.ndarray, *, n_rows: int, max_distance: float, ratio: float) -> np.ndarray:
    """Match of each row (index of its column, -1: none) among candidate pairs (`rows`,
    `cols`) (P,) with distances `dist` (P,): the closest column if its distance is `<=
    max_distance` and `< ratio` times the row's second closest candidate (ties: the pair
    given first is the closest, and the second closest is as close); then one-to-one (a
    column keeps only its closest row; ties: the lower row). One compiled pass over the
    pairs (`_best_matches_kernel`), as the candidates of a frame against the local map run
    to tens of thousands."""
    if rows.size == 0:
        return np.full(n_rows, -1, dtype=np.int64)
    rows_i = np.ascontiguousarray(rows, dtype=np.int64)
    cols_i = np.ascontiguousarray(cols, dtype=np.int64)
    d = np.ascontiguousarray(dist, dtype=np.float64)
    return _best_matches_kernel(rows_i, cols_i, d, n_rows, int(cols_i.max()) + 1, float(max_distance), float(ratio))


@numba.njit(cache=True, nogil=True)
def _best_matches_kernel(rows, cols, dist, n_rows, n_cols, max_distance, ratio):  # pragma: no cover - compiled
    best = np.full(n_rows, np.inf)
    second = np.full(n_rows, np.inf)
    best_col = np.full(n_rows, -1, np.int64)
    finite = np.zeros(n_rows, np.int64)
    has_nan = np.zeros(n_rows, np.bool_)
    for p in range(rows.size):
        r = rows[p]
        d = dist[p]
        if d != d:  # NaN: sorted after every distance
            has_nan[r] = True
            continue
        finite[r] += 1
        keep_closest(r, d, cols[p], best, second, best_col)
    return resolve_matches(best, second, best_col, finite, has_nan, n_cols, max_distance, ratio)


@numba.njit(cache=True, nogil=True, inline="always")
def keep_closest(r, d, col, best, second, best_col):  # pragma: no cover - compiled
    """Row r's candidate `col` at distance d: kept as its closest (the first seen of equal
    ones) or its second closest distance."""
    if d < best[r] or best_col[r] < 0:
        second[r] = best[r]
        best[r] = d
        best_col[r] = col
    elif d < second[r]:
        second[r] = d


@numba.njit(cache=True, nogil=True)
def resolve_matches(best, second, best_col, finite, has_nan, n_cols, max_distance, ratio):  # pragma: no cover - compiled
    """The ratio test and the one-to-one check of :func:`best_matches` from each row's
    closest distance `best`, second closest `second`, closest column `best_col`, number of
    finite candidates `finite` and whether it had a NaN one `has_nan` (all (n_rows,))."""
    n_rows = best.size
    col_row = np.full(n_cols, -1, np.int64)
    for r in range(n_rows):
        if finite[r] == 0 or (finite[r] == 1 and has_nan[r]):  # no candidate, or a NaN second: the ratio test fails
            continue
        if not (best[r] <= max_distance and best[r] < ratio * second[r]):
            continue
        c = best_col[r]
        held = col_row[c]
        if held < 0 or best[r] < best[held]:
            col_row[c] = r
    out = np.full(n_rows, -1, np.int64)
    for c in range(n_cols):
        if col_row[c] >= 0:
            out[col_row[c]] = c
    return out


def _row_candidates(uv_a: np.ndarray, uv_b: np.ndarray, *, row_tol: float, min_du: float, max_du: float) -> tuple[np.ndarray, np.ndarray]:
    """Pairs (i, j) with `|v_a - v_b| <= row_tol` and `min_du <= u_a - u_b <= max_du`."""
    order = np.argsort(uv_b[:, 1], kind="stable")
    v_sorted = uv_b[order, 1]
    lo = np.searchsorted(v_sorted, uv_a[:, 1] - row_tol, side="left")
    hi = np.searchsorted(v_sorted, uv_a[:, 1] + row_tol, side="right")
    counts = hi - lo
    rows = np.repeat(np.arange(uv_a.shape[0]), counts)
    offsets = np.arange(rows.size) - np.repeat(np.cumsum(counts) - counts, counts)
    cols = order[np.repeat(lo, counts) + offsets]
    du = uv_a[rows, 0] - uv_b[cols, 0]
    ok = (du >= min_du) & (du <= max_du)
    return rows[ok], cols[ok]


def _refine_disparity(left: np.ndarray, right: np.ndarray, u_left: np.ndarray, v: np.ndarray, u_right: np.ndarray, *, block_px: int, radius_px: int) -> tuple[np.ndarray, np.ndarray]:
    """Sub-pixel right columns for integer left pixels (`u_left`, `v`) matched near the
    integer right columns `u_right`: SAD of a `block_px` square over ±`radius_px` column
    offsets, parabola through the minimum and its neighbours. Returns the refined right
    columns and a validity mask (the minimum inside the search range and the block inside
    both images)."""
    h, w = left.shape
    r = block_px // 2
    n = u_left.size
    ok = (v - r >= 0) & (v + r < h) & (u_left - r >= 0) & (u_left + r < w) & (u_right - r - radius_px - 1 >= 0) & (u_right + r + radius_px + 1 < w)
    refined = np.full(n, np.nan)
    if not ok.any():
        return refined, ok
    idx = np.flatnonzero(ok)
    dy, dx = np.mgrid[-r : r + 1, -r : r + 1]
    rows = v[idx, None, None] + dy
    patch_l = left[rows, u_left[idx, None, None] + dx].astype(np.int32)
    patch_l -= patch_l[:, r : r + 1, r : r + 1]  # compare intensity around the centre value
    offsets = np.arange(-radius_px - 1, radius_px + 2)
    sad = np.empty((idx.size, offsets.size))
    for j, off in enumerate(offsets):
        patch_r = right[rows, u_right[idx, None, None] + off + dx].astype(np.int32)
        patch_r -= patch_r[:, r : r + 1, r : r + 1]
        sad[:, j] = np.abs(patch_l - patch_r).sum(axis=(1, 2))
    inner = sad[:, 1:-1]
    j = np.argmin(inner, axis=1) + 1
    s0 = sad[np.arange(idx.size), j - 1]
    s1 = sad[np.arange(idx.size), j]
    s2 = sad[np.arange(idx.size), j + 1]
    denom = s0 - 2.0 * s1 + s2
    delta = np.where(denom > 0, 0.5 * (s0 - s2) / np.where(denom > 0, denom, 1.0), 0.0)
    good = (np.abs(delta) < 1.0) & (j > 1) & (j < offsets.size - 2)
    refined[idx] = u_right[idx] + offsets[j] + delta
    ok[idx] &= good
    return refined, ok


def stereo_points(left: np.ndarray, right: np.ndarray, *, camera: PinholeCamera, settings: PointSettings = PointSettings(), left_keypoints: Keypoints | None = None) -> StereoPoints:
    """Detect ORB points in the rectified left and right uint8 images (H, W), match them
    along rows and triangulate in the left rectified camera frame (`camera` with baseline).
    `left_keypoints`: the left image's keypoints when already detected (tracking detects
    them on every frame; the right image is only needed for keyframes)."""
    s = settings
    kp_left = detect_points(left, settings=s) if left_keypoints is None else left_keypoints
    kp_right = detect_points(right, settings=s)
    uv_left = kp_left.uv.copy()
    n = uv_left.shape[0]
    u_right = np.full(n, np.nan)
    p_cam = np.full((n, 3), np.nan)
    if n and kp_right.uv.shape[0]:
        # Octave > 0 keypoints are located to about a pixel of their level: widen the row band.
        row_tol = s.max_row_diff_px * s.scale_factor ** max(0, s.n_levels - 1)
        rows, cols = _row_candidates(kp_left.uv, kp_right.uv, row_tol=row_tol, min_du=s.min_disparity_px - 1.0, max_du=s.max_disparity_px + 1.0)
        dv = np.abs(kp_left.uv[rows, 1] - kp_right.uv[cols, 1])
        ok = dv <= s.max_row_diff_px * s.scale_factor ** np.maximum(kp_left.octave[rows], kp_right.octave[cols])
        rows, cols = rows[ok], cols[ok]
        dist = pair_hamming(kp_left.descriptors[rows], kp_right.descriptors[cols])
        match = best_matches(rows, cols, dist, n_rows=n, max_distance=s.max_hamming, ratio=s.ratio)
        i = np.flatnonzero(match >= 0)
        # Sub-pixel disparity at the rounded left pixel, searched around the matched right keypoint.
        u_l = np.rint(kp_left.uv[i, 0]).astype(int)
        v_l = np.rint(kp_left.uv[i, 1]).astype(int)
        u_r0 = np.rint(u_l - (kp_left.uv[i, 0] - kp_right.uv[match[i], 0])).astype(int)
        u_r, ok = _refine_disparity(left, right, u_l, v_l, u_r0, block_px=s.block_px, radius_px=s.refine_radius_px)
        d = u_l - u_r
        ok &= (d >= s.min_disparity_px) & (d <= s.max_disparity_px)
        i, u_l, v_l, d = i[ok], u_l[ok], v_l[ok], d[ok]
        uv_left[i] = np.stack([u_l, v_l], axis=1)  # the pixel the disparity was measured at
        u_right[i] = u_l - d
        z = camera.fx * camera.baseline / d
        p_cam[i] = camera.normalize(uv_left[i]) * z[:, None]
    return StereoPoints(uv_left=uv_left, descriptors=kp_left.descriptors, octave=kp_left.octave, u_right=u_right, p_cam=p_cam)
