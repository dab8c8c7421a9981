"""Step 4 of a Monte-Carlo keyframe, the window problem: keyframes [w0, k] are optimized,
the `fixed_horizon` keyframes before w0 that observe window landmarks are held fixed (as is
a landmark's anchor view, however old), odometry links consecutive keyframes whose later
one is in the window, and while nothing is held fixed a prior holds the first keyframe at
its true pose (the gauge, as in the study).

Poses `T_world_camera` (world frame z up, metres); points by inverse depth in their anchor
keyframe, lines in the orthonormal representation; pixels of `camera`."""

from __future__ import annotations

import numpy as np

from backend.geometry import line as line_geo
from backend.geometry.camera import PinholeCamera
from backend.geometry.se3 import Poses
from backend.mapping import coplanar
from backend.mapping.window import Window
from backend.optim.problem import Observations, Odometry, PosePrior, ProblemData
from backend.pipeline.sim_stages.state import FrameObs, SimKeyframes, SimLandmarks

PRIOR_SIGMA = 1e-6  # rad and m: the gauge prior on the first keyframe
FALLBACK_DEPTH_M = 4.0  # a point's initial anchor depth where its estimate lies behind the anchor (< 1 mm)


def window_start(k: int, *, window: int) -> int:
    """The first keyframe w0 of the window [w0, k] of `window` keyframes."""
    return max(0, k - window + 1)


def assemble_window(
    landmarks: SimLandmarks,
    observations: dict[int, FrameObs],
    keyframes: SimKeyframes,
    planes: coplanar.PlaneSet,
    k: int,
    *,
    camera: PinholeCamera,
    window: int,
    fixed_horizon: int,
    min_plane_support: int,
    pixel_sigma: float,
    odometry_rotation_sigma_rad: float,
    odometry_position_sigma_m: float,
) -> Window:
    """The problem of the window ending at keyframe k (module docstring): its triangulated
    landmarks with their observations from keyframe w0 - `fixed_horizon` on (and their
    anchor views), the planes with at least `min_plane_support` of those landmarks, the
    estimated poses as the start; observations σ `pixel_sigma` (px), odometry σ per axis
    (rad, m; at least 1e-6)."""
    w0 = window_start(k, window=window)
    oldest = max(0, w0 - fixed_horizon)
    win_obs = [observations[i] for i in range(w0, k + 1)]
    pts = np.unique(np.concatenate([o.point_id for o in win_obs]))
    pts = pts[landmarks.p_ok[pts]]
    lns = np.unique(np.concatenate([o.line_id for o in win_obs]))
    lns = lns[landmarks.l_ok[lns]]
    kf_p, lm_p, uv_p = landmarks.views(observations, "point", pts)
    kf_l, lm_l, uv_l = landmarks.views(observations, "line", lns)
    use_p = (kf_p >= oldest) | (kf_p == landmarks.p_anchor[lm_p])
    use_l = (kf_l >= oldest) | (kf_l == landmarks.l_anchor[lm_l])
    kf_p, lm_p, uv_p = kf_p[use_p], lm_p[use_p], uv_p[use_p]
    kf_l, lm_l, uv_l = kf_l[use_l], lm_l[use_l], uv_l[use_l]
    kfs = np.unique(np.concatenate([kf_p, kf_l, np.arange(w0, k + 1), [max(w0 - 1, 0)]]))

    def to_local(keyframe: np.ndarray) -> np.ndarray:  # keyframe index -> problem pose
        return np.searchsorted(kfs, keyframe)

    p_local = np.full(len(landmarks.p_ok), -1)
    p_local[pts] = np.arange(len(pts))
    l_local = np.full(len(landmarks.l_ok), -1)
    l_local[lns] = np.arange(len(lns))

    # A plane is optimized only with enough of its features in the window; with a few it
    # would swing freely (its features are then free landmarks here, and the plane
    # follows its whole support by refitting).
    owner = np.concatenate([landmarks.p_plane[pts], landmarks.l_plane[lns]])
    support = np.bincount(owner[owner >= 0], minlength=len(planes.n))
    chosen = np.flatnonzero(support >= min_plane_support)
    q_local = np.full(len(planes.n) + 1, -1)
    q_local[chosen] = np.arange(len(chosen))

    R, t = keyframes.R_est[kfs].copy(), keyframes.t_est[kfs].copy()
    fixed = kfs < w0
    a_p = to_local(landmarks.p_anchor[pts])
    p_a = np.einsum("nji,nj->ni", R[a_p], landmarks.p_world[pts] - t[a_p])
    rho = 1.0 / np.where(p_a[:, 2] > 1e-3, p_a[:, 2], FALLBACK_DEPTH_M)
    U, phi = line_geo.to_orthonormal(landmarks.l_m[lns], landmarks.l_v[lns]) if len(lns) else (np.zeros((0, 3, 3)), np.zeros((0, 2)))

    # Odometry between consecutive keyframes whose later one is in the window.
    j = np.arange(max(w0, 1), k + 1)
    i = j - 1
    odometry = Odometry(
        i=to_local(i),
        j=to_local(j),
        R_i_j=keyframes.R_odo[j],
        t_i_j=keyframes.t_odo[j],
        sigma_rot=max(odometry_rotation_sigma_rad, 1e-6),
        sigma_pos=max(odometry_position_sigma_m, 1e-6),
    )
    prior = None
    if not np.any(fixed):  # the gauge: the first keyframe at its true pose
        prior = PosePrior(index=np.array([0]), R_world_camera=keyframes.R_gt[kfs[:1]], t_world_camera=keyframes.t_gt[kfs[:1]], sigma_rot=PRIOR_SIGMA, sigma_pos=PRIOR_SIGMA)
    data = ProblemData(
        camera=camera,
        poses=Poses(R, t),
        point_anchor=a_p,
        point_anchor_uv=landmarks.p_anchor_uv[pts],
        point_rho=rho,
        point_plane=q_local[landmarks.p_plane[pts]],
        point_obs=Observations(p_local[lm_p], to_local(kf_p), uv_p, np.zeros((len(kf_p), 3))),
        line_anchor=to_local(landmarks.l_anchor[lns]),
        line_anchor_uv=landmarks.l_anchor_uv[lns],
        line_U=U,
        line_phi=phi,
        line_plane=q_local[landmarks.l_plane[lns]],
        line_obs=Observations(l_local[lm_l], to_local(kf_l), uv_l, np.zeros((len(kf_l), 3))),
        plane_n=np.array(planes.n).reshape(-1, 3)[chosen],
        plane_d=np.array(planes.d)[chosen],
        odometry=odometry,
        prior=prior,
        sigma_px=pixel_sigma,
        fixed_poses=fixed,
    )
    return Window(k, data, kfs, pts, lns, chosen)
