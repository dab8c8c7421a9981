"""The stereo SLAM pipeline of the paper (§III, stereo branch) as a step-able engine.

Input: anything with the reader interface of :class:`backend.data.euroc.EurocDataset`
(`timestamps_ns`, `camera` rectified with its baseline, `rectified_pair(i)`,
`T_world_rect0`, `ground_truth_valid`), such as an EuRoC folder or a
:class:`backend.data.synthetic.SyntheticSequence`. One :meth:`StereoEngine.step` reads frames
until the next keyframe and returns its snapshot.

Every frame: ORB on the left image (point D&M), the pose predicted by a constant-velocity
motion model, map points of the local map (those the window's keyframes see) matched by
projection and the pose refined against them with a Cauchy kernel. When that finds too few
inliers (the motion model failed: fast or suddenly changing motion), four candidates are
tried and the one with the most inliers wins: a three times wider search around the
prediction, the same around the last frame's pose, and PnP-RANSAC on descriptor matches
with the last keyframe's points and with the whole local map; when none has enough
inliers, variants with lines try the local map's lines with the points (`LineAid` in
`stages/track.py`: a bare wall's few corners and its marks' edges); when that fails too,
the frame is placed by optical flow from the last placed frame (`stages/flow_track.py`:
that frame's corners with stereo depth followed into this one, EPnP-RANSAC), and only
where that fails as well is the frame *lost* (its pose is the prediction). A frame placed
by flow becomes a keyframe once it has the keypoints a new map would need, and its pose is
held in every later window. The paper's keyframe rule (at
least 1 s since the last keyframe, the paper's 20 frames at 20 Hz, more than 40 tracked
points, at least 10 % new keypoints) with a quality fallback (tracked points below a share
of the last keyframe's: the scene changed; at least 0.1 s after it) and a fast-motion rule
(less than half of the tracked points would stay in view at the next frame's predicted
pose). Gaps are in seconds, counted in frames at the input's rate.

Every keyframe:
1. stereo matching of its ORB points (right image), LSD + LBD segments in both images,
   stereo-matched, and matched to the local map's lines by projection (line D&M);
2. pose refinement against the matched points and lines (Cauchy);
3. new landmarks from stereo for the features no map landmark claimed (points: depth from
   the disparity, close ones up to `max_depth_m` and far ones beyond while the disparity
   is at least `far_min_disparity_px`; lines: the two triangulated endpoints, close only);
4. plane-instance segmentation (plane seg.) and the co-planar detection (plane fitting):
   per instance, RANSAC with Eq. 4 over its triangulated features, θ_cp = 80 %, merging with
   existing planes; new landmarks tested against existing planes;
5. sliding-window bundle adjustment with the selected variant (Cauchy kernel on the
   reprojection residuals, stereo observations as a second camera `baseline` to the right),
   older keyframes that see window landmarks held fixed;
6. culling: observations that stay far off after the solve are dropped, landmarks whose
   anchor observation is off or that no later keyframe re-observes are removed.

When a frame has features but neither tracking nor relocalization succeeds, the map is
re-initialized at the predicted pose: a new keyframe starts a new map segment (the window
never reaches back across it), and the snapshot reports it. Frames without features (black
frames) are lost and predicted until features return.

Per-frame trajectory (as ORB-SLAM's CameraTrajectory): every tracked frame keeps its pose
relative to its reference keyframe (the newest keyframe when it was tracked; a keyframe is
its own reference), so its world pose follows the keyframes' later optimization:
`T_world_frame = T_world_refkf · T_refkf_frame` (:meth:`StereoEngine.frame_trajectory`).
Lost frames have no pose and are not recorded; a re-initialization frame becomes a keyframe.
"""

from __future__ import annotations

import time
from collections.abc import Callable

import numpy as np

from backend.common.blas import single_threaded_blas
from backend.common.timing import PER_FRAME_STAGES, Stage
from backend.data.source import StereoSource
from backend.frontend.lines import StereoSegments, stereo_segments
from backend.frontend.points import Keypoints, stereo_points
from backend.frontend.segmentation import PlaneSegmenter
from backend.geometry import line as line_geo
from backend.mapping.map import KeyframeObservations
from backend.optim.variant import Variant
from backend.pipeline.core import CoreEngine, PipelineCore, visual_window_range
from backend.pipeline.overlay import POINT_NEW, POINT_OUTLIER, POINT_TRACKED, POINT_UNUSED
from backend.pipeline.snapshot import Snapshot, Tracking
from backend.pipeline.stages.flow_track import FlowReference, track_by_flow
from backend.pipeline.stages.fuse import fuse_points
from backend.pipeline.stages.solve import VisualWindow, WindowExtension
from backend.pipeline.stages.track import Tracked, kept_in_view_next
from backend.pipeline.stereo_settings import StereoSettings
from backend.pipeline.tracking import pixel_errors, refine_pose


class StereoEngine(CoreEngine):
    """The stereo pipeline (module docstring; implements :class:`~backend.pipeline.engine.Engine`
    through :class:`~backend.pipeline.core.CoreEngine`): stereo matching for new landmarks
    and the constant-velocity motion model plugged into the shared :class:`PipelineCore`."""

    def __init__(
        self,
        source: StereoSource,
        *,
        settings: StereoSettings = StereoSettings(),
        name: str = "stereo sequence",
        segmenter: PlaneSegmenter | None = None,
        on_frame: Callable[[int], None] | None = None,
    ) -> None:
        from backend.frontend.segmentation_geometric import GeometricPlaneSegmenter

        self.settings = settings
        self.core = PipelineCore(source, settings=settings, name=name, segmenter=segmenter if segmenter is not None else GeometricPlaneSegmenter(), plan=self, on_frame=on_frame)
        self._flow_reference: FlowReference | None = None  # the last placed frame (stages.flow_track)
        self._pinned: tuple[int, ...] = ()  # keyframes placed by flow: their poses held in the window

    # Checkpoints (backend.pipeline.engine.EngineCheckpoint): the core checkpoints itself; the
    # engine holds nothing else but its settings.
    STATE: tuple[str, ...] = ("_flow_reference", "_pinned")  # the reference is immutable: a checkpoint shares it
    SHARED: tuple[str, ...] = ("settings",)

    def reset(self) -> None:
        self.core.reset()
        self._flow_reference = None
        self._pinned = ()

    @single_threaded_blas
    def step(self) -> Snapshot:
        s = self.settings
        t_start = time.perf_counter()
        timing: dict[str, float] = {Stage.POINT_DM: 0.0, Stage.TRACKING: 0.0}
        frames = lost = reinitializations = 0
        c = self.core
        messages = c.messages = []
        while True:
            i, left, right, kp = c.read_frame(timing)
            frames += 1
            t0 = time.perf_counter()
            if self.keyframes == 0:
                R, t = c.initial_pose(i)
                tracked = Tracked(R, t, np.full(0, -1, np.int64), 0, True)
                reason = "first frame"
            else:
                predicted = c.constant_velocity(i)
                tracked = c.track(i, kp, predicted=predicted, verify_below=self._verify_below(), left=left)
                if not tracked.ok:
                    tracked = self._placed_by_flow(i, left, right, tracked, R_world_predicted=predicted[0], t_world_predicted=predicted[1])
                reason = self._keyframe_reason(i, kp, tracked)
            timing[Stage.TRACKING] += 1e3 * (time.perf_counter() - t0)
            c.remember_frame(i, tracked.R, tracked.t)
            if not tracked.ok:
                lost += 1
                if len(kp.uv) >= 3 * s.min_tracking_inliers:
                    # Features but no pose: a new map segment from this frame's stereo.
                    reinitializations += 1
                    c.start_segment()
                    tracked = Tracked(tracked.R, tracked.t, np.zeros(0, np.int64), 0, True)
                    messages.append(f"tracking lost at frame {i}: map re-initialized at the predicted pose")
                    reason = "re-initialization"
                else:
                    continue
            if s.flow_track is not None:
                self._flow_reference = FlowReference.of(i, left, right, tracked.R, tracked.t)
            if reason:
                break
            c.map.record_frame(i, self.keyframes - 1, tracked.R, tracked.t)
        return self._keyframe(i, left, right, kp, tracked, timing, t_start, frames=frames, lost=lost, reinitializations=reinitializations, message="; ".join(messages), reason=reason)

    # ------------------------------------------------------------------ tracking

    def _placed_by_flow(self, i: int, left: np.ndarray, right: np.ndarray, lost: Tracked, *, R_world_predicted: np.ndarray, t_world_predicted: np.ndarray) -> Tracked:
        """Frame i, which the map could not place (`lost`), placed by optical flow from the
        last placed frame (`stages.flow_track`; the motion model's pose `R_world_predicted`,
        `t_world_predicted` starts a second try); `lost` itself where that fails too or is
        off (`flow_track` None) or no frame was placed yet in this run."""
        s = self.settings
        reference = self._flow_reference
        if s.flow_track is None or reference is None:
            return lost
        pose = track_by_flow(self.core.camera, reference, left, right, settings=s.flow_track, seed=s.seed + i, R_world_predicted=R_world_predicted, t_world_predicted=t_world_predicted)
        if not pose.ok:
            return lost
        self.core.messages.append(f"frame {i}: placed by optical flow from frame {reference.frame} ({pose.inliers} inliers; the map could not place it)")
        return Tracked(pose.R_world_camera, pose.t_world_camera, np.full(len(self.core.local_points), -1, np.int64), 0, True, by_flow=True)

    def _verify_below(self) -> int:
        """The inliers below which the motion model's pose is checked against PnP (the
        prediction is not trusted): all of them before the motion model has a velocity (the
        first frame after a keyframe that starts a map segment), else
        `verify_tracked_ratio` of the last keyframe's tracked points."""
        c = self.core
        if len(c.frame_poses) < 2:
            return np.iinfo(np.int64).max
        return int(np.ceil(self.settings.verify_tracked_ratio * c.last_kf_tracked))

    def _keyframe_reason(self, i: int, kp: Keypoints, tracked: Tracked) -> str:
        """Why frame i becomes a keyframe ("" if it does not)."""
        s = self.settings
        c = self.core
        if not tracked.ok:
            return ""
        last_kf = int(c.map.keyframe_frame[-1])
        gap = i - last_kf
        stamps = c.data_source.timestamps_ns
        min_gap, min_fallback_gap = s.keyframe_gap_frames(1e-9 * float(stamps[i] - stamps[last_kf]) / max(gap, 1))  # the mean frame period since the keyframe
        if tracked.by_flow:  # the map could not place it: new landmarks from its stereo once there are enough to build on
            return "placed by flow" if gap >= min_fallback_gap and len(kp.uv) >= 3 * s.min_tracking_inliers else ""
        new_fraction = 1.0 - tracked.inliers / max(len(kp.uv), 1)
        if gap >= min_gap and tracked.inliers > s.min_tracked_points and new_fraction >= s.min_new_fraction:
            return "rule"
        if gap >= min_fallback_gap and tracked.inliers < s.fallback_tracked_ratio * c.last_kf_tracked:
            return "fallback"
        last = c.frame_poses[-1] if c.frame_poses else None
        if kept_in_view_next(c.camera, s.min_depth_m, i, tracked, last_frame=last, the_map=c.map, local_points=c.local_points) < s.min_kept_in_view:
            return "fast motion"
        return ""

    # ------------------------------------------------------------------ keyframes

    def _keyframe(
        self,
        i: int,
        left: np.ndarray,
        right: np.ndarray,
        kp: Keypoints,
        tracked: Tracked,
        timing: dict[str, float],
        t_start: float,
        *,
        frames: int,
        lost: int,
        reinitializations: int,
        message: str,
        reason: str,
    ) -> Snapshot:
        s = self.settings
        c = self.core
        cam = c.camera
        use_lines = c.variant.with_lines or not s.skip_unused_stages
        use_planes = c.variant.uses_planes or not s.skip_unused_stages
        k = self.keyframes
        rng = np.random.default_rng([s.seed, k, 0x57E])
        frames_per = max(frames, 1)
        for stage in PER_FRAME_STAGES:
            timing[stage] = timing.get(stage, 0.0) / frames_per  # means per frame

        # 1. Stereo points (the left ORB is there already), segments and their map matches;
        # the plane segmentation (images only) meanwhile on the worker.
        plane_job = c.start_segmentation(i, (left, right)) if use_planes else None
        t0 = time.perf_counter()
        stereo = stereo_points(left, right, camera=cam, settings=s.points, left_keypoints=kp)
        timing[Stage.POINT_DM] += 1e3 * (time.perf_counter() - t0) / frames_per
        local_p = c.local_points
        p_match = tracked.match if len(tracked.match) == len(local_p) else np.full(len(local_p), -1, np.int64)
        segs: StereoSegments | None = None
        l_match = np.zeros(0, np.int64)
        local_l = c.local_lines
        timing[Stage.LINE_DM] = 0.0
        if use_lines:
            t0 = time.perf_counter()
            segs = stereo_segments(left, right, camera=cam, settings=s.lines)
            l_match = c.match_lines(tracked.R, tracked.t, local_l, segs.left) if len(local_l) else np.full(0, -1, np.int64)
            timing[Stage.LINE_DM] = 1e3 * (time.perf_counter() - t0)

        # 2. Pose refinement against points and lines.
        t0 = time.perf_counter()
        R, t = tracked.R, tracked.t
        mp = np.flatnonzero(p_match >= 0)
        ml = np.flatnonzero(l_match >= 0)
        if len(mp) >= s.min_tracking_inliers:
            lines_world = (c.map.lines.m[local_l[ml]], c.map.lines.v[local_l[ml]]) if len(ml) else None
            seg_uv = np.concatenate([segs.left.start[l_match[ml]], segs.left.end[l_match[ml]]], axis=1) if len(ml) and segs is not None else None
            ref = refine_pose(cam, R, t, c.map.points.p_world[local_p[mp]], stereo.uv_left[p_match[mp]], lines_world=lines_world, segments_uv=seg_uv, sigma_px=s.pixel_sigma, cauchy=s.cauchy)
            R, t = ref.R_world_camera, ref.t_world_camera
            err = pixel_errors(cam, R, t, c.map.points.p_world[local_p[mp]], stereo.uv_left[p_match[mp]])
            p_match = p_match.copy()
            p_match[mp[~(err < s.outlier_px)]] = -1
        timing[Stage.TRACKING] += 1e3 * (time.perf_counter() - t0) / frames_per

        # 3. The keyframe, its observations and new landmarks.
        t0 = time.perf_counter()
        if tracked.by_flow:
            self._pinned = (*self._pinned, k)
        status = np.full(len(kp.uv), POINT_UNUSED, np.uint8)
        status[tracked.match[tracked.match >= 0]] = POINT_OUTLIER if len(tracked.match) == len(local_p) else POINT_UNUSED
        c.add_keyframe(i, R, t)
        obs, new_points, new_lines, p_match = self._observe(k, R, t, kp, stereo, local_p, p_match, segs, local_l, l_match)
        status[p_match[p_match >= 0]] = POINT_TRACKED
        status[c.new_point_kp] = POINT_NEW
        c.last_kf_tracked = len(obs.point_id)
        timing[Stage.MAPPING] = 1e3 * (time.perf_counter() - t0)

        # 4. Plane segmentation and co-planar detection, 5. window bundle adjustment, 6. culling.
        masks, detection, report, hessian = c.detect_and_solve(k, i, obs, new_points, new_lines, rng, timing, planes=plane_job)
        c.follow_keyframe(i, k)  # the motion model continues from the optimized keyframe pose
        if s.flow_track is not None:  # and so does the flow's reference
            self._flow_reference = FlowReference.of(i, left, right, c.map.R_world_keyframe[k], c.map.t_world_keyframe[k])

        image = None
        if s.image_scale is not None:
            t0 = time.perf_counter()
            image = c.draw(left, kp, status, segs, obs, masks, detection)
            timing[Stage.IMAGE] = 1e3 * (time.perf_counter() - t0)
        total = 1e3 * (time.perf_counter() - t_start) - timing[Stage.LOAD_WAIT] * frames_per  # reading or rendering images is not the pipeline's
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
        return c.snapshot(k, detection, c.det_state, report, hessian, image=image, tracking=tracking, message=message)

    def _observe(
        self, k: int, R: np.ndarray, t: np.ndarray, kp: Keypoints, stereo, local_p: np.ndarray, p_match: np.ndarray, segs: StereoSegments | None, local_l: np.ndarray, l_match: np.ndarray
    ) -> tuple[KeyframeObservations, np.ndarray, np.ndarray, np.ndarray]:
        """Record keyframe k's observations of map landmarks and create new ones from stereo;
        the local map's points that tracking left unmatched are fused first (`stages.fuse`).
        Returns the observations, the new points' and lines' ids, and `p_match` with the
        fused points' keypoints added."""
        s = self.settings
        c = self.core
        P, Lm = c.map.points, c.map.lines
        z = stereo.p_cam[:, 2]
        usable = stereo.matched & (z > s.min_depth_m) & (z < s.depth_limit_m(c.camera))  # close and far points
        if s.fuse is not None and len(local_p):
            free = usable.copy()
            free[p_match[p_match >= 0]] = False
            unmatched = np.flatnonzero(p_match < 0)
            fused = fuse_points(c.camera, R, t, P.p_world[local_p[unmatched]], P.desc[local_p[unmatched]], stereo, free, settings=s.fuse)
            p_match = p_match.copy()
            p_match[unmatched[fused >= 0]] = fused[fused >= 0]
        tracked_ids, j, claimed = P.reobserve(local_p, p_match, kp.descriptors, n_features=len(kp.uv))
        fresh = np.flatnonzero(~claimed & usable)
        c.new_point_kp = fresh
        new_points = P.add(
            p_world=stereo.p_cam[fresh] @ R.T + t,
            ok=np.ones(len(fresh), bool),
            anchor=np.full(len(fresh), k),
            anchor_uv=stereo.uv_left[fresh],
            anchor_ur=stereo.u_right[fresh],
            plane=np.full(len(fresh), -1),
            desc=kp.descriptors[fresh],
            n_kf=np.ones(len(fresh), np.int64),
        )
        point_id = np.concatenate([tracked_ids, new_points])
        point_kp = np.concatenate([j, fresh])
        line_id = np.zeros(0, np.int64)
        line_uv = np.zeros((0, 4))
        line_ruv = np.zeros((0, 4))
        new_lines = np.zeros(0, np.int64)
        if segs is not None:
            left, right = segs.left, segs.right
            uv = np.concatenate([left.start, left.end], axis=1)
            ruv = np.full((len(left), 4), np.nan)
            has_r = segs.right_index >= 0
            ruv[has_r] = np.concatenate([right.start[segs.right_index[has_r]], right.end[segs.right_index[has_r]]], axis=1)
            tracked_l, jl, claimed_l = Lm.reobserve(local_l, l_match, left.descriptors, n_features=len(left))
            ps, pe = segs.p_start_cam, segs.p_end_cam
            length = np.linalg.norm(pe - ps, axis=1)
            with np.errstate(invalid="ignore"):
                good = has_r & (np.minimum(ps[:, 2], pe[:, 2]) > s.min_depth_m) & (np.maximum(ps[:, 2], pe[:, 2]) < s.max_depth_m) & (length > s.min_line_length_m)
            fresh_l = np.flatnonzero(~claimed_l & good)
            a_w, b_w = ps[fresh_l] @ R.T + t, pe[fresh_l] @ R.T + t
            m, v = line_geo.from_points(a_w, b_w)
            norm = np.linalg.norm(v, axis=1, keepdims=True)
            new_lines = Lm.add(
                m=m / norm,
                v=v / norm,
                ok=np.ones(len(fresh_l), bool),
                anchor=np.full(len(fresh_l), k),
                anchor_uv=uv[fresh_l],
                anchor_ruv=ruv[fresh_l],
                plane=np.full(len(fresh_l), -1),
                desc=left.descriptors[fresh_l],
                n_kf=np.ones(len(fresh_l), np.int64),
            )
            line_id = np.concatenate([tracked_l, new_lines])
            sel = np.concatenate([jl, fresh_l])
            line_uv, line_ruv = uv[sel], ruv[sel]
            c.line_seg_index = sel
        else:
            c.line_seg_index = np.zeros(0, np.int64)
        obs = KeyframeObservations(point_id, stereo.uv_left[point_kp], stereo.u_right[point_kp], line_id, line_uv, line_ruv)
        c.map.observations[k] = obs
        return obs, new_points, new_lines, p_match

    # ------------------------------------------------------------------ the window plan (core.WindowPlan)

    def window_range(self, k: int) -> tuple[int, int]:
        s = self.settings
        return visual_window_range(self.core.map, k, window=s.window, fixed_horizon=s.fixed_horizon)

    def window_extension(self) -> WindowExtension:
        """The visual window (VIO adds its inertial part), the keyframes placed by flow held."""
        return VisualWindow(np.asarray(self._pinned, np.int64))

    def finish_snapshot(self, snapshot: Snapshot, k: int) -> Snapshot:
        return snapshot

    def solve_variant(self, variant: Variant) -> Variant:
        """Always the run's variant (stereo depth fixes the scale from the first keyframe)."""
        return variant
