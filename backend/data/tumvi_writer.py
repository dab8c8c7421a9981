"""Convert a rendered EuRoC folder into a TUM-VI-style export with equidistant fisheye images
(`coplanar render --format tumvi`; the TUM-VI reader's tests).

```
OUT/mav0/cam0/{data.csv, data/<t>.png}   left fisheye, 16-bit grey PNG (8-bit value × 257)
OUT/mav0/cam1/{data.csv, data/<t>.png}   right fisheye
OUT/mav0/imu0/data.csv                   the rendered IMU samples, as they are
OUT/mav0/mocap0/data.csv                 the rendered ground truth: body (IMU) poses, 8 columns
OUT/dso/camchain.yaml                    Kalibr: pinhole + equidistant cam0, cam1 (T_cam_imu, T_cn_cnm1)
OUT/dso/imu_config.yaml                  Kalibr: the rendered IMU's noise densities and rate
```

The fisheye cameras: the rendered pinhole camera's image size, focal length and principal
point, with TUM-VI's calibrated equidistant coefficients k1..k4 (`FISHEYE_DISTORTION`, cam0's
and cam1's of the 512_16 sequences), at the rendered cameras' poses (parallel, cam1 `baseline`
along cam0's x). The TUM-VI reader's rectified camera (backend.data.calibration: the raw
size, the smaller focal length, the mean principal point) is then the rendered camera
itself, so its rectified images can be compared with the rendered ones pixel for pixel.

Each fisheye image is the rendered pinhole image warped with `cv2.remap` (bilinear): a
fisheye pixel looks up the pinhole pixel of its ray. The fisheye sees wider than the pinhole
render (at f = 458 px its 752x480 image spans about ±48° across and ±31° down, the render
±39° and ±28°): what the render does not see is black, a band round the image.
Rectification resamples once more, so the reader's rectified images and trajectories
approximate the EuRoC folder's; they are not identical.
"""

from __future__ import annotations

import pathlib
import shutil

import cv2
import numpy as np
from PIL import Image
from scipy.spatial.transform import Rotation

from backend.data.calibration import CameraCalibration, CameraModel, ImuCalibration
from backend.data.euroc import EurocDataset, GroundTruth
from backend.data.euroc_writer import CSV_CAMERA

FISHEYE_DISTORTION = (
    (0.0034823894022493434, 0.0007150348452162257, -0.0020532361418706202, 0.00020293673591811182),
    (0.0034003170790442797, 0.001766278153469831, -0.00266312569781606, 0.0003299517423931039),
)
CSV_MOCAP = "#timestamp [ns],p_RS_R_x [m],p_RS_R_y [m],p_RS_R_z [m],q_RS_w [],q_RS_x [],q_RS_y [],q_RS_z []\n"
SIXTEEN_BIT_SCALE = 257  # 8-bit v -> 16-bit 257 v, whose high byte is v again


def fisheye_camera(pinhole: CameraCalibration, distortion: tuple[float, ...]) -> CameraCalibration:
    """An equidistant camera with `pinhole`'s size, intrinsics (pixels) and pose `T_body_camera`."""
    return CameraCalibration(
        fx=pinhole.fx,
        fy=pinhole.fy,
        cx=pinhole.cx,
        cy=pinhole.cy,
        width=pinhole.width,
        height=pinhole.height,
        distortion=np.array(distortion, dtype=float),
        T_body_camera=pinhole.T_body_camera,
        rate_hz=pinhole.rate_hz,
        model=CameraModel.EQUIDISTANT,
    )


def fisheye_from_pinhole_map(fisheye: CameraCalibration, pinhole: CameraCalibration) -> tuple[np.ndarray, np.ndarray]:
    """float32 remap tables (H, W) of the fisheye image: for each fisheye pixel, the pinhole
    pixel of its ray (both cameras at one place); -1 where the ray has no pinhole pixel."""
    u, v = np.meshgrid(np.arange(fisheye.width, dtype=np.float64), np.arange(fisheye.height, dtype=np.float64))
    pixels = np.stack([u.ravel(), v.ravel()], axis=-1)[:, None, :]
    looked_up = cv2.fisheye.undistortPoints(pixels, fisheye.K, fisheye.distortion, P=pinhole.K)[:, 0, :]
    looked_up[~np.isfinite(looked_up).all(axis=1)] = -1.0
    x = looked_up[:, 0].reshape(fisheye.height, fisheye.width).astype(np.float32)
    y = looked_up[:, 1].reshape(fisheye.height, fisheye.width).astype(np.float32)
    return x, y


def camchain_yaml(cam0: CameraCalibration, cam1: CameraCalibration) -> str:
    """Kalibr's `camchain.yaml` (its PyYAML layout) for two cameras with the IMU as the body:
    `T_cam_imu = T_body_camera⁻¹`, cam1's `T_cn_cnm1 = T_cam1_cam0`."""
    T_cam0_imu = np.linalg.inv(cam0.T_body_camera)
    T_cam1_imu = np.linalg.inv(cam1.T_body_camera)
    return _kalibr_camera("cam0", cam0, T_cam0_imu, overlaps=1) + _kalibr_camera("cam1", cam1, T_cam1_imu, overlaps=0, T_cn_cnm1=T_cam1_imu @ cam0.T_body_camera)


def _kalibr_camera(name: str, camera: CameraCalibration, T_cam_imu: np.ndarray, *, overlaps: int, T_cn_cnm1: np.ndarray | None = None) -> str:
    model = "equidistant" if camera.model == CameraModel.EQUIDISTANT else "radtan"
    text = f"{name}:\n" + _rows("T_cam_imu", T_cam_imu)
    if T_cn_cnm1 is not None:
        text += _rows("T_cn_cnm1", T_cn_cnm1)
    return text + (
        f"  cam_overlaps: [{overlaps}]\n"
        "  camera_model: pinhole\n"
        f"  distortion_coeffs: {_list(camera.distortion)}\n"
        f"  distortion_model: {model}\n"
        f"  intrinsics: {_list([camera.fx, camera.fy, camera.cx, camera.cy])}\n"
        f"  resolution: [{camera.width}, {camera.height}]\n"
        f"  rostopic: /{name}/image_raw\n"
    )


def _list(values: np.ndarray | list[float]) -> str:
    return "[" + ", ".join(repr(float(x) + 0.0) for x in values) + "]"  # + 0.0: no -0.0


def _rows(key: str, T: np.ndarray) -> str:
    return f"  {key}:\n" + "".join(f"  - {_list(row)}\n" for row in T)


def imu_config_yaml(imu: ImuCalibration) -> str:
    """Kalibr's IMU file (TUM-VI's `dso/imu_config.yaml`): noise densities per √Hz, rate in Hz."""
    noise = imu.noise
    return (
        f"accelerometer_noise_density: {noise.accelerometer_noise_density!r}  # [ m / s^2 / sqrt(Hz) ]\n"
        f"accelerometer_random_walk: {noise.accelerometer_random_walk!r}  # [ m / s^3 / sqrt(Hz) ]\n"
        f"gyroscope_noise_density: {noise.gyroscope_noise_density!r}  # [ rad / s / sqrt(Hz) ]\n"
        f"gyroscope_random_walk: {noise.gyroscope_random_walk!r}  # [ rad / s^2 / sqrt(Hz) ]\n"
        "rostopic: /imu0\n"
        f"update_rate: {float(imu.rate_hz)!r}\n"
    )


def mocap_csv(truth: GroundTruth) -> str:
    """`mocap0/data.csv`: timestamp (ns), body position (m) and quaternion (w, x, y, z)."""
    q_wxyz = Rotation.from_matrix(truth.R_world_body).as_quat(scalar_first=True)
    values = np.concatenate([truth.p_world_body, q_wxyz], axis=1)
    return CSV_MOCAP + "".join(f"{int(t)},{','.join(f'{x:.12g}' for x in row)}\n" for t, row in zip(truth.timestamp_ns, values))


def convert(euroc_folder: pathlib.Path, out: pathlib.Path) -> None:
    """Write the TUM-VI-style export of the rendered EuRoC folder `euroc_folder` into `out`
    (module docstring): `mav0/{cam0, cam1, imu0, mocap0}` and `dso/`."""
    source = EurocDataset(euroc_folder)
    fisheyes = tuple(fisheye_camera(pinhole, k) for pinhole, k in zip((source.cam0, source.cam1), FISHEYE_DISTORTION))
    maps = [fisheye_from_pinhole_map(fisheye, pinhole) for fisheye, pinhole in zip(fisheyes, (source.cam0, source.cam1))]
    mav0 = out / "mav0"
    folders = [mav0 / f"cam{i}" for i in (0, 1)]
    for folder in folders:
        (folder / "data").mkdir(parents=True, exist_ok=True)
    for index, t in enumerate(source.timestamps_ns):
        for folder, image, (x, y) in zip(folders, source.raw_pair(index), maps):
            fisheye = cv2.remap(image, x, y, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT, borderValue=0)
            Image.fromarray(fisheye.astype(np.uint16) * SIXTEEN_BIT_SCALE).save(folder / "data" / f"{int(t)}.png", compress_level=1)
    rows = "".join(f"{int(t)},{int(t)}.png\n" for t in source.timestamps_ns)
    for folder in folders:
        (folder / "data.csv").write_text(CSV_CAMERA + rows)
    _write_imu_and_truth(source, euroc_folder, mav0)
    dso = out / "dso"
    dso.mkdir(parents=True, exist_ok=True)
    (dso / "camchain.yaml").write_text(camchain_yaml(*fisheyes))
    if source.has_imu:
        (dso / "imu_config.yaml").write_text(imu_config_yaml(source.imu_calibration))


def _write_imu_and_truth(source: EurocDataset, euroc_folder: pathlib.Path, mav0: pathlib.Path) -> None:
    """`imu0/data.csv` copied as it is; `mocap0/data.csv` from the ground truth."""
    if source.has_imu:
        (mav0 / "imu0").mkdir(parents=True, exist_ok=True)
        shutil.copyfile(euroc_folder / "mav0" / "imu0" / "data.csv", mav0 / "imu0" / "data.csv")
    if source.ground_truth is not None:
        (mav0 / "mocap0").mkdir(parents=True, exist_ok=True)
        (mav0 / "mocap0" / "data.csv").write_text(mocap_csv(source.ground_truth))
