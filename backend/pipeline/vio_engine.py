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
  start waits for more parallax. Visual-only windows of `init_window` keyframes follow (the
  first keyframe held, the distance of the first two fixing the scale). Until the initialization (`flow_tracks`) the
  map points seen in the last frame and up to `flow_max_tracks` candidate features of the
  recent keyframes are followed the same way, as VINS-Mono's front end: a frame's pose is
  EPnP-RANSAC on the followed map points, refined with them and the projection search's
  matches for the others; a candidate becomes a point when it has the parallax against the
  keyframe that detected it (at most `flow_max_age_keyframes` back).
- **Initialization** (`backend.vio.alignment`, VINS-Mono's loosely coupled alignment): once
  `init_keyframes` keyframes span at least `init_min_span_s`, over the visual window's
  keyframes thinned to `init_alignment_interval_s` apart (positions differenced over 0.2 s
  carry the visual noise into the accelerations and shrink the scale), the gyroscope bias, gravity,
  the scale, the velocities and (under a prior) the accelerometer bias are estimated; the
  map is scaled and rotated into a gravity-aligned world (yaw and position of the first
  keyframe from the ground truth where it is known, only to draw both in the same frame; after
  a restart from the pose the segment started at, never the truth), and every following
  window carries IMU factors. A rejected alignment is retried at the next keyframe with the
  latest keyframes; the snapshot says what was estimated and why it was rejected.
- **Failure detection** (VINS-Mono's): after each window solve, an implausible bias, speed
  or jump, or frames whose well-supported visual pose is far from the IMU's prediction,
  start a new map segment from the last keyframe's pose (counted as a re-initialization),
  rather than running on with a wrong inertial state.
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
from collections.abc import Callable

import numpy as np

from backend.common.blas import single_threaded_blas
from backend.common.timing import PER_FRAME_STAGES, Stage
from backend.data.motion import ImuData
from backend.data.source import InertialSource
from backend.frontend.flow import follow
from backend.frontend.lines import Segments, detect_segments
from backend.frontend.points import Keypoints
from backend.frontend.segmentation import PlaneSegmenter
from backend.geometry import so3
from backend.imu.preintegration import preintegration_params
from backend.mapping.map import KeyframeObservations
from backend.optim.variant import Variant
from backend.pipeline.core import CoreEngine, PipelineCore
from backend.pipeline.imu_window import ImuModel, InertialState, InertialWindow, InertialWindowSettings, check_imu_coverage
from backend.pipeline.overlay import POINT_NEW, POINT_OUTLIER, POINT_TRACKED, POINT_UNUSED
from backend.pipeline.snapshot import Snapshot, Tracking
from backend.pipeline.stages.follow import FeatureFollower
from backend.pipeline.stages.mono import MonoSettings, add_two_view_points, observe_mono_lines, triangulate_matches
from backend.pipeline.stages.solve import WindowExtension
from backend.pipeline.stages.track import Tracked
from backend.pipeline.stages.two_view import StartPair, two_view_start
from backend.pipeline.vio_settings import VioSettings
from backend.pipeline.vio_start import StartContext, VioStart, imu_state


class VioEngine(CoreEngine):
    """The VIO pipeline (module docstring; implements :class:`~backend.pipeline.engine.Engine`
    through :class:`~backend.pipeline.core.CoreEngine`): optical flow, the IMU's prediction,
    the visual-inertial start and the inertial window plugged into the shared
    :class:`PipelineCore`."""

    def __init__(
        self, source: InertialSource, *, settings: VioSettings = VioSettings(), name: str = "VIO sequence", segmenter: PlaneSegmenter | None = None, on_frame: Callable[[int], None] | None = None
    ) -> None:
        self.imu: ImuData = source.imu  # DatasetError (one line) without imu0
        self.imu_noise = source.imu_noise
        self.T_body_camera = source.T_body_rect0
        self.imu_params = preintegration_params(self.imu_noise)
        self.imu_model = ImuModel(self.imu, self.imu_noise, self.T_body_camera, self.imu_params)
        if segmenter is None:
            from backend.frontend.segmentation_learned import LearnedSegmenter

            segmenter = LearnedSegmenter()
        self.settings = settings
        self.inertial_source = source
        self.core = PipelineCore(source, settings=settings, name=name, segmenter=segmenter, plan=self, on_frame=on_frame)
        self.reset()
        check_imu_coverage(self.imu, source)

    # ------------------------------------------------------------------ Engine interface

    # Checkpoints (backend.pipeline.engine.EngineCheckpoint): the core checkpoints itself.
    STATE: tuple[str, ...] = (
        "inertial",
        "start",
        "_kf_features",
        "_kf_segments",
        "_bootstrapping",
        "_flow",
        "_restart_flow",
        "follower",
        "_lost_run",
        "_last_frame_ns",
        "_R_flow",
        "_imu_only_run",
        "_disagreeing_run",
        "_restart_pose",
    )
    SHARED: tuple[str, ...] = ("settings", "inertial_source", "imu", "imu_noise", "T_body_camera", "imu_params", "imu_model")

    def reset(self) -> None:
        self.core.reset()
        self.inertial = InertialState()  # velocities, biases, preintegrations, the prior (imu_window.py)
        self.start = VioStart()  # how far the visual-inertial initialization got (vio_start.py)
        self._kf_features: dict[int, tuple[Keypoints, np.ndarray]] = {}
        self._kf_segments: dict[int, tuple[Segments, np.ndarray]] = {}
        self._bootstrapping = True  # no map in the segment yet: frames are matched with its first keyframe
        self._flow: tuple[np.ndarray, np.ndarray, np.ndarray] = (np.zeros(0, np.int64), np.zeros((0, 2)), np.zeros((0, 0), np.uint8))
        self._restart_flow = False
        self.follower = FeatureFollower()  # before the initialization: map points and candidates followed frame to frame
        self._lost_run = 0
        self._last_frame_ns: int | None = None  # the last frame read
        self._R_flow: np.ndarray | None = None  # the camera's rotation since then, from the gyroscope
        self._imu_only_run = 0
        self._disagreeing_run = 0  # frames in a row whose supported visual pose is far from the IMU's prediction
        self._restart_pose: tuple[np.ndarray, np.ndarray] | None = None  # after a detected failure: the new segment's first pose

    @single_threaded_blas
    def step(self) -> Snapshot:
        s = self.settings
        t_start = time.perf_counter()
        timing: dict[str, float] = {Stage.POINT_DM: 0.0, Stage.TRACKING: 0.0}
        frames = lost = reinitializations = 0
        c = self.core
        messages = c.messages = []
        bootstrap = None
        while True:
            i, left, _, kp = c.read_frame(timing)
            frames += 1
            t0 = time.perf_counter()
            t_ns = int(self.data_source.timestamps_ns[i])
            following = self._bootstrapping or self._flow_tracks_on()
            self._R_flow = self._gyro_rotation(self._last_frame_ns, t_ns) if following and self._last_frame_ns is not None else None
            self._last_frame_ns = t_ns
            if self._flow_tracks_on():
                kp = self.follower.follow(left, kp, self.camera, R_prev_cur=self._R_flow)
            if self.keyframes == self.map.segment_start:
                if self._restart_pose is None:
                    (R, t), reason = c.initial_pose(i), "first frame"
                else:
                    (R, t), reason = self._restart_pose, "restart after a failure"
                    self._restart_pose = None
                tracked = Tracked(R, t, np.full(0, -1, np.int64), 0, True)
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
            c.remember_frame(i, tracked.R, tracked.t)
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
            if self._flow_tracks_on() and len(tracked.match) == len(c.local_points):
                m = np.flatnonzero(tracked.match >= 0)
                self.follower.map_points = (c.local_points[m], kp.uv[tracked.match[m]])
            if reason:
                break
            self.map.record_frame(i, self.keyframes - 1, tracked.R, tracked.t)
        return self._vio_keyframe(i, left, kp, tracked, timing, t_start, frames=frames, lost=lost, reinitializations=reinitializations, reason=reason, bootstrap=bootstrap)

    # ------------------------------------------------------------------ start

    def _start_segment(self) -> None:
        """A new map segment from the next keyframe: structure from motion and
        initialization again (the old map stays, frozen)."""
        self.core.start_segment()
        self.inertial.initialized = False
        self.inertial.prior = None
        self._bootstrapping = True
        self.follower.clear()
        self._lost_run = 0
        self._disagreeing_run = 0
        self.start.status = "structure from motion: waiting for parallax (after a loss)"
        self.inertial.marginalized_before = self.keyframes

    def _bootstrap(self, i: int, kp: Keypoints, image: np.ndarray) -> StartPair | None:
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
        dt_s = (int(self.data_source.timestamps_ns[i]) - int(self.map.keyframe_stamp_ns[k0])) * 1e-9
        # Too few features left to pair with; or followed for so long that they drift and the
        # gyroscope's rotation (its bias not yet known) bounds the essential matrix's less and
        # less: a slow creep gave pairs ~90° wrong (docs/results/vio.md, the start).
        why = ""
        if len(ids) < s.init_restart_matches:
            why = f"{len(ids)} features followed from the first keyframe (fewer than {s.init_restart_matches})"
        elif dt_s > s.init_max_pair_interval_s:
            why = f"no initial pair within {s.init_max_pair_interval_s:g} s of the first keyframe"
        if why:
            self.core.messages.append(f"frame {i}: {why}; starting again from this frame")
            self._restart_flow = True
            return None
        kp0 = self._kf_features[k0][0]
        uv0, uv1 = kp0.uv[ids], uv_prev
        R_01_imu = self._gyro_rotation(int(self.map.keyframe_stamp_ns[k0]), int(self.data_source.timestamps_ns[i]))
        return two_view_start(cam, s, ids=ids, uv0=uv0, uv1=uv1, R_01_imu=R_01_imu, dt_s=dt_s, R_world_kf0=self.map.R_world_keyframe[k0], t_world_kf0=self.map.t_world_keyframe[k0], kp=kp, image=image)

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
            return self.core.constant_velocity(i)
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
        if tracked.inliers < s.fallback_tracked_ratio * self.core.last_kf_tracked:
            return "fallback"
        # Rotation-compensated parallax of the tracked points against the last keyframe.
        o = self.map.observations[k]
        ids = self.core.local_points[tracked.match >= 0]
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
        self,
        i: int,
        left: np.ndarray,
        kp: Keypoints,
        tracked: Tracked,
        timing: dict[str, float],
        t_start: float,
        *,
        frames: int,
        lost: int,
        reinitializations: int,
        reason: str,
        bootstrap: StartPair | None,
    ) -> Snapshot:
        s = self.settings
        c = self.core
        use_lines = c.variant.with_lines or not s.skip_unused_stages
        use_planes = c.variant.uses_planes or not s.skip_unused_stages
        k = self.keyframes
        rng = np.random.default_rng([s.seed, k, 0x57E])
        frames_per = max(frames, 1)
        for stage in PER_FRAME_STAGES:
            timing[stage] = timing.get(stage, 0.0) / frames_per

        local_p = c.local_points
        p_match = tracked.match if len(tracked.match) == len(local_p) else np.full(len(local_p), -1, np.int64)
        segments: Segments | None = None
        l_match = np.zeros(0, np.int64)
        local_l = c.local_lines
        timing[Stage.LINE_DM] = 0.0
        # Monocular: the segmenter sees the left image only; it runs on the worker meanwhile.
        plane_job = c.start_segmentation(i, (left, left)) if use_planes and k > self.map.segment_start else None
        if use_lines:
            t0 = time.perf_counter()
            segments = detect_segments(left, settings=s.lines)
            l_match = c.match_lines(tracked.R, tracked.t, local_l, segments) if len(local_l) else np.full(0, -1, np.int64)
            timing[Stage.LINE_DM] = 1e3 * (time.perf_counter() - t0)

        t0 = time.perf_counter()
        status = np.full(len(kp.uv), POINT_UNUSED, np.uint8)
        if len(tracked.match) == len(local_p):
            status[tracked.match[tracked.match >= 0]] = POINT_OUTLIER
        c.add_keyframe(i, tracked.R, tracked.t)
        self.inertial.add_keyframe(self.map, k, self.imu_model)
        if k == self.map.segment_start:  # the start follows this keyframe's features frame to frame
            self._flow = (np.arange(len(kp.uv)), kp.uv.copy(), left)
        obs, new_points, new_lines = self._observe_mono(k, kp, local_p, p_match, segments, local_l, l_match, bootstrap)
        status[p_match[p_match >= 0]] = POINT_TRACKED
        status[c.new_point_kp] = POINT_NEW
        if s.flow_tracks and not self.inertial.initialized:
            self.follower.seed(k, kp, left, self._kf_features[k][1], max_age_keyframes=s.flow_max_age_keyframes, min_distance_px=s.flow_min_distance_px, max_tracks=s.flow_max_tracks)
            self.follower.map_points = (obs.point_id, obs.point_uv)
        c.last_kf_tracked = int(np.count_nonzero(p_match >= 0)) if k > self.map.segment_start + 1 else len(obs.point_id)  # map points tracked (new ones are not yet)
        timing[Stage.MAPPING] = 1e3 * (time.perf_counter() - t0)

        masks, detection, report, hessian = c.detect_and_solve(k, i, obs, new_points, new_lines, rng, timing, planes=plane_job)
        if not self.inertial.initialized:
            start = StartContext(self.map, self.inertial, self.imu_model, self.inertial_source, self.settings, c.messages)
            self.start.try_initialize(k, start)
            if self.inertial.initialized:
                # A visual-inertial bundle adjustment over every aligned keyframe (ORB-SLAM3's
                # after its inertial-only start): the alignment treats the visual positions as
                # exact, the joint solve weighs their pixels and the IMU together.
                report, hessian = c.optimize(k, timing, max_iterations=s.init_joint_iterations)
                self.start.narrow(start)
        elif k > self.start.keyframe and (failure := self._failure(k)):
            reinitializations += 1
            c.messages.append(f"VIO failure ({failure}): starting again from keyframe {k - 1}'s pose (new map segment)")
            self._restart_pose = (self.map.R_world_keyframe[k - 1].copy(), self.map.t_world_keyframe[k - 1].copy())
            self._start_segment()
        elif k > self.start.keyframe:
            self.start.refine(k, StartContext(self.map, self.inertial, self.imu_model, self.inertial_source, self.settings, c.messages))
        if s.frames_by_imu and self.inertial.initialized:
            # At the start every interval of the segment so far (its frames were tracked in the
            # monocular scale), then the newest.
            first = self.map.segment_start + 1 if self.start.keyframe == k else k
            for j in range(max(first, self.map.segment_start + 1), k + 1):
                self._frames_by_imu(j)
        c.follow_keyframe(i, k)

        image = None
        if s.image_scale is not None:
            t0 = time.perf_counter()
            c.line_seg_index = np.arange(len(obs.line_id))
            image = c.draw(left, kp, status, segments if use_lines else None, obs, masks, detection)
            timing[Stage.IMAGE] = 1e3 * (time.perf_counter() - t0)
        total = 1e3 * (time.perf_counter() - t_start) - timing[Stage.LOAD_WAIT] * frames_per
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
        return c.snapshot(k, detection, c.det_state, report, hessian, image=image, tracking=tracking, message="; ".join(c.messages))

    def _observe_mono(
        self, k: int, kp: Keypoints, local_p: np.ndarray, p_match: np.ndarray, segments: Segments | None, local_l: np.ndarray, l_match: np.ndarray, bootstrap: StartPair | None
    ) -> tuple[KeyframeObservations, np.ndarray, np.ndarray]:
        """Keyframe k's observations of map landmarks, and new landmarks triangulated with
        the previous keyframe (or the initial pair's points)."""
        P = self.map.points
        tracked_ids, j, claimed = P.reobserve(local_p, p_match, kp.descriptors, n_features=len(kp.uv))
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
            if self.follower.in_frame():
                ids, fr = self.follower.triangulate(self.map, k, kp, claimed, self._kf_features, settings=self._mono_settings())
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
        self.core.new_point_kp = fresh
        point_id = np.concatenate([tracked_ids, new_points])
        point_kp = np.concatenate([j, fresh])
        self._kf_features[k] = (kp, claimed)
        self._kf_features.pop(k - 1 - self.settings.triangulation_keyframes, None)
        line_id, line_uv, new_lines = np.zeros(0, np.int64), np.zeros((0, 4)), np.zeros(0, np.int64)
        if segments is not None:
            line_id, line_uv, new_lines = observe_mono_lines(self.map, k, segments, local_l, l_match, self._kf_segments, settings=self._mono_settings())
        obs = KeyframeObservations(point_id, kp.uv[point_kp], np.full(len(point_id), np.nan), line_id, line_uv, np.full((len(line_id), 4), np.nan))
        self.map.observations[k] = obs
        return obs, new_points, new_lines

    def _frames_by_imu(self, k: int) -> None:
        """The frames tracked between keyframes k - 1 and k (their reference is k - 1): poses
        from the IMU between the two keyframes' solved states instead of each frame's own
        monocular PnP (VioSettings' `frames_by_imu`). Keyframe k - 1's state is propagated
        to each frame's time and its disagreement with keyframe k's solved pose at k (rotation
        in world axes, position, m) is spread linearly in time over the interval."""
        m = self.map
        idx = np.flatnonzero(m.frame_reference[:] == k - 1)
        idx = idx[m.frame_index[idx] != m.keyframe_frame[k - 1]]
        if not len(idx):
            return
        v, b = self.inertial.velocity[k - 1], self.inertial.bias[k - 1]
        t0_ns, t1_ns = int(m.keyframe_stamp_ns[k - 1]), int(m.keyframe_stamp_ns[k])
        R_k, t_k, _ = self.imu_model.predict(m, k - 1, t1_ns, v, b)
        d_rot = so3.log(m.R_world_keyframe[k] @ R_k.T)
        d_pos = m.t_world_keyframe[k] - t_k
        R_ref, t_ref = m.R_world_keyframe[k - 1], m.t_world_keyframe[k - 1]
        for j in idx:
            t_ns = int(self.data_source.timestamps_ns[int(m.frame_index[j])])
            R_p, t_p, _ = self.imu_model.predict(m, k - 1, t_ns, v, b)
            a = (t_ns - t0_ns) / max(t1_ns - t0_ns, 1)
            R = so3.exp(a * d_rot) @ R_p
            m.R_reference_frame[j] = R_ref.T @ R
            m.t_reference_frame[j] = R_ref.T @ (t_p + a * d_pos - t_ref)

    # ------------------------------------------------------------------ followed features (before the initialization)

    def _failure(self, k: int) -> str:
        """Why keyframe k's inertial state is implausible after its window solve (VioSettings'
        failure detection), or "" when it is not."""
        s = self.settings
        bias, v = self.inertial.bias[k], self.inertial.velocity[k]
        if not (np.all(np.isfinite(bias)) and np.all(np.isfinite(v)) and np.all(np.isfinite(self.map.t_world_keyframe[k]))):
            return "non-finite state"
        if np.linalg.norm(bias[:3]) > s.failure_max_bias_accel:
            return f"accelerometer bias {np.linalg.norm(bias[:3]):.2f} m/s² > {s.failure_max_bias_accel:g}"
        if np.linalg.norm(bias[3:]) > s.failure_max_bias_gyro:
            return f"gyroscope bias {np.linalg.norm(bias[3:]):.3f} rad/s > {s.failure_max_bias_gyro:g}"
        if np.linalg.norm(v) > s.failure_max_speed_mps:
            return f"speed {np.linalg.norm(v):.1f} m/s > {s.failure_max_speed_mps:g}"
        if k > self.map.segment_start:
            dt = (int(self.map.keyframe_stamp_ns[k]) - int(self.map.keyframe_stamp_ns[k - 1])) * 1e-9
            jump = float(np.linalg.norm(self.map.t_world_keyframe[k] - self.map.t_world_keyframe[k - 1]))
            if jump > s.failure_max_speed_mps * dt + s.failure_max_jump_m:
                return f"a jump of {jump:.2f} m in {dt:.2f} s"
        if self._disagreeing_run >= s.failure_disagreeing_frames:  # the restart resets the count
            return f"{s.failure_disagreeing_frames} frames in a row tracked far from the IMU's prediction"
        return ""

    def _check_prediction(self, predicted: tuple[np.ndarray, np.ndarray], tracked: Tracked) -> None:
        """Counts the frames in a row whose well-supported visual pose disagrees with the IMU's
        prediction (VioSettings' failure detection)."""
        s = self.settings
        if not (self.inertial.initialized and tracked.ok and tracked.inliers >= s.failure_support_inliers):
            return
        R_p, t_p = predicted
        d_t = float(np.linalg.norm(tracked.t - t_p))
        d_r = float(np.degrees(np.linalg.norm(so3.log(R_p.T @ tracked.R))))
        self._disagreeing_run = self._disagreeing_run + 1 if (d_t > s.failure_prediction_m or d_r > s.failure_prediction_deg) else 0

    def _flow_tracks_on(self) -> bool:
        """Whether candidate features are followed frame to frame: from the segment's first
        map until the initialization."""
        return self.settings.flow_tracks and not self.inertial.initialized and not self._bootstrapping and self.keyframes > self.map.segment_start

    def _track(self, i: int, kp: Keypoints) -> Tracked:
        """Before the initialization the map points followed from the last frame are matches
        too (the followed ones first, then those the projection search found for the others);
        otherwise the stereo pipeline's tracking."""
        predicted = self._predict(i)
        result = self.core.track(i, kp, predicted=predicted)  # the shared tracking (with this engine's prediction)
        self._check_prediction(predicted, result)
        if not self._flow_tracks_on():
            return result
        need = self.settings.flow_min_tracking_inliers
        return self.follower.track(result, self.camera, self.core.track_settings(), kp, the_map=self.map, local_points=self.core.local_points, min_inliers=need, seed=self.settings.seed + i)

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

    # ------------------------------------------------------------------ the window plan (core.WindowPlan)

    def window_range(self, k: int) -> tuple[int, int]:
        s = self.settings
        return self.inertial.window_range(self.map, k, window=s.window, init_window=s.init_window, fixed_horizon=s.fixed_horizon)

    def window_extension(self) -> WindowExtension:
        s = self.settings
        return InertialWindow(self.inertial, self.map, self.imu_model, InertialWindowSettings(s.window, s.rebias_accel, s.rebias_gyro))

    def solve_variant(self, variant: Variant) -> Variant:
        """The run's variant; points alone until the initialization where
        `VioSettings.points_only_before_init` (an experiment, off by default)."""
        if self.settings.points_only_before_init and not self.inertial.initialized:
            return Variant.P_WO
        return variant

    def finish_snapshot(self, snapshot: Snapshot, k: int) -> Snapshot:
        """With the IMU state (`vio_start.imu_state`)."""
        return dataclasses.replace(snapshot, imu=imu_state(self.map, k, self.inertial, self.start, self.inertial_source, self.imu.timestamp_ns))
