"""Camera and IMU calibration from EuRoC `sensor.yaml` files and Kalibr `camchain.yaml` /
IMU files, and stereo rectification of pinhole cameras with radial-tangential or
equidistant (fisheye) distortion.

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

Kalibr's files (`camchain.yaml`, `imu.yaml`; TUM-VI's `dso/camchain.yaml` and
`dso/imu_config.yaml`) are plain YAML 1.1 written by PyYAML, with block sequences at their
key's indentation, which OpenCV's parser rejects; they are read with PyYAML (`safe_load`),
the parser they were written with, and every value is checked the same way.

Frames (metres): `body` is EuRoC's body frame (the IMU's). A sensor's `T_BS` is
`T_body_sensor`: `p_body = R p_sensor + t`. cam0 is the left camera, cam1 the right one.
Rectification turns camN into rectN by a rotation about its centre, `p_rectN = R_rectN_camN
p_camN` (OpenCV's R1, R2); rect1 is rect0 shifted by `baseline` along +x, and both share the
pinhole intrinsics of the rectified `PinholeCamera` (rectified pixels, no distortion).
Kalibr's `T_cam_imu` is `T_camera_body` (the IMU is the body), so `T_body_camera` is its
inverse; `T_cn_cnm1` of cam1 is `T_cam1_cam0`.

Equidistant (fisheye) rectification: OpenCV's `cv2.fisheye.stereoRectify` gives the
rectifying rotations, but not the rectified camera: its focal length comes from the
undistorted midpoints of the image edges, which for TUM-VI's ~190° lenses lie ~77° off the
axis, so it picks f ≈ 59 px for 512x512 images (a 154° pinhole view that squeezes the centre
threefold; `balance` barely changes it and `fov_scale` would have to be tuned per lens).
The rectified camera is chosen instead as the raw image's size, the smaller of the two
cameras' focal lengths (so the image centre keeps its resolution, never upsampled) and the
mean of their principal points (zero disparity at infinity): for TUM-VI's 512x512, f ≈ 190
px cameras, a 512x512 pinhole with a 2·atan(256/190) ≈ 107° field across (≈ 124° on the
diagonal), whose corners (62° off the axis) still lie inside the fisheye image, so every
rectified pixel is valid, as with `alpha = 0` for radial-tangential cameras. The periphery
beyond that cannot be kept by a pinhole image of any sensible size.
"""

from __future__ import annotations

import dataclasses
import enum
import pathlib
import re
from typing import Any

import cv2
import numpy as np
import yaml

from backend.data.errors import DatasetError, read_text
from backend.data.motion import ImuNoise
from backend.geometry.camera import PinholeCamera

RADIAL_TANGENTIAL = ("radial-tangential", "radtan", "plumb_bob")  # accepted `distortion_model` names
EQUIDISTANT = ("equidistant", "equi", "fisheye")  # accepted names of the equidistant (Kannala-Brandt k1..k4) model
ROTATION_TOLERANCE = 1e-3  # max |RᵀR - I| of a T_BS before it is rejected as not a rotation
MAX_RESOLUTION_PX = 16384  # per side: larger would not fit the rectification maps in memory


class CameraModel(enum.StrEnum):
    """The raw cameras' projection: pinhole with radial-tangential distortion
    `(k1, k2, p1, p2[, k3])` (OpenCV's plumb-bob order), or pinhole with equidistant fisheye
    distortion `(k1, k2, k3, k4)`: `θ_d = θ (1 + k1 θ² + k2 θ⁴ + k3 θ⁶ + k4 θ⁸)`, pixels
    `f θ_d / r (x, y) + c` (OpenCV's `cv2.fisheye`, Kalibr's `pinhole-equi`)."""

    RADIAL_TANGENTIAL = "pinhole-radtan"
    EQUIDISTANT = "pinhole-equi"


@dataclasses.dataclass(frozen=True, eq=False)
class CameraCalibration:
    """One raw camera (`mav0/camN/sensor.yaml`, or a camera of a Kalibr camchain): pinhole
    intrinsics in pixels of the raw image, `distortion` coefficients of `model`, and
    `T_body_camera` (4, 4), metres (EuRoC's `T_BS`). `rate_hz` is 0 where the file gives none
    (Kalibr)."""

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
    model: CameraModel = CameraModel.RADIAL_TANGENTIAL

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
        return _rigid(self.path, key, self.matrix(key, rows=4, cols=4))


def _rigid(path: pathlib.Path, key: str, T: np.ndarray) -> np.ndarray:
    """`T` (4, 4) checked to be a rigid transform, its rotation re-orthonormalized (SVD)
    within tolerance; a DatasetError naming `path` and `key` otherwise."""
    R = T[:3, :3]
    if not np.allclose(T[3], [0.0, 0.0, 0.0, 1.0], atol=1e-9):
        raise DatasetError(path, f"'{key}' last row must be [0, 0, 0, 1]")
    if np.abs(R.T @ R - np.eye(3)).max() > ROTATION_TOLERANCE or np.linalg.det(R) <= 0.0:
        raise DatasetError(path, f"'{key}' rotation part is not a rotation matrix")
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
    """A camera's `sensor.yaml` (pinhole; radial-tangential or equidistant distortion)."""
    path = pathlib.Path(path)
    yaml = _OpenCvYaml(path)
    T_body_camera = yaml.transform("T_BS")
    width, height = _resolution(path, "resolution", yaml.numbers("resolution", (2,)))
    _pinhole(path, "camera_model", yaml.text("camera_model"))
    fu, fv, cu, cv = _intrinsics(path, "intrinsics", yaml.numbers("intrinsics", (4,)))
    model = _distortion_model(path, "distortion_model", yaml.text("distortion_model"))
    distortion = yaml.numbers("distortion_coefficients", _DISTORTION_COUNTS[model])
    return CameraCalibration(
        fx=fu,
        fy=fv,
        cx=cu,
        cy=cv,
        width=width,
        height=height,
        distortion=distortion,
        T_body_camera=T_body_camera,
        rate_hz=yaml.number("rate_hz", positive=True),
        source=str(path),
        model=model,
    )


_DISTORTION_COUNTS = {CameraModel.RADIAL_TANGENTIAL: (4, 5), CameraModel.EQUIDISTANT: (4,)}


def _resolution(path: pathlib.Path, key: str, resolution: np.ndarray) -> tuple[int, int]:
    """`[width, height]` checked: positive whole numbers, at most MAX_RESOLUTION_PX."""
    if np.any(resolution < 1) or np.any(resolution != np.round(resolution)):
        raise DatasetError(path, f"'{key}' must be two positive integers [width, height]")
    if np.any(resolution > MAX_RESOLUTION_PX):
        raise DatasetError(path, f"'{key}' {int(resolution[0])}x{int(resolution[1])} is larger than {MAX_RESOLUTION_PX} pixels per side")
    return int(resolution[0]), int(resolution[1])


def _pinhole(path: pathlib.Path, key: str, model: str) -> None:
    if model != "pinhole":
        raise DatasetError(path, f"{key} '{model}' is not supported (only pinhole)")


def _intrinsics(path: pathlib.Path, key: str, values: np.ndarray) -> tuple[float, float, float, float]:
    """`[fu, fv, cu, cv]` (pixels) with positive focal lengths."""
    fu, fv, cu, cv = (float(v) for v in values)
    if fu <= 0.0 or fv <= 0.0:
        raise DatasetError(path, f"'{key}' focal lengths fu, fv must be positive")
    return fu, fv, cu, cv


def _distortion_model(path: pathlib.Path, key: str, name: str) -> CameraModel:
    if name in RADIAL_TANGENTIAL:
        return CameraModel.RADIAL_TANGENTIAL
    if name in EQUIDISTANT:
        return CameraModel.EQUIDISTANT
    raise DatasetError(path, f"{key} '{name}' is not supported (only radial-tangential or equidistant)")


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


class _PlainYaml:
    """A plain YAML file (Kalibr's) read with PyYAML; the getters take a mapping and a dotted
    key (`cam0.intrinsics`, named in errors) and raise DatasetError naming the file."""

    def __init__(self, path: pathlib.Path) -> None:
        self.path = path
        text = read_text(path)
        try:
            self.root = yaml.safe_load(text)
        except yaml.YAMLError as error:
            mark = getattr(error, "problem_mark", None)
            problem = getattr(error, "problem", None) or str(error)
            raise DatasetError(path, f"not valid YAML: {problem}", line=mark.line + 1 if mark is not None else None) from None
        if not isinstance(self.root, dict):
            raise DatasetError(path, "expected `key: value` entries at the top level")

    def value(self, node: dict[str, Any], key: str) -> Any:
        name = key.rsplit(".", 1)[-1]
        if node.get(name) is None:
            raise DatasetError(self.path, f"missing key '{key}'")
        return node[name]

    def mapping(self, node: dict[str, Any], key: str) -> dict[str, Any]:
        value = self.value(node, key)
        if not isinstance(value, dict):
            raise DatasetError(self.path, f"'{key}' must hold `key: value` entries")
        return value

    def text(self, node: dict[str, Any], key: str) -> str:
        value = self.value(node, key)
        if not isinstance(value, str):
            raise DatasetError(self.path, f"'{key}' must be a name")
        return value.strip()

    def _scalar(self, value: Any, what: str) -> float:
        """A number: YAML's int or float, or a string that is one (YAML 1.1 reads `1e-5`,
        without a dot, as a string); not a boolean."""
        if isinstance(value, bool) or not isinstance(value, (int, float, str)):
            raise DatasetError(self.path, f"{what} must be a number")
        try:
            number = float(value)
        except ValueError:
            raise DatasetError(self.path, f"{what} must be a number, got '{value}'") from None
        if not np.isfinite(number):
            raise DatasetError(self.path, f"{what} must be finite, got {number}")
        return number

    def number(self, node: dict[str, Any], key: str, *, positive: bool = False) -> float:
        value = self._scalar(self.value(node, key), f"'{key}'")
        if positive and value <= 0.0:
            raise DatasetError(self.path, f"'{key}' must be positive, got {value:g}")
        return value

    def numbers(self, node: dict[str, Any], key: str, counts: tuple[int, ...]) -> np.ndarray:
        value = self.value(node, key)
        if not isinstance(value, list) or len(value) not in counts:
            wanted = " or ".join(str(c) for c in counts)
            raise DatasetError(self.path, f"'{key}' must be a list of {wanted} numbers")
        return np.array([self._scalar(v, f"'{key}' entry {i + 1}") for i, v in enumerate(value)])

    def transform(self, node: dict[str, Any], key: str) -> np.ndarray:
        """A rigid transform (4, 4) given as four rows of four numbers."""
        rows = self.value(node, key)
        if not isinstance(rows, list) or len(rows) != 4 or any(not isinstance(row, list) or len(row) != 4 for row in rows):
            raise DatasetError(self.path, f"'{key}' must be a 4x4 matrix (four rows of four numbers)")
        T = np.array([[self._scalar(v, f"'{key}' row {i + 1}") for v in row] for i, row in enumerate(rows)])
        return _rigid(self.path, key, T)


def read_kalibr_camchain(path: pathlib.Path | str) -> tuple[CameraCalibration, CameraCalibration]:
    """cam0 (left) and cam1 (right) of a Kalibr `camchain.yaml` (e.g. TUM-VI's
    `dso/camchain.yaml`): `camera_model` pinhole, `distortion_model` radtan or equidistant,
    `intrinsics` [fu, fv, pu, pv] and `distortion_coeffs` (4; 4 or 5 for radtan) in raw
    pixels, `resolution` [w, h]. Extrinsics with the IMU as the body: `T_body_cam0 =
    T_cam_imu⁻¹` of cam0; `T_body_cam1 = T_body_cam0 T_cn_cnm1⁻¹` from cam1's `T_cn_cnm1`
    (`T_cam1_cam0`, Kalibr's stereo calibration), else from cam1's own `T_cam_imu`. Other
    keys (`rostopic`, `cam_overlaps`, `timeshift_cam_imu`, further cameras) are ignored;
    `rate_hz` is 0 (Kalibr gives none). Every problem is one DatasetError naming the file."""
    path = pathlib.Path(path)
    file = _PlainYaml(path)
    cam0_node = file.mapping(file.root, "cam0")
    cam1_node = file.mapping(file.root, "cam1")
    T_body_cam0 = np.linalg.inv(file.transform(cam0_node, "cam0.T_cam_imu"))
    if cam1_node.get("T_cn_cnm1") is not None:
        T_body_cam1 = T_body_cam0 @ np.linalg.inv(file.transform(cam1_node, "cam1.T_cn_cnm1"))
    elif cam1_node.get("T_cam_imu") is not None:
        T_body_cam1 = np.linalg.inv(file.transform(cam1_node, "cam1.T_cam_imu"))
    else:
        raise DatasetError(path, "missing key 'cam1.T_cn_cnm1' (or 'cam1.T_cam_imu'): where cam1 is")
    return _kalibr_camera(file, cam0_node, "cam0", T_body_cam0), _kalibr_camera(file, cam1_node, "cam1", T_body_cam1)


def _kalibr_camera(file: _PlainYaml, node: dict[str, Any], name: str, T_body_camera: np.ndarray) -> CameraCalibration:
    """One camera of a Kalibr camchain (read_kalibr_camchain)."""
    _pinhole(file.path, f"{name}.camera_model", file.text(node, f"{name}.camera_model"))
    model = _distortion_model(file.path, f"{name}.distortion_model", file.text(node, f"{name}.distortion_model"))
    fu, fv, cu, cv = _intrinsics(file.path, f"{name}.intrinsics", file.numbers(node, f"{name}.intrinsics", (4,)))
    width, height = _resolution(file.path, f"{name}.resolution", file.numbers(node, f"{name}.resolution", (2,)))
    distortion = file.numbers(node, f"{name}.distortion_coeffs", _DISTORTION_COUNTS[model])
    return CameraCalibration(
        fx=fu,
        fy=fv,
        cx=cu,
        cy=cv,
        width=width,
        height=height,
        distortion=distortion,
        T_body_camera=T_body_camera,
        rate_hz=0.0,
        source=str(file.path),
        model=model,
    )


def read_kalibr_imu(path: pathlib.Path | str) -> ImuCalibration:
    """A Kalibr IMU file (`imu.yaml`; TUM-VI's `dso/imu_config.yaml`): continuous-time noise
    densities (`gyroscope_noise_density`, ..., per √Hz) and `update_rate` (Hz), at the top
    level or under `imu0`. The IMU is the body (`T_body_imu` the identity)."""
    path = pathlib.Path(path)
    file = _PlainYaml(path)
    node = file.root
    if "gyroscope_noise_density" not in node and isinstance(node.get("imu0"), dict):
        node = node["imu0"]
    noise = ImuNoise(**{name: file.number(node, name) for name in ("gyroscope_noise_density", "gyroscope_random_walk", "accelerometer_noise_density", "accelerometer_random_walk")})
    for name, value in dataclasses.asdict(noise).items():
        if value < 0.0:
            raise DatasetError(path, f"'{name}' must not be negative, got {value:g}")
    return ImuCalibration(T_body_imu=np.eye(4), rate_hz=file.number(node, "update_rate", positive=True), noise=noise, source=str(path))


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
    """Stereo rectification of left camera `cam0` and right camera `cam1`, with the relative
    pose `T_cam1_cam0 = T_body_cam1⁻¹ T_body_cam0` from their extrinsics: OpenCV's
    `stereoRectify` (alpha = 0: only valid pixels, zero disparity at infinity) for
    radial-tangential cameras, `cv2.fisheye.stereoRectify`'s rotations and the rectified camera
    of the module docstring for equidistant ones. Both cameras must share one model (the
    readers check their intrinsics and baseline first: backend/data/plausibility.py)."""
    size = (cam0.width, cam0.height)
    if (cam1.width, cam1.height) != size:
        raise DatasetError(cam1.source, f"resolution {cam1.width}x{cam1.height} differs from cam0's {size[0]}x{size[1]}")
    if cam1.model != cam0.model:
        raise DatasetError(cam1.source, f"cam1's camera model {cam1.model} differs from cam0's {cam0.model} (both must be radial-tangential or both equidistant)")
    T_cam1_cam0 = np.linalg.inv(cam1.T_body_camera) @ cam0.T_body_camera
    R_cam1_cam0 = T_cam1_cam0[:3, :3]
    t_cam1_cam0 = T_cam1_cam0[:3, 3]
    if np.linalg.norm(t_cam1_cam0) < 1e-6:
        raise DatasetError(cam1.source, "cam1 is at the same place as cam0 (zero stereo baseline)")
    rectify = _equidistant_rectify if cam0.model == CameraModel.EQUIDISTANT else _radtan_rectify
    R1, R2, P1, P2 = rectify(cam0, cam1, R_cam1_cam0, t_cam1_cam0)
    # Horizontal rectification puts the baseline in P2[0, 3] = -f·b; a vertical one in P2[1, 3].
    baseline = -P2[0, 3] / P2[0, 0]
    if abs(P2[1, 3]) > 1e-9 * abs(P2[0, 3]) or baseline <= 0.0:
        raise DatasetError(cam1.source, _NOT_RIGHT)
    x0, y0, x1, y1 = _rectification_maps(cam0, cam1, (R1, R2, P1, P2))
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


_NOT_RIGHT = "cam1 is not to the right of cam0 (horizontal stereo with cam0 on the left expected)"
_Rectify = tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]  # R1, R2 (3, 3), P1, P2 (3, 4)


def _radtan_rectify(cam0: CameraCalibration, cam1: CameraCalibration, R_cam1_cam0: np.ndarray, t_cam1_cam0: np.ndarray) -> _Rectify:
    """OpenCV's `stereoRectify` (alpha = 0, zero disparity) of two radial-tangential cameras."""
    R1, R2, P1, P2, _, _, _ = cv2.stereoRectify(
        cam0.K,
        cam0.distortion,
        cam1.K,
        cam1.distortion,
        (cam0.width, cam0.height),
        R_cam1_cam0,
        t_cam1_cam0,
        flags=cv2.CALIB_ZERO_DISPARITY,
        alpha=0.0,
    )
    return R1, R2, P1, P2


def _equidistant_rectify(cam0: CameraCalibration, cam1: CameraCalibration, R_cam1_cam0: np.ndarray, t_cam1_cam0: np.ndarray) -> _Rectify:
    """The rectifying rotations of `cv2.fisheye.stereoRectify` (zero disparity) and the
    rectified pinhole camera of the module docstring: the smaller focal length, the mean
    principal point. `P2 = K [I | (t_x, 0, 0)]` with `t = R2 t_cam1_cam0`, as OpenCV's."""
    c_cam1_in_cam0 = -R_cam1_cam0.T @ t_cam1_cam0
    if c_cam1_in_cam0[0] <= abs(c_cam1_in_cam0[1]):  # fisheye.stereoRectify would turn a vertical rig by 90°
        raise DatasetError(cam1.source, _NOT_RIGHT)
    R1, R2, _, _, _ = cv2.fisheye.stereoRectify(
        cam0.K,
        cam0.distortion,
        cam1.K,
        cam1.distortion,
        (cam0.width, cam0.height),
        R_cam1_cam0,
        t_cam1_cam0,
        flags=cv2.CALIB_ZERO_DISPARITY,
    )
    f = min(cam0.fx, cam0.fy, cam1.fx, cam1.fy)
    K = np.array([[f, 0.0, 0.5 * (cam0.cx + cam1.cx)], [0.0, f, 0.5 * (cam0.cy + cam1.cy)], [0.0, 0.0, 1.0]])
    t_rect = R2 @ t_cam1_cam0
    P1 = np.hstack([K, np.zeros((3, 1))])
    P2 = np.hstack([K, K @ np.array([[t_rect[0]], [0.0], [0.0]])])
    return R1, R2, P1, P2


def _rectification_maps(cam0: CameraCalibration, cam1: CameraCalibration, rectify: _Rectify) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The float32 remap tables `(x0, y0, x1, y1)` from rectified to raw pixels."""
    R1, R2, P1, P2 = rectify
    size = (cam0.width, cam0.height)
    init = cv2.fisheye.initUndistortRectifyMap if cam0.model == CameraModel.EQUIDISTANT else cv2.initUndistortRectifyMap
    x0, y0 = init(cam0.K, cam0.distortion, R1, P1, size, cv2.CV_32FC1)
    x1, y1 = init(cam1.K, cam1.distortion, R2, P2, size, cv2.CV_32FC1)
    return x0, y0, x1, y1
