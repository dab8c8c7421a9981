"""The VIO pipeline's settings (`backend.pipeline.vio_engine` says what each stage does):
the stereo settings that apply, plus the monocular-inertial ones. Times in seconds, pixels of
the rectified left camera, angles as named."""

from __future__ import annotations

import dataclasses

from backend.optim.solver import Damping
from backend.pipeline.stereo_settings import StereoSettings
from backend.vio.alignment import AlignmentSettings


@dataclasses.dataclass(frozen=True)
class VioSettings(StereoSettings):
    """The stereo settings that apply (tracking, culling, window, plane detection), plus the
    VIO ones (module docstring): keyframes by `keyframe_parallax_px` (rotation-compensated,
    average), `min_tracked_points`, fewer than `fallback_tracked_ratio` of the last keyframe's
    tracked points, or `max_keyframe_interval_s` (`init_max_keyframe_interval_s` before the
    initialization, so that its keyframes come sooner); new landmarks need
    `epipolar_px` agreement and `min_parallax_deg` with one of the `triangulation_keyframes`
    previous keyframes (newest first); the start needs `init_parallax_px`
    and `init_min_matches` (ORB-SLAM's monocular initializer asks for 100; fewer than
    `init_restart_matches` followed features from the first keyframe, or no pair within
    `init_max_pair_interval_s` of it: it starts again from the frame), `init_rotation_free_parallax_px` after the best pure rotation
    (`rotation_free_parallax_px`), and an essential matrix whose rotation agrees with the gyroscope's
    (`init_gyro_agreement_deg` + `init_gyro_bias_bound_rad_s` × interval); before the
    initialization, `flow_tracks` follows map points and candidate features frame to frame
    (at most `flow_max_tracks`, `flow_min_distance_px` apart, for `flow_max_age_keyframes`,
    triangulated with `min_parallax_deg`), and a frame is tracked with `flow_min_tracking_inliers`
    followed map points (forward-backward checked, then EPnP-RANSAC: fewer suffice than for
    descriptor matches); the last `init_window` keyframes are optimized together before the
    initialization (a shorter window let the monocular scale drift by half within 4 s at a
    slow pace), with points alone where `points_only_before_init` (off: an experiment, not
    the default; lines and planes are then detected and triangulated from the start but
    join the solve with the metric scale. Triangulated from keyframes centimetres apart and
    fitted to those points, they bent PL-w's up-to-scale path by 31 % of its extent on
    `corridor` seed 2 at speed 1, and the alignment found no positive scale for 5 s; points
    alone held the shape but cost other runs more than they gained, CHANGELOG 2026-11-29),
    and `window` after it (IMU factors over ~6 s hold the scale of a slow
    camera); initialization after `init_keyframes` keyframes spanning
    `init_min_span_s`, aligned over the visual window's keyframes at least
    `init_alignment_interval_s` apart (fewer where the span holds fewer than
    `init_keyframes`: `vio_start.thinned`), then a visual-inertial bundle adjustment over
    them of at most `init_joint_iterations` iterations (the alignment's scale may be tens of
    per cent off: more than the windows' iterations correct) (`alignment`: its acceptance; the scale may be 30 % uncertain, the
    joint solve and the windows with IMU factors refine it, and `refine_after_s` after the
    start the alignment again over the last `refine_window` keyframes, accepted by
    `refine_alignment` (σ ≤ 15 %, χ²/dof ≤ 1; a rejected one is tried again `refine_retry_s`
    later), scales the segment by its factor (`VioStart.refine`); the accelerometer bias is estimated with a 0.2 m/s²
    prior: at 20 % the monocular structure's drift at a slow start passed scales 50-60 % off); the gauge prior's σ (`gauge_sigma_m`, `gauge_sigma_yaw_rad` for
    position and yaw, `gauge_sigma_tilt_rad` for roll and pitch) and the initial bias σ
    (`bias_sigma_accel`, `bias_sigma_gyro`) and velocity σ (`velocity_sigma`); the bias
    drift (`rebias_accel`, `rebias_gyro`) beyond which a preintegration is redone. After the
    initialization a frame the images cannot track takes the IMU's predicted pose and becomes
    a keyframe, up to `max_imu_only_keyframes` in a row; `max_lost_frames` untracked frames in
    a row start a new map segment. No far points (`far_min_disparity_px` None): the culling's
    depth limit stays `max_depth_m`, as before the stereo pipeline had far points.
    Failure detection (VINS-Mono's, after each window solve once initialized): an
    accelerometer or gyroscope bias estimate above `failure_max_bias_accel` (m/s²) /
    `failure_max_bias_gyro` (rad/s), a speed above `failure_max_speed_mps`, a keyframe
    further from the last than that speed allows (+ `failure_max_jump_m`), or
    `failure_disagreeing_frames` frames in a row whose visual pose, supported by at least
    `failure_support_inliers` inliers, is more than `failure_prediction_m` /
    `failure_prediction_deg` from the IMU's prediction: the inertial state is wrong, and the
    VIO starts again (a new map segment) from the last keyframe's pose rather than run on.
    Once initialized, the frames between two keyframes take their poses from the IMU between
    the keyframes' solved states where `frames_by_imu` (`VioEngine._frames_by_imu`), not from
    their own monocular PnP."""

    window: int = 20  # VIO's keyframes are denser than stereo's (backend.pipeline.factory.DEFAULT_WINDOW)
    init_window: int = 40  # keyframes optimized together before the initialization (at least `window`)
    fixed_horizon: int = 10  # before the initialization only; after it the prior replaces it
    min_keyframe_observations: int = 3  # a two-view point must be seen once more to stay
    far_min_disparity_px: float | None = None  # VIO triangulates, it has no stereo depth
    flow_track: None = None  # the stereo engine's flow fallback needs the right image (VIO follows features its own way)
    damping: Damping = Damping.MARQUARDT  # Nielsen's rule damped the scale too long (CHANGELOG, issue 27)
    keyframe_parallax_px: float = 20.0
    max_keyframe_interval_s: float = 0.3
    epipolar_px: float = 2.0
    min_parallax_deg: float = 0.5
    init_parallax_px: float = 15.0
    init_rotation_free_parallax_px: float = 2.0  # twice the essential matrix RANSAC threshold (1 px)
    init_max_keyframe_interval_s: float = 0.2
    init_gyro_agreement_deg: float = 1.0
    init_gyro_bias_bound_rad_s: float = 0.1
    init_min_matches: int = 100
    init_restart_matches: int = 120
    init_max_pair_interval_s: float = 2.0
    init_median_depth: float = 3.0
    init_keyframes: int = 8
    init_min_span_s: float = 1.0
    init_alignment_interval_s: float = 0.5
    init_joint_iterations: int = 40
    gauge_sigma_m: float = 1e-3
    gauge_sigma_yaw_rad: float = 1e-3
    gauge_sigma_tilt_rad: float = 0.02
    velocity_sigma: float = 0.2
    bias_sigma_accel: float = 0.1
    bias_sigma_gyro: float = 0.01
    rebias_accel: float = 0.05
    rebias_gyro: float = 0.003
    max_lost_frames: int = 10
    max_imu_only_keyframes: int = 40
    triangulation_keyframes: int = 2
    failure_max_bias_accel: float = 1.0
    failure_max_bias_gyro: float = 0.5
    failure_max_speed_mps: float = 50.0
    failure_max_jump_m: float = 1.0
    failure_support_inliers: int = 40
    failure_prediction_m: float = 0.5
    failure_prediction_deg: float = 10.0
    failure_disagreeing_frames: int = 3
    points_only_before_init: bool = False  # an experiment (docstring): lines and planes wait for the start
    flow_tracks: bool = True
    flow_max_tracks: int = 300
    flow_min_distance_px: float = 20.0
    flow_max_age_keyframes: int = 20
    flow_min_tracking_inliers: int = 12
    alignment: AlignmentSettings = AlignmentSettings(max_scale_rel_std=0.3, accel_bias_sigma=0.2)
    refine_after_s: tuple[float, ...] = (15.0,)
    refine_window: int = 40
    refine_retry_s: float = 5.0  # a rejected refinement is tried again this much later
    frames_by_imu: bool = True
    refine_alignment: AlignmentSettings = AlignmentSettings(max_scale_rel_std=0.15, accel_bias_sigma=0.2, scale_range=(0.5, 2.0), max_chi2_per_dof=1.0)
