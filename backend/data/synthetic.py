"""Synthetic stereo + IMU sequences of a scene, written as EuRoC ASL folders.

The body (IMU) frame moves along a smooth random trajectory inside the scene's camera
region; the left camera looks along the body's x axis (`R_BODY_CAMERA_FORWARD`), 5 cm ahead
of the IMU, the right one `baseline` metres along the left camera's x. Stereo pairs at 20 Hz
(752×480, EuRoC-like intrinsics, square pixels, already rectified), IMU at 200 Hz consistent
with the trajectory (`backend.data.motion`), then IMU noise and bias random walk at EuRoC's
`imu0/sensor.yaml` values. Ground truth: the body state at every IMU sample, and per frame
the depth and plane-instance masks of both cameras, with the plane table.
"""

from __future__ import annotations

import dataclasses
import pathlib
from collections.abc import Callable

import numpy as np

from backend.data.euroc_writer import EurocWriter, GroundTruthRows
from backend.data.motion import ImuNoise, add_imu_noise, imu_samples, random_trajectory
from backend.data.render import R_BODY_CAMERA_FORWARD, render_stereo
from backend.data.scenes import Scene
from backend.geometry.camera import PinholeCamera

CAMERA = PinholeCamera(fx=458.0, fy=458.0, cx=367.0, cy=248.0, width=752, height=480, baseline=0.11)
T_BODY_CAM0 = np.eye(4)
T_BODY_CAM0[:3, :3] = R_BODY_CAMERA_FORWARD
T_BODY_CAM0[:3, 3] = [0.05, CAMERA.baseline / 2.0, 0.0]  # the stereo pair is centred on the IMU


@dataclasses.dataclass(frozen=True)
class SequenceSettings:
    """What to render: `duration_s` seconds at `camera_rate_hz` / `imu_rate_hz`; the
    trajectory, IMU noise and image effects are drawn from `seed`. Image effects: Gaussian
    noise of `image_noise` grey levels, blur of `blur_px` pixels, and an exposure gain
    varying by ±`exposure` (relative) with a 7 s period."""

    duration_s: float = 30.0
    camera_rate_hz: float = 20.0
    imu_rate_hz: float = 200.0
    seed: int = 0
    imu_noise: ImuNoise = ImuNoise()
    image_noise: float = 0.0
    blur_px: float = 0.0
    exposure: float = 0.0

    def __post_init__(self) -> None:
        if not self.duration_s > 0:
            raise ValueError("duration must be positive")
        if self.image_noise < 0 or self.blur_px < 0 or not 0 <= self.exposure < 1:
            raise ValueError("image noise and blur must be >= 0, exposure in [0, 1)")


def render_sequence(scene: Scene, out: pathlib.Path | str, *, settings: SequenceSettings = SequenceSettings(), on_frame: Callable[[int, int], None] | None = None) -> int:
    """Render `scene` into the EuRoC folder `out`; returns the number of stereo frames.
    `on_frame(done, total)` reports progress."""
    rng = np.random.default_rng([settings.seed, 0xDA7A])
    centre, half = scene.camera_region if scene.camera_region is not None else (np.array([0.0, 0.0, 1.4]), np.array([1.0, 1.0, 0.2]))
    trajectory = random_trajectory(rng, centre=np.asarray(centre, float), half_extent=np.asarray(half, float), height=0.0)
    frame_period_ns = int(round(1e9 / settings.camera_rate_hz))
    stamps = np.arange(0, int(settings.duration_s * 1e9) + 1, frame_period_ns, dtype=np.int64)
    imu = imu_samples(trajectory, start_ns=0, end_ns=int(stamps[-1]), rate_hz=settings.imu_rate_hz)
    noisy, bias_gyro, bias_accel = add_imu_noise(imu, rng, noise=settings.imu_noise)

    writer = EurocWriter(out, camera=CAMERA, T_body_cam0=T_BODY_CAM0, imu_noise=settings.imu_noise, camera_rate_hz=settings.camera_rate_hz, imu_rate_hz=settings.imu_rate_hz)
    writer.write_imu(noisy.timestamp_ns, noisy.gyro, noisy.accel)
    t_imu = imu.timestamp_ns * 1e-9
    writer.write_ground_truth(GroundTruthRows(imu.timestamp_ns, trajectory.position(t_imu), trajectory.rotation(t_imu), trajectory.velocity(t_imu), bias_gyro, bias_accel))
    table = scene.planes
    ids = sorted(table)
    plane = np.array([table[i] for i in ids]).reshape(-1, 4)
    if ids != list(range(len(ids))):  # the table is indexed by id: fill gaps with NaN rows
        full = np.full((max(ids) + 1, 4), np.nan)
        full[ids] = plane
        plane = full
    writer.write_planes(plane[:, :3], plane[:, 3])

    t_frames = stamps * 1e-9
    R_world_body, p_world_body = trajectory.rotation(t_frames), trajectory.position(t_frames)
    image_rng = np.random.default_rng([settings.seed, 0x1A6E])
    for k, t in enumerate(stamps):
        R_world_cam0 = R_world_body[k] @ T_BODY_CAM0[:3, :3]
        t_world_cam0 = p_world_body[k] + R_world_body[k] @ T_BODY_CAM0[:3, 3]
        gain = 1.0 + settings.exposure * np.sin(2.0 * np.pi * t_frames[k] / 7.0)
        left, right = render_stereo(scene, CAMERA, R_world_cam0, t_world_cam0, gain=gain, blur_sigma_px=settings.blur_px, noise_sigma=settings.image_noise, rng=image_rng)
        writer.add_frame(int(t), images=(left.image, right.image), depths=(left.depth, right.depth), planes=(left.plane_id, right.plane_id))
        if on_frame is not None:
            on_frame(k + 1, len(stamps))
    writer.close()
    return len(stamps)
