"""The monocular keyframe's new landmarks (VIO): points triangulated between two keyframes
from descriptor matches along epipolar lines, or from pixels followed between them, and
lines from LBD matches of two keyframes' segments, triangulated from their back-projection
planes. New landmarks are anchored in the older keyframe, whose observations they join.

World frame z up, metres; pixels of the map's camera."""

from __future__ import annotations

import dataclasses

import numpy as np

from backend.frontend.lines import LineSettings, Segments, match_segments_temporal
from backend.frontend.points import Keypoints, best_matches, pair_hamming
from backend.geometry import so3
from backend.mapping.map import KeyframeObservations, Map
from backend.mapping.triangulation import triangulate_lines, triangulate_two_views
from backend.optim import factors


@dataclasses.dataclass(frozen=True)
class MonoSettings:
    """Matches within `epipolar_px` of their epipolar line, ORB Hamming `<= max_hamming`
    with ratio `match_ratio`; a landmark needs `min_parallax_deg` between its two views, a
    depth in [`min_depth_m`, `max_depth_m`] in both, reprojection errors under `outlier_px`
    (points) and `min_line_length_m` (lines, whose segments match with `lines`)."""

    epipolar_px: float
    max_hamming: int
    match_ratio: float
    min_depth_m: float
    max_depth_m: float
    min_parallax_deg: float
    outlier_px: float
    min_line_length_m: float
    lines: LineSettings


def triangulate_matches(the_map: Map, j: int, k: int, kp0: Keypoints, cand0: np.ndarray, kp1: Keypoints, cand1: np.ndarray, *, settings: MonoSettings) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Unclaimed keypoints of keyframes j < k matched by descriptor along the epipolar
    lines of their relative pose, triangulated; returns keypoint indices in both and the
    world points of those with parallax and positive depth."""
    s = settings
    cam = the_map.camera
    empty = (np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros((0, 3)))
    if len(cand0) == 0 or len(cand1) == 0:
        return empty
    R0, t0, R1, t1 = the_map.R_world_keyframe[j], the_map.t_world_keyframe[j], the_map.R_world_keyframe[k], the_map.t_world_keyframe[k]
    R_10 = R1.T @ R0
    t_10 = R1.T @ (t0 - t1)
    if np.linalg.norm(t_10) < 1e-6:
        return empty
    E = so3.hat(t_10) @ R_10
    x0 = cam.normalize(kp0.uv[cand0])
    x1 = cam.normalize(kp1.uv[cand1])
    lines = x0 @ E.T  # epipolar lines in image 1 (normalized)
    num = np.abs(lines @ x1.T)
    den = np.linalg.norm(lines[:, :2], axis=1, keepdims=True)
    rows, cols = np.nonzero(num < (s.epipolar_px / cam.fx) * np.maximum(den, 1e-12))
    dist = pair_hamming(kp0.descriptors[cand0[rows]], kp1.descriptors[cand1[cols]])
    match = best_matches(rows, cols, dist, n_rows=len(cand0), max_distance=s.max_hamming, ratio=s.match_ratio)
    a = np.flatnonzero(match >= 0)
    if len(a) == 0:
        return empty
    i0, i1 = cand0[a], cand1[match[a]]
    p_w, good = triangulate_pixels(the_map, j, k, kp0.uv[i0], kp1.uv[i1], settings=settings)
    return i0[good], i1[good], p_w[good]


def triangulate_pixels(the_map: Map, j: int, k: int, uv0: np.ndarray, uv1: np.ndarray, *, settings: MonoSettings) -> tuple[np.ndarray, np.ndarray]:
    """Pixels `uv0` of keyframe j and `uv1` (N, 2) of keyframe k triangulated (DLT) at
    their estimated poses; returns the world points (N, 3) and which of them are in front
    of both cameras within the depth limits, with at least `min_parallax_deg` and both
    reprojection errors under `outlier_px`."""
    s = settings
    cam = the_map.camera
    R0, t0, R1, t1 = the_map.R_world_keyframe[j], the_map.t_world_keyframe[j], the_map.R_world_keyframe[k], the_map.t_world_keyframe[k]
    if len(uv0) == 0:
        return np.zeros((0, 3)), np.zeros(0, bool)
    p_w = triangulate_two_views(cam.normalize(uv0)[:, :2], cam.normalize(uv1)[:, :2], R0, t0, R1, t1)
    z0 = np.einsum("ij,nj->ni", R0.T, p_w - t0)[:, 2]
    z1 = np.einsum("ij,nj->ni", R1.T, p_w - t1)[:, 2]
    ray0 = p_w - t0
    ray1 = p_w - t1
    cos = np.sum(ray0 * ray1, axis=1) / np.maximum(np.linalg.norm(ray0, axis=1) * np.linalg.norm(ray1, axis=1), 1e-12)
    with np.errstate(invalid="ignore"):
        good = np.all(np.isfinite(p_w), axis=1) & (z0 > s.min_depth_m) & (z1 > s.min_depth_m) & (z0 < s.max_depth_m) & (cos < np.cos(np.radians(s.min_parallax_deg)))
        err0 = np.linalg.norm(cam.project((p_w - t0) @ R0) - uv0, axis=1)
        err1 = np.linalg.norm(cam.project((p_w - t1) @ R1) - uv1, axis=1)
        good &= (err0 < s.outlier_px) & (err1 < s.outlier_px)
    return p_w, good


def add_two_view_points(the_map: Map, k: int, k0: int, uv0: np.ndarray, desc: np.ndarray, p_world: np.ndarray) -> np.ndarray:
    """Points triangulated between keyframes k0 < k, anchored in k0 at pixels `uv0` (N, 2)
    and observed in both; their re-observations are counted from keyframe k - 1 (as for a
    pair with the previous keyframe, whatever k0). Returns their ids."""
    n = len(uv0)
    ids = the_map.points.add(
        p_world=p_world,
        ok=np.ones(n, bool),
        anchor=np.full(n, k0),
        anchor_uv=uv0,
        anchor_ur=np.full(n, np.nan),
        plane=np.full(n, -1),
        desc=desc,
        n_kf=np.full(n, 2, np.int64),
        born=np.full(n, k - 1),
    )
    o = the_map.observations[k0]
    the_map.observations[k0] = KeyframeObservations(
        np.concatenate([o.point_id, ids]), np.concatenate([o.point_uv, uv0]), np.concatenate([o.point_ur, np.full(n, np.nan)]), o.line_id, o.line_uv, o.line_ruv
    )
    return ids


def add_two_view_lines(the_map: Map, k: int, prev: Segments, claimed_prev: np.ndarray, cur: Segments, claimed_cur: np.ndarray, *, settings: MonoSettings) -> tuple[np.ndarray, np.ndarray]:
    """Lines from LBD matches between the unclaimed segments of keyframes k-1 and k,
    triangulated from the two back-projection planes (at least `min_parallax_deg`
    apart), with both endpoints in front of both cameras."""
    s = settings
    cam = the_map.camera
    Lm = the_map.lines
    a = np.flatnonzero(~claimed_prev)
    b = np.flatnonzero(~claimed_cur)
    empty = (np.zeros(0, np.int64), np.zeros(0, np.int64))
    if len(a) == 0 or len(b) == 0:
        return empty
    wide = dataclasses.replace(s.lines, max_shift_px=max(s.lines.max_shift_px, 120.0))
    sub = lambda seg, idx: Segments(seg.start[idx], seg.end[idx], seg.descriptors[idx])  # noqa: E731
    pairs = match_segments_temporal(sub(prev, a), sub(cur, b), settings=wide)
    if len(pairs) == 0:
        return empty
    ia, ib = a[pairs[:, 0]], b[pairs[:, 1]]
    n = len(ia)
    xs = np.concatenate([cam.normalize(prev.start[ia]), cam.normalize(cur.start[ib])])
    xe = np.concatenate([cam.normalize(prev.end[ia]), cam.normalize(cur.end[ib])])
    landmark = np.concatenate([np.arange(n), np.arange(n)])
    pose = np.concatenate([np.zeros(n, np.int64), np.ones(n, np.int64)])
    Rs = np.stack([the_map.R_world_keyframe[k - 1], the_map.R_world_keyframe[k]])
    ts = np.stack([the_map.t_world_keyframe[k - 1], the_map.t_world_keyframe[k]])
    m, v, spread = triangulate_lines(xs, xe, landmark, pose, n, Rs, ts)
    norm = np.linalg.norm(v, axis=1)
    good = (spread > np.sin(np.radians(s.min_parallax_deg))) & (norm > 1e-12)
    m = m / np.maximum(norm, 1e-12)[:, None]
    v = v / np.maximum(norm, 1e-12)[:, None]
    # Endpoints: the line's points nearest the anchor (k-1) endpoint rays, in front of both cameras.

    ends = []
    for x in (cam.normalize(prev.start[ia]), cam.normalize(prev.end[ia])):
        w = x @ Rs[0].T
        p, _, _ = factors.line_point_nearest_ray(m, v, np.tile(ts[0], (n, 1)), w)
        ends.append(p)
    with np.errstate(invalid="ignore"):
        for R, t in zip(Rs, ts):
            for p in ends:
                z = (p - t) @ R[:, 2]
                good &= np.isfinite(z) & (z > s.min_depth_m) & (z < s.max_depth_m)
        good &= np.linalg.norm(ends[1] - ends[0], axis=1) > s.min_line_length_m
    sel = np.flatnonzero(good)
    if len(sel) == 0:
        return empty
    uv_prev = np.concatenate([prev.start[ia[sel]], prev.end[ia[sel]]], axis=1)
    ids = Lm.add(
        m=m[sel],
        v=v[sel],
        ok=np.ones(len(sel), bool),
        anchor=np.full(len(sel), k - 1),
        anchor_uv=uv_prev,
        anchor_ruv=np.full((len(sel), 4), np.nan),
        plane=np.full(len(sel), -1),
        desc=cur.descriptors[ib[sel]],
        n_kf=np.full(len(sel), 2, np.int64),
    )
    o = the_map.observations[k - 1]
    the_map.observations[k - 1] = KeyframeObservations(
        o.point_id, o.point_uv, o.point_ur, np.concatenate([o.line_id, ids]), np.concatenate([o.line_uv, uv_prev]), np.concatenate([o.line_ruv, np.full((len(ids), 4), np.nan)])
    )
    claimed_prev[ia[sel]] = True
    return ids, ib[sel]


def observe_mono_lines(
    the_map: Map, k: int, segments: Segments, local_l: np.ndarray, l_match: np.ndarray, kf_segments: dict[int, tuple[Segments, np.ndarray]], *, settings: MonoSettings
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Keyframe k's line observations: the local map's lines `local_l` matched to its
    `segments` (`l_match`: segment index or -1) and new lines from LBD matches with keyframe
    k - 1's unclaimed segments (`kf_segments`: each recent keyframe's segments and which
    have a line; k's are added, k - 2's dropped). Returns the observed line ids, their
    segments' endpoints (M, 4) in pixels, and the new line ids."""
    Lm = the_map.lines
    uv = np.concatenate([segments.start, segments.end], axis=1)
    tracked_l, jl, claimed_l = Lm.reobserve(local_l, l_match, segments.descriptors, n_features=len(segments))
    fresh_l = np.zeros(0, np.int64)
    new_lines = np.zeros(0, np.int64)
    if k - 1 in kf_segments and k > the_map.segment_start:
        prev, claimed_prev_l = kf_segments[k - 1]
        new_lines, fresh_l = add_two_view_lines(the_map, k, prev, claimed_prev_l, segments, claimed_l, settings=settings)
    claimed_l[fresh_l] = True
    kf_segments[k] = (segments, claimed_l)
    kf_segments.pop(k - 2, None)
    return np.concatenate([tracked_l, new_lines]), uv[np.concatenate([jl, fresh_l])], new_lines
