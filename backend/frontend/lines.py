"""LSD line segments with LBD descriptors, matched between rectified left and right images
(and triangulated) and over time.

Segments come from OpenCV's LSD (`cv2.createLineSegmentDetector`), the `max_lines` longest
at least `min_length_px` long; their descriptors are OpenCV contrib's LBD
(`cv2.line_descriptor.BinaryDescriptor.compute` on KeyLines built from the LSD segments:
256 bits, compared by Hamming distance), as in the paper.

Stereo: a left segment pairs with a right one when their descriptors are close (ratio test,
one-to-one), their vertical extents overlap (the images are rectified, so a line's rows are
the same in both), their directions agree, and the disparity lies in range. Near-horizontal
segments are skipped: their disparity is ill-defined. Each left endpoint's row meets the
right line at column `u_r`; its depth is `z = fx·b / (u_l - u_r)` and its 3D point `x̂·z`
(left rectified camera frame, metres).
"""

from __future__ import annotations

import dataclasses

import cv2
import numpy as np

from backend.common.workers import per_thread, submit
from backend.frontend.points import best_matches, hamming_distances
from backend.geometry.camera import PinholeCamera


@dataclasses.dataclass(frozen=True)
class LineSettings:
    """Detection: LSD at image scale `lsd_scale`, segments `>= min_length_px` long, the
    `max_lines` longest kept, of which up to a `steep_share` fraction are reserved for
    segments at least `min_angle_deg` from horizontal (the ones stereo can triangulate; in
    man-made scenes the longest segments are often horizontal). Matching: Hamming distance (of 256 bits) `<= max_hamming`,
    best / second best `< ratio`. Stereo: segments at least `min_angle_deg` from horizontal,
    direction difference `<= max_angle_diff_deg`, vertical overlap `>= min_row_overlap` of
    the longer extent, endpoint disparities in [`min_disparity_px`, `max_disparity_px`].
    Temporal: midpoint shift `<= max_shift_px`, direction change `<= max_angle_diff_deg`."""

    lsd_scale: float = 0.5
    min_length_px: float = 25.0
    max_lines: int = 100
    steep_share: float = 0.5
    max_hamming: int = 70
    ratio: float = 0.9
    min_angle_deg: float = 10.0
    max_angle_diff_deg: float = 10.0
    min_row_overlap: float = 0.6
    min_disparity_px: float = 0.5
    max_disparity_px: float = 150.0
    max_shift_px: float = 120.0


@dataclasses.dataclass(frozen=True, eq=False)
class Segments:
    """Line segments of one image: `start`, `end` (N, 2) pixels; `descriptors` (N, 32)
    uint8 LBD. Endpoints are ordered top to bottom (`start` has the smaller v)."""

    start: np.ndarray
    end: np.ndarray
    descriptors: np.ndarray

    def __len__(self) -> int:
        return int(self.start.shape[0])

    @property
    def direction(self) -> np.ndarray:
        """Unit directions (N, 2) from start to end, pixels."""
        d = self.end - self.start
        return d / np.linalg.norm(d, axis=1, keepdims=True)

    @property
    def midpoint(self) -> np.ndarray:
        return 0.5 * (self.start + self.end)


@dataclasses.dataclass(frozen=True, eq=False)
class StereoSegments:
    """Left segments of one rectified stereo frame with their stereo matches: `right_index`
    (N,) index into `right` (-1: unmatched); `p_start_cam`, `p_end_cam` (N, 3) the 3D
    endpoints (on the rays of the left endpoints) in the left rectified camera frame,
    metres, NaN where unmatched."""

    left: Segments
    right: Segments
    right_index: np.ndarray
    p_start_cam: np.ndarray
    p_end_cam: np.ndarray

    @property
    def matched(self) -> np.ndarray:
        """(N,) bool: the left segment has a stereo match and a 3D segment."""
        return self.right_index >= 0


def _keyline(index: int, start: np.ndarray, end: np.ndarray) -> cv2.line_descriptor.KeyLine:
    """An octave-0 KeyLine for an external segment (what LBD's `compute` reads)."""
    kl = cv2.line_descriptor.KeyLine()
    sx, sy, ex, ey = float(start[0]), float(start[1]), float(end[0]), float(end[1])
    kl.startPointX, kl.startPointY, kl.endPointX, kl.endPointY = sx, sy, ex, ey
    kl.sPointInOctaveX, kl.sPointInOctaveY, kl.ePointInOctaveX, kl.ePointInOctaveY = sx, sy, ex, ey
    length = float(np.hypot(ex - sx, ey - sy))
    kl.lineLength = length
    kl.numOfPixels = int(length)
    kl.angle = float(np.arctan2(ey - sy, ex - sx))
    kl.pt = (0.5 * (sx + ex), 0.5 * (sy + ey))
    kl.size = length
    kl.octave = 0
    kl.class_id = index
    return kl


def detect_segments(image: np.ndarray, *, settings: LineSettings = LineSettings()) -> Segments:
    """LSD segments of a uint8 grey image (H, W) with their LBD descriptors."""
    s = settings
    lsd = per_thread(("lsd", s.lsd_scale), lambda: cv2.createLineSegmentDetector(cv2.LSD_REFINE_NONE, s.lsd_scale))  # keeps its working images: one per thread
    found = lsd.detect(image)[0]
    seg = np.zeros((0, 4)) if found is None else found[:, 0, :].astype(float)
    length = np.hypot(seg[:, 2] - seg[:, 0], seg[:, 3] - seg[:, 1])
    keep = np.flatnonzero(length >= s.min_length_px)
    keep = keep[np.argsort(-length[keep], kind="stable")]
    steep = np.abs(seg[keep, 3] - seg[keep, 1]) >= np.sin(np.radians(s.min_angle_deg)) * length[keep]
    chosen = np.zeros(keep.size, bool)
    chosen[np.flatnonzero(steep)[: int(s.steep_share * s.max_lines)]] = True
    chosen[np.flatnonzero(~chosen)[: s.max_lines - int(chosen.sum())]] = True  # the rest by length
    seg = seg[keep[chosen]]
    flip = seg[:, 3] < seg[:, 1]
    seg[flip] = seg[flip][:, [2, 3, 0, 1]]
    if len(seg) == 0:
        return Segments(start=np.zeros((0, 2)), end=np.zeros((0, 2)), descriptors=np.zeros((0, 32), np.uint8))
    lbd = per_thread("lbd", cv2.line_descriptor.BinaryDescriptor_createBinaryDescriptor)  # type: ignore[attr-defined]  # not in OpenCV's stubs
    keylines, desc = lbd.compute(image, [_keyline(i, a[:2], a[2:]) for i, a in enumerate(seg)])
    index = np.array([kl.class_id for kl in keylines], dtype=int)  # compute may drop lines
    seg = seg[index]
    return Segments(start=seg[:, :2].copy(), end=seg[:, 2:].copy(), descriptors=np.asarray(desc, np.uint8).reshape(-1, 32))


def _column_at_rows(start: np.ndarray, end: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Column where each line through `start`, `end` (..., 2) crosses the rows `v` (...)."""
    t = (v - start[..., 1]) / (end[..., 1] - start[..., 1])
    return start[..., 0] + t * (end[..., 0] - start[..., 0])


def match_stereo_segments(left: Segments, right: Segments, *, camera: PinholeCamera, settings: LineSettings = LineSettings()) -> StereoSegments:
    """Match left to right segments of a rectified pair and triangulate the matches in the
    left rectified camera frame (`camera` with baseline)."""
    s = settings
    n = len(left)
    right_index = np.full(n, -1, dtype=np.int64)
    p_start = np.full((n, 3), np.nan)
    p_end = np.full((n, 3), np.nan)
    if n and len(right):
        sin_min = np.sin(np.radians(s.min_angle_deg))
        dir_l, dir_r = left.direction, right.direction
        steep_l = np.abs(dir_l[:, 1]) >= sin_min
        steep_r = np.abs(dir_r[:, 1]) >= sin_min
        top = np.maximum(left.start[:, None, 1], right.start[None, :, 1])
        bottom = np.minimum(left.end[:, None, 1], right.end[None, :, 1])
        extent = np.maximum((left.end - left.start)[:, None, 1], (right.end - right.start)[None, :, 1])
        overlap = (bottom - top) / np.maximum(extent, 1e-9)
        cos_angle = np.abs(dir_l @ dir_r.T)
        # Disparity at both left endpoints against the right line.
        with np.errstate(divide="ignore", invalid="ignore"):
            d_start = left.start[:, None, 0] - _column_at_rows(right.start[None], right.end[None], left.start[:, None, 1])
            d_end = left.end[:, None, 0] - _column_at_rows(right.start[None], right.end[None], left.end[:, None, 1])
        in_range = (np.minimum(d_start, d_end) >= s.min_disparity_px) & (np.maximum(d_start, d_end) <= s.max_disparity_px)
        allowed = steep_l[:, None] & steep_r[None, :] & (overlap >= s.min_row_overlap) & (cos_angle >= np.cos(np.radians(s.max_angle_diff_deg))) & in_range
        rows, cols = np.nonzero(allowed)
        dist = hamming_distances(left.descriptors, right.descriptors)[rows, cols]
        right_index = best_matches(rows, cols, dist, n_rows=n, max_distance=s.max_hamming, ratio=s.ratio)
        i = np.flatnonzero(right_index >= 0)
        j = right_index[i]
        for endpoint, d, out in ((left.start, d_start, p_start), (left.end, d_end, p_end)):
            z = camera.fx * camera.baseline / d[i, j]
            out[i] = camera.normalize(endpoint[i]) * z[:, None]
    return StereoSegments(left=left, right=right, right_index=right_index, p_start_cam=p_start, p_end_cam=p_end)


def stereo_segments(left: np.ndarray, right: np.ndarray, *, camera: PinholeCamera, settings: LineSettings = LineSettings()) -> StereoSegments:
    """Detect, describe, match and triangulate segments of a rectified uint8 pair (H, W)
    (the right image's segments on a worker thread meanwhile: the same segments)."""
    right_segments = submit(lambda: detect_segments(right, settings=settings))
    left_segments = detect_segments(left, settings=settings)
    return match_stereo_segments(left_segments, right_segments.result(), camera=camera, settings=settings)


def match_segments_temporal(previous: Segments, current: Segments, *, settings: LineSettings = LineSettings()) -> np.ndarray:
    """Matches (M, 2) `(i_previous, i_current)` between the segments of two images of the
    same camera: mutual best LBD Hamming distance under `max_hamming` with the ratio test,
    gated by midpoint shift (`max_shift_px`) and direction change (`max_angle_diff_deg`)."""
    s = settings
    if len(previous) == 0 or len(current) == 0:
        return np.zeros((0, 2), dtype=np.int64)
    dist = hamming_distances(previous.descriptors, current.descriptors)
    shift = np.linalg.norm(previous.midpoint[:, None, :] - current.midpoint[None, :, :], axis=2)
    cos_angle = np.abs(previous.direction @ current.direction.T)
    allowed = (shift <= s.max_shift_px) & (cos_angle >= np.cos(np.radians(s.max_angle_diff_deg)))
    rows, cols = np.nonzero(allowed)
    d = dist[rows, cols]
    forward = best_matches(rows, cols, d, n_rows=len(previous), max_distance=s.max_hamming, ratio=s.ratio)
    backward = best_matches(cols, rows, d, n_rows=len(current), max_distance=s.max_hamming, ratio=s.ratio)
    i = np.flatnonzero(forward >= 0)
    mutual = backward[forward[i]] == i
    return np.stack([i[mutual], forward[i[mutual]]], axis=1)
