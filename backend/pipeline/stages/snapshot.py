"""The last stage of a keyframe: the frozen snapshot of the map that the viewer draws and
the command line writes (keyframe trajectory and truth, landmarks with their detection
state, planes with their hulls, the solve's report, running accuracy)."""

from __future__ import annotations

import numpy as np

from backend.common.allocator import own_mapping
from backend.eval.trajectory import ate_rmse, translational_rmse
from backend.mapping.map import Map
from backend.optim.structure import HessianStructure
from backend.pipeline.snapshot import (
    Detection,
    KeyframeImage,
    LineLandmarks,
    Metrics,
    OptimizationReport,
    PlaneLandmark,
    PointLandmarks,
    Snapshot,
    Tracking,
    Trajectory,
    drawable_points,
    frozen,
)


def build_snapshot(
    the_map: Map,
    k: int,
    w0: int,
    detection: Detection,
    det_state: tuple,
    report: OptimizationReport,
    hessian: HessianStructure | None,
    *,
    source: str,
    image: KeyframeImage | None,
    tracking: Tracking | None,
    message: str,
) -> Snapshot:
    """Keyframe k's snapshot; the window is [w0, k] (its poses are copied, the older ones
    shared with earlier snapshots); `det_state`: the features' detection states (point
    ids, states, line ids, states)."""
    n = k + 1
    estimate = Trajectory(
        (
            (the_map.keyframe_stamp_ns.prefix(w0), the_map.R_world_keyframe.prefix(w0), the_map.t_world_keyframe.prefix(w0)),
            (frozen(the_map.keyframe_stamp_ns[w0:n].copy()), frozen(the_map.R_world_keyframe[w0:n].copy()), frozen(the_map.t_world_keyframe[w0:n].copy())),
        )
    )
    gt = Trajectory.of(the_map.keyframe_stamp_ns.prefix(n), the_map.R_world_keyframe_true.prefix(n), the_map.t_world_keyframe_true.prefix(n))
    P, Lm = the_map.points, the_map.lines
    p_ids, p_world = drawable_points(P.p_world[:], np.flatnonzero(P.ok[:]))
    p_det = np.zeros(len(P), np.uint8)
    p_det[det_state[0]] = det_state[1]
    l_ids = np.flatnonzero(Lm.ok[:])
    l_det = np.zeros(len(Lm), np.uint8)
    l_det[det_state[2]] = det_state[3]
    i32 = np.int32  # the snapshot's integers (snapshot.PointLandmarks)
    kept = own_mapping  # kept for as long as the debugger keeps the snapshot (backend/common/allocator.py)
    points = PointLandmarks(
        frozen(kept(p_ids.astype(i32))),
        frozen(kept(p_world)),
        frozen(kept(P.plane[p_ids].astype(i32))),
        frozen(kept(P.anchor[p_ids].astype(i32))),
        frozen(kept(p_det[p_ids])),
    )
    lines = LineLandmarks(frozen(l_ids.astype(i32)), frozen(the_map.segments_world(l_ids)), frozen(Lm.plane[l_ids].astype(i32)), frozen(Lm.anchor[l_ids].astype(i32)), frozen(l_det[l_ids]))
    planes = []
    Q = len(the_map.planes)
    p_plane, l_plane = P.plane[p_ids], Lm.plane[l_ids]
    count_p = np.bincount(p_plane[p_plane >= 0], minlength=Q)
    count_l = np.bincount(l_plane[l_plane >= 0], minlength=Q)
    hulls = the_map.hulls()
    for q in range(Q):
        n_p, n_l = int(count_p[q]), int(count_l[q])
        if n_p + n_l == 0:
            continue
        planes.append(
            PlaneLandmark(
                id=q,
                n=frozen(np.array(the_map.planes.n[q])),
                d=float(the_map.planes.d[q]),
                hull_world=frozen(hulls[q]),
                n_points=n_p,
                n_lines=n_l,
                last_consensus=the_map.planes.consensus[q][0],
                last_candidates=the_map.planes.consensus[q][1],
            )
        )
    valid = np.isfinite(gt.t_world_camera[:, 0])
    t_est, t_gt = estimate.t_world_camera[valid], gt.t_world_camera[valid]
    rmse = 100.0 * translational_rmse(t_est, t_gt) if len(t_gt) else float("nan")
    ate = 100.0 * ate_rmse(t_est, t_gt, align="se3") if len(t_gt) >= 3 else rmse
    return Snapshot(
        keyframe=k,
        timestamp_ns=int(the_map.keyframe_stamp_ns[k]),
        source=source,
        camera=the_map.camera,
        estimate=estimate,
        ground_truth=gt if valid.any() else None,
        window=frozen(np.arange(w0, n)),
        points=points,
        lines=lines,
        planes=tuple(planes),
        detection=detection,
        report=report,
        hessian=hessian,
        metrics=Metrics(rmse_cm=rmse, ate_cm=ate),
        message=message,
        image=image,
        tracking=tracking,
    )
