"""What the two image engines share, as one object they each hold (composition, not a base
engine): :class:`PipelineCore` owns the input position, the map, the local map, the
constant-velocity motion model, the last window and the last snapshot, and runs the steps
that do not depend on stereo or monocular-inertial input: reading a frame and its ORB
keypoints, tracking a frame against the local map (`stages.track`), adding a keyframe,
matching map lines, plane segmentation and detection (`stages.planes`), the window solve
(`stages.solve`), culling (`stages.culling`), the keyframe image and the snapshot.

What differs comes from the engine that holds the core, as its :class:`WindowPlan`: which
keyframes the window spans, what it adds to the visual problem (nothing for stereo; VIO's
inertial part) and what a snapshot carries besides (VIO's IMU state). The stereo engine
(`stereo_engine.py`) plugs in stereo matching; VIO (`vio_engine.py`) optical flow, the IMU's
prediction, its start and the inertial window. :class:`CoreEngine` is the
:class:`~backend.pipeline.engine.Engine` facade both expose: one-line delegations to the
core, nothing engine-specific.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from concurrent.futures import Future
from typing import Protocol

import numpy as np

from backend.common import workers
from backend.common.timing import Stage
from backend.data.source import StereoSource
from backend.frontend.lines import Segments, StereoSegments, detect_segments
from backend.frontend.points import Keypoints, detect_points
from backend.frontend.segmentation import PlaneMasks, PlaneSegmenter
from backend.geometry.camera import PinholeCamera
from backend.mapping.map import KeyframeObservations, Map
from backend.mapping.window import Window, WindowSettings
from backend.optim.problem import build_problem
from backend.optim.structure import HessianStructure, hessian_structure
from backend.optim.variant import Variant
from backend.pipeline.engine import EndOfSequence, EngineCheckpoint
from backend.pipeline.overlay import draw_keyframe_image
from backend.pipeline.prefetch import FramePrefetch, timed_prepare
from backend.pipeline.snapshot import Detection, FrameTrajectory, KeyframeImage, OptimizationReport, Snapshot, Tracking, Trajectory, frozen
from backend.pipeline.stages.culling import CullSettings, cull, local_map
from backend.pipeline.stages.planes import FeatureStates, detect_planes, segment_keyframe
from backend.pipeline.stages.snapshot import build_snapshot
from backend.pipeline.stages.solve import SolveSettings, WindowExtension, solve_window
from backend.pipeline.stages.track import LineAid, Tracked, TrackSettings, extrapolate, match_map_lines, track_frame
from backend.pipeline.stereo_settings import StereoSettings


class WindowPlan(Protocol):
    """What an engine plugs into its core's window solve and snapshot."""

    def window_range(self, k: int) -> tuple[int, int]:
        """Keyframe k's window `[w0, k]` and the oldest keyframe whose observations enter
        (held fixed)."""
        ...

    def window_extension(self) -> WindowExtension:
        """What the window adds to the visual problem (`stages.solve`)."""
        ...

    def finish_snapshot(self, snapshot: Snapshot, k: int) -> Snapshot:
        """Keyframe k's snapshot with what the engine adds (or as it is)."""
        ...

    def solve_variant(self, variant: Variant) -> Variant:
        """The variant the window is solved with now, for the run's `variant` (VIO: points
        alone until the initialization where `VioSettings.points_only_before_init`, off by
        default)."""
        ...


def visual_window_range(the_map: Map, k: int, *, window: int, fixed_horizon: int) -> tuple[int, int]:
    """The last `window` keyframes of the current map segment, and `fixed_horizon` keyframes
    before them held fixed (never across a segment's start)."""
    w0 = max(the_map.segment_start, k - window + 1)
    return w0, max(the_map.segment_start, w0 - fixed_horizon)


class PipelineCore:
    """The state and the steps both image engines share (module docstring). `settings` are
    the stereo settings (VIO's extend them); `plan` is the engine that holds the core."""

    # A checkpoint: the map's own copy, a deep copy of the state below, and the attributes
    # shared by reference (the input, settings, callbacks, the plan, the last immutable
    # snapshot). Every attribute is one of the three (tests/backend/pipeline/test_checkpoints.py).
    STATE: tuple[str, ...] = (
        "next_frame",
        "variant",
        "local_points",
        "local_lines",
        "frame_poses",
        "last_kf_tracked",
        "window",
        "messages",
        "det_state",
        "instance_plane",
        "new_point_kp",
        "line_seg_index",
    )
    SHARED: tuple[str, ...] = ("data_source", "settings", "name", "segmenter", "camera", "on_frame", "plan", "last", "prefetch")

    # The last keyframe's, set by its steps (none before the first): the features' plane
    # states, each segmentation instance's plane, the keypoints that became new points and
    # the segments its line observations come from (for the keyframe image).
    det_state: tuple
    instance_plane: np.ndarray
    new_point_kp: np.ndarray
    line_seg_index: np.ndarray

    def __init__(self, source: StereoSource, *, settings: StereoSettings, name: str, segmenter: PlaneSegmenter, plan: WindowPlan, on_frame: Callable[[int], None] | None) -> None:
        self.data_source = source
        self.settings = settings
        self.name = name
        self.variant = settings.variant
        self.segmenter = segmenter
        self.camera = source.camera
        self.on_frame = on_frame
        self.plan = plan
        point_settings = settings.points
        self.prefetch = FramePrefetch(timed_prepare(source.rectified_pair, lambda left: detect_points(left, settings=point_settings)), n_frames=len(source), enabled=settings.read_ahead)
        self.reset()

    def reset(self) -> None:
        self.next_frame = 0
        self.map = Map(self.camera)
        self.local_points = np.zeros(0, np.int64)  # the local map: landmarks the window's keyframes see
        self.local_lines = np.zeros(0, np.int64)
        self.frame_poses: list[tuple[int, np.ndarray, np.ndarray]] = []  # (frame, R, t) of the last two frames
        self.last_kf_tracked = 0
        self.window: Window | None = None
        self.last: Snapshot | None = None
        self.messages: list[str] = []

    def checkpoint(self) -> EngineCheckpoint:
        return EngineCheckpoint.of(self, self.map)

    def restore(self, state: EngineCheckpoint) -> None:
        self.map = state.restore_into(self)

    @property
    def keyframes(self) -> int:
        return len(self.map)

    def start_segment(self) -> None:
        """A new map segment from the next keyframe (the window never reaches back across it)."""
        self.map.segment_start = self.keyframes
        self.local_points = np.zeros(0, np.int64)
        self.local_lines = np.zeros(0, np.int64)

    # ------------------------------------------------------------------ frames and tracking

    def read_frame(self, timing: dict[str, float]) -> tuple[int, np.ndarray, np.ndarray, Keypoints]:
        """The next frame: its index, rectified pair and left ORB keypoints (reading and
        detection times, ms of the thread that did them, added to `timing`'s "load" and
        "point_dm"; with `settings.read_ahead` the frame after it is read and detected on a
        worker thread meanwhile). Raises EndOfSequence."""
        n = len(self.data_source)
        if self.next_frame >= n:
            raise EndOfSequence(f"{self.name}: all {n} frames processed")
        i = self.next_frame
        frame = self.prefetch.take(i)
        self.next_frame += 1
        timing[Stage.LOAD] = timing.get(Stage.LOAD, 0.0) + frame.load_ms
        timing[Stage.LOAD_WAIT] = timing.get(Stage.LOAD_WAIT, 0.0) + frame.load_wait_ms
        timing[Stage.POINT_DM] += frame.detect_ms
        if self.on_frame is not None:
            self.on_frame(i)
        return i, frame.left, frame.right, frame.keypoints

    def initial_pose(self, i: int) -> tuple[np.ndarray, np.ndarray]:
        """The first keyframe's `R_world_camera, t_world_camera`: its ground-truth pose where
        known (the gauge), else the origin."""
        if bool(self.data_source.ground_truth_valid[i]):
            T = self.data_source.T_world_rect0[i]
            return T[:3, :3].copy(), T[:3, 3].copy()
        return np.eye(3), np.zeros(3)

    def remember_frame(self, i: int, R: np.ndarray, t: np.ndarray) -> None:
        self.frame_poses = (self.frame_poses + [(i, R, t)])[-2:]

    def constant_velocity(self, i: int) -> tuple[np.ndarray, np.ndarray]:
        """Frame i's pose predicted at constant velocity (per frame) from the last two frames."""
        (j1, R1, t1) = self.frame_poses[-1]
        if len(self.frame_poses) < 2:
            return R1, t1
        (j0, R0, t0) = self.frame_poses[-2]
        return extrapolate(R0, t0, R1, t1, (i - j1) / max(j1 - j0, 1))

    def track_settings(self) -> TrackSettings:
        s = self.settings
        return TrackSettings(s.search_radius_px, s.refine_radius_px, s.max_hamming, s.match_ratio, s.min_tracking_inliers, s.pixel_sigma, s.cauchy, s.outlier_px, s.seed, s.verify_agreement)

    def track(self, i: int, kp: Keypoints, *, predicted: tuple[np.ndarray, np.ndarray], verify_below: int | None = None, left: np.ndarray | None = None) -> Tracked:
        """Frame i's pose against the local map from the `predicted` one (stages/track.py;
        `verify_below`: fewer inliers than this and the PnP candidates are tried too, None:
        the prediction's pose is trusted as it was before the stereo engine verified it).
        `left`: the frame's left image, whose segments help place it against the local
        map's lines where its points alone cannot (variants with lines only; None: points
        only)."""
        last = (self.frame_poses[-1][1], self.frame_poses[-1][2]) if len(self.frame_poses) == 2 else None  # (one frame: the prediction is its pose)
        s = self.track_settings()
        aid = None
        if left is not None and self.variant.with_lines and len(self.local_lines):
            line_settings = self.settings.lines
            aid = LineAid(self.local_lines, lambda: detect_segments(left, settings=line_settings), line_settings, self.settings.line_search_px, self.settings.min_depth_m)
        return track_frame(self.camera, s, i, kp, the_map=self.map, local_points=self.local_points, predicted=predicted, last_frame=last, messages=self.messages, verify_below=verify_below, lines=aid)

    def match_lines(self, R: np.ndarray, t: np.ndarray, ids: np.ndarray, segments: Segments) -> np.ndarray:
        s = self.settings
        return match_map_lines(self.map, R, t, ids, segments, min_depth_m=s.min_depth_m, line_search_px=s.line_search_px, settings=s.lines)

    # ------------------------------------------------------------------ keyframes

    def add_keyframe(self, i: int, R: np.ndarray, t: np.ndarray) -> None:
        """Frame i becomes a keyframe at (R, t), with its true pose where the input has it."""
        T_true = self.data_source.T_world_rect0[i] if bool(self.data_source.ground_truth_valid[i]) else None
        self.map.add_keyframe(i, R, t, stamp_ns=int(self.data_source.timestamps_ns[i]), T_world_true=T_true)

    def start_segmentation(self, i: int, images: tuple[np.ndarray, np.ndarray]) -> Future[tuple[PlaneMasks, float]]:
        """Frame i's plane segmentation of `images` (the segmenter's left and right) started on
        a worker thread: it depends on the images alone, so the keyframe's points and lines
        are matched meanwhile (`detect_and_solve` takes the result)."""
        return workers.submit_timed(lambda: segment_keyframe(self.segmenter, i, *images, self.camera))

    def detect_and_solve(
        self,
        k: int,
        i: int,
        obs: KeyframeObservations,
        new_points: np.ndarray,
        new_lines: np.ndarray,
        rng: np.random.Generator,
        timing: dict[str, float],
        *,
        planes: Future[tuple[PlaneMasks, float]] | None,
    ) -> tuple[PlaneMasks | None, Detection, OptimizationReport, HessianStructure | None]:
        """Keyframe k (frame i) after its landmarks: plane segmentation (`planes`, from
        `start_segmentation`; None: no planes this keyframe) and co-planar detection,
        the window bundle adjustment, culling and the next local map (stage times, ms, into
        `timing`). Returns the masks (or None), the detection, the solver report and the
        Hessian image."""
        masks: PlaneMasks | None = None
        detection = Detection((), (), (), (), ())
        self.det_state = FeatureStates.undetected(self.map, obs).as_tuple()
        timing[Stage.PLANE_SEG] = timing[Stage.PLANE_FIT] = 0.0
        if planes is not None:
            masks, timing[Stage.PLANE_SEG] = planes.result()
            t0 = time.perf_counter()
            found = detect_planes(self.map, obs, masks, new_points, new_lines, rng, settings=self.settings.coplanar)
            detection, self.det_state, self.instance_plane = found.detection, found.features.as_tuple(), found.instance_plane
            timing[Stage.PLANE_FIT] = 1e3 * (time.perf_counter() - t0)
        report, hessian = self.optimize(k, timing)
        t0 = time.perf_counter()
        s = self.settings
        w0, _ = self.plan.window_range(k)
        cull(self.map, k, w0, settings=CullSettings(s.outlier_px, s.min_depth_m, s.depth_limit_m(self.camera), s.cull_after_keyframes, s.min_keyframe_observations))  # VIO: max_depth_m (no far points)
        self.local_points, self.local_lines = local_map(self.map, k, w0)
        timing[Stage.CULLING] = 1e3 * (time.perf_counter() - t0)
        return masks, detection, report, hessian

    def optimize(self, k: int, timing: dict[str, float], *, max_iterations: int | None = None) -> tuple[OptimizationReport, HessianStructure | None]:
        """The window of keyframe k solved with the current variant as the plan has it (its
        `solve_variant`, range and extension), at most `max_iterations` iterations (None: the
        settings')."""
        s = self.settings
        w0, oldest = self.plan.window_range(k)
        window = WindowSettings(s.min_depth_m, s.pixel_sigma, s.min_plane_support)
        settings = SolveSettings(method=s.method, max_iterations=max_iterations or s.max_iterations, cauchy=s.cauchy, hessian=s.hessian, window=window, damping=s.damping)
        self.window, report, hessian = solve_window(self.map, k, self.plan.solve_variant(self.variant), w0=w0, oldest=oldest, extension=self.plan.window_extension(), settings=settings, timing=timing)
        return report, hessian

    def follow_keyframe(self, i: int, k: int) -> None:
        """The motion model continues from keyframe k's optimized pose (frame i)."""
        if self.frame_poses:
            self.frame_poses[-1] = (i, self.map.R_world_keyframe[k].copy(), self.map.t_world_keyframe[k].copy())

    # ------------------------------------------------------------------ results

    def draw(
        self, left: np.ndarray, kp: Keypoints, status: np.ndarray, segs: StereoSegments | Segments | None, obs: KeyframeObservations, masks: PlaneMasks | None, detection: Detection
    ) -> KeyframeImage:
        """The keyframe image: keypoints by status, the observed segments and plane instances."""
        if segs is not None and len(self.line_seg_index):
            seg_uv = obs.line_uv.reshape(-1, 2, 2)
            seg_plane = np.where(self.map.lines.ok[obs.line_id], self.map.lines.plane[obs.line_id], -1)
        else:
            seg_uv, seg_plane = np.zeros((0, 2, 2)), np.zeros(0, np.int64)
        instance_plane = self.instance_plane if masks is not None and len(self.instance_plane) == masks.count else None
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

    def snapshot(
        self, k: int, detection: Detection, det_state: tuple, report: OptimizationReport, hessian: HessianStructure | None, *, image: KeyframeImage | None, tracking: Tracking | None, message: str
    ) -> Snapshot:
        """Keyframe k's snapshot (kept as the last one)."""
        w0, _ = self.plan.window_range(k)
        snap = build_snapshot(self.map, k, w0, detection, det_state, report, hessian, source=self.name, image=image, tracking=tracking, message=message)
        self.last = self.plan.finish_snapshot(snap, k)
        return self.last

    def reoptimize(self) -> Snapshot:
        if self.last is None:
            raise RuntimeError("nothing to re-optimize before the first step")
        last = self.last
        timing: dict[str, float] = {}
        t0 = time.perf_counter()
        report, hessian = self.optimize(last.keyframe, timing)
        timing[Stage.TOTAL] = 1e3 * (time.perf_counter() - t0)
        return self.snapshot(last.keyframe, last.detection, self.det_state, report, hessian, image=last.image, tracking=last.tracking, message=last.message)

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
        if self.window is None:
            return {}
        return {v: hessian_structure(build_problem(self.window.data, v, robust_px=self.settings.cauchy)) for v in variants}


class CoreEngine:
    """The :class:`~backend.pipeline.engine.Engine` interface of an engine that holds a
    :class:`PipelineCore` as `core`: delegations only. The engines that use it differ by what
    they plug in (their `step` and :class:`WindowPlan`), not by overriding anything here."""

    core: PipelineCore
    PARTS: tuple[str, ...] = ("core",)  # checkpointed by their own checkpoint()

    @property
    def source(self) -> str:
        return self.core.name

    @property
    def variant(self) -> Variant:
        return self.core.variant

    @property
    def keyframes(self) -> int:
        return self.core.keyframes

    @property
    def frames(self) -> int:
        """Frames read so far."""
        return self.core.next_frame

    @property
    def map(self) -> Map:
        return self.core.map

    @property
    def data_source(self) -> StereoSource:
        return self.core.data_source

    @property
    def camera(self) -> PinholeCamera:
        """The input's rectified left camera."""
        return self.core.camera

    @property
    def segmenter(self) -> PlaneSegmenter:
        return self.core.segmenter

    @segmenter.setter
    def segmenter(self, segmenter: PlaneSegmenter) -> None:
        self.core.segmenter = segmenter

    @property
    def on_frame(self) -> Callable[[int], None] | None:
        """Called with each frame's index as it is read (progress bars)."""
        return self.core.on_frame

    @on_frame.setter
    def on_frame(self, callback: Callable[[int], None] | None) -> None:
        self.core.on_frame = callback

    def set_variant(self, variant: Variant) -> None:
        self.core.variant = Variant.parse(variant)

    def checkpoint(self) -> EngineCheckpoint:
        return EngineCheckpoint.of(self)

    def restore(self, state: EngineCheckpoint) -> None:
        state.restore_into(self)

    def reoptimize(self) -> Snapshot:
        return self.core.reoptimize()

    def frame_trajectory(self) -> FrameTrajectory:
        return self.core.frame_trajectory()

    def compare_hessians(self, variants: tuple[Variant, ...]) -> dict[Variant, HessianStructure]:
        return self.core.compare_hessians(variants)
