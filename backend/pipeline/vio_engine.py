"""Monocular visual-inertial odometry with the co-planar parametrization (paper §III, the VIO
branch; DESIGN §5), one keyframe per step, implementing the same engine interface as the
stereo pipeline (it shares its mapping, plane detection, optimizer, culling and snapshots).

What differs from stereo:

- **Front end.** The left image only. New points are triangulated between the previous
  keyframe and the new one (ORB descriptors matched where the relative pose puts them on
  each other's epipolar line, `epipolar_px`; parallax at least `min_parallax_deg`), new
  lines likewise (LBD matches; back-projection planes at least `min_parallax_deg` apart).
  Landmarks are anchored in the keyframe that saw them first.
- **Start (structure from motion).** The first keyframe's features are followed frame to
  frame (Lucas-Kanade flow started where the gyroscope's rotation moves them,
  `backend.frontend.flow`) until their median rotation-compensated parallax reaches
  `init_parallax_px`; the essential matrix (OpenCV, RANSAC) gives the second keyframe and
  the first points, with the median depth set to `init_median_depth` (an arbitrary unit
  until the IMU gives the scale), unless its rotation disagrees with the gyroscope's by more
  than `init_gyro_agreement_deg` plus `init_gyro_bias_bound_rad_s` times the interval (the
  unknown gyro bias): then too little translation separates it from the rotation, and the
  start waits for more parallax. Visual-only windows follow (the first keyframe held, the
  distance of the first two fixing the scale). Until the initialization (`flow_tracks`) the
  map points seen in the last frame and up to `flow_max_tracks` candidate features of the
  recent keyframes are followed the same way, as VINS-Mono's front end: a frame's pose is
  EPnP-RANSAC on the followed map points, refined with them and the projection search's
  matches for the others; a candidate becomes a point when it has the parallax against the
  keyframe that detected it (at most `flow_max_age_keyframes` back).
- **Initialization** (`backend.vio.alignment`, VINS-Mono's loosely coupled alignment): once
  `init_keyframes` keyframes span at least `init_min_span_s`, the gyroscope bias, gravity,
  the scale and the velocities are estimated; the map is scaled and rotated into a
  gravity-aligned world (yaw and position of the first keyframe from the ground truth
  where it is known, only to draw both in the same frame), and every following window
  carries IMU factors. A rejected alignment is retried at the next keyframe with the
  latest keyframes; the snapshot says what was estimated and why it was rejected.
- **Tracking** predicts each frame's pose by preintegrating the IMU from the last keyframe
  (constant velocity before the initialization), then refines it against the local map
  (before the initialization with the followed map points too, above).
- **Keyframes** (VINS-Mono): the average rotation-compensated parallax of the tracked points
  since the last keyframe reaches `keyframe_parallax_px`, or fewer than
  `min_tracked_points` are tracked, or `max_keyframe_interval_s` passed (IMU factors
  over long intervals are weak).
- **Window.** The last `window` keyframes with pose, velocity and biases; IMU and bias
  random-walk factors between them; when the window is full, the oldest keyframe and the
  landmarks it anchors are marginalized into a prior (`backend.optim.marginalization`) that
  the next windows carry. Under -w the prior keeps the planes of the marginalized features,
  and they stay variables of the window.
- **Plane instances** come from a monocular segmenter: the learned one by default, or on
  rendered scenes the "oracle" (the renderer's exact ids, a clearly labelled reference).
"""

from __future__ import annotations

import dataclasses
import time

import cv2
import numpy as np

from backend.common.timing import PER_FRAME_STAGES, Stage
from backend.data.motion import ImuData
from backend.data.source import InertialSource
from backend.frontend.flow import FlowTracks, follow
from backend.frontend.lines import Segments, detect_segments
from backend.frontend.points import Keypoints, best_matches
from backend.frontend.segmentation import PlaneSegmenter
from backend.geometry import so3
from backend.imu.preintegration import preintegration_params
from backend.mapping.map import KeyframeObservations
from backend.mapping.triangulation import triangulate_two_views
from backend.pipeline.imu_window import ImuModel, InertialState, InertialWindow, InertialWindowSettings, check_imu_coverage
from backend.pipeline.snapshot import Detection, ImuState, Snapshot, Tracking
from backend.pipeline.stages.mono import MonoSettings, add_two_view_lines, add_two_view_points, triangulate_matches, triangulate_pixels
from backend.pipeline.stages.solve import WindowExtension
from backend.pipeline.stages.track import Tracked, refine
from backend.pipeline.stereo_engine import (
    POINT_NEW,
    POINT_OUTLIER,
    POINT_TRACKED,
    POINT_UNUSED,
    StereoEngine,
    StereoSettings,
)
from backend.pipeline.tracking import merge_matches, pnp_ransac
from backend.pipeline.vio_start import StartContext, VioStart, imu_state
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
    and `init_min_matches` (fewer than `init_restart_matches` followed features from the
    first keyframe: it starts again from the frame), `init_rotation_free_parallax_px` after the best pure rotation
    (`rotation_free_parallax_px`), and an essential matrix whose rotation agrees with the gyroscope's
    (`init_gyro_agreement_deg` + `init_gyro_bias_bound_rad_s` × interval); before the
    initialization, `flow_tracks` follows map points and candidate features frame to frame
    (at most `flow_max_tracks`, `flow_min_distance_px` apart, for `flow_max_age_keyframes`,
    triangulated with `min_parallax_deg`), and a frame is tracked with `flow_min_tracking_inliers`
    followed map points (forward-backward checked, then EPnP-RANSAC: fewer suffice than for
    descriptor matches); initialization after `init_keyframes` keyframes spanning
    `init_min_span_s` (`alignment`: its acceptance; the scale may be 20 % uncertain, the
    windows with IMU factors refine it); the gauge prior's σ (`gauge_sigma_m`, `gauge_sigma_yaw_rad` for
    position and yaw, `gauge_sigma_tilt_rad` for roll and pitch) and the initial bias σ
    (`bias_sigma_accel`, `bias_sigma_gyro`) and velocity σ (`velocity_sigma`); the bias
    drift (`rebias_accel`, `rebias_gyro`) beyond which a preintegration is redone. After the
    initialization a frame the images cannot track takes the IMU's predicted pose and becomes
    a keyframe, up to `max_imu_only_keyframes` in a row; `max_lost_frames` untracked frames in
    a row start a new map segment."""

    window: int = 10
    fixed_horizon: int = 10  # before the initialization only; after it the prior replaces it
    min_keyframe_observations: int = 3  # a two-view point must be seen once more to stay
    keyframe_parallax_px: float = 20.0
    max_keyframe_interval_s: float = 0.3
    epipolar_px: float = 2.0
    min_parallax_deg: float = 1.0
    init_parallax_px: float = 15.0
    init_rotation_free_parallax_px: float = 2.0  # twice the essential matrix RANSAC threshold (1 px)
    init_max_keyframe_interval_s: float = 0.2
    init_gyro_agreement_deg: float = 1.0
    init_gyro_bias_bound_rad_s: float = 0.1
    init_min_matches: int = 60
    init_restart_matches: int = 120
    init_median_depth: float = 3.0
    init_keyframes: int = 8
    init_min_span_s: float = 1.0
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
    flow_tracks: bool = True
    flow_max_tracks: int = 300
    flow_min_distance_px: float = 20.0
    flow_max_age_keyframes: int = 20
    flow_min_tracking_inliers: int = 12
    alignment: AlignmentSettings = AlignmentSettings(max_scale_rel_std=0.2)


class VioEngine(StereoEngine):
    """The VIO pipeline (module docstring; implements :class:`~backend.pipeline.engine.Engine`)."""

    settings: VioSettings
    data_source: InertialSource

    def __init__(self, source, *, settings: VioSettings = VioSettings(), name: str = "VIO sequence", segmenter: PlaneSegmenter | None = None, on_frame=None) -> None:
        self.imu: ImuData = source.imu  # DatasetError (one line) without imu0
        self.imu_noise = source.imu_noise
        self.T_body_camera = source.T_body_rect0
        self.imu_params = preintegration_params(self.imu_noise)
        self.imu_model = ImuModel(self.imu, self.imu_noise, self.T_body_camera, self.imu_params)
        if segmenter is None:
            from backend.frontend.segmentation_learned import LearnedSegmenter

            segmenter = LearnedSegmenter()
        super().__init__(source, settings=settings, name=name, segmenter=segmenter, on_frame=on_frame)
        self._check_imu_coverage()

    # ------------------------------------------------------------------ Engine interface

    STATE = (
        *StereoEngine.STATE,
        "inertial",
        "start",
        "_kf_features",
        "_kf_segments",
        "_bootstrapping",
        "_flow",
        "_restart_flow",
        "_ftracks",
        "_ftrack_image",
        "_track_kp",
        "_mflow",
        "_mflow_kp",
        "_lost_run",
        "_last_frame_ns",
        "_R_flow",
        "_imu_only_run",
    )
    SHARED = (*StereoEngine.SHARED, "imu", "imu_noise", "T_body_camera", "imu_params", "imu_model")

    def reset(self) -> None:
        super().reset()
        self.inertial = InertialState()  # velocities, biases, preintegrations, the prior (imu_window.py)
        self.start = VioStart()  # how far the visual-inertial initialization got (vio_start.py)
        self._kf_features: dict[int, tuple[Keypoints, np.ndarray]] = {}
        self._kf_segments: dict[int, tuple[Segments, np.ndarray]] = {}
        self._bootstrapping = True  # no map in the segment yet: frames are matched with its first keyframe
        self._flow: tuple[np.ndarray, np.ndarray, np.ndarray] = (np.zeros(0, np.int64), np.zeros((0, 2)), np.zeros((0, 0), np.uint8))
        self._restart_flow = False
        self._ftracks = FlowTracks.empty()  # before the initialization: candidate features followed frame to frame
        self._ftrack_image: np.ndarray | None = None
        self._track_kp = np.zeros(0, np.int64)  # each track's keypoint in the current frame (-1: none)
        self._mflow: tuple[np.ndarray, np.ndarray] = (np.zeros(0, np.int64), np.zeros((0, 2)))  # map points seen in the last frame: ids, pixels
        self._mflow_kp = np.zeros(0, np.int64)  # their keypoint in the current frame (-1: none)
        self._lost_run = 0
        self._last_frame_ns: int | None = None  # the last frame read
        self._R_flow: np.ndarray | None = None  # the camera's rotation since then, from the gyroscope
        self._imu_only_run = 0

    def step(self) -> Snapshot:
        s = self.settings
        t_start = time.perf_counter()
        timing: dict[str, float] = {Stage.POINT_DM: 0.0, Stage.TRACKING: 0.0}
        frames = lost = reinitializations = 0
        messages = self._messages = []
        bootstrap = None
        while True:
            i, left, _, kp = self._read_frame(timing)
            frames += 1
            t0 = time.perf_counter()
            t_ns = int(self.data_source.timestamps_ns[i])
            following = self._bootstrapping or self._flow_tracks_on()
            self._R_flow = self._gyro_rotation(self._last_frame_ns, t_ns) if following and self._last_frame_ns is not None else None
            self._last_frame_ns = t_ns
            if self._flow_tracks_on():
                kp = self._follow_tracks(left, kp)
            if self.keyframes == self.map.segment_start:
                R, t = self._initial_pose(i)
                tracked, reason = Tracked(R, t, np.full(0, -1, np.int64), 0, True), "first frame"
            elif self._bootstrapping:
                bootstrap = self._bootstrap(i, kp, left)
                if bootstrap is None:
                    timing[Stage.TRACKING] += 1e3 * (time.perf_counter() - t0)
                    if not self._restart_flow:
                        continue
                    # Nothing left to follow from the first keyframe: this frame starts again.
                    self._restart_flow = False
                    self._start_segment()
                    R, t = self.map.R_world_keyframe[-1], self.map.t_world_keyframe[-1]
                    tracked, reason = Tracked(R.copy(), t.copy(), np.full(0, -1, np.int64), 0, True), "first frame"
                    break
                tracked, reason, kp = bootstrap[0], "initial pair", bootstrap[4]
            else:
                tracked = self._track(i, kp)
                reason = self._keyframe_reason(i, kp, tracked)
            timing[Stage.TRACKING] += 1e3 * (time.perf_counter() - t0)
            if not tracked.ok and self.inertial.initialized and self._imu_only_run < s.max_imu_only_keyframes:
                # The images alone lost the map (a fast turn): the IMU's prediction is the
                # pose, and the frame becomes a keyframe so that new points are triangulated
                # from it; the window's IMU factors keep it consistent.
                self._imu_only_run += 1
                messages.append(f"frame {i}: tracked by the IMU alone ({tracked.inliers} map points matched)")
                tracked = Tracked(tracked.R, tracked.t, tracked.match, tracked.inliers, True)
                reason = "IMU only"
            elif tracked.ok and reason != "first frame":
                self._imu_only_run = 0
            self._remember_frame(i, tracked.R, tracked.t)
            if not tracked.ok:
                lost += 1
                self._lost_run += 1
                if self._lost_run >= s.max_lost_frames:
                    reinitializations += 1
                    messages.append(f"tracking lost for {self._lost_run} frames at frame {i}: VIO starts again (new map segment)")
                    self._start_segment()
                    R, t = tracked.R, tracked.t
                    tracked, reason = Tracked(R, t, np.full(0, -1, np.int64), 0, True), "re-initialization"
                    break
                continue
            self._lost_run = 0
            if self._flow_tracks_on() and len(tracked.match) == len(self._local_points):
                m = np.flatnonzero(tracked.match >= 0)
                self._mflow = (self._local_points[m], kp.uv[tracked.match[m]])
            if reason:
                break
            self.map.record_frame(i, self.keyframes - 1, tracked.R, tracked.t)
        return self._vio_keyframe(i, left, kp, tracked, timing, t_start, frames=frames, lost=lost, reinitializations=reinitializations, reason=reason, bootstrap=bootstrap)

    # ------------------------------------------------------------------ start

    def _start_segment(self) -> None:
        """A new map segment from the next keyframe: structure from motion and
        initialization again (the old map stays, frozen)."""
        self.map.segment_start = self.keyframes
        self._local_points = np.zeros(0, np.int64)
        self._local_lines = np.zeros(0, np.int64)
        self.inertial.initialized = False
        self.inertial.prior = None
        self._bootstrapping = True
        self._ftracks, self._ftrack_image = FlowTracks.empty(), None
        self._mflow = (np.zeros(0, np.int64), np.zeros((0, 2)))
        self._lost_run = 0
        self.start.status = "structure from motion: waiting for parallax (after a loss)"
        self.inertial.marginalized_before = self.keyframes

    def _bootstrap(self, i: int, kp: Keypoints, image: np.ndarray):
        """Frame i against the segment's first keyframe, whose keypoints are followed frame to
        frame by pyramidal Lucas-Kanade flow (forward-backward checked): when the median
        rotation-compensated parallax reaches `init_parallax_px`, the relative pose from the
        essential matrix and the first points. Returns (tracked, kf-0 keypoint indices, the
        keypoint indices in frame i, p_world) or None."""
        s = self.settings
        cam = self.camera
        k0 = self.map.segment_start
        ids, uv_prev, image_prev = self._flow
        if len(ids) >= 8:
            uv, ok = follow(image_prev, image, uv_prev, cam, R_prev_cur=self._R_flow)
            ids, uv_prev = ids[ok], uv[ok]
        self._flow = (ids, uv_prev, image)
        if len(ids) < s.init_restart_matches:
            self._messages.append(f"frame {i}: {len(ids)} features followed from the first keyframe (fewer than {s.init_restart_matches}); starting again from this frame")
            self._restart_flow = True
            return None
        kp0 = self._kf_features[k0][0]
        uv0, uv1 = kp0.uv[ids], uv_prev
        R_01_imu = self._gyro_rotation(int(self.map.keyframe_stamp_ns[k0]), int(self.data_source.timestamps_ns[i]))
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
        R_w0, t_w0 = self.map.R_world_keyframe[k0], self.map.t_world_keyframe[k0]
        R_01 = R_10.T  # camera 1 in camera 0
        # A rotation the gyroscope contradicts is a wrong decomposition (too little translation
        # for the essential matrix to separate it from the rotation): wait for more parallax.
        dt_s = (int(self.data_source.timestamps_ns[i]) - int(self.map.keyframe_stamp_ns[k0])) * 1e-9
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
        kp, nearest = self._with_followed_keypoints(kp, uv1[sel], image)
        keep = nearest >= 0
        tracked = Tracked(Rs[1], t1, np.zeros(0, np.int64), int(keep.sum()), True)
        return tracked, ids[sel][keep], nearest[keep], pts[good][keep], kp

    def _with_followed_keypoints(self, kp: Keypoints, uv: np.ndarray, image: np.ndarray, *, radius_px: float = 2.0) -> tuple[Keypoints, np.ndarray]:
        """`kp` with a keypoint for each followed pixel `uv` (M, 2) that has no ORB keypoint
        within `radius_px` (its ORB descriptor computed there, at the finest level), and the
        keypoint index of each pixel (-1 where no descriptor could be computed: too near the
        border)."""
        index = np.full(len(uv), -1, np.int64)
        if len(kp.uv) and len(uv):
            d = np.linalg.norm(uv[:, None, :] - kp.uv[None, :, :], axis=2)
            rows, cols = np.nonzero(d <= radius_px)
            index = best_matches(rows, cols, d[rows, cols], n_rows=len(uv), max_distance=radius_px, ratio=1.01)
        missing = np.flatnonzero(index < 0)
        if len(missing) == 0:
            return kp, index
        orb = cv2.ORB_create(edgeThreshold=19, patchSize=31)  # type: ignore[attr-defined]  # not in OpenCV's stubs
        points = [cv2.KeyPoint(float(x), float(y), 31.0, -1.0, 0.0, 0, int(j)) for j, (x, y) in zip(missing, uv[missing])]
        points, desc = orb.compute(image, points)
        if desc is None or len(points) == 0:
            return kp, index
        which = np.array([p.class_id for p in points], np.int64)
        index[which] = len(kp.uv) + np.arange(len(points))
        grown = Keypoints(uv=np.concatenate([kp.uv, uv[which]]), descriptors=np.concatenate([kp.descriptors, desc]), octave=np.concatenate([kp.octave, np.zeros(len(points), kp.octave.dtype)]))
        return grown, index

    def _gyro_rotation(self, t0_ns: int, t1_ns: int) -> np.ndarray:
        """Camera rotation `R_cam0_cam1` from the gyroscope between two times (the current
        gyro bias estimate; zero before the initialization)."""
        bias = self.inertial.bias[-1] if self.inertial.bias else np.zeros(6)
        pim = self.imu_model.preintegrate(t0_ns, t1_ns, bias)
        R_bc = self.T_body_camera[:3, :3]
        return R_bc.T @ np.array(pim.deltaRij().matrix()) @ R_bc

    # ------------------------------------------------------------------ tracking

    def _predict(self, i: int) -> tuple[np.ndarray, np.ndarray]:
        """After the initialization: the IMU preintegrated from the last keyframe's state;
        before it: constant velocity (the stereo pipeline's model)."""
        if not self.inertial.initialized:
            return super()._predict(i)
        k = self.keyframes - 1
        R, t, _ = self.imu_model.predict(self.map, k, int(self.data_source.timestamps_ns[i]), self.inertial.velocity[k], self.inertial.bias[k])
        return R, t

    def _keyframe_reason(self, i: int, kp: Keypoints, tracked: Tracked) -> str:
        s = self.settings
        if not tracked.ok:
            return ""
        k = self.keyframes - 1
        interval = s.max_keyframe_interval_s if self.inertial.initialized else s.init_max_keyframe_interval_s
        if (int(self.data_source.timestamps_ns[i]) - int(self.map.keyframe_stamp_ns[k])) * 1e-9 >= interval:
            return "IMU interval"
        if tracked.inliers < s.min_tracked_points:
            return "few tracked"
        if tracked.inliers < s.fallback_tracked_ratio * self._last_kf_tracked:
            return "fallback"
        # Rotation-compensated parallax of the tracked points against the last keyframe.
        o = self.map.observations[k]
        ids = self._local_points[tracked.match >= 0]
        uv_now = kp.uv[tracked.match[tracked.match >= 0]]
        _, a, b = np.intersect1d(o.point_id, ids, assume_unique=True, return_indices=True)  # a point is observed once per keyframe
        if len(a) == 0:
            return "few tracked"
        R_rel = tracked.R.T @ self.map.R_world_keyframe[k]  # keyframe camera -> frame camera
        x = self.camera.normalize(o.point_uv[a]) @ R_rel.T
        with np.errstate(divide="ignore", invalid="ignore"):
            parallax = np.linalg.norm(self.camera.project(x) - uv_now[b], axis=1)
        if float(np.nanmean(parallax)) >= s.keyframe_parallax_px:
            return "parallax"
        return ""

    # ------------------------------------------------------------------ keyframes

    def _vio_keyframe(
        self, i: int, left: np.ndarray, kp: Keypoints, tracked: Tracked, timing: dict[str, float], t_start: float, *, frames: int, lost: int, reinitializations: int, reason: str, bootstrap
    ) -> Snapshot:
        s = self.settings
        use_lines = self._variant.with_lines or not s.skip_unused_stages
        use_planes = self._variant.uses_planes or not s.skip_unused_stages
        k = self.keyframes
        rng = np.random.default_rng([s.seed, k, 0x57E])
        frames_per = max(frames, 1)
        for stage in PER_FRAME_STAGES:
            timing[stage] = timing.get(stage, 0.0) / frames_per

        local_p = self._local_points
        p_match = tracked.match if len(tracked.match) == len(local_p) else np.full(len(local_p), -1, np.int64)
        segments: Segments | None = None
        l_match = np.zeros(0, np.int64)
        local_l = self._local_lines
        timing[Stage.LINE_DM] = 0.0
        if use_lines:
            t0 = time.perf_counter()
            segments = detect_segments(left, settings=s.lines)
            l_match = self._match_lines(tracked.R, tracked.t, local_l, segments) if len(local_l) else np.full(0, -1, np.int64)
            timing[Stage.LINE_DM] = 1e3 * (time.perf_counter() - t0)

        t0 = time.perf_counter()
        status = np.full(len(kp.uv), POINT_UNUSED, np.uint8)
        if len(tracked.match) == len(local_p):
            status[tracked.match[tracked.match >= 0]] = POINT_OUTLIER
        self._add_keyframe(i, tracked.R, tracked.t)
        self.inertial.add_keyframe(self.map, k, self.imu_model)
        if k == self.map.segment_start:  # the start follows this keyframe's features frame to frame
            self._flow = (np.arange(len(kp.uv)), kp.uv.copy(), left)
        obs, new_points, new_lines = self._observe_mono(k, kp, local_p, p_match, segments, local_l, l_match, bootstrap)
        status[p_match[p_match >= 0]] = POINT_TRACKED
        status[self._new_point_kp] = POINT_NEW
        if s.flow_tracks and not self.inertial.initialized:
            self._seed_tracks(k, kp, left)
            self._mflow = (obs.point_id, obs.point_uv)
        self._last_kf_tracked = int(np.count_nonzero(p_match >= 0)) if k > self.map.segment_start + 1 else len(obs.point_id)  # map points tracked (new ones are not yet)
        timing[Stage.MAPPING] = 1e3 * (time.perf_counter() - t0)

        # Monocular: the segmenter sees the left image only.
        images = (left, left) if use_planes and k > self.map.segment_start else None
        masks, detection, report, hessian = self._detect_and_solve(k, i, obs, new_points, new_lines, rng, timing, images=images)
        if not self.inertial.initialized:
            self.start.try_initialize(k, StartContext(self.map, self.inertial, self.imu_model, self.data_source, self.settings, self._messages))
        if self._frame_poses:
            self._frame_poses[-1] = (i, self.map.R_world_keyframe[k].copy(), self.map.t_world_keyframe[k].copy())

        image = None
        if s.image_scale is not None:
            t0 = time.perf_counter()
            self._line_seg_index = np.arange(len(obs.line_id))
            image = self._draw(left, kp, status, segments if use_lines else None, obs, masks, detection)
            timing[Stage.IMAGE] = 1e3 * (time.perf_counter() - t0)
        total = 1e3 * (time.perf_counter() - t_start) - timing[Stage.LOAD] * frames_per
        timing[Stage.TOTAL] = total
        timing[Stage.TOTAL_PER_FRAME] = total / frames_per
        tracking = Tracking(
            frames=frames,
            lost_frames=lost,
            reinitializations=reinitializations,
            tracked_points=int(np.count_nonzero(p_match >= 0)),
            tracked_lines=int(np.count_nonzero(l_match >= 0)),
            keyframe_reason=reason,
        )
        self._last = self._snapshot(k, detection, self._det_state, report, hessian, image=image, tracking=tracking, message="; ".join(self._messages))
        return self._last

    def _observe_mono(
        self, k: int, kp: Keypoints, local_p: np.ndarray, p_match: np.ndarray, segments: Segments | None, local_l: np.ndarray, l_match: np.ndarray, bootstrap
    ) -> tuple[KeyframeObservations, np.ndarray, np.ndarray]:
        """Keyframe k's observations of map landmarks, and new landmarks triangulated with
        the previous keyframe (or the initial pair's points)."""
        P, Lm = self.map.points, self.map.lines
        mp = np.flatnonzero(p_match >= 0)
        j = p_match[mp]
        tracked_ids = local_p[mp]
        P.desc[tracked_ids] = kp.descriptors[j]
        P.n_kf[tracked_ids] = P.n_kf[tracked_ids] + 1
        claimed = np.zeros(len(kp.uv), bool)
        claimed[j] = True
        new_points = np.zeros(0, np.int64)
        fresh = np.zeros(0, np.int64)
        if bootstrap is not None:
            self._bootstrapping = False
            _, idx0, idx1, p_w, _ = bootstrap
            new_points, fresh = self._add_points(k, k - 1, self._kf_features[k - 1][0], idx0, kp, idx1, p_w)
        elif k > self.map.segment_start:
            # With the previous keyframes, newest first: a feature too close to its match in
            # k - 1 (parallax) may be far enough from it in an older one.
            found_ids, found_kp = [], []
            if len(self._track_kp) and len(self._track_kp) == len(self._ftracks):
                ids, fr = self._triangulate_tracks(k, kp, claimed)
                claimed[fr] = True
                found_ids.append(ids)
                found_kp.append(fr)
            for older in range(k - 1, max(self.map.segment_start, k - 1 - self.settings.triangulation_keyframes) - 1, -1):
                if older not in self._kf_features:
                    break
                kp_prev, claimed_prev = self._kf_features[older]
                idx0, idx1, p_w = triangulate_matches(self.map, older, k, kp_prev, np.flatnonzero(~claimed_prev), kp, np.flatnonzero(~claimed), settings=self._mono_settings())
                ids, fr = self._add_points(k, older, kp_prev, idx0, kp, idx1, p_w)
                claimed[fr] = True
                found_ids.append(ids)
                found_kp.append(fr)
            if found_ids:
                new_points, fresh = np.concatenate(found_ids), np.concatenate(found_kp)
        claimed[fresh] = True
        self._new_point_kp = fresh
        point_id = np.concatenate([tracked_ids, new_points])
        point_kp = np.concatenate([j, fresh])
        self._kf_features[k] = (kp, claimed)
        self._kf_features.pop(k - 1 - self.settings.triangulation_keyframes, None)
        line_id = np.zeros(0, np.int64)
        line_uv = np.zeros((0, 4))
        new_lines = np.zeros(0, np.int64)
        if segments is not None:
            uv = np.concatenate([segments.start, segments.end], axis=1)
            ml = np.flatnonzero(l_match >= 0)
            jl = l_match[ml]
            tracked_l = local_l[ml]
            Lm.desc[tracked_l] = segments.descriptors[jl]
            Lm.n_kf[tracked_l] = Lm.n_kf[tracked_l] + 1
            claimed_l = np.zeros(len(segments), bool)
            claimed_l[jl] = True
            fresh_l = np.zeros(0, np.int64)
            if k - 1 in self._kf_segments and k > self.map.segment_start:
                prev, claimed_prev_l = self._kf_segments[k - 1]
                new_lines, fresh_l = add_two_view_lines(self.map, k, prev, claimed_prev_l, segments, claimed_l, settings=self._mono_settings())
            claimed_l[fresh_l] = True
            self._kf_segments[k] = (segments, claimed_l)
            self._kf_segments.pop(k - 2, None)
            line_id = np.concatenate([tracked_l, new_lines])
            line_uv = uv[np.concatenate([jl, fresh_l])]
        obs = KeyframeObservations(point_id, kp.uv[point_kp], np.full(len(point_id), np.nan), line_id, line_uv, np.full((len(line_id), 4), np.nan))
        self.map.observations[k] = obs
        return obs, new_points, new_lines

    # ------------------------------------------------------------------ followed features (before the initialization)

    def _flow_tracks_on(self) -> bool:
        """Whether candidate features are followed frame to frame: from the segment's first
        map until the initialization."""
        return self.settings.flow_tracks and not self.inertial.initialized and not self._bootstrapping and self.keyframes > self.map.segment_start

    def _follow_tracks(self, image: np.ndarray, kp: Keypoints) -> Keypoints:
        """The map points seen in the last frame and the candidate features followed into
        `image`; returns `kp` with a keypoint at each followed pixel (the ORB keypoint within 2
        px, or a new one), each one's index in `_mflow_kp` and `_track_kp`."""
        ids, uv_map = self._mflow
        self._mflow_kp = np.full(len(ids), -1, np.int64)
        self._track_kp = np.full(len(self._ftracks), -1, np.int64)
        if self._ftrack_image is not None and len(ids) + len(self._ftracks):
            uv, ok = follow(self._ftrack_image, image, np.concatenate([uv_map, self._ftracks.uv]), self.camera, R_prev_cur=self._R_flow)
            n = len(ids)
            self._mflow = (ids[ok[:n]], uv[:n][ok[:n]])
            self._ftracks = self._ftracks.followed(uv[n:], ok[n:])
            kp, self._mflow_kp = self._with_followed_keypoints(kp, self._mflow[1], image)
            kp, self._track_kp = self._with_followed_keypoints(kp, self._ftracks.uv, image)
        self._ftrack_image = image
        return kp

    def _track(self, i: int, kp: Keypoints) -> Tracked:
        """Before the initialization the map points followed from the last frame are matches
        too (the followed ones first, then those the projection search found for the others);
        otherwise the stereo pipeline's tracking."""
        result = super()._track(i, kp)  # the stereo pipeline's tracking (with this engine's prediction)
        ids, _ = self._mflow
        if not self._flow_tracks_on() or len(ids) == 0 or len(self._mflow_kp) != len(ids):
            return result
        local = self._local_points
        match = np.full(len(local), -1, np.int64)
        _, at_local, at_flow = np.intersect1d(local, ids, assume_unique=True, return_indices=True)
        match[at_local] = self._mflow_kp[at_flow]
        P = self.map.points.p_world[local]
        m = np.flatnonzero(match >= 0)
        need = self.settings.flow_min_tracking_inliers
        pose = pnp_ransac(self.camera, P[m], kp.uv[match[m]], min_inliers=need, seed=self.settings.seed + i)
        if pose is None:
            return result
        match[m[~pose[2]]] = -1
        if result.ok and len(result.match) == len(local):
            match = merge_matches(match, result.match, n_keypoints=len(kp.uv))
        flowed = refine(self.camera, self._track_settings(), pose[0], pose[1], P, self.map.points.desc[local], kp, match, min_inliers=need, keep_matches=True)
        return flowed if flowed.ok and flowed.inliers >= result.inliers else result

    def _triangulate_tracks(self, k: int, kp: Keypoints, claimed: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """New points from the followed features with parallax between the keyframe that
        detected them and keyframe k (`stages.mono.triangulate_pixels`); a feature whose keypoint is
        already claimed in either keyframe is left. Returns the new ids and their keypoint
        indices in keyframe k."""
        tr, j1 = self._ftracks, self._track_kp
        cand = np.flatnonzero((j1 >= 0) & (tr.anchor < k))
        cand = cand[~claimed[j1[cand]]]
        _, first = np.unique(j1[cand], return_index=True)  # one track per keypoint
        cand = cand[np.sort(first)]
        found_ids, found_kp = [np.zeros(0, np.int64)], [np.zeros(0, np.int64)]
        for k0 in np.unique(tr.anchor[cand]):
            c = cand[tr.anchor[cand] == k0]
            if k0 in self._kf_features:
                c = c[~self._kf_features[k0][1][tr.anchor_kp[c]]]
            p_w, good = triangulate_pixels(self.map, int(k0), k, tr.uv_anchor[c], kp.uv[j1[c]], settings=self._mono_settings())
            c = c[good]
            if len(c) == 0:
                continue
            ids = add_two_view_points(self.map, k, int(k0), tr.uv_anchor[c], kp.descriptors[j1[c]], p_w[good])
            if k0 in self._kf_features:
                self._kf_features[k0][1][tr.anchor_kp[c]] = True
            found_ids.append(ids)
            found_kp.append(j1[c])
        return np.concatenate(found_ids), np.concatenate(found_kp)

    def _seed_tracks(self, k: int, kp: Keypoints, image: np.ndarray) -> None:
        """After keyframe k's landmarks: the followed features that became or met a map point,
        or that are older than `flow_max_age_keyframes` keyframes, are dropped; keyframe k's
        unclaimed keypoints start new ones (at least `flow_min_distance_px` apart, at most
        `flow_max_tracks`)."""
        s = self.settings
        claimed = self._kf_features[k][1]
        tr, j1 = self._ftracks, self._track_kp
        keep = (k - tr.anchor) <= s.flow_max_age_keyframes
        if len(j1) == len(tr):
            keep &= ~((j1 >= 0) & claimed[np.maximum(j1, 0)])
        tr = tr.subset(keep)
        cand = np.flatnonzero(~claimed)
        self._ftracks = tr.seeded(k, kp.uv[cand], cand, min_distance_px=s.flow_min_distance_px, max_tracks=s.flow_max_tracks)
        self._ftrack_image = image
        self._track_kp = np.zeros(0, np.int64)

    def _mono_settings(self) -> MonoSettings:
        s = self.settings
        return MonoSettings(s.epipolar_px, s.max_hamming, s.match_ratio, s.min_depth_m, s.max_depth_m, s.min_parallax_deg, s.outlier_px, s.min_line_length_m, s.lines)

    def _add_points(self, k: int, k0: int, kp0: Keypoints, idx0: np.ndarray, kp1: Keypoints, idx1: np.ndarray, p_world: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """New points of keyframe k anchored in keyframe k0 (observed there and in keyframe
        k); appends their observation to keyframe k0's record. Returns their ids and keypoint
        indices in keyframe k."""
        if len(idx0) == 0:
            return np.zeros(0, np.int64), np.zeros(0, np.int64)
        ids = add_two_view_points(self.map, k, k0, kp0.uv[idx0], kp1.descriptors[idx1], p_world)
        self._kf_features[k0][1][idx0] = True
        return ids, idx1

    # ------------------------------------------------------------------ initialization

    # ------------------------------------------------------------------ window (the inertial WindowExtension of stages.solve)

    def _window_range(self, k: int) -> tuple[int, int]:
        return self.inertial.window_range(self.map, k, window=self.settings.window, fixed_horizon=self.settings.fixed_horizon)

    def _window_extension(self) -> WindowExtension:
        s = self.settings
        return InertialWindow(self.inertial, self.map, self.imu_model, InertialWindowSettings(s.window, s.rebias_accel, s.rebias_gyro))

    # ------------------------------------------------------------------ snapshots

    def _snapshot(self, k: int, detection: Detection, det_state: tuple, report, hessian, *, image, tracking, message: str) -> Snapshot:
        snap = super()._snapshot(k, detection, det_state, report, hessian, image=image, tracking=tracking, message=message)
        return dataclasses.replace(snap, imu=self._imu_state(k))

    def _imu_state(self, k: int) -> ImuState:
        return imu_state(self.map, k, self.inertial, self.start, self.data_source, self.imu.timestamp_ns)

    def _check_imu_coverage(self) -> None:
        check_imu_coverage(self.imu, self.data_source)


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
