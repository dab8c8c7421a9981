"""Every frame: its pose against the local map (the stereo engine's module docstring tells
the candidates tried when the motion model fails), and the stereo keyframe rule.

Inputs are explicit: the map, the local map's point ids, the predicted pose and the last
frame's. World frame z up, metres; pixels of `camera`."""

from __future__ import annotations

import dataclasses
from collections.abc import Callable

import numpy as np

from backend.frontend.lines import LineSettings, Segments
from backend.frontend.points import Keypoints, best_matches, nearest_hamming, pair_hamming
from backend.geometry import so3
from backend.geometry.camera import PinholeCamera
from backend.mapping.map import Map
from backend.pipeline.tracking import line_errors, line_reprojection, match_by_projection, merge_matches, pixel_errors, refine_pose, relocalize, reprojection, translation_std_m


@dataclasses.dataclass(frozen=True)
class Tracked:
    """A frame's pose, the keypoint matched to each local map point (-1: none), point
    inliers, and the map lines that helped place it (`line_inliers`: 0 unless the points
    alone could not, `LineAid`); `by_flow`: placed by optical flow from the last placed
    frame, not against the map (`stages.flow_track`; no matches then)."""

    R: np.ndarray
    t: np.ndarray
    match: np.ndarray
    inliers: int
    ok: bool
    line_inliers: int = 0
    by_flow: bool = False


@dataclasses.dataclass(frozen=True)
class LineAid:
    """The local map's lines for a frame whose points alone cannot place it (a bare wall
    with a few marks: too few corners, but their edges): the map line ids `ids`, the
    frame's left segments (`segments`, called only when needed: LSD costs a keyframe's
    line detection), and how segments match map lines (`settings`, `line_search_px`,
    `min_depth_m`, as at keyframes). A line inlier counts as a point inlier (two residuals
    each); the pose needs `min_inliers` of them together, at least `min_line_inliers`
    lines among them, and must be well constrained: its translation's standard deviation
    (the inliers' Gauss-Newton covariance at the refinement's `pixel_sigma`, largest
    axis) at most `max_translation_std_m` (a few marks on one wall leave the distance to it
    loose)."""

    ids: np.ndarray
    segments: Callable[[], Segments]
    settings: LineSettings
    line_search_px: float
    min_depth_m: float
    min_inliers: int = 10
    min_line_inliers: int = 3
    max_translation_std_m: float = 0.02


@dataclasses.dataclass(frozen=True)
class TrackSettings:
    """Projection search radius `search_radius_px` (then `refine_radius_px` around the
    refined pose), ORB Hamming distance `<= max_hamming` and ratio `match_ratio`; a pose needs
    `min_tracking_inliers` inliers; the refinement's `pixel_sigma` and Cauchy width `cauchy`
    (px); matches off by more than `outlier_px` after it are dropped; `seed` for the RANSACs.
    `verify_agreement`: a pose from the prediction that is being verified stays when it
    places at least this fraction of the best other candidate's inliers within
    `outlier_px` (the two agree; a wrong translation that far points alone accept places
    the near points far off)."""

    search_radius_px: float
    refine_radius_px: float
    max_hamming: int
    match_ratio: float
    min_tracking_inliers: int
    pixel_sigma: float
    cauchy: float
    outlier_px: float
    seed: int
    verify_agreement: float = 0.8


def extrapolate(R0: np.ndarray, t0: np.ndarray, R1: np.ndarray, t1: np.ndarray, steps: float) -> tuple[np.ndarray, np.ndarray]:
    """The world pose `steps` times the motion from pose 0 to pose 1 beyond pose 1 (constant
    velocity in the body frame). Through the rotation vector, projected back onto SO(3):
    products of rotations extrapolated frame after frame would amplify rounding errors (no
    longer rotations after a few hundred frames)."""
    R_rel = so3.exp(steps * so3.log(R0.T @ R1))
    t_rel = steps * (R0.T @ (t1 - t0))
    return so3.project_to_so3(R1 @ R_rel), t1 + R1 @ t_rel


def refine(
    camera: PinholeCamera,
    s: TrackSettings,
    R: np.ndarray,
    t: np.ndarray,
    P: np.ndarray,
    D: np.ndarray,
    kp: Keypoints,
    match: np.ndarray,
    *,
    widen: bool = False,
    min_inliers: int | None = None,
    keep_matches: bool = False,
) -> Tracked:
    """Refine from `match`; where that leaves fewer than twice the inliers needed (always
    with `widen`: a pose from a subset of the map), search again around the refined pose
    (`refine_radius_px`) and refine once more. `min_inliers`: what tracking needs (default
    `min_tracking_inliers`); `keep_matches`: the search only adds matches for points that
    have none (to keypoints not yet used) instead of replacing them."""
    need = s.min_tracking_inliers if min_inliers is None else min_inliers
    for radius in (None, s.refine_radius_px):
        if radius is not None:
            if not widen and np.count_nonzero(match >= 0) >= 2 * s.min_tracking_inliers:
                break
            found = match_by_projection(camera, R, t, P, D, kp.uv, kp.descriptors, radius_px=radius, max_hamming=s.max_hamming, ratio=s.match_ratio)
            match = merge_matches(match, found, n_keypoints=len(kp.uv)) if keep_matches else found
        m = np.flatnonzero(match >= 0)
        if len(m) < need:
            return Tracked(R, t, match, 0, False)
        ref = refine_pose(camera, R, t, P[m], kp.uv[match[m]], sigma_px=s.pixel_sigma, cauchy=s.cauchy)
        R, t = ref.R_world_camera, ref.t_world_camera
        err = pixel_errors(camera, R, t, P[m], kp.uv[match[m]])
        match = match.copy()
        match[m[~(err < s.outlier_px)]] = -1
    inliers = int(np.count_nonzero(match >= 0))
    return Tracked(R, t, match, inliers, inliers >= need)


def last_keyframe_points(the_map: Map, local_points: np.ndarray) -> np.ndarray:
    """Indices into the local map of the points the last keyframe observed."""
    if not the_map.observations:
        return np.zeros(0, np.int64)
    seen = the_map.observations[len(the_map) - 1].point_id
    return np.flatnonzero(np.isin(local_points, seen[the_map.points.ok[seen]]))


def rows_of(pairs: tuple[np.ndarray, np.ndarray, np.ndarray], subset: np.ndarray, *, n_rows: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The candidate `pairs` (rows, cols, distances) of the rows in `subset` (indices into
    `n_rows` rows, no repeats), their rows renumbered as positions in `subset`."""
    rows, cols, dist = pairs
    position = np.full(n_rows, -1, np.int64)
    position[subset] = np.arange(len(subset))
    keep = position[rows] >= 0
    return position[rows[keep]], cols[keep], dist[keep]


def nearest_ahead(P: np.ndarray, D: np.ndarray, kp: Keypoints, pose: tuple[np.ndarray, np.ndarray]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The two nearest keypoints of `kp` by descriptor (:func:`nearest_hamming`'s candidate
    pairs, rows indexing `P`) of the map points `P` (world, descriptors `D`) that lie in
    front of the camera at `pose` (`R_world_camera`, `t_world_camera`): the last frame's,
    which a frame a moment later cannot have turned away from. The others cannot be in
    view; on a drive they are most of the local map (the points passed: 76 % on the
    street), whose search would be wasted."""
    R, t = pose
    ahead = np.flatnonzero(((P - t) @ R)[:, 2] > 0.0)
    rows, cols, dist = nearest_hamming(D[ahead], kp.descriptors, k=2)
    return ahead[rows], cols, dist


def track_frame(
    camera: PinholeCamera,
    s: TrackSettings,
    i: int,
    kp: Keypoints,
    *,
    the_map: Map,
    local_points: np.ndarray,
    predicted: tuple[np.ndarray, np.ndarray],
    last_frame: tuple[np.ndarray, np.ndarray] | None,
    messages: list[str],
    verify_below: int | None = None,
    lines: LineAid | None = None,
) -> Tracked:
    """Pose of frame i against the local map, from the `predicted` pose; `last_frame`: the
    last frame's pose where a motion model made the prediction (None: it is that pose).
    `verify_below`: a pose from the prediction with fewer inliers than this is not trusted
    (far points alone can agree on a wrong translation): the PnP candidates, which need no
    prediction, are tried too and the one with the most inliers wins (None: trusted).
    A candidate other than the prediction that wins says how in `messages` where the
    prediction failed; replacing a tracked but untrusted prediction is routine (every stereo
    run's second frame, before the motion model has a velocity) and says nothing, so that a
    run's output stays quiet. `lines`: where no candidate has enough point inliers, the
    prediction and the last frame's pose are tried once more with the local map's lines
    added (`LineAid`; None: points only)."""
    R, t = predicted
    ids = local_points
    if len(ids) == 0 or len(kp.uv) == 0:
        return Tracked(R, t, np.full(len(ids), -1, np.int64), 0, False)
    P, D = the_map.points.p_world[ids], the_map.points.desc[ids]
    match = match_by_projection(camera, R, t, P, D, kp.uv, kp.descriptors, radius_px=s.search_radius_px, max_hamming=s.max_hamming, ratio=s.match_ratio)
    result = refine(camera, s, R, t, P, D, kp, match)
    if result.ok and (verify_below is None or result.inliers >= verify_below):
        return result
    # The motion model failed (a sudden change of motion) or is not trusted. Candidates: a
    # three times wider search around the prediction, the same around the last frame's
    # pose (where the prediction failed), and PnP-RANSAC by descriptor on the last
    # keyframe's points and on the local map (as ORB-SLAM's tracking of the reference
    # keyframe and its relocalization), each of its points in front of the last frame's camera.
    # The one with the most inliers wins: in repeated texture a wide search or a subset of
    # the map can agree on a wrong pose with enough inliers to pass.
    candidates: list[tuple[Tracked, str]] = []
    if result.ok:
        candidates.append((result, ""))
    else:
        priors = [(R, t, "")]
        if last_frame is not None:
            priors.append((last_frame[0], last_frame[1], "tracked from the last frame's pose (the motion model failed)"))
        for R0, t0, how in priors:
            match = match_by_projection(camera, R0, t0, P, D, kp.uv, kp.descriptors, radius_px=3.0 * s.search_radius_px, max_hamming=s.max_hamming, ratio=s.match_ratio)
            candidates.append((refine(camera, s, R0, t0, P, D, kp, match), how))
    nearest: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None  # the local map's two nearest keypoints, searched once
    for what, subset in (("the last keyframe", last_keyframe_points(the_map, ids)), ("the local map", np.arange(len(ids)))):
        if len(subset) < s.min_tracking_inliers:
            continue
        if nearest is None:
            nearest = nearest_ahead(P, D, kp, last_frame if last_frame is not None else (R, t))
        found = rows_of(nearest, subset, n_rows=len(ids))
        reloc = relocalize(camera, P[subset], D[subset], kp.uv, kp.descriptors, max_hamming=s.max_hamming, ratio=s.match_ratio, min_inliers=s.min_tracking_inliers, seed=s.seed + i, candidates=found)
        if reloc is not None:
            match = np.full(len(ids), -1, np.int64)
            match[subset] = reloc[2]
            candidates.append((refine(camera, s, reloc[0], reloc[1], P, D, kp, match, widen=True), f"relocalized by PnP against {what}"))
    good = [c for c in candidates if c[0].ok]
    if good:
        best, how = max(good, key=lambda c: c[0].inliers)
        if result.ok and best is not result and agrees(camera, result, best, P, kp, outlier_px=s.outlier_px, fraction=s.verify_agreement):
            return result  # verified: the prediction's pose and matches stand
        if how and not result.ok:
            messages.append(f"frame {i}: {how}")
        return best
    if lines is not None and len(lines.ids):
        starts = [(R, t)] + ([last_frame] if last_frame is not None else [])
        segments = lines.segments()  # once for every start
        aided = [refine_with_lines(camera, s, lines, segments, R0, t0, P, D, kp, the_map=the_map) for R0, t0 in starts]
        best = max(aided, key=lambda a: a.inliers + a.line_inliers)
        if best.ok:
            return best
    return Tracked(R, t, np.full(len(ids), -1, np.int64), 0, False)


def refine_with_lines(camera: PinholeCamera, s: TrackSettings, aid: LineAid, segments: Segments, R: np.ndarray, t: np.ndarray, P: np.ndarray, D: np.ndarray, kp: Keypoints, *, the_map: Map) -> Tracked:
    """The pose from (R, t) against map points `P` (descriptors `D`) and the map lines of
    `aid` seen as the frame's left `segments` together: both matched by projection (points
    within three times the search radius, lines as at keyframes), refined with points and
    lines, outliers (off by more than `outlier_px`) dropped, matched again around the
    refined pose and refined once more."""
    m_world, v_world = the_map.lines.m[aid.ids], the_map.lines.v[aid.ids]
    p_match = match_by_projection(camera, R, t, P, D, kp.uv, kp.descriptors, radius_px=3.0 * s.search_radius_px, max_hamming=s.max_hamming, ratio=s.match_ratio)
    need = aid.min_inliers
    for attempt in range(2):
        l_match = match_map_lines(the_map, R, t, aid.ids, segments, min_depth_m=aid.min_depth_m, line_search_px=aid.line_search_px, settings=aid.settings)
        mp, ml = np.flatnonzero(p_match >= 0), np.flatnonzero(l_match >= 0)
        if len(mp) + len(ml) < need or len(ml) < aid.min_line_inliers:
            return Tracked(R, t, np.full(len(P), -1, np.int64), 0, False)
        seg_uv = np.concatenate([segments.start[l_match[ml]], segments.end[l_match[ml]]], axis=1)
        ref = refine_pose(camera, R, t, P[mp], kp.uv[p_match[mp]], lines_world=(m_world[ml], v_world[ml]), segments_uv=seg_uv, sigma_px=s.pixel_sigma, cauchy=s.cauchy)
        R, t = ref.R_world_camera, ref.t_world_camera
        p_ok = pixel_errors(camera, R, t, P[mp], kp.uv[p_match[mp]]) < s.outlier_px
        l_ok = line_errors(camera, R, t, m_world[ml], v_world[ml], seg_uv) < s.outlier_px
        if attempt == 0:
            kept = np.full(len(P), -1, np.int64)
            kept[mp[p_ok]] = p_match[mp[p_ok]]
            found = match_by_projection(camera, R, t, P, D, kp.uv, kp.descriptors, radius_px=s.refine_radius_px, max_hamming=s.max_hamming, ratio=s.match_ratio)
            p_match = merge_matches(kept, found, n_keypoints=len(kp.uv))
    p_match[mp[~p_ok]] = -1  # p_match is merge_matches' own array here
    n_points, n_lines = int(np.count_nonzero(p_ok)), int(np.count_nonzero(l_ok))
    ok = n_points + n_lines >= need and n_lines >= aid.min_line_inliers
    if ok:
        _, J_p, _ = reprojection(camera, R, t, P[mp[p_ok]], kp.uv[p_match[mp[p_ok]]])
        _, J_l = line_reprojection(camera, R, t, m_world[ml[l_ok]], v_world[ml[l_ok]], seg_uv[l_ok])
        ok = translation_std_m(np.concatenate([J_p, J_l]) / s.pixel_sigma) <= aid.max_translation_std_m
    return Tracked(R, t, p_match, n_points, ok, line_inliers=n_lines)


def agrees(camera: PinholeCamera, pose: Tracked, other: Tracked, P: np.ndarray, kp: Keypoints, *, outlier_px: float, fraction: float) -> bool:
    """Whether `pose` places at least `fraction` of `other`'s matched map points `P` (world,
    one row per local map point) within `outlier_px` pixels of their keypoints in `kp`
    (False when `other` has no matches)."""
    m = np.flatnonzero(other.match >= 0)
    if len(m) == 0:
        return False
    err = pixel_errors(camera, pose.R, pose.t, P[m], kp.uv[other.match[m]])
    return bool(np.mean(err < outlier_px) >= fraction)


def kept_in_view_next(
    camera: PinholeCamera,
    min_depth_m: float,
    i: int,
    tracked: Tracked,
    *,
    last_frame: tuple[int, np.ndarray, np.ndarray] | None,
    the_map: Map,
    local_points: np.ndarray,
) -> float:
    """Fraction of frame i's tracked map points that stay in the image (depth above
    `min_depth_m`) at the next frame's pose as the constant-velocity model predicts it
    from the previous frame (`last_frame`: index, R, t) and frame i. 1 without a previous
    frame."""
    matched = np.flatnonzero(tracked.match >= 0)
    if last_frame is None or len(matched) == 0:
        return 1.0
    j, R0, t0 = last_frame
    R_next, t_next = extrapolate(R0, t0, tracked.R, tracked.t, 1.0 / max(i - j, 1))
    p_cam = (the_map.points.p_world[local_points[matched]] - t_next) @ R_next
    front = p_cam[:, 2] > min_depth_m
    uv = camera.project(p_cam[front])
    return float(np.count_nonzero(camera.in_image(uv))) / len(matched)


def match_map_lines(the_map: Map, R: np.ndarray, t: np.ndarray, ids: np.ndarray, segments: Segments, *, min_depth_m: float, line_search_px: float, settings: LineSettings) -> np.ndarray:
    """Map lines `ids` to left segments of the keyframe at pose (R, t) (world, metres): the map line's
    segment projected into the image must agree in direction (`max_angle_diff_deg`), the
    detected endpoints lie within `line_search_px` of the projected line and overlap the
    projected segment; then LBD Hamming distance with ratio test, one-to-one."""
    out = np.full(len(ids), -1, np.int64)
    if len(ids) == 0 or len(segments) == 0:
        return out
    seg_w = the_map.segments_world(ids)
    p_cam = (seg_w - t) @ R
    front = np.all(p_cam[..., 2] > min_depth_m, axis=1)
    uv = np.full((len(ids), 2, 2), np.nan)
    uv[front] = the_map.camera.project(p_cam[front])
    a, b = uv[:, 0], uv[:, 1]
    d = b - a
    length = np.linalg.norm(d, axis=1)
    ok = front & (length > 5.0)
    dn = d / np.where(ok, length, 1.0)[:, None]
    normal = np.stack([-dn[:, 1], dn[:, 0]], axis=1)
    ds = segments.direction
    cos = np.abs(dn @ ds.T)
    dist_s = np.abs(np.einsum("ik,ijk->ij", normal, segments.start[None] - a[:, None]))
    dist_e = np.abs(np.einsum("ik,ijk->ij", normal, segments.end[None] - a[:, None]))
    t_mid = np.einsum("ik,ijk->ij", dn, segments.midpoint[None] - a[:, None]) / np.where(ok, length, 1.0)[:, None]
    with np.errstate(invalid="ignore"):
        allowed = ok[:, None] & (cos >= np.cos(np.radians(settings.max_angle_diff_deg))) & (np.maximum(dist_s, dist_e) < line_search_px) & (t_mid > -0.25) & (t_mid < 1.25)
    rows, cols = np.nonzero(allowed)
    if len(rows) == 0:
        return out
    dist = pair_hamming(the_map.lines.desc[ids[rows]], segments.descriptors[cols])
    return best_matches(rows, cols, dist, n_rows=len(ids), max_distance=settings.max_hamming, ratio=settings.ratio)
