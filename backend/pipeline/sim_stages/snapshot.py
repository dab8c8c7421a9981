"""The last step of a Monte-Carlo keyframe: the frozen snapshot the viewer draws and `coplanar
sim` reports (keyframe trajectory and truth, landmarks with their detection state, planes
with their hulls, the solve's report, running accuracy in cm).

Poses `T_world_camera` (world frame z up, metres); pixels of `camera`."""

from __future__ import annotations

import numpy as np

from backend.eval.trajectory import ate_rmse, translational_rmse
from backend.geometry.camera import PinholeCamera
from backend.mapping import coplanar
from backend.optim.structure import HessianStructure
from backend.pipeline.sim_stages.state import SimKeyframes, SimLandmarks
from backend.pipeline.snapshot import (
    Detection,
    LineLandmarks,
    Metrics,
    OptimizationReport,
    PlaneLandmark,
    PointLandmarks,
    Snapshot,
    Trajectory,
    drawable_points,
    frozen,
)


def build_snapshot(
    landmarks: SimLandmarks,
    keyframes: SimKeyframes,
    planes: coplanar.PlaneSet,
    k: int,
    w0: int,
    detection: Detection,
    det_state: tuple,
    report: OptimizationReport,
    hessian: HessianStructure,
    *,
    camera: PinholeCamera,
    source: str,
) -> Snapshot:
    """Keyframe k's snapshot; the window is [w0, k] (its poses are copied, the older ones
    shared with earlier snapshots); `det_state`: the features' detection states (point ids,
    states, line ids, states). Every plane is listed, with its hull (possibly empty)."""
    kfs = keyframes
    n = k + 1
    estimate = Trajectory(
        (
            (kfs.stamp.prefix(w0), kfs.R_est.prefix(w0), kfs.t_est.prefix(w0)),
            (frozen(kfs.stamp[w0:n].copy()), frozen(kfs.R_est[w0:n].copy()), frozen(kfs.t_est[w0:n].copy())),
        )
    )
    gt = Trajectory.of(kfs.stamp.prefix(n), kfs.R_gt.prefix(n), kfs.t_gt.prefix(n))
    L = landmarks
    poses = kfs.estimate()
    p_ids, p_world = drawable_points(L.p_world, np.flatnonzero(L.p_ok))
    p_det = np.zeros(len(L.p_ok), np.uint8)
    p_det[det_state[0]] = det_state[1]
    l_ids = np.flatnonzero(L.l_ok)
    l_det = np.zeros(len(L.l_ok), np.uint8)
    l_det[det_state[2]] = det_state[3]
    segs = L.segments_world(l_ids, camera=camera, poses=poses)
    i32 = np.int32  # the snapshot's integers (snapshot.PointLandmarks)
    points = PointLandmarks(frozen(p_ids.astype(i32)), frozen(p_world), frozen(L.p_plane[p_ids].astype(i32)), frozen(L.p_anchor[p_ids].astype(i32)), frozen(p_det[p_ids]))
    lines = LineLandmarks(frozen(l_ids.astype(i32)), frozen(segs), frozen(L.l_plane[l_ids].astype(i32)), frozen(L.l_anchor[l_ids].astype(i32)), frozen(l_det[l_ids]))
    plane_marks = []
    for q in range(len(planes.n)):
        hull = L.hull(q, planes, camera=camera, poses=poses)
        plane_marks.append(
            PlaneLandmark(
                id=q,
                n=frozen(np.array(planes.n[q])),
                d=float(planes.d[q]),
                hull_world=frozen(hull),
                n_points=int(np.sum(L.p_plane == q)),
                n_lines=int(np.sum(L.l_plane == q)),
                last_consensus=planes.consensus[q][0],
                last_candidates=planes.consensus[q][1],
            )
        )
    t_est = estimate.t_world_camera
    rmse = 100.0 * translational_rmse(t_est, gt.t_world_camera)
    ate = 100.0 * ate_rmse(t_est, gt.t_world_camera, align="se3") if n >= 3 else rmse
    return Snapshot(
        keyframe=k,
        timestamp_ns=int(kfs.stamp[k]),
        source=source,
        camera=camera,
        estimate=estimate,
        ground_truth=gt,
        window=frozen(np.arange(w0, n)),
        points=points,
        lines=lines,
        planes=tuple(plane_marks),
        detection=detection,
        report=report,
        hessian=hessian,
        metrics=Metrics(rmse_cm=rmse, ate_cm=ate),
    )
