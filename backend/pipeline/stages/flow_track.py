"""A stereo frame that the map cannot place, placed by optical flow from the last placed
frame (the stereo engine's last resort before a frame is lost).

Why: on a bare wall ORB finds a few dozen corners at its FAST threshold, too few to match
the map, and those it finds on the paint's grain do not repeat from frame to frame; but
that grain still has gradient enough for Lucas-Kanade. So the reference frame (the last
frame whose pose is known, with its left and right images) gets Shi-Tomasi corners at a
low quality level, their depth from its own right image (rectified: a search along the
same row, then flow from the best match, forward-backward checked; `follow_along_row`),
and the corners followed into the frame's left image (forward-backward checked; from the
reference's pixels and, given the motion model's pose, from where it puts their points)
give 3D-2D matches for EPnP-RANSAC and a robust refinement (`backend.pipeline.tracking`);
an inlier must also be found in the frame's own right image where the pose puts it. The pose stands only with
`min_inliers` inliers and a translation that they constrain to `max_translation_std_m`
(largest axis of the inliers' Gauss-Newton covariance, both images' columns at
`pixel_sigma`): a frame-to-frame
pose, so its error adds up while the map cannot place frames (as visual odometry's does),
and the map's tracking takes over again at the next frame that it can place.

Frames: world z up, metres; pixels of the rectified left camera; images 8-bit grey.
"""

from __future__ import annotations

import dataclasses

import cv2
import numpy as np

from backend.frontend.flow import follow, follow_along_row
from backend.geometry.camera import PinholeCamera
from backend.pipeline.tracking import pixel_errors, pnp_ransac, refine_pose, reprojection, translation_std_m


@dataclasses.dataclass(frozen=True)
class FlowTrackSettings:
    """Corners: at most `max_corners` (Shi-Tomasi quality `quality_level` of the strongest,
    `min_distance_px` apart); stereo: rows within `max_row_px`, disparity at least
    `min_disparity_px`, depth within [`min_depth_m`, `max_depth_m`]; the pose: EPnP-RANSAC
    (3 px), refined with a Cauchy width `cauchy` at `pixel_sigma`, inliers within
    `outlier_px` in the left and the right image, at least `min_inliers` of them,
    translation standard deviation at most `max_translation_std_m`."""

    max_corners: int = 400
    quality_level: float = 1e-5  # of the strongest corner: at 0.001 a dark post in view hid the grain (`low-texture` seed 3, frame 184: 25 corners, not 400)
    min_distance_px: float = 12.0
    max_row_px: float = 1.0
    min_disparity_px: float = 1.0
    min_depth_m: float = 0.2
    max_depth_m: float = 40.0
    pixel_sigma: float = 0.5  # the forward-backward check keeps flow that returns within 0.5 px
    cauchy: float = 2.0
    outlier_px: float = 2.0
    min_inliers: int = 20
    max_translation_std_m: float = 0.02


@dataclasses.dataclass(frozen=True, eq=False)
class FlowReference:
    """The last placed frame: its index, left and right images (read-only) and pose
    (`R_world_camera`, `t_world_camera`). Immutable, so an engine checkpoint shares it
    instead of copying the images."""

    frame: int
    left: np.ndarray
    right: np.ndarray
    R_world_camera: np.ndarray
    t_world_camera: np.ndarray

    @staticmethod
    def of(frame: int, left: np.ndarray, right: np.ndarray, R_world_camera: np.ndarray, t_world_camera: np.ndarray) -> FlowReference:
        arrays = [np.array(a) for a in (left, right, R_world_camera, t_world_camera)]
        for a in arrays:
            a.flags.writeable = False
        return FlowReference(frame, *arrays)

    def __deepcopy__(self, memo: dict) -> FlowReference:
        return self

    def __copy__(self) -> FlowReference:
        return self


@dataclasses.dataclass(frozen=True)
class FlowPose:
    """A frame's pose from flow (`R_world_camera`, `t_world_camera`), its inliers, the
    translation's standard deviation (m) and whether it stands (`ok`)."""

    R_world_camera: np.ndarray
    t_world_camera: np.ndarray
    inliers: int
    translation_std_m: float
    ok: bool


def stereo_corners(camera: PinholeCamera, left: np.ndarray, right: np.ndarray, s: FlowTrackSettings) -> tuple[np.ndarray, np.ndarray]:
    """Corners of `left` with stereo depth: pixels (N, 2) and points in the left camera's
    frame (N, 3), metres (module docstring)."""
    found = cv2.goodFeaturesToTrack(left, maxCorners=s.max_corners, qualityLevel=s.quality_level, minDistance=s.min_distance_px)
    if found is None or camera.baseline <= 0.0:
        return np.zeros((0, 2)), np.zeros((0, 3))
    uv = found.reshape(-1, 2).astype(float)
    uv_right, ok = _in_right(camera, left, right, uv, s)
    disparity = uv[:, 0] - uv_right[:, 0]
    ok &= (np.abs(uv_right[:, 1] - uv[:, 1]) <= s.max_row_px) & (disparity >= s.min_disparity_px)
    uv, disparity = uv[ok], disparity[ok]
    z = camera.fx * camera.baseline / disparity
    near = (z >= s.min_depth_m) & (z <= s.max_depth_m)
    uv, z = uv[near], z[near]
    return uv, camera.normalize(uv) * z[:, None]


def track_by_flow(
    camera: PinholeCamera,
    reference: FlowReference,
    left: np.ndarray,
    right: np.ndarray,
    *,
    settings: FlowTrackSettings,
    seed: int = 0,
    R_world_predicted: np.ndarray | None = None,
    t_world_predicted: np.ndarray | None = None,
) -> FlowPose:
    """The pose of the frame whose rectified pair is `left`, `right`, from `reference` by
    flow (module docstring). An inlier must also agree with the frame's own stereo: followed
    into `right`, it lies within `outlier_px` of where the pose puts it there (a wrong
    depth at the reference, e.g. flow into its right image caught on the grain's repeat, is
    what the left image alone cannot see: consistent wrong depths fit a wrong pose). With
    the frame's predicted pose (`R_world_predicted`, `t_world_predicted`: camera to world,
    metres; the motion model's) the flow is also started where that pose puts each corner's
    point, and the placed pose with more inliers stands: a turn of 2-3° moves a faint grain
    beyond the pyramid's reach, and flow that stays where it started fits a pose near the
    reference's with a few dozen inliers (`low-texture` seed 0, frame 6: 27 inliers, 9 cm
    off); a start from the predicted rotation alone left `low-texture` at speed 3 with 6-7
    lost frames on the tuning seeds, from the pose with none. `ok`
    False where too few corners, matches or inliers are found or the translation is not
    constrained enough."""
    s = settings
    R0, t0 = reference.R_world_camera, reference.t_world_camera
    fail = FlowPose(R0.copy(), t0.copy(), 0, float("inf"), False)
    uv_ref, p_ref = stereo_corners(camera, reference.left, reference.right, s)
    if len(uv_ref) < s.min_inliers:
        return fail
    pose = _pose_by_flow(camera, reference, left, right, uv_ref, p_ref, s, seed=seed, uv_guess=None)
    if R_world_predicted is None or t_world_predicted is None:
        return pose
    p_predicted = (p_ref @ R0.T + t0 - t_world_predicted) @ R_world_predicted  # the corners' points in the predicted camera
    guess = np.full((len(p_ref), 2), np.nan)
    ahead = p_predicted[:, 2] > s.min_depth_m
    guess[ahead] = camera.project(p_predicted[ahead])
    predicted = _pose_by_flow(camera, reference, left, right, uv_ref, p_ref, s, seed=seed, uv_guess=guess)
    return predicted if (predicted.ok, predicted.inliers) > (pose.ok, pose.inliers) else pose


def _pose_by_flow(
    camera: PinholeCamera,
    reference: FlowReference,
    left: np.ndarray,
    right: np.ndarray,
    uv_ref: np.ndarray,
    p_ref: np.ndarray,
    s: FlowTrackSettings,
    *,
    seed: int,
    uv_guess: np.ndarray | None,
) -> FlowPose:
    """`track_by_flow` for the reference's corners `uv_ref` (N, 2) with points `p_ref` (N, 3)
    in its camera, the flow started at the reference's pixels (`uv_guess` None) or at
    `uv_guess` (N, 2; NaN rows at their own pixels)."""
    R0, t0 = reference.R_world_camera, reference.t_world_camera
    fail = FlowPose(R0.copy(), t0.copy(), 0, float("inf"), False)
    uv, ok = follow(reference.left, left, uv_ref, camera, uv_guess=uv_guess)
    if np.count_nonzero(ok) < s.min_inliers:
        return fail
    p_world = p_ref[ok] @ R0.T + t0
    uv = uv[ok]
    pose = pnp_ransac(camera, p_world, uv, min_inliers=s.min_inliers, seed=seed)
    if pose is None:
        return fail
    R, t, inlier = pose
    ref = refine_pose(camera, R, t, p_world[inlier], uv[inlier], sigma_px=s.pixel_sigma, cauchy=s.cauchy)
    R, t = ref.R_world_camera, ref.t_world_camera
    uv_right = _right_pixels(camera, left, right, uv, s)
    keep = (pixel_errors(camera, R, t, p_world, uv) < s.outlier_px) & (_right_errors(camera, R, t, p_world, uv_right) < s.outlier_px)
    n = int(np.count_nonzero(keep))
    if n < s.min_inliers:
        return FlowPose(R, t, n, float("inf"), False)
    ref = refine_pose(camera, R, t, p_world[keep], uv[keep], sigma_px=s.pixel_sigma, cauchy=s.cauchy)
    R, t = ref.R_world_camera, ref.t_world_camera
    _, J_left, _ = reprojection(camera, R, t, p_world[keep], uv[keep])
    _, J_right, _ = reprojection(camera, R, t, p_world[keep], uv_right[keep], offset_camera=camera.offset_right)
    std_m = translation_std_m(np.concatenate([J_left.reshape(-1, 6), J_right[:, 0]]) / s.pixel_sigma)  # the right image measures u (its row is the left's)
    return FlowPose(R, t, n, std_m, bool(std_m <= s.max_translation_std_m))


def _right_pixels(camera: PinholeCamera, left: np.ndarray, right: np.ndarray, uv: np.ndarray, s: FlowTrackSettings) -> np.ndarray:
    """Pixels `uv` (N, 2) of `left` found in `right` (N, 2; `_in_right`); NaN where not
    found or off the row by more than `max_row_px`."""
    uv_right, found = _in_right(camera, left, right, uv, s)
    found &= np.abs(uv_right[:, 1] - uv[:, 1]) <= s.max_row_px
    return np.where(found[:, None], uv_right, np.nan)


def _in_right(camera: PinholeCamera, left: np.ndarray, right: np.ndarray, uv: np.ndarray, s: FlowTrackSettings) -> tuple[np.ndarray, np.ndarray]:
    """Pixels `uv` (N, 2) of `left` found in `right` along their rows (`follow_along_row`),
    over the disparities of depths from `min_depth_m` on (at least `min_disparity_px`)."""
    max_disparity = min(float(left.shape[1]), camera.fx * camera.baseline / s.min_depth_m)
    return follow_along_row(left, right, uv, camera, min_disparity_px=s.min_disparity_px, max_disparity_px=max_disparity)


def _right_errors(camera: PinholeCamera, R: np.ndarray, t: np.ndarray, p_world: np.ndarray, uv_right: np.ndarray) -> np.ndarray:
    """Horizontal distance (N,) in pixels between where the pose (R, t: `R_world_camera`,
    `t_world_camera`) puts points `p_world` (N, 3) in the right image and `uv_right`; inf
    where that is NaN or the point is behind the camera."""
    p_right = (p_world - t) @ R - camera.offset_right
    with np.errstate(divide="ignore", invalid="ignore"):
        err = np.abs(camera.fx * p_right[:, 0] / p_right[:, 2] + camera.cx - uv_right[:, 0])
    return np.where((p_right[:, 2] > 1e-6) & np.isfinite(err), err, np.inf)
