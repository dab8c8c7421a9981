"""Step 3 of a Monte-Carlo keyframe, the co-planar detection (paper §III-A) on its
labelled features, and the planes' upkeep after a solve: planes a variant does not
optimize follow their landmarks.

Planes `n·X + d = 0` in the world frame (z up, metres); poses `T_world_camera`; pixels of
`camera`."""

from __future__ import annotations

import numpy as np

from backend.geometry.camera import PinholeCamera
from backend.geometry.se3 import Poses
from backend.mapping import coplanar
from backend.pipeline.sim_stages.state import FrameObs, SimLandmarks
from backend.pipeline.snapshot import Detection


def detect_planes(
    landmarks: SimLandmarks,
    obs: FrameObs,
    new_points: np.ndarray,
    new_lines: np.ndarray,
    rng: np.random.Generator,
    *,
    planes: coplanar.PlaneSet,
    camera: PinholeCamera,
    poses: Poses,
    settings: coplanar.CoplanarSettings,
) -> tuple[Detection, tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]]:
    """Co-planar detection on a keyframe's triangulated features (observations `obs`,
    grouped by their instance labels): accepted planes merge into or extend `planes`, and
    the landmarks' plane ids are set; then the new landmarks the detection did not place
    are tested against the existing planes (:func:`associate_new`). Returns the detection
    and the features' RANSAC states (point ids, states, line ids, states)."""
    p_sel = landmarks.p_ok[obs.point_id]
    l_sel = landmarks.l_ok[obs.line_id]
    p_ids, l_ids = obs.point_id[p_sel], obs.line_id[l_sel]
    det = coplanar.detect_keyframe_planes(
        point_ids=p_ids,
        point_label=obs.point_label[p_sel],
        p_world=landmarks.p_world[p_ids],
        line_ids=l_ids,
        line_label=obs.line_label[l_sel],
        segments_world=landmarks.segments_world(l_ids, camera=camera, poses=poses),
        point_plane=landmarks.p_plane,
        line_plane=landmarks.l_plane,
        planes=planes,
        rng=rng,
        settings=settings,
    )
    associate_new(landmarks, new_points, new_lines, planes=planes, camera=camera, poses=poses, threshold_m=settings.threshold_m)
    detection = Detection(det.instance, det.candidates, det.inliers, det.accepted, det.plane)
    return detection, (p_ids, det.point_state, l_ids, det.line_state)


def associate_new(landmarks: SimLandmarks, new_points: np.ndarray, new_lines: np.ndarray, *, planes: coplanar.PlaneSet, camera: PinholeCamera, poses: Poses, threshold_m: float) -> None:
    """New landmarks without a plane join the nearest existing plane they lie on (Eq. 4
    distance below `threshold_m`, m) when they fall within its landmarks' hull (with a
    margin)."""
    if not planes.n:
        return
    pts = new_points[landmarks.p_plane[new_points] < 0]
    lns = new_lines[landmarks.l_plane[new_lines] < 0]
    N, D = planes.arrays()
    q_p, q_l = coplanar.associate_to_planes(
        landmarks.p_world[pts],
        landmarks.segments_world(lns, camera=camera, poses=poses),
        N,
        D,
        [landmarks.hull(q, planes, camera=camera, poses=poses) for q in range(len(N))],
        threshold_m=threshold_m,
    )
    landmarks.p_plane[pts[q_p >= 0]] = q_p[q_p >= 0]
    landmarks.l_plane[lns[q_l >= 0]] = q_l[q_l >= 0]


def refit_unused_planes(landmarks: SimLandmarks, planes: coplanar.PlaneSet, optimized: set[int], *, camera: PinholeCamera, poses: Poses) -> None:
    """Planes not in `optimized` (ids the solve did not estimate) follow their landmarks: a
    least-squares fit to their support, where there is one."""
    for q in range(len(planes.n)):
        fit = None if q in optimized else coplanar.refit_plane(planes.n[q], landmarks.plane_support(q, camera=camera, poses=poses))
        if fit is not None:
            planes.n[q], planes.d[q] = fit
