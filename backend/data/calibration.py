"""Camera and IMU calibration from EuRoC `sensor.yaml` files, and stereo rectification.

Parsing: the files are OpenCV FileStorage YAML. They begin with the directive `%YAML:1.0`,
which YAML 1.1/1.2 parsers (PyYAML, ruamel) reject, and hold matrices as
`{cols, rows, data}` maps. They are read with OpenCV's own parser, `cv2.FileStorage` (from
memory), the parser the format was written for: comments, flow lists over several lines and
`!!opencv-matrix` tags all work, and OpenCV is needed anyway for rectification, so no YAML
package is added and no hand-written parser has to second-guess the format. Its quirks are
handled here: a file without the directive gets one (writers of ASL folders often omit it);
its parse errors (a `cv2.error`, raised through a `SystemError` by the constructor) become a
DatasetError with the file and line; its getters, which assert or return DBL_MAX on the
wrong type, are only called after the node's type is checked. Every value is checked for
presence, type, count and finiteness.

Frames (metres): `body` is EuRoC's body frame (the IMU's). A sensor's `T_BS` is
`T_body_sensor`: `p_body = R p_sensor + t`. cam0 is the left camera, cam1 the right one.
Rectification turns camN into rectN by a rotation about its centre, `p_rectN = R_rectN_camN
p_camN` (OpenCV's R1, R2); rect1 is rect0 shifted by `baseline` along +x, and both share the
pinhole intrinsics of the rectified `PinholeCamera` (rectified pixels, no distortion).
"""

from __future__ import annotations

import dataclasses
import pathlib
import re

import cv2
import numpy as np

from backend.data.errors import DatasetError, read_text
from backend.data.motion import ImuNoise
from backend.geometry.camera import PinholeCamera

RADIAL_TANGENTIAL = ("radial-tangential", "radtan", "plumb_bob")  # accepted `distortion_model` names
ROTATION_TOLERANCE = 1e-3  # max |RᵀR - I| of a T_BS before it is rejected as not a rotation
MAX_RESOLUTION_PX = 16384  # per side: larger would not fit the rectification maps in memory


@dataclasses.dataclass(frozen=True, eq=False)
class CameraCalibration:
    """One raw camera (`mav0/camN/sensor.yaml`): pinhole intrinsics in pixels of the raw
    image, radial-tangential distortion `(k1, k2, p1, p2[, k3])` (OpenCV's plumb-bob order),
    and `T_body_camera` (4, 4), metres (EuRoC's `T_BS`)."""

    fx: float
    fy: float
    cx: float
    cy: float
    width: int
    height: int
    distortion: np.ndarray
    T_body_camera: np.ndarray
    rate_hz: float
    source: str = ""  # the file it was read from, named in errors

    @property
    def K(self) -> np.ndarray:
        return np.array([[self.fx, 0.0, self.cx], [0.0, self.fy, self.cy], [0.0, 0.0, 1.0]])


@dataclasses.dataclass(frozen=True, eq=False)
class ImuCalibration:
    """`mav0/imu0/sensor.yaml`: `T_body_imu` (4, 4), metres; sample rate in Hz; continuous-time
    noise densities (per √Hz, EuRoC's convention)."""

    T_body_imu: np.ndarray
    rate_hz: float
    noise: ImuNoise
    source: str = ""


class _OpenCvYaml:
    """A parsed OpenCV YAML file whose typed getters raise DatasetError naming the file and key."""

    def __init__(self, path: pathlib.Path) -> None:
        self.path = path
        text = read_text(path)
        offset = 0
        if not text.lstrip().startswith("%YAML"):
            text = "%YAML:1.0\n" + text
            offset = 1
        try:
            # Keep the storage alive: its nodes point into it.
            self._storage = cv2.FileStorage(text, cv2.FILE_STORAGE_READ | cv2.FILE_STORAGE_MEMORY)
        except (cv2.error, SystemError) as error:
            raise _parse_error(path, error, offset) from None
        if not self._storage.root().isMap():
            raise DatasetError(path, "expected `key: value` entries at the top level")

    def has(self, key: str) -> bool:
        node = self._storage.getNode(key)
        return not (node.empty() or node.isNone())

    def _node(self, key: str) -> cv2.FileNode:
        node = self._storage.getNode(key)
        if node.empty() or node.isNone():
            raise DatasetError(self.path, f"missing key '{key}'")
        return node

    def _scalar(self, node: cv2.FileNode, what: str) -> float:
        if not (node.isInt() or node.isReal()):
            raise DatasetError(self.path, f"{what} must be a number")
        value = float(node.real())
        if not np.isfinite(value):
            raise DatasetError(self.path, f"{what} must be finite, got {value}")
        return value

    def number(self, key: str, *, positive: bool = False) -> float:
        value = self._scalar(self._node(key), f"'{key}'")
        if positive and value <= 0.0:
            raise DatasetError(self.path, f"'{key}' must be positive, got {value:g}")
        return value

    def numbers(self, key: str, counts: tuple[int, ...]) -> np.ndarray:
        node = self._node(key)
        wanted = " or ".join(str(c) for c in counts)
        if not node.isSeq() or node.size() not in counts:
            raise DatasetError(self.path, f"'{key}' must be a list of {wanted} numbers")
        return np.array([self._scalar(node.at(i), f"'{key}' entry {i + 1}") for i in range(node.size())])

    def text(self, key: str) -> str:
        node = self._node(key)
        if not node.isString():
            raise DatasetError(self.path, f"'{key}' must be a name")
        return node.string().strip()

    def matrix(self, key: str, *, rows: int, cols: int) -> np.ndarray:
        node = self._node(key)
        form = f"'{key}' must be a {rows}x{cols} matrix {{cols: {cols}, rows: {rows}, data: [{rows * cols} numbers]}}"
        if not node.isMap():
            raise DatasetError(self.path, form)
        for name, expected in (("rows", rows), ("cols", cols)):
            size = node.getNode(name)
            if size.empty() or not size.isInt() or int(size.real()) != expected:
                raise DatasetError(self.path, form)
        data = node.getNode("data")
        if data.empty() or not data.isSeq() or data.size() != rows * cols:
            raise DatasetError(self.path, form)
        values = [self._scalar(data.at(i), f"'{key}' data entry {i + 1}") for i in range(rows * cols)]
        return np.array(values).reshape(rows, cols)

    def transform(self, key: str) -> np.ndarray:
        """A rigid transform (4, 4); the rotation is re-orthonormalized (SVD) within tolerance."""
        T = self.matrix(key, rows=4, cols=4)
        R = T[:3, :3]
        if not np.allclose(T[3], [0.0, 0.0, 0.0, 1.0], atol=1e-9):
            raise DatasetError(self.path, f"'{key}' last row must be [0, 0, 0, 1]")
        if np.abs(R.T @ R - np.eye(3)).max() > ROTATION_TOLERANCE or np.linalg.det(R) <= 0.0:
            raise DatasetError(self.path, f"'{key}' rotation part is not a rotation matrix")
        U, _, Vt = np.linalg.svd(R)
        T = T.copy()
        T[:3, :3] = U @ Vt
        return T


def _parse_error(path: pathlib.Path, error: Exception, offset: int) -> DatasetError:
    """OpenCV's parse error, e.g. `... (-212:Parsing error) parseKey in function '(8): Missing ':''`,
    as a DatasetError with the file's own line number."""
    message = str(error.__cause__ or error).strip()
    located = re.search(r"'\((\d+)\): (.*)'$", message)
    if located:
        line = int(located.group(1)) - offset
        return DatasetError(path, f"not valid OpenCV YAML: {located.group(2)}", line=line if line >= 1 else None)
    described = re.search(r"error: \([^)]*\) (.*)$", message)
    return DatasetError(path, f"not valid OpenCV YAML: {described.group(1) if described else message}")


def read_camera_yaml(path: pathlib.Path | str) -> CameraCalibration:
    """A camera's `sensor.yaml` (pinhole, radial-tangential)."""
    path = pathlib.Path(path)
    yaml = _OpenCvYaml(path)
    T_body_camera = yaml.transform("T_BS")
    resolution = yaml.numbers("resolution", (2,))
    if np.any(resolution < 1) or np.any(resolution != np.round(resolution)):
        raise DatasetError(path, "'resolution' must be two positive integers [width, height]")
    if np.any(resolution > MAX_RESOLUTION_PX):
        raise DatasetError(path, f"'resolution' {int(resolution[0])}x{int(resolution[1])} is larger than {MAX_RESOLUTION_PX} pixels per side")
    model = yaml.text("camera_model")
    if model != "pinhole":
        raise DatasetError(path, f"camera_model '{model}' is not supported (only pinhole)")
    fu, fv, cu, cv = yaml.numbers("intrinsics", (4,))
    if fu <= 0.0 or fv <= 0.0:
        raise DatasetError(path, "'intrinsics' focal lengths fu, fv must be positive")
    distortion_model = yaml.text("distortion_model")
    if distortion_model not in RADIAL_TANGENTIAL:
        raise DatasetError(path, f"distortion_model '{distortion_model}' is not supported (only radial-tangential)")
    distortion = yaml.numbers("distortion_coefficients", (4, 5))
    return CameraCalibration(
        fx=float(fu),
        fy=float(fv),
        cx=float(cu),
        cy=float(cv),
        width=int(resolution[0]),
        height=int(resolution[1]),
        distortion=distortion,
        T_body_camera=T_body_camera,
        rate_hz=yaml.number("rate_hz", positive=True),
        source=str(path),
    )


def read_imu_yaml(path: pathlib.Path | str) -> ImuCalibration:
    """The IMU's `sensor.yaml`: extrinsics, rate and noise densities."""
    path = pathlib.Path(path)
    yaml = _OpenCvYaml(path)
    noise = ImuNoise(
        gyroscope_noise_density=yaml.number("gyroscope_noise_density"),
        gyroscope_random_walk=yaml.number("gyroscope_random_walk"),
        accelerometer_noise_density=yaml.number("accelerometer_noise_density"),
        accelerometer_random_walk=yaml.number("accelerometer_random_walk"),
    )
    for name, value in dataclasses.asdict(noise).items():
        if value < 0.0:
            raise DatasetError(path, f"'{name}' must not be negative, got {value:g}")
    return ImuCalibration(T_body_imu=yaml.transform("T_BS"), rate_hz=yaml.number("rate_hz", positive=True), noise=noise, source=str(path))


def read_sensor_transform(path: pathlib.Path | str, *, default: np.ndarray | None = None) -> np.ndarray:
    """`T_BS` (4, 4) of any `sensor.yaml` (e.g. the ground truth's), `T_body_sensor`, metres;
    `default` where the file has no `T_BS` (an error when None)."""
    yaml = _OpenCvYaml(pathlib.Path(path))
    if default is not None and not yaml.has("T_BS"):
        return np.array(default, dtype=float)
    return yaml.transform("T_BS")


@dataclasses.dataclass(frozen=True, eq=False)
class StereoRectification:
    """Rectified pinhole stereo from two raw cameras (frames in the module docstring).

    `camera` is the rectified left camera (rect0), with `baseline` in metres; `P_rect0`,
    `P_rect1` (3, 4) are OpenCV's P1, P2; `maps` are the float32 remap tables
    `(x0, y0, x1, y1)`, each (height, width), from rectified to raw pixels.
    """

    camera: PinholeCamera
    R_rect0_cam0: np.ndarray
    R_rect1_cam1: np.ndarray
    T_cam1_cam0: np.ndarray
    T_body_rect0: np.ndarray
    P_rect0: np.ndarray
    P_rect1: np.ndarray
    maps: tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]

    @property
    def T_cam0_rect0(self) -> np.ndarray:
        """`[R_rect0_cam0ᵀ | 0]` (4, 4): rectified left camera to raw cam0."""
        T = np.eye(4)
        T[:3, :3] = self.R_rect0_cam0.T
        return T

    def rectify(self, image0: np.ndarray, image1: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Raw cam0, cam1 images to rectified rect0, rect1 images (bilinear; black outside)."""
        shape = (self.camera.height, self.camera.width)
        if image0.shape[:2] != shape or image1.shape[:2] != shape:
            raise ValueError(f"images must be {shape[1]}x{shape[0]}, got {image0.shape[:2]} and {image1.shape[:2]}")
        x0, y0, x1, y1 = self.maps
        rect0 = cv2.remap(image0, x0, y0, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT)
        rect1 = cv2.remap(image1, x1, y1, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT)
        return rect0, rect1


def stereo_rectification(cam0: CameraCalibration, cam1: CameraCalibration) -> StereoRectification:
    """OpenCV stereo rectification (`stereoRectify`, alpha = 0: only valid pixels, zero
    disparity at infinity) of left camera `cam0` and right camera `cam1`, with the relative pose
    `T_cam1_cam0 = T_body_cam1⁻¹ T_body_cam0` from their extrinsics."""
    size = (cam0.width, cam0.height)
    if (cam1.width, cam1.height) != size:
        raise DatasetError(cam1.source, f"resolution {cam1.width}x{cam1.height} differs from cam0's {size[0]}x{size[1]}")
    T_cam1_cam0 = np.linalg.inv(cam1.T_body_camera) @ cam0.T_body_camera
    R_cam1_cam0 = T_cam1_cam0[:3, :3]
    t_cam1_cam0 = T_cam1_cam0[:3, 3]
    if np.linalg.norm(t_cam1_cam0) < 1e-6:
        raise DatasetError(cam1.source, "cam1 is at the same place as cam0 (zero stereo baseline)")
    R1, R2, P1, P2, _, _, _ = cv2.stereoRectify(
        cam0.K,
        cam0.distortion,
        cam1.K,
        cam1.distortion,
        size,
        R_cam1_cam0,
        t_cam1_cam0,
        flags=cv2.CALIB_ZERO_DISPARITY,
        alpha=0.0,
    )
    # Horizontal rectification puts the baseline in P2[0, 3] = -f·b; a vertical one in P2[1, 3].
    baseline = -P2[0, 3] / P2[0, 0]
    if abs(P2[1, 3]) > 1e-9 * abs(P2[0, 3]) or baseline <= 0.0:
        raise DatasetError(cam1.source, "cam1 is not to the right of cam0 (horizontal stereo with cam0 on the left expected)")
    x0, y0 = cv2.initUndistortRectifyMap(cam0.K, cam0.distortion, R1, P1, size, cv2.CV_32FC1)
    x1, y1 = cv2.initUndistortRectifyMap(cam1.K, cam1.distortion, R2, P2, size, cv2.CV_32FC1)
    camera = PinholeCamera(
        fx=float(P1[0, 0]),
        fy=float(P1[1, 1]),
        cx=float(P1[0, 2]),
        cy=float(P1[1, 2]),
        width=size[0],
        height=size[1],
        baseline=float(baseline),
    )
    T_cam0_rect0 = np.eye(4)
    T_cam0_rect0[:3, :3] = R1.T
    return StereoRectification(
        camera=camera,
        R_rect0_cam0=R1,
        R_rect1_cam1=R2,
        T_cam1_cam0=T_cam1_cam0,
        T_body_rect0=cam0.T_body_camera @ T_cam0_rect0,
        P_rect0=P1,
        P_rect1=P2,
        maps=(x0, y0, x1, y1),
    )
