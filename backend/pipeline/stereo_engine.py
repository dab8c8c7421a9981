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
inliers, the frame is *lost* (its pose is the prediction). The paper's keyframe rule (at
least 20 frames since the last keyframe, more than 40 tracked points, at least 10 % new
keypoints) with a quality fallback (tracked points below a share of the last keyframe's)
and a fast-motion rule (less than half of the tracked points would stay in view at the
next frame's predicted pose).

Every keyframe:
1. stereo matching of its ORB points (right image), LSD + LBD segments in both images,
   stereo-matched, and matched to the local map's lines by projection (line D&M);
2. pose refinement against the matched points and lines (Cauchy);
3. new landmarks from stereo for the features no map landmark claimed (points: depth from
   the disparity; lines: the two triangulated endpoints);
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

import dataclasses
import time
from collections.abc import Callable

import numpy as np

from backend.common.timing import PER_FRAME_STAGES, Stage
from backend.data.source import StereoSource
from backend.frontend.lines import LineSettings, Segments, StereoSegments, stereo_segments
from backend.frontend.points import Keypoints, PointSettings, detect_points, stereo_points
from backend.frontend.segmentation import PlaneMasks, PlaneSegmenter
from backend.geometry import line as line_geo
from backend.mapping import coplanar
from backend.mapping.map import KeyframeObservations, Map
from backend.mapping.window import Window, WindowSettings
from backend.optim.problem import build_problem
from backend.optim.structure import HessianStructure, hessian_structure
from backend.optim.variant import Variant
from backend.pipeline.engine import EndOfSequence, EngineCheckpoint
from backend.pipeline.overlay import POINT_NEW, POINT_OUTLIER, POINT_TRACKED, POINT_UNUSED, draw_keyframe_image
from backend.pipeline.snapshot import (
    Detection,
    FrameTrajectory,
    KeyframeImage,
    OptimizationReport,
    Snapshot,
    Tracking,
    Trajectory,
    frozen,
)
from backend.pipeline.stages.culling import CullSettings, cull, local_map
from backend.pipeline.stages.planes import FeatureStates, detect_planes, segment_keyframe
from backend.pipeline.stages.snapshot import build_snapshot
from backend.pipeline.stages.solve import SolveSettings, VisualWindow, WindowExtension, solve_window
from backend.pipeline.stages.track import Tracked, TrackSettings, extrapolate, kept_in_view_next, match_map_lines, track_frame
from backend.pipeline.tracking import pixel_errors, refine_pose


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


class StereoEngine:
    """The stereo pipeline (implements :class:`~backend.pipeline.engine.Engine`)."""

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

        self.data_source = source
        self.settings = settings
        self._name = name
        self._variant = settings.variant
        self.segmenter = segmenter if segmenter is not None else GeometricPlaneSegmenter()
        self.camera = source.camera
        self.on_frame = on_frame
        self.reset()

    # ------------------------------------------------------------------ Engine interface

    @property
    def source(self) -> str:
        return self._name

    @property
    def variant(self) -> Variant:
        return self._variant

    @property
    def keyframes(self) -> int:
        return len(self.map)

    @property
    def frames(self) -> int:
        """Frames read so far."""
        return self._next_frame

    def set_variant(self, variant: Variant) -> None:
        self._variant = Variant.parse(variant)

    # A checkpoint: the map's own copy, a deep copy of the engine's state below, and the
    # attributes shared by reference (the input, settings, callbacks, the last immutable
    # snapshot). Every attribute is one of the three (tests/backend/pipeline/test_checkpoints.py).
    STATE: tuple[str, ...] = (
        "_next_frame",
        "_variant",
        "_local_points",
        "_local_lines",
        "_frame_poses",
        "_last_kf_tracked",
        "_window",
        "_messages",
        "_det_state",
        "_instance_plane",
        "_new_point_kp",
        "_line_seg_index",
    )
    SHARED: tuple[str, ...] = ("data_source", "settings", "_name", "segmenter", "camera", "on_frame", "_last")

    def checkpoint(self) -> EngineCheckpoint:
        return EngineCheckpoint.of(self, self.map)

    def restore(self, state: EngineCheckpoint) -> None:
        self.map = state.restore_into(self)

    def reset(self) -> None:
        self._next_frame = 0
        self.map = Map(self.camera)
        self._local_points = np.zeros(0, np.int64)
        self._local_lines = np.zeros(0, np.int64)
        self._frame_poses: list[tuple[int, np.ndarray, np.ndarray]] = []  # (frame, R, t) of the last two frames
        self._last_kf_tracked = 0
        self._window: Window | None = None
        self._last: Snapshot | None = None
        self._messages: list[str] = []

    def step(self) -> Snapshot:
        s = self.settings
        t_start = time.perf_counter()
        timing: dict[str, float] = {Stage.POINT_DM: 0.0, Stage.TRACKING: 0.0}
        frames = lost = reinitializations = 0
        messages = self._messages = []
        while True:
            i, left, right, kp = self._read_frame(timing)
            frames += 1
            t0 = time.perf_counter()
            if self.keyframes == 0:
                R, t = self._initial_pose(i)
                tracked = Tracked(R, t, np.full(0, -1, np.int64), 0, True)
                reason = "first frame"
            else:
                tracked = self._track(i, kp)
                reason = self._keyframe_reason(i, kp, tracked)
            timing[Stage.TRACKING] += 1e3 * (time.perf_counter() - t0)
            self._remember_frame(i, tracked.R, tracked.t)
            if not tracked.ok:
                lost += 1
                if len(kp.uv) >= 3 * s.min_tracking_inliers:
                    # Features but no pose: a new map segment from this frame's stereo.
                    reinitializations += 1
                    self.map.segment_start = self.keyframes
                    self._local_points = np.zeros(0, np.int64)
                    self._local_lines = np.zeros(0, np.int64)
                    tracked = Tracked(tracked.R, tracked.t, np.zeros(0, np.int64), 0, True)
                    messages.append(f"tracking lost at frame {i}: map re-initialized at the predicted pose")
                    reason = "re-initialization"
                else:
                    continue
            if reason:
                break
            self.map.record_frame(i, self.keyframes - 1, tracked.R, tracked.t)
        return self._keyframe(i, left, right, kp, tracked, timing, t_start, frames=frames, lost=lost, reinitializations=reinitializations, message="; ".join(messages), reason=reason)

    def _read_frame(self, timing: dict[str, float]) -> tuple[int, np.ndarray, np.ndarray, Keypoints]:
        """The next frame: its index, rectified pair and left ORB keypoints (reading and
        detection times added to `timing`'s "load" and "point_dm"). Raises EndOfSequence."""
        n = len(self.data_source)
        if self._next_frame >= n:
            raise EndOfSequence(f"{self._name}: all {n} frames processed")
        i = self._next_frame
        self._next_frame += 1
        t0 = time.perf_counter()
        left, right = self.data_source.rectified_pair(i)
        timing[Stage.LOAD] = timing.get(Stage.LOAD, 0.0) + 1e3 * (time.perf_counter() - t0)
        if self.on_frame is not None:
            self.on_frame(i)
        t0 = time.perf_counter()
        kp = detect_points(left, settings=self.settings.points)
        timing[Stage.POINT_DM] += 1e3 * (time.perf_counter() - t0)
        return i, left, right, kp

    def reoptimize(self) -> Snapshot:
        if self._last is None:
            raise RuntimeError("nothing to re-optimize before the first step")
        last = self._last
        timing: dict[str, float] = {}
        t0 = time.perf_counter()
        report, hessian = self._optimize(last.keyframe, timing)
        timing[Stage.TOTAL] = 1e3 * (time.perf_counter() - t0)
        self._last = self._snapshot(last.keyframe, last.detection, self._det_state, report, hessian, image=last.image, tracking=last.tracking, message=last.message)
        return self._last

    def frame_trajectory(self) -> FrameTrajectory:
        """Every tracked frame so far (lost frames left out), in frame order, at its pose
        relative to its reference keyframe composed with that keyframe's latest estimate."""
        frame, ref, R, t = self.map.frame_poses()
        stamp = np.asarray(self.data_source.timestamps_ns, dtype=np.int64)[frame]
        R_gt = np.full((len(frame), 3, 3), np.nan)
        t_gt = np.full((len(frame), 3), np.nan)
        if len(frame):
            valid = np.asarray(self.data_source.ground_truth_valid, dtype=bool)[frame]
            T = np.asarray(self.data_source.T_world_rect0)[frame[valid]]
            R_gt[valid], t_gt[valid] = T[:, :3, :3], T[:, :3, 3]
        kf_frame = self.map.keyframe_frame[:]
        is_kf = kf_frame[ref] == frame
        return FrameTrajectory(
            frame=frozen(frame),
            reference_keyframe=frozen(ref),
            is_keyframe=frozen(is_kf),
            estimate=Trajectory.of(stamp, R, t),
            ground_truth=Trajectory.of(stamp.copy(), R_gt, t_gt),
        )

    def compare_hessians(self, variants: tuple[Variant, ...]) -> dict[Variant, HessianStructure]:
        if self._window is None:
            return {}
        return {v: hessian_structure(build_problem(self._window.data, v, robust_px=self.settings.cauchy)) for v in variants}

    # ------------------------------------------------------------------ tracking

    def _initial_pose(self, i: int) -> tuple[np.ndarray, np.ndarray]:
        """The first keyframe at its ground-truth pose where known (the gauge), else the origin."""
        if bool(self.data_source.ground_truth_valid[i]):
            T = self.data_source.T_world_rect0[i]
            return T[:3, :3].copy(), T[:3, 3].copy()
        return np.eye(3), np.zeros(3)

    def _remember_frame(self, i: int, R: np.ndarray, t: np.ndarray) -> None:
        self._frame_poses = (self._frame_poses + [(i, R, t)])[-2:]

    def _predict(self, i: int) -> tuple[np.ndarray, np.ndarray]:
        """Constant-velocity prediction from the last two frames' poses (per frame)."""
        (j1, R1, t1) = self._frame_poses[-1]
        if len(self._frame_poses) < 2:
            return R1, t1
        (j0, R0, t0) = self._frame_poses[-2]
        return extrapolate(R0, t0, R1, t1, (i - j1) / max(j1 - j0, 1))

    def _track_settings(self) -> TrackSettings:
        s = self.settings
        return TrackSettings(s.search_radius_px, s.refine_radius_px, s.max_hamming, s.match_ratio, s.min_tracking_inliers, s.pixel_sigma, s.cauchy, s.outlier_px, s.seed)

    def _track(self, i: int, kp: Keypoints) -> Tracked:
        """Pose of frame i against the local map (module docstring; stages/track.py)."""
        last = (self._frame_poses[-1][1], self._frame_poses[-1][2]) if len(self._frame_poses) == 2 else None  # (one frame: the prediction is its pose)
        return track_frame(self.camera, self._track_settings(), i, kp, the_map=self.map, local_points=self._local_points, predicted=self._predict(i), last_frame=last, messages=self._messages)

    def _keyframe_reason(self, i: int, kp: Keypoints, tracked: Tracked) -> str:
        """Why frame i becomes a keyframe ("" if it does not)."""
        s = self.settings
        if not tracked.ok:
            return ""
        gap = i - int(self.map.keyframe_frame[-1])
        new_fraction = 1.0 - tracked.inliers / max(len(kp.uv), 1)
        if gap >= s.min_keyframe_gap and tracked.inliers > s.min_tracked_points and new_fraction >= s.min_new_fraction:
            return "rule"
        if gap >= s.min_fallback_gap and tracked.inliers < s.fallback_tracked_ratio * self._last_kf_tracked:
            return "fallback"
        last = self._frame_poses[-1] if self._frame_poses else None
        if kept_in_view_next(self.camera, s.min_depth_m, i, tracked, last_frame=last, the_map=self.map, local_points=self._local_points) < s.min_kept_in_view:
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
        cam = self.camera
        use_lines = self._variant.with_lines or not s.skip_unused_stages
        use_planes = self._variant.uses_planes or not s.skip_unused_stages
        k = self.keyframes
        rng = np.random.default_rng([s.seed, k, 0x57E])
        frames_per = max(frames, 1)
        for stage in PER_FRAME_STAGES:
            timing[stage] = timing.get(stage, 0.0) / frames_per  # means per frame

        # 1. Stereo points (the left ORB is there already), segments and their map matches.
        t0 = time.perf_counter()
        stereo = stereo_points(left, right, camera=cam, settings=s.points, left_keypoints=kp)
        timing[Stage.POINT_DM] += 1e3 * (time.perf_counter() - t0) / frames_per
        local_p = self._local_points
        p_match = tracked.match if len(tracked.match) == len(local_p) else np.full(len(local_p), -1, np.int64)
        segs: StereoSegments | None = None
        l_match = np.zeros(0, np.int64)
        local_l = self._local_lines
        timing[Stage.LINE_DM] = 0.0
        if use_lines:
            t0 = time.perf_counter()
            segs = stereo_segments(left, right, camera=cam, settings=s.lines)
            l_match = self._match_lines(tracked.R, tracked.t, local_l, segs.left) if len(local_l) else np.full(0, -1, np.int64)
            timing[Stage.LINE_DM] = 1e3 * (time.perf_counter() - t0)

        # 2. Pose refinement against points and lines.
        t0 = time.perf_counter()
        R, t = tracked.R, tracked.t
        mp = np.flatnonzero(p_match >= 0)
        ml = np.flatnonzero(l_match >= 0)
        if len(mp) >= s.min_tracking_inliers:
            lines_world = (self.map.lines.m[local_l[ml]], self.map.lines.v[local_l[ml]]) if len(ml) else None
            seg_uv = np.concatenate([segs.left.start[l_match[ml]], segs.left.end[l_match[ml]]], axis=1) if len(ml) and segs is not None else None
            ref = refine_pose(cam, R, t, self.map.points.p_world[local_p[mp]], stereo.uv_left[p_match[mp]], lines_world=lines_world, segments_uv=seg_uv, sigma_px=s.pixel_sigma, cauchy=s.cauchy)
            R, t = ref.R_world_camera, ref.t_world_camera
            err = pixel_errors(cam, R, t, self.map.points.p_world[local_p[mp]], stereo.uv_left[p_match[mp]])
            p_match = p_match.copy()
            p_match[mp[~(err < s.outlier_px)]] = -1
        timing[Stage.TRACKING] += 1e3 * (time.perf_counter() - t0) / frames_per

        # 3. The keyframe, its observations and new landmarks.
        t0 = time.perf_counter()
        status = np.full(len(kp.uv), POINT_UNUSED, np.uint8)
        status[tracked.match[tracked.match >= 0]] = POINT_OUTLIER if len(tracked.match) == len(local_p) else POINT_UNUSED
        self._add_keyframe(i, R, t)
        obs, new_points, new_lines = self._observe(k, R, t, kp, stereo, local_p, p_match, segs, local_l, l_match)
        status[p_match[p_match >= 0]] = POINT_TRACKED
        status[self._new_point_kp] = POINT_NEW
        self._last_kf_tracked = len(obs.point_id)
        timing[Stage.MAPPING] = 1e3 * (time.perf_counter() - t0)

        # 4. Plane segmentation and co-planar detection, 5. window bundle adjustment, 6. culling.
        masks, detection, report, hessian = self._detect_and_solve(k, i, obs, new_points, new_lines, rng, timing, images=(left, right) if use_planes else None)
        if self._frame_poses:  # the motion model continues from the optimized keyframe pose
            self._frame_poses[-1] = (i, self.map.R_world_keyframe[k].copy(), self.map.t_world_keyframe[k].copy())

        image = None
        if s.image_scale is not None:
            t0 = time.perf_counter()
            image = self._draw(left, kp, status, segs, obs, masks, detection)
            timing[Stage.IMAGE] = 1e3 * (time.perf_counter() - t0)
        total = 1e3 * (time.perf_counter() - t_start) - timing[Stage.LOAD] * frames_per  # reading or rendering images is not the pipeline's
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
        self._last = self._snapshot(k, detection, self._det_state, report, hessian, image=image, tracking=tracking, message=message)
        return self._last

    def _detect_and_solve(self, k: int, i: int, obs, new_points, new_lines, rng, timing: dict[str, float], *, images: tuple[np.ndarray, np.ndarray] | None):
        """Steps 4–6 for keyframe k (frame i): plane segmentation of `images` (the
        segmenter's left and right; None: no planes this keyframe) and co-planar detection,
        the window bundle adjustment, culling and the next local map (backend/pipeline/stages).
        Returns the masks (or None), the detection, the solver report and the Hessian image."""
        masks: PlaneMasks | None = None
        detection = Detection((), (), (), (), ())
        self._det_state = FeatureStates.undetected(self.map, obs).as_tuple()
        timing[Stage.PLANE_SEG] = timing[Stage.PLANE_FIT] = 0.0
        if images is not None:
            t0 = time.perf_counter()
            masks = segment_keyframe(self.segmenter, i, *images, self.camera)
            timing[Stage.PLANE_SEG] = 1e3 * (time.perf_counter() - t0)
            t0 = time.perf_counter()
            found = detect_planes(self.map, obs, masks, new_points, new_lines, rng, settings=self.settings.coplanar)
            detection, self._det_state, self._instance_plane = found.detection, found.features.as_tuple(), found.instance_plane
            timing[Stage.PLANE_FIT] = 1e3 * (time.perf_counter() - t0)
        report, hessian = self._optimize(k, timing)
        t0 = time.perf_counter()
        s = self.settings
        w0, _ = self._window_range(k)
        cull(self.map, k, w0, settings=CullSettings(s.outlier_px, s.min_depth_m, s.max_depth_m, s.cull_after_keyframes, s.min_keyframe_observations))
        self._local_points, self._local_lines = local_map(self.map, k, w0)
        timing[Stage.CULLING] = 1e3 * (time.perf_counter() - t0)
        return masks, detection, report, hessian

    def _add_keyframe(self, i: int, R: np.ndarray, t: np.ndarray) -> None:
        """Frame i becomes a keyframe at (R, t), with its true pose where the input has it."""
        T_true = self.data_source.T_world_rect0[i] if bool(self.data_source.ground_truth_valid[i]) else None
        self.map.add_keyframe(i, R, t, stamp_ns=int(self.data_source.timestamps_ns[i]), T_world_true=T_true)

    def _observe(
        self, k: int, R: np.ndarray, t: np.ndarray, kp: Keypoints, stereo, local_p: np.ndarray, p_match: np.ndarray, segs: StereoSegments | None, local_l: np.ndarray, l_match: np.ndarray
    ) -> tuple[KeyframeObservations, np.ndarray, np.ndarray]:
        """Record keyframe k's observations of map landmarks and create new ones from stereo."""
        s = self.settings
        P, Lm = self.map.points, self.map.lines
        mp = np.flatnonzero(p_match >= 0)
        j = p_match[mp]
        tracked_ids = local_p[mp]
        P.desc[tracked_ids] = kp.descriptors[j]  # the newest view describes the point best
        P.n_kf[tracked_ids] = P.n_kf[tracked_ids] + 1
        claimed = np.zeros(len(kp.uv), bool)
        claimed[j] = True
        z = stereo.p_cam[:, 2]
        fresh = np.flatnonzero(~claimed & stereo.matched & (z > s.min_depth_m) & (z < s.max_depth_m))
        self._new_point_kp = fresh
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
            ml = np.flatnonzero(l_match >= 0)
            jl = l_match[ml]
            tracked_l = local_l[ml]
            Lm.desc[tracked_l] = left.descriptors[jl]
            Lm.n_kf[tracked_l] = Lm.n_kf[tracked_l] + 1
            claimed_l = np.zeros(len(left), bool)
            claimed_l[jl] = True
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
            self._line_seg_index = sel
        else:
            self._line_seg_index = np.zeros(0, np.int64)
        obs = KeyframeObservations(point_id, stereo.uv_left[point_kp], stereo.u_right[point_kp], line_id, line_uv, line_ruv)
        self.map.observations[k] = obs
        return obs, new_points, new_lines

    def _match_lines(self, R: np.ndarray, t: np.ndarray, ids: np.ndarray, segments: Segments) -> np.ndarray:
        s = self.settings
        return match_map_lines(self.map, R, t, ids, segments, min_depth_m=s.min_depth_m, line_search_px=s.line_search_px, settings=s.lines)

    # ------------------------------------------------------------------ window bundle adjustment

    def _window_range(self, k: int) -> tuple[int, int]:
        s = self.settings
        w0 = max(self.map.segment_start, k - s.window + 1)
        return w0, max(self.map.segment_start, w0 - s.fixed_horizon)

    def _window_extension(self) -> WindowExtension:
        """What this engine's window adds to the visual one (nothing; VIO: its inertial part)."""
        return VisualWindow()

    def _optimize(self, k: int, timing: dict[str, float]) -> tuple[OptimizationReport, HessianStructure | None]:
        s = self.settings
        w0, oldest = self._window_range(k)
        settings = SolveSettings(method=s.method, max_iterations=s.max_iterations, cauchy=s.cauchy, hessian=s.hessian, window=WindowSettings(s.min_depth_m, s.pixel_sigma, s.min_plane_support))
        self._window, report, hessian = solve_window(self.map, k, self._variant, w0=w0, oldest=oldest, extension=self._window_extension(), settings=settings, timing=timing)
        return report, hessian

    # ------------------------------------------------------------------ snapshot

    def _draw(
        self, left: np.ndarray, kp: Keypoints, status: np.ndarray, segs: StereoSegments | Segments | None, obs: KeyframeObservations, masks: PlaneMasks | None, detection: Detection
    ) -> KeyframeImage:
        if segs is not None and len(self._line_seg_index):
            seg_uv = obs.line_uv.reshape(-1, 2, 2)
            seg_plane = np.where(self.map.lines.ok[obs.line_id], self.map.lines.plane[obs.line_id], -1)
        else:
            seg_uv, seg_plane = np.zeros((0, 2, 2)), np.zeros(0, np.int64)
        instance_plane = self._instance_plane if masks is not None and len(self._instance_plane) == masks.count else None
        return draw_keyframe_image(
            left,
            points_uv=kp.uv,
            point_status=status,
            segments_uv=seg_uv,
            segment_plane=seg_plane,
            instance_labels=None if masks is None else masks.labels,
            instance_plane=instance_plane,
            scale=float(self.settings.image_scale or 1.0),
        )

    def _snapshot(
        self, k: int, detection: Detection, det_state: tuple, report: OptimizationReport, hessian: HessianStructure | None, *, image: KeyframeImage | None, tracking: Tracking | None, message: str
    ) -> Snapshot:
        w0, _ = self._window_range(k)
        return build_snapshot(self.map, k, w0, detection, det_state, report, hessian, source=self._name, image=image, tracking=tracking, message=message)
