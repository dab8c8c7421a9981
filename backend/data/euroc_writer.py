"""Write a sequence in the EuRoC ASL layout (what `coplanar render` produces).

```
DIR/mav0/cam0/{data.csv, sensor.yaml, data/<t>.png}     left, rectified pinhole
DIR/mav0/cam1/{data.csv, sensor.yaml, data/<t>.png}     right
DIR/mav0/imu0/{data.csv, sensor.yaml}
DIR/mav0/state_groundtruth_estimate0/{data.csv, sensor.yaml}
DIR/mav0/depth{0,1}/data/<t>.png, DIR/mav0/planes{0,1}/data/<t>.png, mav0/planes.csv
    (extras for cam0 and cam1: depth along z in millimetres as uint16, 0 = nothing; plane
    ids + 1 as uint16, 0 = none; the table of plane parameters; the reader ignores them)
```

Frames: the body is the IMU frame; `T_BS` of each camera is `T_body_camera`. Images are
already rectified and undistorted, so the distortion coefficients are zero.
"""

from __future__ import annotations

import dataclasses
import pathlib

import numpy as np
from PIL import Image
from scipy.spatial.transform import Rotation

from backend.data.motion import ImuNoise
from backend.geometry.camera import PinholeCamera

CSV_CAMERA = "#timestamp [ns],filename\n"
CSV_IMU = "#timestamp [ns],w_RS_S_x [rad s^-1],w_RS_S_y [rad s^-1],w_RS_S_z [rad s^-1],a_RS_S_x [m s^-2],a_RS_S_y [m s^-2],a_RS_S_z [m s^-2]\n"
CSV_GROUND_TRUTH = (
    "#timestamp, p_RS_R_x [m], p_RS_R_y [m], p_RS_R_z [m], q_RS_w [], q_RS_x [], q_RS_y [], q_RS_z [], "
    "v_RS_R_x [m s^-1], v_RS_R_y [m s^-1], v_RS_R_z [m s^-1], b_w_RS_S_x [rad s^-1], b_w_RS_S_y [rad s^-1], "
    "b_w_RS_S_z [rad s^-1], b_a_RS_S_x [m s^-2], b_a_RS_S_y [m s^-2], b_a_RS_S_z [m s^-2]\n"
)


def _matrix_yaml(name: str, T: np.ndarray) -> str:
    rows = ",\n         ".join(", ".join(f"{x:.12g}" for x in row) for row in T)
    return f"{name}:\n  cols: 4\n  rows: 4\n  data: [{rows}]\n"


def camera_sensor_yaml(camera: PinholeCamera, T_body_camera: np.ndarray, *, rate_hz: float, comment: str) -> str:
    """A camera `sensor.yaml` in EuRoC's style (OpenCV `%YAML:1.0` directive first)."""
    return (
        "%YAML:1.0\n"
        f"# {comment}\n"
        "sensor_type: camera\n"
        "comment: coplanar synthetic camera (rectified, undistorted)\n\n"
        "# Sensor extrinsics wrt. the body-frame.\n" + _matrix_yaml("T_BS", T_body_camera) + "\n# Camera specific definitions.\n"
        f"rate_hz: {rate_hz:g}\n"
        f"resolution: [{camera.width}, {camera.height}]\n"
        "camera_model: pinhole\n"
        f"intrinsics: [{camera.fx:.12g}, {camera.fy:.12g}, {camera.cx:.12g}, {camera.cy:.12g}] #fu, fv, cu, cv\n"
        "distortion_model: radial-tangential\n"
        "distortion_coefficients: [0.0, 0.0, 0.0, 0.0]\n"
    )


def imu_sensor_yaml(noise: ImuNoise, *, rate_hz: float) -> str:
    """An IMU `sensor.yaml` in EuRoC's style; the body frame is the IMU frame."""
    return (
        "%YAML:1.0\n"
        "# coplanar synthetic IMU\n"
        "sensor_type: imu\n"
        "comment: coplanar synthetic IMU, EuRoC noise model\n" + _matrix_yaml("T_BS", np.eye(4)) + f"rate_hz: {rate_hz:g}\n\n"
        "# inertial sensor noise model parameters (static)\n"
        f"gyroscope_noise_density: {noise.gyroscope_noise_density:.6e}     # [ rad / s / sqrt(Hz) ]\n"
        f"gyroscope_random_walk: {noise.gyroscope_random_walk:.6e}       # [ rad / s^2 / sqrt(Hz) ]\n"
        f"accelerometer_noise_density: {noise.accelerometer_noise_density:.6e}  # [ m / s^2 / sqrt(Hz) ]\n"
        f"accelerometer_random_walk: {noise.accelerometer_random_walk:.6e}    # [ m / s^3 / sqrt(Hz) ]\n"
    )


@dataclasses.dataclass(frozen=True)
class GroundTruthRows:
    """Body states (N rows): timestamps ns, `p_world_body` (m), `R_world_body`, world
    velocity (m/s), gyro and accelerometer biases."""

    timestamp_ns: np.ndarray
    p_world_body: np.ndarray
    R_world_body: np.ndarray
    v_world: np.ndarray
    bias_gyro: np.ndarray
    bias_accel: np.ndarray


class EurocWriter:
    """Writes one sequence under `root` (created); call the add methods, then :meth:`close`."""

    def __init__(self, root: pathlib.Path | str, *, camera: PinholeCamera, T_body_cam0: np.ndarray, imu_noise: ImuNoise, camera_rate_hz: float, imu_rate_hz: float) -> None:
        self.root = pathlib.Path(root)
        mav = self.root / "mav0"
        self._dirs = {name: mav / name for name in ("cam0", "cam1", "imu0", "state_groundtruth_estimate0", "depth0", "depth1", "planes0", "planes1")}
        for name in ("cam0", "cam1", "depth0", "depth1", "planes0", "planes1"):
            (self._dirs[name] / "data").mkdir(parents=True, exist_ok=True)
        for name in ("imu0", "state_groundtruth_estimate0"):
            self._dirs[name].mkdir(parents=True, exist_ok=True)
        T_cam0_cam1 = np.eye(4)
        T_cam0_cam1[0, 3] = camera.baseline
        for name, T, comment in (("cam0", T_body_cam0, "left camera"), ("cam1", T_body_cam0 @ T_cam0_cam1, "right camera")):
            (self._dirs[name] / "sensor.yaml").write_text(camera_sensor_yaml(camera, T, rate_hz=camera_rate_hz, comment=comment))
        (self._dirs["imu0"] / "sensor.yaml").write_text(imu_sensor_yaml(imu_noise, rate_hz=imu_rate_hz))
        (self._dirs["state_groundtruth_estimate0"] / "sensor.yaml").write_text("%YAML:1.0\nsensor_type: visual-inertial\ncomment: exact synthetic ground truth of the body (IMU) frame\n")
        self._cam_rows: list[str] = []

    def add_frame(self, timestamp_ns: int, *, images: tuple[np.ndarray, np.ndarray], depths: tuple[np.ndarray, np.ndarray] | None = None, planes: tuple[np.ndarray, np.ndarray] | None = None) -> None:
        """One stereo frame: (left, right) uint8 images (H, W); optional depths along z (m,
        inf = nothing) and plane ids (-1 = none), each (left, right)."""
        name = f"{int(timestamp_ns)}.png"
        for i, image in enumerate(images):
            Image.fromarray(image).save(self._dirs[f"cam{i}"] / "data" / name, compress_level=1)
        for i, depth in enumerate(depths or ()):
            mm = np.where(np.isfinite(depth), np.clip(np.round(depth * 1000.0), 0, 65535), 0).astype(np.uint16)
            Image.fromarray(mm).save(self._dirs[f"depth{i}"] / "data" / name, compress_level=1)
        for i, plane in enumerate(planes or ()):
            Image.fromarray((plane.astype(np.int32) + 1).astype(np.uint16)).save(self._dirs[f"planes{i}"] / "data" / name, compress_level=1)
        self._cam_rows.append(f"{int(timestamp_ns)},{name}\n")

    def write_imu(self, timestamp_ns: np.ndarray, gyro: np.ndarray, accel: np.ndarray) -> None:
        rows = [f"{int(t)},{','.join(f'{x:.12g}' for x in (*w, *a))}\n" for t, w, a in zip(timestamp_ns, gyro, accel)]
        (self._dirs["imu0"] / "data.csv").write_text(CSV_IMU + "".join(rows))

    def write_ground_truth(self, gt: GroundTruthRows) -> None:
        q_xyzw = Rotation.from_matrix(gt.R_world_body).as_quat()
        q_wxyz = np.concatenate([q_xyzw[:, 3:], q_xyzw[:, :3]], axis=1)
        values = np.concatenate([gt.p_world_body, q_wxyz, gt.v_world, gt.bias_gyro, gt.bias_accel], axis=1)
        rows = [f"{int(t)},{','.join(f'{x:.12g}' for x in row)}\n" for t, row in zip(gt.timestamp_ns, values)]
        (self._dirs["state_groundtruth_estimate0"] / "data.csv").write_text(CSV_GROUND_TRUTH + "".join(rows))

    def write_planes(self, plane_n: np.ndarray, plane_d: np.ndarray) -> None:
        """The plane table of the extras: id, n (world), d (n·X + d = 0)."""
        rows = [f"{i},{n[0]:.12g},{n[1]:.12g},{n[2]:.12g},{d:.12g}\n" for i, (n, d) in enumerate(zip(plane_n, plane_d))]
        (self.root / "mav0" / "planes.csv").write_text("#id,n_x,n_y,n_z,d\n" + "".join(rows))

    def close(self) -> None:
        for name in ("cam0", "cam1"):
            (self._dirs[name] / "data.csv").write_text(CSV_CAMERA + "".join(self._cam_rows))
