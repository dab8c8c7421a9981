"""The monocular start (structure from motion, VIO): the relative pose of a frame to the
map segment's first keyframe from the essential matrix of the features followed between
them, and the first points, with the median depth set to `init_median_depth` (an arbitrary
unit until the IMU gives the scale). The pair is accepted only with enough parallax after
the gyroscope's rotation, enough parallax after the best pure rotation, and a rotation that
agrees with the gyroscope's (backend.pipeline.vio_engine's docstring says why).

World frame z up, metres (up to the start's scale); pixels of the rectified left camera."""

from __future__ import annotations

import cv2
import numpy as np

from backend.frontend.points import Keypoints
from backend.geometry import so3
from backend.geometry.camera import PinholeCamera
from backend.mapping.triangulation import triangulate_two_views
from backend.pipeline.stages.follow import with_followed_keypoints
from backend.pipeline.stages.track import Tracked
from backend.pipeline.vio_settings import VioSettings

StartPair = tuple[Tracked, np.ndarray, np.ndarray, np.ndarray, Keypoints]
"""(the frame's pose, the first keyframe's keypoint indices, the frame's keypoint indices,
the points in the world frame (N, 3), the frame's keypoints grown by the followed ones)."""


def two_view_start(
    cam: PinholeCamera,
    s: VioSettings,
    *,
    ids: np.ndarray,
    uv0: np.ndarray,
    uv1: np.ndarray,
    R_01_imu: np.ndarray,
    dt_s: float,
    R_world_kf0: np.ndarray,
    t_world_kf0: np.ndarray,
    kp: Keypoints,
    image: np.ndarray,
) -> StartPair | None:
    """The start from the first keyframe's keypoints `ids` at pixels `uv0`, followed to `uv1`
    in the frame (`image`, keypoints `kp`), `dt_s` seconds later, the gyroscope's rotation
    `R_01_imu` (the frame's camera in the keyframe's), and the keyframe's pose; None while
    the pair does not qualify (module docstring)."""
    x0 = cam.normalize(uv0) @ R_01_imu  # the first view's rays rotated into frame i
    with np.errstate(divide="ignore", invalid="ignore"):
        parallax = np.linalg.norm(cam.project(x0) - uv1, axis=1)
    if not np.nanmedian(parallax) >= s.init_parallax_px:
        return None
    E, inl = cv2.findEssentialMat(uv0, uv1, cam.K, method=cv2.RANSAC, prob=0.999, threshold=1.0)
    if E is None or E.shape != (3, 3):
        return None
    _, R_10, t_10, inl = cv2.recoverPose(E, uv0, uv1, cam.K, mask=inl)
    inlier = inl.ravel() > 0
    if inlier.sum() < s.init_min_matches // 2:
        return None
    # Parallax the best pure rotation leaves (the gyro's rotation carries its unknown bias,
    # which alone can make 15 px over half a second): a turn, or a sideways step in front
    # of one depth, has none, and its essential matrix gets the translation wrong.
    if rotation_free_parallax_px(cam, uv0[inlier], uv1[inlier]) < s.init_rotation_free_parallax_px:
        return None
    R_w0, t_w0 = R_world_kf0, t_world_kf0
    R_01 = R_10.T  # camera 1 in camera 0
    # A rotation the gyroscope contradicts is a wrong decomposition (too little translation
    # for the essential matrix to separate it from the rotation): wait for more parallax.
    tolerance_rad = np.radians(s.init_gyro_agreement_deg) + s.init_gyro_bias_bound_rad_s * dt_s
    if np.linalg.norm(so3.log(R_01.T @ R_01_imu)) > tolerance_rad:
        return None
    t_01 = -R_10.T @ t_10.ravel()
    Rs = np.stack([R_w0, R_w0 @ R_01])
    ts = np.stack([t_w0, t_w0 + R_w0 @ t_01])
    sel = np.flatnonzero(inlier)
    pts = triangulate_two_views(cam.normalize(uv0[sel])[:, :2], cam.normalize(uv1[sel])[:, :2], Rs[0], ts[0], Rs[1], ts[1])
    z0 = (pts - ts[0]) @ Rs[0]
    z1 = (pts - ts[1]) @ Rs[1]
    good = np.all(np.isfinite(pts), axis=1) & (z0[:, 2] > 0) & (z1[:, 2] > 0)
    if good.sum() < s.init_min_matches:
        return None
    scale = s.init_median_depth / float(np.median(z0[good, 2]))
    t1 = t_w0 + scale * (R_w0 @ t_01)
    pts = ts[0] + scale * (pts - ts[0])
    sel = sel[good]
    # The followed features become keypoints of frame i: the ORB keypoint within 2 px, or
    # a new keypoint with its ORB descriptor computed at the followed pixel.
    kp, nearest = with_followed_keypoints(kp, uv1[sel], image)
    keep = nearest >= 0
    tracked = Tracked(Rs[1], t1, np.zeros(0, np.int64), int(keep.sum()), True)
    return tracked, ids[sel][keep], nearest[keep], pts[good][keep], kp


def rotation_free_parallax_px(camera, uv0: np.ndarray, uv1: np.ndarray) -> float:
    """Median pixel distance (image 1) between `uv1` and `uv0` moved by the rotation that
    best explains the pair alone (Kabsch on the unit rays, least squares): the parallax
    that only a translation with depth differences makes; 0 for fewer than 3 pairs."""
    if len(uv0) < 3:
        return 0.0
    b0 = camera.normalize(uv0)
    b1 = camera.normalize(uv1)
    b0 /= np.linalg.norm(b0, axis=1, keepdims=True)
    b1 /= np.linalg.norm(b1, axis=1, keepdims=True)
    U, _, Vt = np.linalg.svd(b1.T @ b0)
    R_10 = U @ np.diag([1.0, 1.0, np.sign(np.linalg.det(U @ Vt))]) @ Vt  # b1 ≈ R_10 b0
    r = b0 @ R_10.T
    with np.errstate(divide="ignore", invalid="ignore"):
        d = np.linalg.norm(camera.project(r) - uv1, axis=1)
    d = d[np.isfinite(d) & (r[:, 2] > 0)]
    return float(np.median(d)) if len(d) else 0.0
