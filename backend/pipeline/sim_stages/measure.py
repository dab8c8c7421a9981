"""Steps 1 of a Monte-Carlo keyframe: what the engine receives (the odometry measurement,
noisy pixel observations of the visible points and segments and their simulated
plane-instance labels) and the tracking of the predicted pose against the triangulated
points.

Poses are `T_world_camera` (world frame z up, metres); pixels of the world's camera; noise
σ in pixels, radians per axis and metres per axis."""

from __future__ import annotations

import dataclasses

import numpy as np

from backend.eval import sequences
from backend.geometry import so3
from backend.geometry.camera import PinholeCamera
from backend.pipeline.sim_stages.state import FrameObs, SimKeyframes, SimLandmarks
from backend.pipeline.tracking import refine_pose

MIN_TRACKED_POINTS = 6  # triangulated points a keyframe must see to refine its predicted pose


def frame_index(k: int, n: int, name: str) -> int:
    """World pose index of keyframe k in sequence `name` of n poses: a closed circle
    repeats (a), an open path returns (b)."""
    if name == "a":
        return k % n
    period = 2 * (n - 1)
    r = k % period
    return r if r < n else period - r


@dataclasses.dataclass(frozen=True)
class SimulatedKeyframe:
    """Keyframe k as the engine receives it: the true pose (`R_gt`, `t_gt`), the odometry
    measurement from keyframe k-1 (`R_odo`, `t_odo`: pose of k in k-1's camera frame;
    identity for k = 0), the pose it predicts from k-1's estimate (`R_pred`, `t_pred`; for
    k = 0 the true pose) and the noisy observations."""

    R_gt: np.ndarray
    t_gt: np.ndarray
    R_odo: np.ndarray
    t_odo: np.ndarray
    R_pred: np.ndarray
    t_pred: np.ndarray
    obs: FrameObs


def simulate_keyframe(
    world: sequences.World,
    keyframes: SimKeyframes,
    k: int,
    rng: np.random.Generator,
    *,
    sequence: str,
    pixel_sigma: float,
    rotation_sigma_rad: float,
    position_sigma_m: float,
    mislabel: float,
) -> SimulatedKeyframe:
    """Keyframe k of `world` (sequence `sequence`) after the keyframes `keyframes` holds
    (k of them). Draws from `rng`, in this order: the odometry noise (rotation, position;
    per axis), pixel noise for every point and every segment endpoint (visible or not: a
    fixed stream per step) and the instance labels (points, then segments)."""
    f = frame_index(k, len(world.t_world_camera), sequence)
    R_gt, t_gt = world.R_world_camera[f], world.t_world_camera[f]
    n_rot = rotation_sigma_rad * rng.standard_normal(3)
    n_pos = position_sigma_m * rng.standard_normal(3)
    if k == 0:
        R_est, t_est = R_gt.copy(), t_gt.copy()
        R_rel, t_rel = np.eye(3), np.zeros(3)
    else:  # odometry: the noisy relative pose from the previous keyframe, applied to its estimate
        R_prev, t_prev = keyframes.R_gt[k - 1], keyframes.t_gt[k - 1]
        R_rel = R_prev.T @ R_gt @ so3.exp(n_rot)
        t_rel = R_prev.T @ (t_gt - t_prev) + n_pos
        R_est = keyframes.R_est[k - 1] @ R_rel
        t_est = keyframes.t_est[k - 1] + keyframes.R_est[k - 1] @ t_rel

    cam = world.camera
    p_cam = (world.points - t_gt) @ R_gt
    uv = cam.project(p_cam) + pixel_sigma * rng.standard_normal((len(world.points), 2))
    ok = (p_cam[:, 2] > sequences.MIN_DEPTH_M) & cam.in_image(cam.project(p_cam))
    seg_cam = (world.segments - t_gt) @ R_gt
    seg_uv = cam.project(seg_cam) + pixel_sigma * rng.standard_normal((len(world.segments), 2, 2))
    ok_l = np.all((seg_cam[..., 2] > sequences.MIN_DEPTH_M) & cam.in_image(cam.project(seg_cam)), axis=1)
    labels_p = instance_labels(world.point_plane, ok, rng, mislabel=mislabel)
    labels_l = instance_labels(world.segment_plane, ok_l, rng, mislabel=mislabel)
    ids_p, ids_l = np.flatnonzero(ok), np.flatnonzero(ok_l)
    obs = FrameObs(ids_p, uv[ids_p], labels_p[ids_p], ids_l, seg_uv[ids_l].reshape(-1, 4), labels_l[ids_l])
    return SimulatedKeyframe(R_gt, t_gt, R_rel, t_rel, R_est, t_est, obs)


def instance_labels(true_label: np.ndarray, visible: np.ndarray, rng: np.random.Generator, *, mislabel: float) -> np.ndarray:
    """Simulated instance segmentation of every feature (visible or not): its wall id, or
    with probability `mislabel` another wall visible in this image (-1 if none is)."""
    u = rng.random(len(true_label))
    pick = rng.random(len(true_label))
    labels = true_label.copy()
    walls = np.unique(true_label[visible])
    wrong = u < mislabel
    for i in np.flatnonzero(wrong):
        others = walls[walls != true_label[i]]
        labels[i] = others[int(pick[i] * len(others))] if len(others) else -1
    return labels


def track_keyframe(landmarks: SimLandmarks, obs: FrameObs, R_pred: np.ndarray, t_pred: np.ndarray, *, camera: PinholeCamera, pixel_sigma: float) -> tuple[np.ndarray, np.ndarray]:
    """The keyframe's pose: the predicted one refined against the triangulated points it
    observes (σ `pixel_sigma`, px) when it sees at least MIN_TRACKED_POINTS, else the
    prediction."""
    known = obs.point_id[landmarks.p_ok[obs.point_id]]
    if len(known) < MIN_TRACKED_POINTS:
        return R_pred, t_pred
    sel = landmarks.p_ok[obs.point_id]
    ref = refine_pose(camera, R_pred, t_pred, landmarks.p_world[known], obs.point_uv[sel], sigma_px=pixel_sigma)
    return ref.R_world_camera, ref.t_world_camera
