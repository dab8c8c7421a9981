"""The stereo pipeline's settings (`backend.pipeline.stereo_engine` says what each stage
does); VIO's settings extend them (`backend.pipeline.vio_settings`). Pixels of the rectified
left camera, depths and lengths in metres."""

from __future__ import annotations

import dataclasses

from backend.frontend.lines import LineSettings
from backend.frontend.points import PointSettings
from backend.mapping import coplanar
from backend.optim.variant import Variant


@dataclasses.dataclass(frozen=True)
class StereoSettings:
    """Settings of the stereo pipeline (all thresholds of DESIGN §5).

    Keyframes: the paper's rule, at least `min_keyframe_gap` frames since the last keyframe,
    more than `min_tracked_points` tracked points and at least `min_new_fraction` of the
    keypoints new; or the fallback, after at least `min_fallback_gap` frames, fewer tracked
    points than `fallback_tracked_ratio` times the last keyframe's map points; or, under
    fast motion, when fewer than `min_kept_in_view` of the frame's tracked points would stay
    in the image at the pose the motion model predicts for the next frame (the next frame
    would see too little of the map to be tracked).
    Tracking: projection search radius `search_radius_px` (then `refine_radius_px` around the
    refined pose), ORB Hamming distance `<= max_hamming` and ratio `match_ratio`; a pose
    needs `min_tracking_inliers` inliers. Landmarks: stereo depth in [`min_depth_m`,
    `max_depth_m`]; segments at least `min_line_length_m` long; a landmark must be seen by
    `min_keyframe_observations` keyframes within `cull_after_keyframes` keyframes of its
    creation. Window: `window` keyframes optimized, observations from `fixed_horizon` older
    keyframes enter with fixed poses; `cauchy` is the kernel scale (whitened units) and
    `outlier_px` the error above which an observation is dropped after the solve. A plane
    is optimized in a window only with `min_plane_support` of its features there.
    `skip_unused_stages`: as the paper's Table III, P variants detect no lines and -wo
    variants segment no planes (off in the debugger, so that every layer and the -wo | -r |
    -w comparison have data). `image_scale`: size of the keyframe image in snapshots
    (None: no image). `hessian`: put the window's Hessian structure in snapshots (the
    debugger shows it; headless runs skip it)."""

    variant: Variant = Variant.PL_W
    window: int = 10
    fixed_horizon: int = 10
    min_keyframe_gap: int = 20
    min_tracked_points: int = 40
    min_new_fraction: float = 0.1
    min_fallback_gap: int = 2
    fallback_tracked_ratio: float = 0.6
    min_kept_in_view: float = 0.5
    search_radius_px: float = 15.0
    refine_radius_px: float = 4.0
    max_hamming: int = 60
    match_ratio: float = 0.9
    min_tracking_inliers: int = 20
    min_depth_m: float = 0.2
    max_depth_m: float = 20.0
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
    seed: int = 0
    skip_unused_stages: bool = False
    image_scale: float | None = 0.5
    hessian: bool = True
    points: PointSettings = PointSettings()
    lines: LineSettings = LineSettings()
    coplanar: coplanar.CoplanarSettings = coplanar.CoplanarSettings()

    def __post_init__(self) -> None:
        object.__setattr__(self, "variant", Variant.parse(self.variant))  # a name given as text is parsed here, once
        if self.window < 2:
            raise ValueError("window must be at least 2 keyframes")
