"""Snapshots: one immutable record per keyframe step (DESIGN §6), all the viewer draws.

Arrays inside a snapshot are read-only. Poses that left the window never change again, so
consecutive snapshots share them (a read-only view of an append-only buffer) instead of
copying the whole trajectory: keeping hundreds of snapshots stays cheap.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from backend.geometry.camera import PinholeCamera
from backend.optim.structure import HessianStructure
from backend.optim.variant import Variant

# Landmark states with respect to the last plane detection (RANSAC of paper Eq. 4).
NOT_TESTED = 0
INLIER = 1
OUTLIER = 2


def frozen(array: np.ndarray) -> np.ndarray:
    """A read-only view of `array` (no copy)."""
    view = np.asarray(array).view()
    view.setflags(write=False)
    return view


def drawable_points(p_world: np.ndarray, ids: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The rows `ids` of the points `p_world` (N, 3) that have a float32 position, and those
    positions (`PointLandmarks`' precision). A point solved out to infinity (an inverse depth
    near zero: beyond float32's 3.4e38 m, e.g. after the VIO start's joint solve, before the
    next keyframe culls it) or not finite has no position to draw or export: it is left out
    of the snapshot as a culled one is, instead of becoming inf with a RuntimeWarning."""
    p = p_world[ids]
    finite = np.all(np.abs(p) <= np.finfo(np.float32).max, axis=1)  # False for inf and NaN too
    if not finite.all():
        ids, p = ids[finite], p[finite]
    return ids, p.astype(np.float32)


@dataclasses.dataclass(frozen=True)
class Trajectory:
    """Keyframe poses `T_world_camera` (metres, world z up) in keyframe order, timestamps in
    nanoseconds. Stored as read-only chunks `(timestamp_ns, R (n, 3, 3), t (n, 3))`: a
    prefix shared with earlier snapshots and a copied tail."""

    chunks: tuple[tuple[np.ndarray, np.ndarray, np.ndarray], ...]

    @staticmethod
    def of(timestamp_ns: np.ndarray, R_world_camera: np.ndarray, t_world_camera: np.ndarray) -> Trajectory:
        return Trajectory(((frozen(timestamp_ns), frozen(R_world_camera), frozen(t_world_camera)),))

    def __len__(self) -> int:
        return sum(int(c[2].shape[0]) for c in self.chunks)

    def _joined(self, i: int) -> np.ndarray:
        return frozen(np.concatenate([c[i] for c in self.chunks])) if len(self.chunks) != 1 else self.chunks[0][i]

    @property
    def timestamp_ns(self) -> np.ndarray:
        return self._joined(0)

    @property
    def R_world_camera(self) -> np.ndarray:
        return self._joined(1)

    @property
    def t_world_camera(self) -> np.ndarray:
        return self._joined(2)


@dataclasses.dataclass(frozen=True)
class FrameTrajectory:
    """Every tracked frame's pose (ORB-SLAM's CameraTrajectory): frame `i`'s pose is
    `T_world_refkf · T_refkf_frame`, its reference keyframe's latest estimate times the
    relative pose measured when the frame was tracked. Lost frames (no pose) are absent.
    Built on request at the end of a run (never part of a snapshot: it grows with every
    frame). `ground_truth` has NaN rows for frames without ground truth."""

    frame: np.ndarray  # (F,) frame index in the source, increasing
    reference_keyframe: np.ndarray  # (F,) keyframe index each pose is relative to
    is_keyframe: np.ndarray  # (F,) bool: the frame became that keyframe
    estimate: Trajectory  # (F,) T_world_camera, timestamps ns
    ground_truth: Trajectory  # (F,) T_world_camera (NaN: none)

    def __len__(self) -> int:
        return int(self.frame.shape[0])


@dataclasses.dataclass(frozen=True)
class PointLandmarks:
    """Triangulated points: world positions (m), plane id (-1: none), anchor keyframe, and
    the state of the last detection that tested them (NOT_TESTED / INLIER / OUTLIER). The
    integers are int32 and the positions float32 (a micrometre at 10 m; the page draws and
    the PLY export writes float32 anyway): every snapshot the debugger keeps holds the
    whole map, and its points are most of it."""

    id: np.ndarray  # (P,) int32 stable landmark ids
    p_world: np.ndarray  # (P, 3) float32
    plane: np.ndarray  # (P,) int32
    anchor: np.ndarray  # (P,) int32 keyframe index
    detection: np.ndarray  # (P,) uint8

    def __len__(self) -> int:
        return int(self.id.shape[0])


@dataclasses.dataclass(frozen=True)
class LineLandmarks:
    """Triangulated lines as world segments (m): the points of the infinite line nearest
    the anchor observation's endpoint rays. Other fields as for points."""

    id: np.ndarray  # (L,) int32
    segment_world: np.ndarray  # (L, 2, 3) float64
    plane: np.ndarray  # (L,) int32
    anchor: np.ndarray  # (L,) int32
    detection: np.ndarray  # (L,) uint8

    def __len__(self) -> int:
        return int(self.id.shape[0])


@dataclasses.dataclass(frozen=True)
class PlaneLandmark:
    """A plane `n·X + d = 0` (world, m), the convex hull of its inliers in the plane
    (world vertices, counter-clockwise seen from +n) and the consensus of its last RANSAC
    detection: inlier fraction and the number of candidates tested."""

    id: int
    n: np.ndarray  # (3,)
    d: float
    hull_world: np.ndarray  # (H, 3)
    n_points: int
    n_lines: int
    last_consensus: float
    last_candidates: int


@dataclasses.dataclass(frozen=True)
class Detection:
    """The co-planar detection run on the step's keyframe: one entry per candidate set."""

    instance: tuple[int, ...]  # segmentation instance label of each candidate set
    candidates: tuple[int, ...]
    inliers: tuple[int, ...]
    accepted: tuple[bool, ...]
    plane: tuple[int, ...]  # plane id it merged into or created (-1: rejected / skipped)


@dataclasses.dataclass(frozen=True)
class OptimizationReport:
    """The window solve: variant, iterations, costs (½ Σ whitened residual², unitless), and
    wall time per stage in milliseconds. `termination` says how the solve ended (see
    `backend.optim.solver`); `dropped_landmarks` counts landmarks left out of a step because
    they were not constrained enough."""

    variant: Variant
    method: str
    iterations: int
    initial_cost: float
    final_cost: float
    converged: bool
    items: int
    params: int
    window: int
    fixed_poses: int
    timing_ms: dict[str, float]
    termination: str = ""
    dropped_landmarks: int = 0

    def __post_init__(self) -> None:
        object.__setattr__(self, "variant", Variant.parse(self.variant))


@dataclasses.dataclass(frozen=True)
class Metrics:
    """Running trajectory error over all keyframes so far (cm): RMSE without alignment (the
    gauge is fixed) and ATE after SE(3) alignment. NaN where no ground truth is known."""

    rmse_cm: float
    ate_cm: float


@dataclasses.dataclass(frozen=True)
class KeyframeImage:
    """The keyframe's left image with what the front end found on it, drawn by
    `backend.pipeline.overlay` (plane masks tinted by plane, points, segments), stored as
    JPEG bytes (a few tens of kB, so hundreds of snapshots stay cheap). `width`, `height`:
    pixels of the encoded image."""

    jpeg: bytes
    width: int
    height: int


@dataclasses.dataclass(frozen=True)
class Tracking:
    """Tracking since the previous snapshot: frames processed (keyframe included), frames
    whose pose could not be tracked (predicted by the motion model instead), map
    re-initializations after a loss, the tracked points / lines of the keyframe, and why
    the frame became a keyframe ("first frame", "rule", "fallback", "fast motion",
    "placed by flow", "re-initialization"; see StereoSettings)."""

    frames: int
    lost_frames: int
    reinitializations: int
    tracked_points: int
    tracked_lines: int
    keyframe_reason: str = ""


@dataclasses.dataclass(frozen=True)
class ImuState:
    """The VIO's inertial state: whether the visual-inertial initialization succeeded, a
    one-line status (what the start is waiting for, why an alignment was rejected, what it
    estimated), the keyframe the latest one succeeded at (-1: not yet) and its figures (`report`: scale,
    gyro bias, gravity, quality; against the truth where known), and per keyframe so far the
    velocity (K, 3) m/s in the world frame and the biases (K, 6) `(b_a m/s², b_g rad/s)`;
    gravity in the world frame (m/s², NaN before the initialization); the true velocity and
    biases where the input has them (rendered scenes)."""

    initialized: bool
    status: str
    init_keyframe: int
    report: dict
    velocity_world: np.ndarray
    bias: np.ndarray
    gravity_world: np.ndarray
    velocity_true: np.ndarray | None = None
    bias_true: np.ndarray | None = None
    first_init_keyframe: int = -1  # the first initialization (after a loss VIO starts again and initializes anew)
    first_report: dict = dataclasses.field(default_factory=dict)


@dataclasses.dataclass(frozen=True)
class Snapshot:
    """Everything about one keyframe step. `keyframe` is the index of the newest keyframe;
    `window` are the keyframe indices optimized in this step."""

    keyframe: int
    timestamp_ns: int
    source: str
    camera: PinholeCamera  # the (left) camera of every keyframe
    estimate: Trajectory
    ground_truth: Trajectory | None
    window: np.ndarray  # (W,) keyframe indices, ascending
    points: PointLandmarks
    lines: LineLandmarks
    planes: tuple[PlaneLandmark, ...]
    detection: Detection
    report: OptimizationReport
    hessian: HessianStructure | None
    metrics: Metrics
    message: str = ""
    image: KeyframeImage | None = None  # image pipelines only
    tracking: Tracking | None = None  # image pipelines only
    imu: ImuState | None = None  # VIO only

    @property
    def variant(self) -> Variant:
        return self.report.variant

    def plane_by_id(self) -> dict[int, PlaneLandmark]:
        return {p.id: p for p in self.planes}
