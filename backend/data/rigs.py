"""The sensor rigs of rendered scenes: a rectified stereo camera, where its left camera sits
on the body (the IMU), and the rates of the cameras and the IMU.

`EUROC_RIG` (the default; every scene before `street`): EuRoC-like 752×480 px, f = 458 px,
baseline 0.11 m, 20 Hz, the pair centred on the IMU 5 cm ahead of it. `KITTI_RIG`
(`street`): KITTI-like 1241×376 px, f ≈ 718 px, baseline 0.54 m, 10 Hz, the left camera
0.81 m ahead of, 0.32 m left of and 0.80 m above the IMU (KITTI's own lever arm). Both
look along the body's x axis (`R_BODY_CAMERA_FORWARD`); both IMUs run at 200 Hz.
"""

from __future__ import annotations

import dataclasses
import math
from typing import Any

import numpy as np

from backend.data.json_fields import bounded, integer, vector
from backend.geometry.camera import PinholeCamera

# a camera that looks along the body's x axis with image y along body -z (image x along
# body -y): `R_world_camera = R_world_body @ R_BODY_CAMERA_FORWARD` for a level body
R_BODY_CAMERA_FORWARD = np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]])
MAX_IMAGE_PX = 4096  # per side
MAX_FOCAL_PX = 1e5
MAX_BASELINE_M = 100.0
MAX_LEVER_ARM_M = 100.0
MAX_CAMERA_RATE_HZ = 1000.0
MAX_IMU_RATE_HZ = 1000.0


def body_camera(translation_body: tuple[float, float, float]) -> np.ndarray:
    """`T_body_cam0` (4, 4) of a forward-looking camera (`R_BODY_CAMERA_FORWARD`) at
    `translation_body` (metres, body frame), read-only."""
    T = np.eye(4)
    T[:3, :3] = R_BODY_CAMERA_FORWARD
    T[:3, 3] = translation_body
    T.setflags(write=False)
    return T


@dataclasses.dataclass(frozen=True, eq=False)
class Rig:
    """A rectified stereo `camera` (left camera's intrinsics in pixels, `baseline` metres to
    the right one along its x axis), the left camera in the body (IMU) frame `T_body_cam0`
    (4, 4, metres), and the rates: stereo pairs at `camera_rate_hz`, IMU samples at
    `imu_rate_hz` (Hz)."""

    camera: PinholeCamera
    T_body_cam0: np.ndarray
    camera_rate_hz: float = 20.0
    imu_rate_hz: float = 200.0

    def __post_init__(self) -> None:
        c = self.camera
        if not (isinstance(c.width, int) and isinstance(c.height, int) and 16 <= c.width <= MAX_IMAGE_PX and 16 <= c.height <= MAX_IMAGE_PX):
            raise ValueError(f"camera: width and height must be whole pixels in [16, {MAX_IMAGE_PX}]")
        if not all(math.isfinite(f) and 0 < f <= MAX_FOCAL_PX for f in (c.fx, c.fy)):
            raise ValueError(f"camera: fx and fy must be in (0, {MAX_FOCAL_PX:g}] pixels")
        if not all(math.isfinite(p) and abs(p) <= MAX_IMAGE_PX * 4 for p in (c.cx, c.cy)):
            raise ValueError("camera: cx and cy must be finite, near the image")
        if not (math.isfinite(c.baseline) and 0 < c.baseline <= MAX_BASELINE_M):
            raise ValueError(f"camera.baseline: must be in (0, {MAX_BASELINE_M:g}] metres")
        T = np.asarray(self.T_body_cam0, dtype=float)
        if T.shape != (4, 4) or not np.all(np.isfinite(T)):
            raise ValueError("T_body_cam0: expected a 4x4 matrix of finite numbers")
        if np.max(np.abs(T[:3, 3])) > MAX_LEVER_ARM_M:
            raise ValueError(f"T_body_cam0: the camera must be within {MAX_LEVER_ARM_M:g} m of the body")
        R = T[:3, :3]
        rigid = np.max(np.abs(R)) <= 1.0 + 1e-6 and np.max(np.abs(R.T @ R - np.eye(3))) <= 1e-6 and np.linalg.det(R) > 0 and np.array_equal(T[3], [0.0, 0.0, 0.0, 1.0])
        if not rigid:
            raise ValueError("T_body_cam0: expected a rigid transform (a rotation, a translation, last row 0 0 0 1)")
        if not (math.isfinite(self.camera_rate_hz) and 0 < self.camera_rate_hz <= MAX_CAMERA_RATE_HZ):
            raise ValueError(f"camera_rate_hz: must be in (0, {MAX_CAMERA_RATE_HZ:g}]")
        if not (math.isfinite(self.imu_rate_hz) and 0 < self.imu_rate_hz <= MAX_IMU_RATE_HZ):
            raise ValueError(f"imu_rate_hz: must be in (0, {MAX_IMU_RATE_HZ:g}]")


EUROC_CAMERA = PinholeCamera(fx=458.0, fy=458.0, cx=367.0, cy=248.0, width=752, height=480, baseline=0.11)
EUROC_RIG = Rig(camera=EUROC_CAMERA, T_body_cam0=body_camera((0.05, EUROC_CAMERA.baseline / 2.0, 0.0)), camera_rate_hz=20.0, imu_rate_hz=200.0)
# KITTI odometry 00's left camera (f 718.856, cx 607.19, cy 185.22) to a quarter pixel, which
# the readers' float32 rectification keeps exactly: a rendered folder reads back this camera
KITTI_CAMERA = PinholeCamera(fx=718.75, fy=718.75, cx=607.25, cy=185.25, width=1241, height=376, baseline=0.54)
KITTI_RIG = Rig(camera=KITTI_CAMERA, T_body_cam0=body_camera((0.81, 0.32, 0.80)), camera_rate_hz=10.0, imu_rate_hz=200.0)


def rig_to_dict(rig: Rig) -> dict[str, Any]:
    """{"camera": {"fx", "fy", "cx", "cy", "width", "height", "baseline"}, "T_body_cam0":
    4 rows of 4, "camera_rate_hz", "imu_rate_hz"} (pixels, metres, Hz)."""
    c = rig.camera
    return {
        "camera": {"fx": c.fx, "fy": c.fy, "cx": c.cx, "cy": c.cy, "width": c.width, "height": c.height, "baseline": c.baseline},
        "T_body_cam0": np.asarray(rig.T_body_cam0, dtype=float).tolist(),
        "camera_rate_hz": rig.camera_rate_hz,
        "imu_rate_hz": rig.imu_rate_hz,
    }


def rig_from_dict(data: Any, where: str = "rig") -> Rig:
    """A rig from `rig_to_dict`'s form; ValueError naming the field when malformed."""
    if not isinstance(data, dict):
        raise ValueError(f"{where}: expected an object with camera, T_body_cam0, camera_rate_hz and imu_rate_hz")
    cam = data.get("camera")
    if not isinstance(cam, dict):
        raise ValueError(f"{where}.camera: expected an object with fx, fy, cx, cy, width, height and baseline")
    w = f"{where}.camera"
    camera = PinholeCamera(
        fx=bounded(cam, "fx", w, low=0.0, high=MAX_FOCAL_PX, low_open=True),
        fy=bounded(cam, "fy", w, low=0.0, high=MAX_FOCAL_PX, low_open=True),
        cx=bounded(cam, "cx", w, low=-4.0 * MAX_IMAGE_PX, high=4.0 * MAX_IMAGE_PX),
        cy=bounded(cam, "cy", w, low=-4.0 * MAX_IMAGE_PX, high=4.0 * MAX_IMAGE_PX),
        width=integer(cam, "width", w),
        height=integer(cam, "height", w),
        baseline=bounded(cam, "baseline", w, low=0.0, high=MAX_BASELINE_M, low_open=True),
    )
    rows = data.get("T_body_cam0")
    if not (isinstance(rows, list) and len(rows) == 4):
        raise ValueError(f"{where}.T_body_cam0: expected 4 rows of 4 numbers")
    T = np.stack([vector({"row": row}, "row", 4, f"{where}.T_body_cam0") for row in rows])
    try:
        return Rig(
            camera=camera,
            T_body_cam0=T,
            camera_rate_hz=bounded(data, "camera_rate_hz", where, low=0.0, high=MAX_CAMERA_RATE_HZ, low_open=True, default=20.0),
            imu_rate_hz=bounded(data, "imu_rate_hz", where, low=0.0, high=MAX_IMU_RATE_HZ, low_open=True, default=200.0),
        )
    except ValueError as e:
        raise ValueError(f"{where}.{e}") from None
