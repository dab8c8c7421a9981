"""Step 6 of a keyframe: culling after the window solve, and the local map tracking matches
against until the next keyframe."""

from __future__ import annotations

import dataclasses

import numpy as np

from backend.geometry import line as line_geo
from backend.mapping.map import KeyframeObservations, Map
from backend.pipeline.tracking import line_errors, pixel_errors


@dataclasses.dataclass(frozen=True)
class CullSettings:
    """`outlier_px`: the reprojection error above which an observation is dropped; landmarks
    must lie within [`min_depth_m`, `max_depth_m`] of their anchor (halved / doubled) and be
    re-observed by `min_keyframe_observations` keyframes within `cull_after_keyframes`."""

    outlier_px: float
    min_depth_m: float
    max_depth_m: float
    cull_after_keyframes: int
    min_keyframe_observations: int


def cull(the_map: Map, k: int, w0: int, *, settings: CullSettings) -> None:
    """Drop window observations whose error stays above `outlier_px` after the solve;
    remove landmarks whose anchor view is such an outlier, that lie behind their anchor
    or beyond `max_depth_m` (a point; a line: its nearest point, or not finite), or that
    too few keyframes re-observed."""
    s = settings
    cam = the_map.camera
    P, Lm = the_map.points, the_map.lines
    bad_p = np.zeros(len(P), bool)
    bad_l = np.zeros(len(Lm), bool)
    for j in range(w0, k + 1):
        o = the_map.observations[j]
        R, t = the_map.R_world_keyframe[j], the_map.t_world_keyframe[j]
        err = pixel_errors(cam, R, t, P.p_world[o.point_id], o.point_uv)
        keep_p = (err < s.outlier_px) & P.ok[o.point_id]
        anchor_p = P.anchor[o.point_id] == j
        bad_p[o.point_id[anchor_p & ~(err < s.outlier_px)]] = True
        err_l = line_errors(cam, R, t, Lm.m[o.line_id], Lm.v[o.line_id], o.line_uv)
        keep_l = (err_l < s.outlier_px) & Lm.ok[o.line_id]
        anchor_l = Lm.anchor[o.line_id] == j
        bad_l[o.line_id[anchor_l & ~(err_l < s.outlier_px)]] = True
        dropped_p = o.point_id[~keep_p & ~anchor_p]
        P.n_kf[dropped_p] = P.n_kf[dropped_p] - 1
        dropped_l = o.line_id[~keep_l & ~anchor_l]
        Lm.n_kf[dropped_l] = Lm.n_kf[dropped_l] - 1
        kp, kl = keep_p | anchor_p, keep_l | anchor_l
        the_map.observations[j] = KeyframeObservations(o.point_id[kp], o.point_uv[kp], o.point_ur[kp], o.line_id[kl], o.line_uv[kl], o.line_ruv[kl])
    # Depth in the anchor and re-observation.
    ids = np.flatnonzero(P.ok[:])
    a = P.anchor[ids]
    z = np.einsum("nji,nj->ni", the_map.R_world_keyframe[a], P.p_world[ids] - the_map.t_world_keyframe[a])[:, 2]
    bad_p[ids[~((z > 0.5 * s.min_depth_m) & (z < 2.0 * s.max_depth_m))]] = True
    stale = (P.born[ids] <= k - s.cull_after_keyframes) & (a >= the_map.segment_start) & (P.n_kf[ids] < s.min_keyframe_observations)
    bad_p[ids[stale]] = True
    ids_l = np.flatnonzero(Lm.ok[:])
    # Lines as points: their nearest point to the anchor camera within the depth range
    # (a solve can push a line weakly seen to infinity, where its coordinates overflow).
    a_l = Lm.anchor[ids_l]
    with np.errstate(over="ignore", invalid="ignore"):
        m_c, v_c = line_geo.to_camera(Lm.m[ids_l], Lm.v[ids_l], the_map.R_world_keyframe[a_l], the_map.t_world_keyframe[a_l])
        reach = np.linalg.norm(line_geo.closest_point_to_origin(m_c, v_c), axis=1)
    bad_l[ids_l[~(reach < 2.0 * s.max_depth_m)]] = True
    stale_l = (Lm.born[ids_l] <= k - s.cull_after_keyframes) & (Lm.anchor[ids_l] >= the_map.segment_start) & (Lm.n_kf[ids_l] < s.min_keyframe_observations)
    bad_l[ids_l[stale_l]] = True
    P.ok[np.flatnonzero(bad_p)] = False
    Lm.ok[np.flatnonzero(bad_l)] = False


def local_map(the_map: Map, k: int, w0: int) -> tuple[np.ndarray, np.ndarray]:
    """The local map: the landmarks of the current map segment (tracking matches only
    those that project into the image, so revisited places are re-associated); the
    window's own landmarks first."""
    win = [the_map.observations[j] for j in range(w0, k + 1)]
    pts = np.unique(np.concatenate([o.point_id for o in win]))
    lns = np.unique(np.concatenate([o.line_id for o in win]))
    P, Lm = the_map.points, the_map.lines
    older_p = np.flatnonzero(P.ok[:] & (P.anchor[:] >= the_map.segment_start))
    older_l = np.flatnonzero(Lm.ok[:] & (Lm.anchor[:] >= the_map.segment_start))
    points = np.concatenate([pts[P.ok[pts]], np.setdiff1d(older_p, pts)])
    lines = np.concatenate([lns[Lm.ok[lns]], np.setdiff1d(older_l, lns)])
    return points, lines
