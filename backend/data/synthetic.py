"""Synthetic stereo + IMU sequences of a scene, written as EuRoC ASL folders.

The scene says how it is seen and how the body moves (`Scene.rig`, `Scene.motion`,
`Scene.exposure`): by default (`backend.data.rigs.EUROC_RIG`) stereo pairs at 20 Hz
(752×480, EuRoC-like intrinsics, square pixels, already rectified), the left camera looking
along the body's x axis (`R_BODY_CAMERA_FORWARD`) 5 cm ahead of the IMU, the right one
`baseline` metres along the left camera's x, and the body moving along a smooth random
trajectory inside the scene's camera region; `street` has a KITTI-like rig at 10 Hz and
drives a car around a road loop (`backend.data.body_motion`). The IMU (200 Hz) is
consistent with the trajectory (`backend.data.motion`), then gets noise and a bias random
walk at EuRoC's `imu0/sensor.yaml` values. Ground truth: the body state at every IMU sample
and at the last frame (past the last IMU sample: every frame has a ground-truth row at its
own time), and per frame the depth and plane-instance masks of both cameras, with the plane
table.
"""

from __future__ import annotations

import collections
import dataclasses
import pathlib
import threading
from collections.abc import Callable
from typing import NamedTuple

import numpy as np

from backend.data.body_motion import BASE_FREQUENCY_HZ as BASE_FREQUENCY_HZ
from backend.data.body_motion import body_trajectory
from backend.data.euroc_writer import EurocWriter, GroundTruthRows
from backend.data.motion import ImuData, ImuNoise, add_imu_noise, imu_samples
from backend.data.render import View, render_stereo, render_view
from backend.data.rigs import EUROC_RIG
from backend.data.scenes import Scene

# The default rig's camera and `T_body_cam0` (the stereo pair centred on the IMU, 5 cm ahead).
CAMERA = EUROC_RIG.camera
T_BODY_CAM0 = EUROC_RIG.T_body_cam0


@dataclasses.dataclass(frozen=True)
class SequenceSettings:
    """What to render: `duration_s` seconds at `camera_rate_hz` / `imu_rate_hz` (None: the
    scene rig's rates); the trajectory, IMU noise and image effects are drawn from `seed`;
    `speed` traverses the same path that many times faster (every channel's frequencies
    scaled, a road's speeds multiplied). Image effects, on top of the scene's own exposure
    schedule: Gaussian noise of `image_noise` grey levels, blur of `blur_px` pixels, and an
    exposure gain varying by ±`exposure` (relative) with a 7 s period. The IMU biases start at
    `imu_bias_gyro` (rad/s) and `imu_bias_accel` (m/s²), by default about those of the real
    EuRoC V1_01 sensor (its ground truth's estimate at the start), and then random-walk at
    `imu_noise`'s densities."""

    duration_s: float = 30.0
    camera_rate_hz: float | None = None
    imu_rate_hz: float | None = None
    seed: int = 0
    imu_noise: ImuNoise = ImuNoise()
    image_noise: float = 0.0
    blur_px: float = 0.0
    exposure: float = 0.0
    speed: float = 1.0
    imu_bias_gyro: tuple[float, float, float] = (-0.002, 0.021, 0.077)
    imu_bias_accel: tuple[float, float, float] = (-0.024, 0.121, 0.075)

    def __post_init__(self) -> None:
        if not self.duration_s > 0:
            raise ValueError("duration must be positive")
        if not (np.isfinite(self.speed) and self.speed > 0):
            raise ValueError("speed must be positive")
        for name in ("camera_rate_hz", "imu_rate_hz"):
            rate = getattr(self, name)
            if rate is not None and not (np.isfinite(rate) and rate > 0):
                raise ValueError(f"{name.removesuffix('_hz').replace('_', ' ')} must be positive")
        if self.image_noise < 0 or self.blur_px < 0 or not 0 <= self.exposure < 1:
            raise ValueError("image noise and blur must be >= 0, exposure in [0, 1)")


class _SimulatedImu(NamedTuple):
    """A rendered sequence's IMU: noise-free and noisy samples, the true biases per sample."""

    true: ImuData
    noisy: ImuData
    bias_gyro: np.ndarray
    bias_accel: np.ndarray


class _CachedFrame(NamedTuple):
    """What the pipeline reads of a rendered frame: both images (H, W) uint8 and the left
    view's plane ids (H, W) int16 (None: not kept, nobody has asked for plane ids yet)."""

    left_image: np.ndarray
    right_image: np.ndarray
    left_plane_id: np.ndarray | None


class SyntheticSequence:
    """A rendered scene read like an EuRoC folder, frames rendered on demand.

    Same reading interface as :class:`backend.data.euroc.EurocDataset`: `timestamps_ns`,
    `camera` (rectified left camera with the baseline; the scene rig's), `imu` / `imu_between`,
    `T_world_body`, `T_world_rect0` (N, 4, 4), `ground_truth_valid`, `rectified_pair(i)`;
    plus the ground-truth extras `views(i)` (left and right :class:`View`: image, depth,
    plane ids), `plane_table` (id -> (n, d)), `trajectory` (the body's, `T_world_body(t)`)
    and the rates in use, `camera_rate_hz` and `imu_rate_hz` (the settings', else the rig's).
    Rendering a pair (about 45 per second for the default rig) is
    faster than reading its PNGs back, so frames are not written anywhere: the last
    `cache_frames` frames read are kept in memory, what the pipeline asks for again (both
    images, 0.7 MB at 752×480: enough for the pipeline's read-ahead of 8 frames; and the left
    plane ids, another 0.7 MB, once something has asked for them: the oracle segmenter asks
    for a keyframe's just after it was read, nothing else does); `views(i)`, with the depths,
    renders anew. Each frame's image noise has its own seed, so any frame renders the same
    whenever it is asked for. The ground truth is the body's
    (`ground_truth_frame` "body", as `render` writes it to `state_groundtruth_estimate0`), the
    left camera in it `T_truth_rect0` = `T_body_rect0`.
    """

    ground_truth_frame: str = "body"

    def __init__(self, scene: Scene, *, settings: SequenceSettings = SequenceSettings(), cache_frames: int = 16) -> None:
        self.scene = scene
        self.settings = settings
        self.camera = scene.rig.camera
        self.T_body_cam0 = scene.rig.T_body_cam0
        self.camera_rate_hz = scene.rig.camera_rate_hz if settings.camera_rate_hz is None else settings.camera_rate_hz
        self.imu_rate_hz = scene.rig.imu_rate_hz if settings.imu_rate_hz is None else settings.imu_rate_hz
        rng = np.random.default_rng([settings.seed, 0xDA7A])
        self.trajectory = body_trajectory(scene.motion, rng=rng, seed=settings.seed, region=scene.camera_region, speed=settings.speed)
        period_ns = int(round(1e9 / self.camera_rate_hz))
        self.timestamps_ns = np.arange(0, int(settings.duration_s * 1e9) + 1, period_ns, dtype=np.int64)
        self._imu_rng_state = rng.bit_generator.state  # the IMU is simulated when first read (_SimulatedImu)
        self._imu_sim: _SimulatedImu | None = None
        self._imu_lock = threading.Lock()
        t = self.timestamps_ns * 1e-9
        T = np.tile(np.eye(4), (len(t), 1, 1))
        T[:, :3, :3] = self.trajectory.rotation(t)
        T[:, :3, 3] = self.trajectory.position(t)
        self.T_world_body = T
        self.T_world_rect0 = T @ self.T_body_cam0  # the cameras are rectified already
        self.T_truth_rect0 = np.asarray(self.T_body_cam0, dtype=float)  # (4, 4) the left camera in the body frame
        self.ground_truth_valid = np.ones(len(t), bool)
        self.plane_table = scene.planes
        self._cache: collections.OrderedDict[int, _CachedFrame] = collections.OrderedDict()
        self._cache_frames = cache_frames
        self._cache_lock = threading.Lock()
        self._keep_plane_ids = False  # set by the first left_plane_ids (the oracle segmenter)

    def __len__(self) -> int:
        return int(self.timestamps_ns.shape[0])

    def _simulated_imu(self) -> _SimulatedImu:
        """The IMU, simulated on first use from the random state the trajectory left (so the
        same samples as simulating it at once): a stereo run never reads it, and 400 s of it
        are 12 MiB."""
        with self._imu_lock:
            if self._imu_sim is None:
                bit_generator = np.random.PCG64()
                bit_generator.state = self._imu_rng_state  # type: ignore[assignment]  # the state PCG64 itself gave
                rng = np.random.Generator(bit_generator)
                s = self.settings
                truth = imu_samples(self.trajectory, start_ns=0, end_ns=int(self.timestamps_ns[-1]), rate_hz=self.imu_rate_hz)
                noisy, bias_gyro, bias_accel = add_imu_noise(truth, rng, noise=s.imu_noise, bias_gyro=np.array(s.imu_bias_gyro), bias_accel=np.array(s.imu_bias_accel))
                self._imu_sim = _SimulatedImu(truth, noisy, bias_gyro, bias_accel)
            return self._imu_sim

    @property
    def imu_true(self) -> ImuData:
        """Noise-free IMU samples at `imu_rate_hz` over the sequence (body frame)."""
        return self._simulated_imu().true

    @property
    def imu(self) -> ImuData:
        """The IMU samples with noise and bias (what a reader of the sequence gets)."""
        return self._simulated_imu().noisy

    @property
    def bias_gyro(self) -> np.ndarray:
        """(N, 3) rad/s the gyro's true bias at each IMU sample."""
        return self._simulated_imu().bias_gyro

    @property
    def bias_accel(self) -> np.ndarray:
        """(N, 3) m/s² the accelerometer's true bias at each IMU sample."""
        return self._simulated_imu().bias_accel

    @property
    def has_imu(self) -> bool:
        """Rendered sequences always simulate the IMU (the reader's interface)."""
        return True

    def imu_between(self, t0_ns: int, t1_ns: int) -> ImuData:
        """Noisy IMU samples with `t0_ns < t <= t1_ns` (body frame)."""
        return self.imu.between(t0_ns, t1_ns)

    @property
    def imu_noise(self) -> ImuNoise:
        """The simulated IMU's noise densities."""
        return self.settings.imu_noise

    @property
    def T_body_rect0(self) -> np.ndarray:
        """(4, 4) the left camera in the body frame (rendered cameras are rectified already)."""
        return np.asarray(self.T_body_cam0, dtype=float)

    @property
    def imu_label(self) -> str:
        return "IMU"

    def views(self, index: int) -> tuple[View, View]:
        """Left and right views of frame `index` (image, depth along z in m, plane ids),
        rendered (not cached: the depths are 60 % of a pair and only writers need them)."""
        index = range(len(self))[index]
        s = self.settings
        T = self.T_world_rect0[index]
        gain = 1.0 + s.exposure * np.sin(2.0 * np.pi * self.timestamps_ns[index] * 1e-9 / 7.0)
        if self.scene.exposure is not None:
            gain *= self.scene.exposure.gain(float(self.timestamps_ns[index]) * 1e-9)
        rng = np.random.default_rng([s.seed, 0x1A6E, index])
        return render_stereo(self.scene, self.camera, T[:3, :3], T[:3, 3], gain=gain, blur_sigma_px=s.blur_px, noise_sigma=s.image_noise, rng=rng)

    def _frame(self, index: int) -> _CachedFrame:
        """Frame `index`'s images and left plane ids, from the cache or rendered into it."""
        index = range(len(self))[index]
        with self._cache_lock:  # the frames are read on a worker thread, the oracle's plane ids on another
            cached = self._cache.get(index)
            if cached is not None:
                self._cache.move_to_end(index)
                return cached
        left, right = self.views(index)
        frame = _CachedFrame(left.image, right.image, left.plane_id if self._keep_plane_ids else None)
        with self._cache_lock:
            self._cache[index] = frame
            while len(self._cache) > self._cache_frames:
                self._cache.popitem(last=False)
        return frame

    def left_depth(self, index: int) -> np.ndarray:
        """Depth (H, W) float32 of frame `index`'s left view (m along the camera's z, inf
        where nothing is hit), rendered without the frame cache: safe to call from another
        thread than the one reading frames (the debugger's dense check)."""
        index = range(len(self))[index]
        T = self.T_world_rect0[index]
        return render_view(self.scene, self.camera, T[:3, :3], T[:3, 3]).depth

    def left_plane_ids(self, index: int) -> np.ndarray:
        """Plane ids (H, W) int16 of frame `index`'s left view (-1 where no plane is hit):
        the cached frame's if it is there (a keyframe's, asked for by the oracle segmenter
        just after it was read), else rendered without the images and not cached."""
        index = range(len(self))[index]
        with self._cache_lock:
            self._keep_plane_ids = True
            cached = self._cache.get(index)
        if cached is not None and cached.left_plane_id is not None:
            return cached.left_plane_id
        T = self.T_world_rect0[index]
        return render_view(self.scene, self.camera, T[:3, :3], T[:3, 3]).plane_id

    def rectified_pair(self, index: int) -> tuple[np.ndarray, np.ndarray]:
        """Left and right uint8 images (H, W) of frame `index`."""
        frame = self._frame(index)
        return frame.left_image, frame.right_image


def render_sequence(scene: Scene, out: pathlib.Path | str, *, settings: SequenceSettings = SequenceSettings(), on_frame: Callable[[int, int], None] | None = None) -> int:
    """Render `scene` into the EuRoC folder `out`; returns the number of stereo frames.
    `on_frame(done, total)` reports progress."""
    seq = SyntheticSequence(scene, settings=settings, cache_frames=1)
    writer = EurocWriter(out, camera=seq.camera, T_body_cam0=np.asarray(seq.T_body_cam0), imu_noise=settings.imu_noise, camera_rate_hz=seq.camera_rate_hz, imu_rate_hz=seq.imu_rate_hz)
    writer.write_imu(seq.imu.timestamp_ns, seq.imu.gyro, seq.imu.accel)
    writer.write_ground_truth(_ground_truth_rows(seq))
    ids = sorted(seq.plane_table)
    plane = np.full((max(ids, default=-1) + 1, 4), np.nan)  # the table is indexed by id
    for i in ids:
        plane[i] = seq.plane_table[i]
    writer.write_planes(plane[:, :3], plane[:, 3])
    for k, t in enumerate(seq.timestamps_ns):
        left, right = seq.views(k)
        writer.add_frame(int(t), images=(left.image, right.image), depths=(left.depth, right.depth), planes=(left.plane_id, right.plane_id))
        if on_frame is not None:
            on_frame(k + 1, len(seq))
    writer.close()
    return len(seq)


def _ground_truth_rows(seq: SyntheticSequence) -> GroundTruthRows:
    """The body state at every IMU sample and at the last frame where it is past the last
    sample (the IMU's last interval ends there), its biases those of the last sample: every
    frame has a ground-truth row at its own time, as evo pairs frames with the file's rows."""
    stamps = seq.imu_true.timestamp_ns
    bias_gyro, bias_accel = seq.bias_gyro, seq.bias_accel
    last_frame = seq.timestamps_ns[-1]
    if len(stamps) and last_frame > stamps[-1]:
        stamps = np.append(stamps, last_frame)
        bias_gyro, bias_accel = np.vstack([bias_gyro, bias_gyro[-1:]]), np.vstack([bias_accel, bias_accel[-1:]])
    t = stamps * 1e-9
    traj = seq.trajectory
    return GroundTruthRows(stamps, traj.position(t), traj.rotation(t), traj.velocity(t), bias_gyro, bias_accel)
