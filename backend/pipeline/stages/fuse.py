"""Landmark fusion at a stereo keyframe: the local map's points that tracking did not match
are searched again among the keyframe's stereo keypoints that nothing claimed, so that a
place seen again re-observes its landmark instead of creating a second one beside it.

ORB-SLAM's `ORBmatcher::Fuse` is the model: a map point projected into the keyframe takes
the keypoint within a small radius whose descriptor is closest (at most `TH_LOW` = 50 bits),
provided the stereo observation agrees with the projection in (u, v, u_right) within the
χ² bound of three degrees of freedom at 95 % (7.815), with the keypoint's octave's pixel
variance. Without it the local map keeps a second copy of what tracking's ratio test or the
one-to-one check left unmatched, and the map grows with every keyframe on a revisited scene.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from backend.frontend.points import StereoPoints
from backend.frontend.radius_match import match_in_radius
from backend.geometry.camera import PinholeCamera


@dataclasses.dataclass(frozen=True)
class FuseSettings:
    """`radius_px`: the search radius around a point's projection (pixels of the rectified
    left image); `max_hamming`: the largest ORB descriptor distance that fuses (bits);
    `chi2`: the bound on the squared (u, v, u_right) error over the keypoint's variance
    (`pixel_sigma` px times `scale_factor` to the power of its octave, squared); `min_depth_m`:
    points closer to the camera (metres) are not searched."""

    radius_px: float = 4.0
    max_hamming: int = 50
    chi2: float = 7.815
    pixel_sigma: float = 1.0
    scale_factor: float = 1.2
    min_depth_m: float = 0.2


def fuse_points(
    camera: PinholeCamera,
    R_world_camera: np.ndarray,
    t_world_camera: np.ndarray,
    p_world: np.ndarray,
    descriptors: np.ndarray,
    stereo: StereoPoints,
    free: np.ndarray,
    *,
    settings: FuseSettings = FuseSettings(),
) -> np.ndarray:
    """Keypoint index (M,) of `stereo` fused with each of the M map points at `p_world`
    (M, 3) metres, world frame, with ORB `descriptors` (M, 32) uint8 (-1: none). The camera's
    pose is `R_world_camera`, `t_world_camera`; only keypoints where `free` (N,) bool is set
    are candidates (stereo matched, not claimed by a tracked point); each keypoint fuses
    with one point at most (the closest descriptor)."""
    s = settings
    out = np.full(len(p_world), -1, np.int64)
    cand = np.flatnonzero(free)
    if len(p_world) == 0 or len(cand) == 0:
        return out
    p_cam = (np.asarray(p_world, float) - t_world_camera) @ R_world_camera
    z = p_cam[:, 2]
    with np.errstate(divide="ignore", invalid="ignore"):
        uv = camera.project(p_cam)
        u_right = uv[:, 0] - camera.fx * camera.baseline / z
    front = np.flatnonzero((z > s.min_depth_m) & np.all(np.isfinite(uv), axis=1))
    if len(front) == 0:
        return out
    j = match_in_radius(uv[front], descriptors[front], stereo.uv_left[cand], stereo.descriptors[cand], radius_px=s.radius_px, max_hamming=s.max_hamming, ratio=1.0)
    hit = np.flatnonzero(j >= 0)
    rows, kps = front[hit], cand[j[hit]]
    err2 = np.sum((uv[rows] - stereo.uv_left[kps]) ** 2, axis=1) + (u_right[rows] - stereo.u_right[kps]) ** 2
    sigma2 = (s.pixel_sigma * s.scale_factor ** stereo.octave[kps].astype(float)) ** 2
    ok = err2 <= s.chi2 * sigma2
    out[rows[ok]] = kps[ok]
    return out
