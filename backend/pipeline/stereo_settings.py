"""The stereo pipeline's settings (`backend.pipeline.stereo_engine` says what each stage
does); VIO's settings extend them (`backend.pipeline.vio_settings`). Pixels of the rectified
left camera, depths and lengths in metres."""

from __future__ import annotations

import dataclasses

import numpy as np

from backend.frontend.lines import LineSettings
from backend.frontend.points import PointSettings
from backend.geometry.camera import PinholeCamera
from backend.mapping import coplanar
from backend.optim.solver import Damping
from backend.optim.variant import Variant
from backend.pipeline.stages.flow_track import FlowTrackSettings
from backend.pipeline.stages.fuse import FuseSettings


@dataclasses.dataclass(frozen=True)
class StereoSettings:
    """Settings of the stereo pipeline (all thresholds of DESIGN §5).

    Keyframes: the paper's rule, at least `min_keyframe_gap_s` seconds since the last
    keyframe (the paper's 20 frames at 20 Hz), more than `min_tracked_points` tracked points
    and at least `min_new_fraction` of the keypoints new; or the fallback, after at least
    `min_fallback_gap_s` seconds, fewer tracked points than `fallback_tracked_ratio` times
    the last keyframe's map points (the scene changed); both gaps are turned into frames at
    the input's frame rate (`keyframe_gap_frames`, at least one frame); or, under
    fast motion, when fewer than `min_kept_in_view` of the frame's tracked points would stay
    in the image at the pose the motion model predicts for the next frame (the next frame
    would see too little of the map to be tracked).
    Tracking: projection search radius `search_radius_px` (then `refine_radius_px` around the
    refined pose), ORB Hamming distance `<= max_hamming` and ratio `match_ratio`; a pose
    needs `min_tracking_inliers` inliers; a pose from the motion model with fewer inliers
    than `verify_tracked_ratio` times the last keyframe's tracked points (or before the
    model has a velocity) is checked against PnP on descriptor matches (no prediction
    needed): it stands where it places at least `verify_agreement` of the PnP pose's
    inliers within `outlier_px` (they agree), else the pose with more inliers wins. Landmarks: stereo depth in [`min_depth_m`,
    `max_depth_m`] (close points), or beyond while the disparity is at least
    `far_min_disparity_px` (far points, as ORB-SLAM's beyond 40 baselines: their inverse
    depth stays uncertain in the window, where the right image's observation weighs it, and
    they hold the rotation in tracking; None: no far points; `depth_limit_m` gives the depth
    this allows; lines stay close); segments at least `min_line_length_m` long; a landmark must be seen by
    `min_keyframe_observations` keyframes within `cull_after_keyframes` keyframes of its
    creation. Window: `window` keyframes optimized, observations from `fixed_horizon` older
    keyframes enter with fixed poses, solved by `method` (`"lm"`: Levenberg-Marquardt) in at
    most `max_iterations` iterations with λ changed by `damping` (Nielsen's rule: fewer
    rejected trial steps than Marquardt's ÷ 10 / × 10, which VIO keeps); `cauchy` is the
    kernel scale (whitened units) and
    `outlier_px` the error above which an observation is dropped after the solve. A plane
    is optimized in a window only with `min_plane_support` of its features there.
    `skip_unused_stages`: as the paper's Table III, P variants detect no lines and -wo
    variants segment no planes (off in the debugger, so that every layer and the -wo | -r |
    -w comparison have data). `image_scale`: size of the keyframe image in snapshots
    (None: no image). `hessian`: put the window's Hessian structure in snapshots (the
    debugger shows it; headless runs skip it). `read_ahead`: the next frame is read and
    its ORB keypoints detected on a worker thread while the current one is tracked
    (`backend.pipeline.prefetch`; the outputs are the same either way). `fuse`: at a
    keyframe, the local map's points that tracking left unmatched are searched again among
    its free stereo keypoints and re-observed instead of duplicated (`stages.fuse`,
    ORB-SLAM's Fuse; None: off; stereo keyframes only, VIO's monocular ones are not fused).
    `flow_track`: a frame that neither tracking nor relocalization places is placed by
    optical flow from the last placed frame (`stages.flow_track`: corners with stereo depth
    followed into it, EPnP-RANSAC; a bare wall's grain, which ORB misses) and becomes a
    keyframe once `min_fallback_gap_s` has passed; None: such a frame is lost (stereo
    only: VIO has no right image)."""

    variant: Variant = Variant.PL_W
    window: int = 10
    fixed_horizon: int = 10
    min_keyframe_gap_s: float = 1.0
    min_tracked_points: int = 40
    min_new_fraction: float = 0.1
    min_fallback_gap_s: float = 0.1
    fallback_tracked_ratio: float = 0.6
    min_kept_in_view: float = 0.5
    search_radius_px: float = 15.0
    refine_radius_px: float = 4.0
    max_hamming: int = 60
    match_ratio: float = 0.9
    min_tracking_inliers: int = 20
    verify_tracked_ratio: float = 0.6
    verify_agreement: float = 0.8
    min_depth_m: float = 0.2
    max_depth_m: float = 20.0
    far_min_disparity_px: float | None = 3.0
    min_line_length_m: float = 0.1
    line_search_px: float = 20.0
    min_keyframe_observations: int = 2
    cull_after_keyframes: int = 3
    pixel_sigma: float = 1.0
    cauchy: float = 2.0
    outlier_px: float = 4.0
    min_plane_support: int = 10
    max_iterations: int = 10
    method: str = "lm"
    damping: Damping = Damping.NIELSEN
    seed: int = 0
    skip_unused_stages: bool = False
    image_scale: float | None = 0.5
    hessian: bool = True
    read_ahead: bool = True
    points: PointSettings = PointSettings()
    lines: LineSettings = LineSettings()
    coplanar: coplanar.CoplanarSettings = coplanar.CoplanarSettings()
    fuse: FuseSettings | None = FuseSettings()
    flow_track: FlowTrackSettings | None = FlowTrackSettings()

    def __post_init__(self) -> None:
        object.__setattr__(self, "variant", Variant.parse(self.variant))  # a name given as text is parsed here, once
        if self.window < 2:
            raise ValueError("window must be at least 2 keyframes")
        if self.far_min_disparity_px is not None and not self.far_min_disparity_px > 0.0:
            raise ValueError("far_min_disparity_px must be positive (or None: no far points)")

    def depth_limit_m(self, camera: PinholeCamera) -> float:
        """The deepest landmark (metres) a stereo match of `camera`'s rig may make: `max_depth_m`,
        or where far points are allowed the depth of `far_min_disparity_px` if that is
        deeper (f·b / d; a camera without a baseline has none)."""
        if self.far_min_disparity_px is None or camera.baseline <= 0.0:
            return self.max_depth_m
        return max(self.max_depth_m, camera.fx * camera.baseline / self.far_min_disparity_px)

    def keyframe_gap_frames(self, frame_period_s: float) -> tuple[int, int]:
        """`min_keyframe_gap_s` and `min_fallback_gap_s` in frames of `frame_period_s` seconds
        (rounded, at least one; a period that is not positive and finite counts as 20 Hz's)."""
        period = frame_period_s if np.isfinite(frame_period_s) and frame_period_s > 0.0 else 0.05
        return max(1, round(self.min_keyframe_gap_s / period)), max(1, round(self.min_fallback_gap_s / period))
