"""Reader of EuRoC ASL folders: `mav0/cam0`, `mav0/cam1` and, optionally, `mav0/imu0` and
`mav0/state_groundtruth_estimate0`, each with `data.csv` and `sensor.yaml`.

Frames and units: timestamps are int64 nanoseconds; poses `T_world_x` (4, 4) in metres with
`p_world = R p_x + t`. `world` is the ground truth's reference frame (EuRoC's Vicon frame,
z up); `body` is EuRoC's body frame (the IMU's); cam0/cam1 are the raw left/right cameras and
rect0 the rectified left camera (`backend.data.calibration`). Ground truth is the body pose
interpolated at frame times (linear in position, slerp in rotation), then
`T_world_cam0 = T_world_body T_body_cam0` and `T_world_rect0 = T_world_cam0 [R_rect0_cam0ᵀ | 0]`;
frames outside the ground truth's time range, or in a gap longer than `max_ground_truth_gap_ns`,
get NaN poses.

Stereo frames are the timestamps listed in both cameras' `data.csv` (DESIGN §8: what users
have is valid). Rows of one camera outside that set are ignored: their images are not looked
for (a camera list may be longer than the other, or name images that were never copied).
Every row must still be a well-formed CSV row (timestamp, non-empty filename). An image
missing *inside* the stereo set is an error at load, not a dropped frame: a one-line
DatasetError naming the camera's `data.csv`, its line and the image (`cam0/data.csv line 12:
image …/data/….png is listed but absent`); a folder with a hole in the middle of the sequence
is a broken copy, and silently skipping frames would hide that. No timestamp in common is a
DatasetError naming both lists. Images may be any format OpenCV decodes (PNG, JPEG, ...) as
`data.csv` names them; they load lazily, by frame index.

The IMU is optional (stereo SLAM does not need it; `has_imu` says whether there is IMU data).
A missing `imu0` folder, or an `imu0/data.csv` with no data rows (a header only), means no IMU
data: the folder loads, and `imu`, `imu_between` (and `imu_calibration` when `imu0` is absent)
raise a one-line DatasetError (`…/mav0/imu0: missing folder: IMU data is needed for VIO`) only
when asked. A present but malformed `imu0` (missing `sensor.yaml` or `data.csv`, a truncated
row, NaN, ...) is an error at load, as is every other problem with the input: a DatasetError
naming the file (and the 1-based line of a CSV).
"""

from __future__ import annotations

import dataclasses
import os
import pathlib
from collections.abc import Callable
from typing import ClassVar

import cv2
import numpy as np
from scipy.spatial.transform import Rotation

from backend.common.native_output import native_stderr_silenced
from backend.data.calibration import (
    CameraCalibration,
    ImuCalibration,
    StereoRectification,
    read_camera_yaml,
    read_imu_yaml,
    read_sensor_transform,
    stereo_rectification,
)
from backend.data.errors import DatasetError, not_regular, read_bytes, read_text
from backend.data.motion import ImuData, ImuNoise
from backend.data.plausibility import check_calibration
from backend.geometry.camera import PinholeCamera

CAMERA_COLUMNS = ("timestamp", "filename")
IMU_COLUMNS = ("timestamp", "w_RS_S_x", "w_RS_S_y", "w_RS_S_z", "a_RS_S_x", "a_RS_S_y", "a_RS_S_z")
GROUND_TRUTH_COLUMNS = (
    "timestamp",
    "p_RS_R_x",
    "p_RS_R_y",
    "p_RS_R_z",
    "q_RS_w",
    "q_RS_x",
    "q_RS_y",
    "q_RS_z",
    "v_RS_R_x",
    "v_RS_R_y",
    "v_RS_R_z",
    "b_w_RS_S_x",
    "b_w_RS_S_y",
    "b_w_RS_S_z",
    "b_a_RS_S_x",
    "b_a_RS_S_y",
    "b_a_RS_S_z",
)
GROUND_TRUTH_POSE_COLUMNS = 8  # a pose-only ground truth (timestamp, p, q) is accepted too
QUATERNION_NORM_TOLERANCE = 1e-2


@dataclasses.dataclass(frozen=True, eq=False)
class GroundTruth:
    """`state_groundtruth_estimate0` samples (M,): body poses in the world frame (metres),
    the file's velocity (m/s, world frame) and gyro (rad/s) / accelerometer (m/s²) biases;
    NaN velocity and biases for a pose-only file."""

    timestamp_ns: np.ndarray
    p_world_body: np.ndarray  # (M, 3)
    R_world_body: np.ndarray  # (M, 3, 3)
    v_world: np.ndarray  # (M, 3)
    gyro_bias: np.ndarray  # (M, 3)
    accel_bias: np.ndarray  # (M, 3)

    def T_world_body(self) -> np.ndarray:
        """(M, 4, 4) the samples' body poses, metres."""
        return _pose(self.R_world_body, self.p_world_body)

    def __len__(self) -> int:
        return int(self.timestamp_ns.shape[0])

    def T_world_body_at(self, timestamp_ns: np.ndarray, *, max_gap_ns: int) -> np.ndarray:
        """Body poses (N, 4, 4) at `timestamp_ns` (N,): linear position, slerp rotation between
        the two samples around each time; NaN outside the samples' range or where they are more
        than `max_gap_ns` apart."""
        t = np.asarray(timestamp_ns, dtype=np.int64)
        T = np.full((t.shape[0], 4, 4), np.nan)
        samples = self.timestamp_ns
        if t.shape[0] == 0 or samples.shape[0] == 0:
            return T
        if samples.shape[0] == 1:
            exact = t == samples[0]
            T[exact] = _pose(self.R_world_body[:1], self.p_world_body[:1])
            return T
        i0 = np.clip(np.searchsorted(samples, t, side="right") - 1, 0, samples.shape[0] - 2)
        i1 = i0 + 1
        span_ns = samples[i1] - samples[i0]
        alpha = (t - samples[i0]).astype(np.float64) / span_ns.astype(np.float64)
        inside = (t >= samples[0]) & (t <= samples[-1])
        on_sample = (t == samples[i0]) | (t == samples[i1])
        valid = inside & (on_sample | (span_ns <= max_gap_ns))
        if not np.any(valid):
            return T
        i0, i1, alpha = i0[valid], i1[valid], alpha[valid]
        r0 = Rotation.from_matrix(self.R_world_body[i0])
        r1 = Rotation.from_matrix(self.R_world_body[i1])
        rotvec_0_1 = (r0.inv() * r1).as_rotvec()  # shortest arc: angle in [0, π]
        R = (r0 * Rotation.from_rotvec(alpha[:, None] * rotvec_0_1)).as_matrix()
        p = (1.0 - alpha)[:, None] * self.p_world_body[i0] + alpha[:, None] * self.p_world_body[i1]
        T[valid] = _pose(R, p)
        return T


class RectifiedRecording:
    """What a recorded stereo + IMU input answers alike, whatever its files (the EuRoC folder,
    TUM-VI export and ROS bag readers): its length, the rectified camera and pairs, the IMU
    where there is one (a one-line DatasetError where VIO asks for a missing one), the body
    frame and the ground truth's samples. A reader sets `timestamps_ns`, `rectification`,
    `T_world_body` (NaN rows: no ground truth), `ground_truth` (the file's samples or None),
    `_imu` and `_no_imu` (what is missing, path and reason), and implements `raw_pair` and
    `imu_calibration`."""

    ground_truth_frame: str = "body"  # what `T_world_body` (the ground truth) is the pose of: the IMU body
    timestamps_ns: np.ndarray
    rectification: StereoRectification
    T_world_body: np.ndarray
    ground_truth: GroundTruth | None
    _imu: ImuData | None
    _no_imu: tuple[pathlib.Path, str] | None

    def __len__(self) -> int:
        return int(self.timestamps_ns.shape[0])

    @property
    def camera(self) -> PinholeCamera:
        """The rectified left camera (rect0) with the stereo baseline, metres."""
        return self.rectification.camera

    @property
    def ground_truth_valid(self) -> np.ndarray:
        """(N,) bool: frames with a ground-truth pose."""
        return ~np.isnan(self.T_world_body[:, 0, 0])

    def raw_pair(self, index: int) -> tuple[np.ndarray, np.ndarray]:
        """Frame `index`'s raw cam0, cam1 images: grey uint8 (height, width)."""
        raise NotImplementedError

    def rectified_pair(self, index: int) -> tuple[np.ndarray, np.ndarray]:
        """Frame `index`'s rectified rect0, rect1 images: grey uint8, pixels of `camera`."""
        return self.rectification.rectify(*self.raw_pair(index))

    @property
    def imu_calibration(self) -> ImuCalibration:
        raise NotImplementedError

    @property
    def has_imu(self) -> bool:
        """Whether the input has IMU samples."""
        return self._imu is not None

    @property
    def imu(self) -> ImuData:
        """Every IMU sample; DatasetError (one line naming what is missing) without IMU data."""
        if self._imu is None:
            raise self._no_imu_error()
        return self._imu

    def imu_between(self, t0_ns: int, t1_ns: int) -> ImuData:
        """IMU samples with `t0_ns < t <= t1_ns`: gyro rad/s, accelerometer m/s², in the IMU
        frame (`imu_calibration.T_body_imu`; the identity, i.e. the body frame, in EuRoC).
        DatasetError (one line) without IMU data (`has_imu` False)."""
        return self.imu.between(t0_ns, t1_ns)

    @property
    def imu_noise(self) -> ImuNoise:
        """The IMU noise densities of its calibration (DatasetError without IMU data)."""
        return self.imu_calibration.noise

    @property
    def T_body_rect0(self) -> np.ndarray:
        """(4, 4) the rectified left camera in the body (IMU) frame, metres."""
        return np.asarray(self.rectification.T_body_rect0, dtype=float)

    @property
    def T_truth_rect0(self) -> np.ndarray:
        """(4, 4) the rectified left camera in the frame the ground truth is the pose of
        (`ground_truth_frame`: the body), metres."""
        return self.T_body_rect0

    def ground_truth_samples(self) -> tuple[np.ndarray, np.ndarray]:
        """The ground truth's samples as the input gives them, in the body (its `T_BS`
        applied): timestamps (M,) int64 ns and `T_world_body` (M, 4, 4), metres; M is 0
        without ground truth."""
        truth = self.ground_truth
        if truth is None:
            return np.zeros(0, np.int64), np.zeros((0, 4, 4))
        return truth.timestamp_ns, truth.T_world_body()

    def _no_imu_error(self) -> DatasetError:
        assert self._no_imu is not None  # set whenever the IMU data is missing
        path, reason = self._no_imu
        return DatasetError(path, f"{reason}: IMU data is needed for VIO (stereo runs without it)")

    def _check_index(self, index: int) -> int:
        n = len(self)
        if not -n <= index < n:
            raise IndexError(f"frame {index} out of range (0..{n - 1})")
        return index % n


class EurocDataset(RectifiedRecording):
    """A stereo EuRoC ASL folder, with or without IMU data (module docstring for frames, units
    and what is accepted).

    `root` is the folder holding `mav0` (or `mav0` itself). Raises DatasetError on bad input.

    A variant of the layout (TUM-VI's export, `backend.data.tumvi`) overrides where the
    calibration comes from (`_read_cameras`, `_read_imu_calibration`), the ground truth's
    folder (`GROUND_TRUTH_FOLDER`) and whether 16-bit images are read (`SIXTEEN_BIT_IMAGES`).
    """

    GROUND_TRUTH_FOLDER: ClassVar[str] = "state_groundtruth_estimate0"
    SIXTEEN_BIT_IMAGES: ClassVar[bool] = False  # EuRoC's images are 8-bit; a 16-bit one is an error

    def __init__(self, root: pathlib.Path | str, *, max_ground_truth_gap_ns: int = 100_000_000) -> None:
        self.root = pathlib.Path(root)
        mav0 = _find_mav0(self.root)
        cam0_dir = _require_folder(mav0 / "cam0")
        cam1_dir = _require_folder(mav0 / "cam1")

        self.cam0: CameraCalibration
        self.cam1: CameraCalibration
        self.cam0, self.cam1 = self._read_cameras(cam0_dir, cam1_dir)
        check_calibration(self.cam0, self.cam1)  # implausible intrinsics or baseline: one line naming the file
        self.rectification: StereoRectification = stereo_rectification(self.cam0, self.cam1)

        stamps0, lines0, names0 = _read_camera_csv(cam0_dir)
        stamps1, lines1, names1 = _read_camera_csv(cam1_dir)
        common, index0, index1 = np.intersect1d(stamps0, stamps1, assume_unique=True, return_indices=True)
        if common.shape[0] == 0:
            raise DatasetError(cam1_dir / "data.csv", f"no timestamp in common with {cam0_dir / 'data.csv'} (stereo frames are the timestamps listed in both)")
        self.timestamps_ns: np.ndarray = common
        self._images0 = _stereo_images(cam0_dir, [lines0[i] for i in index0], [names0[i] for i in index0])
        self._images1 = _stereo_images(cam1_dir, [lines1[i] for i in index1], [names1[i] for i in index1])
        self.unpaired_images: tuple[int, int] = (stamps0.shape[0] - common.shape[0], stamps1.shape[0] - common.shape[0])

        self._imu_calibration, self._imu, self._no_imu = _read_imu(mav0 / "imu0", self._read_imu_calibration)

        self.ground_truth: GroundTruth | None = None
        truth_dir = mav0 / self.GROUND_TRUTH_FOLDER
        if truth_dir.exists():
            self.ground_truth = _read_ground_truth(_require_folder(truth_dir))
            self.T_world_body: np.ndarray = self.ground_truth.T_world_body_at(common, max_gap_ns=max_ground_truth_gap_ns)
        else:
            self.T_world_body = np.full((common.shape[0], 4, 4), np.nan)
        self.T_world_cam0: np.ndarray = self.T_world_body @ self.cam0.T_body_camera
        self.T_world_rect0: np.ndarray = self.T_world_cam0 @ self.rectification.T_cam0_rect0

    def _read_cameras(self, cam0_dir: pathlib.Path, cam1_dir: pathlib.Path) -> tuple[CameraCalibration, CameraCalibration]:
        """The raw cameras' calibration: each camera folder's `sensor.yaml`."""
        return read_camera_yaml(cam0_dir / "sensor.yaml"), read_camera_yaml(cam1_dir / "sensor.yaml")

    def _read_imu_calibration(self, imu_dir: pathlib.Path) -> ImuCalibration:
        """The IMU's calibration, read when `imu_dir` exists: its `sensor.yaml`."""
        return read_imu_yaml(imu_dir / "sensor.yaml")

    def image_paths(self, index: int) -> tuple[pathlib.Path, pathlib.Path]:
        """Files of frame `index`'s cam0 and cam1 images."""
        index = self._check_index(index)
        return self._images0[index], self._images1[index]

    def raw_pair(self, index: int) -> tuple[np.ndarray, np.ndarray]:
        """Frame `index`'s raw cam0, cam1 images: grayscale uint8 (height, width)."""
        path0, path1 = self.image_paths(index)
        sixteen_bit = self.SIXTEEN_BIT_IMAGES
        return _load_gray(path0, self.cam0, sixteen_bit=sixteen_bit), _load_gray(path1, self.cam1, sixteen_bit=sixteen_bit)

    @property
    def imu_calibration(self) -> ImuCalibration:
        """`imu0/sensor.yaml`; DatasetError (one line naming `imu0`) without an `imu0` folder."""
        if self._imu_calibration is None:
            raise self._no_imu_error()
        return self._imu_calibration

    @property
    def imu_label(self) -> str:
        """The IMU samples' file, for messages."""
        return f"{self.root}/mav0/imu0/data.csv"


def _pose(R: np.ndarray, t: np.ndarray) -> np.ndarray:
    T = np.zeros(R.shape[:-2] + (4, 4))
    T[..., :3, :3] = R
    T[..., :3, 3] = t
    T[..., 3, 3] = 1.0
    return T


def _find_mav0(root: pathlib.Path) -> pathlib.Path:
    if not root.exists():
        raise DatasetError(root, "no such folder")
    if not root.is_dir():
        raise DatasetError(root, "not a folder (expected an EuRoC ASL dataset folder holding mav0)")
    if (root / "mav0").is_dir():
        return root / "mav0"
    if root.name == "mav0" and (root / "cam0").is_dir():
        return root
    raise DatasetError(root, "no mav0 folder (expected an EuRoC ASL dataset: mav0/cam0, mav0/cam1 and, optionally, mav0/imu0)")


def _require_folder(path: pathlib.Path) -> pathlib.Path:
    if not path.exists():
        raise DatasetError(path, "missing folder")
    if not path.is_dir():
        raise DatasetError(path, "not a folder")
    return path


def _read_rows(path: pathlib.Path, columns: tuple[str, ...], *, counts: tuple[int, ...] | None = None, allow_empty: bool = False) -> tuple[list[int], list[list[str]]]:
    """Data rows of an EuRoC CSV with their 1-based line numbers. Lines starting with `#`
    (the header) and blank lines are skipped. Every row has `len(columns)` fields, or one of
    `counts` (the first row chooses). No data rows is an error unless `allow_empty`."""
    counts = counts or (len(columns),)
    lines: list[int] = []
    rows: list[list[str]] = []
    expected: int | None = None
    for number, raw in enumerate(read_text(path).split("\n"), start=1):
        text = raw.strip()
        if not text or text.startswith("#"):
            continue
        fields = text.split(",")
        if " " in text or "\t" in text:
            fields = [field.strip() for field in fields]
        if expected is None and len(fields) in counts:
            expected = len(fields)
        target = expected if expected is not None else max(counts)
        if len(fields) != target:
            kind = "truncated row" if len(fields) < target else "too many columns"
            wanted = str(expected) if expected is not None else " or ".join(str(c) for c in counts)
            raise DatasetError(path, f"{kind}: {len(fields)} column{'s' * (len(fields) != 1)}, expected {wanted}", line=number)
        lines.append(number)
        rows.append(fields)
    if not rows and not allow_empty:
        raise DatasetError(path, "no data rows")
    return lines, rows


def _timestamps(path: pathlib.Path, lines: list[int], rows: list[list[str]]) -> np.ndarray:
    """First column as int64 nanoseconds, strictly increasing."""
    stamps = np.empty(len(rows), dtype=np.int64)
    for i, (line, fields) in enumerate(zip(lines, rows)):
        text = fields[0]
        if not (text.isascii() and text.isdigit()) or int(text) >= 2**63:
            raise DatasetError(path, f"timestamp '{text}' is not a whole number of nanoseconds", line=line)
        stamps[i] = int(text)
    backwards = np.flatnonzero(np.diff(stamps) <= 0)
    if backwards.size:
        i = int(backwards[0]) + 1
        raise DatasetError(path, f"timestamp {stamps[i]} is not after the previous row's {stamps[i - 1]}", line=lines[i])
    return stamps


def _values(path: pathlib.Path, lines: list[int], rows: list[list[str]], columns: tuple[str, ...]) -> np.ndarray:
    """Columns 2.. as finite float64 (N, C - 1)."""
    try:
        values = np.array([fields[1:] for fields in rows], dtype=np.float64)
    except ValueError:
        for line, fields in zip(lines, rows):
            for name, text in zip(columns[1:], fields[1:]):
                try:
                    float(text)
                except ValueError:
                    shown = f"non-numeric value '{text}'" if text else "empty field"
                    raise DatasetError(path, f"{shown} in column {name}", line=line) from None
        raise DatasetError(path, "non-numeric value") from None  # numpy and float() disagree: not expected
    bad = np.argwhere(~np.isfinite(values))
    if bad.size:
        i, j = (int(k) for k in bad[0])
        kind = "NaN" if np.isnan(values[i, j]) else "infinite value"
        raise DatasetError(path, f"{kind} in column {columns[j + 1]}", line=lines[i])
    return values


def _read_camera_csv(camera_dir: pathlib.Path) -> tuple[np.ndarray, list[int], list[str]]:
    """A camera's timestamps, with the 1-based line and the image file name of each row.
    Images are not looked for here: only those of stereo frames must exist (`_stereo_images`)."""
    path = camera_dir / "data.csv"
    lines, rows = _read_rows(path, CAMERA_COLUMNS)
    stamps = _timestamps(path, lines, rows)
    for line, fields in zip(lines, rows):
        if not fields[1]:
            raise DatasetError(path, "empty filename", line=line)
    return stamps, lines, [fields[1] for fields in rows]


def _stereo_images(camera_dir: pathlib.Path, lines: list[int], names: list[str]) -> list[pathlib.Path]:
    """The image files of a camera's stereo-frame rows (`lines` of its `data.csv`); every one
    must be a regular file inside `camera_dir/data` (a name that is absolute or climbs out
    with `..` is refused, a FIFO or a device too, without opening it), else a DatasetError
    naming the list, the line and the image. Links are followed: a dataset may link its
    images from elsewhere."""
    path = camera_dir / "data.csv"
    data_dir = camera_dir / "data"
    try:
        os.listdir(data_dir)  # the folder itself: missing, not a folder, unreadable
    except FileNotFoundError:
        raise DatasetError(data_dir, f"missing folder (the images listed in {path})") from None
    except NotADirectoryError:
        raise DatasetError(data_dir, f"not a folder (expected the images listed in {path})") from None
    except OSError as error:
        raise DatasetError(data_dir, f"cannot list ({error.strerror or error})") from None
    images = []
    for line, name in zip(lines, names):
        image = data_dir / name
        if pathlib.PurePath(name).is_absolute() or ".." in pathlib.PurePath(name).parts:
            raise DatasetError(path, f"image {name!r} lies outside {data_dir} (an absolute path or '..'): refused", line=line)
        try:
            mode = image.stat().st_mode
        except OSError:
            raise DatasetError(path, f"image {image} is listed but absent", line=line) from None
        kind = not_regular(mode)
        if kind is not None:
            raise DatasetError(path, f"image {image} is {kind}, not a regular file: refused", line=line)
        images.append(image)
    return images


def _read_imu(imu_dir: pathlib.Path, read_calibration: Callable[[pathlib.Path], ImuCalibration]) -> tuple[ImuCalibration | None, ImuData | None, tuple[pathlib.Path, str] | None]:
    """`imu0`'s calibration (`read_calibration(imu_dir)`) and samples, or None for what is
    not there, with the path and reason to report when IMU data is asked for: no folder, or a
    `data.csv` without data rows. A present but malformed `imu0` is a DatasetError here."""
    if not imu_dir.exists():
        return None, None, (imu_dir, "missing folder")
    _require_folder(imu_dir)
    calibration = read_calibration(imu_dir)
    path = imu_dir / "data.csv"
    imu = _read_imu_csv(path)
    if imu is None:
        return calibration, None, (path, "no data rows")
    return calibration, imu, None


def _read_imu_csv(path: pathlib.Path) -> ImuData | None:
    """The samples of `imu0/data.csv`; None for a file without data rows (a header only)."""
    lines, rows = _read_rows(path, IMU_COLUMNS, allow_empty=True)
    if not rows:
        return None
    stamps = _timestamps(path, lines, rows)
    values = _values(path, lines, rows, IMU_COLUMNS)
    return ImuData(timestamp_ns=stamps, gyro=values[:, 0:3], accel=values[:, 3:6])


@dataclasses.dataclass(frozen=True, eq=False)
class SensorPoses:
    """`state_groundtruth_estimate0` as written: the poses of its sensor S in the world
    frame (metres; quaternions (w, x, y, z) as in the file, not normalized), `T_body_sensor`
    (its `sensor.yaml`'s `T_BS`; None without that file: S is the body) and the velocity and
    bias columns (M, 9), NaN for a pose-only file."""

    timestamp_ns: np.ndarray  # (M,)
    p_world_sensor: np.ndarray  # (M, 3)
    q_world_sensor_wxyz: np.ndarray  # (M, 4)
    T_body_sensor: np.ndarray | None
    extra: np.ndarray  # (M, 9)

    def body_truth(self) -> GroundTruth:
        """Body poses `T_world_body = T_world_S T_BS⁻¹` (:func:`quaternion_poses`)."""
        T_world_body = quaternion_poses(self.q_world_sensor_wxyz, self.p_world_sensor)
        if self.T_body_sensor is not None:
            T_world_body = T_world_body @ np.linalg.inv(self.T_body_sensor)
        return GroundTruth(
            timestamp_ns=self.timestamp_ns,
            p_world_body=T_world_body[:, :3, 3].copy(),
            R_world_body=T_world_body[:, :3, :3].copy(),
            v_world=self.extra[:, 0:3],
            gyro_bias=self.extra[:, 3:6],
            accel_bias=self.extra[:, 6:9],
        )


def quaternion_poses(q_wxyz: np.ndarray, p: np.ndarray) -> np.ndarray:
    """Poses (M, 4, 4) from quaternions (M, 4) (w, x, y, z), normalized here, and positions
    (M, 3), metres. Every reader of poses as quaternions uses this one computation, so that
    the same numbers give the same poses bit for bit, whatever the file."""
    norm = np.linalg.norm(q_wxyz, axis=1)
    return _pose(Rotation.from_quat(q_wxyz / norm[:, None], scalar_first=True).as_matrix(), p)


def read_sensor_poses(truth_dir: pathlib.Path) -> SensorPoses:
    """`truth_dir/data.csv` (full or pose-only rows) and, when present, `sensor.yaml`'s `T_BS`
    (identity where the file has none); DatasetError (file and line) on bad input."""
    path = truth_dir / "data.csv"
    lines, rows = _read_rows(path, GROUND_TRUTH_COLUMNS, counts=(len(GROUND_TRUTH_COLUMNS), GROUND_TRUTH_POSE_COLUMNS))
    stamps = _timestamps(path, lines, rows)
    values = _values(path, lines, rows, GROUND_TRUTH_COLUMNS)
    q_wxyz = values[:, 3:7]
    norm = np.linalg.norm(q_wxyz, axis=1)
    off = np.flatnonzero(np.abs(norm - 1.0) > QUATERNION_NORM_TOLERANCE)
    if off.size:
        i = int(off[0])
        raise DatasetError(path, f"quaternion q_RS (w, x, y, z) has norm {norm[i]:.6g}, expected 1", line=lines[i])
    yaml_path = truth_dir / "sensor.yaml"
    T_body_sensor = read_sensor_transform(yaml_path, default=np.eye(4)) if yaml_path.exists() else None
    extra = values[:, 7:16] if values.shape[1] >= 16 else np.full((len(rows), 9), np.nan)
    return SensorPoses(timestamp_ns=stamps, p_world_sensor=values[:, 0:3], q_world_sensor_wxyz=q_wxyz, T_body_sensor=T_body_sensor, extra=extra)


def _read_ground_truth(truth_dir: pathlib.Path) -> GroundTruth:
    """Body poses from `data.csv` (the pose of the file's sensor S, `T_world_S`) and, when
    present, `sensor.yaml`'s `T_BS` (identity otherwise): `T_world_body = T_world_S T_BS⁻¹`."""
    return read_sensor_poses(truth_dir).body_truth()


def _decode_quietly(encoded: np.ndarray) -> np.ndarray | None:
    """`cv2.imdecode` as stored (depth and channels kept), without OpenCV's warnings on
    stderr for a broken file (the caller reports it in one line)."""
    if not encoded.size:
        return None
    level = cv2.utils.logging.getLogLevel()
    cv2.utils.logging.setLogLevel(cv2.utils.logging.LOG_LEVEL_SILENT)
    try:
        with native_stderr_silenced():  # libpng's own "libpng error: ..." line
            return cv2.imdecode(encoded, cv2.IMREAD_UNCHANGED)
    finally:
        cv2.utils.logging.setLogLevel(level)


def _load_gray(path: pathlib.Path, calibration: CameraCalibration, *, sixteen_bit: bool = False) -> np.ndarray:
    """Grayscale uint8 image of the calibration's size. EuRoC's images are 8-bit grey;
    8-bit colour is converted to grey; with `sixteen_bit` (TUM-VI's exports), 16-bit pixels
    keep their high byte (`>> 8`); any other depth is an error naming the file."""
    encoded = np.frombuffer(read_bytes(path, what="image"), dtype=np.uint8)
    image = _decode_quietly(encoded)
    if image is None:
        raise DatasetError(path, "not a readable image")
    if sixteen_bit and image.dtype == np.uint16:
        image = (image >> 8).astype(np.uint8)
    if image.dtype != np.uint8:
        raise DatasetError(path, f"image has {image.dtype.itemsize * 8}-bit {image.dtype.kind == 'f' and 'float ' or ''}pixels; expected 8-bit grey")
    if image.ndim == 3:
        if image.shape[2] not in (3, 4):
            raise DatasetError(path, f"image has {image.shape[2]} channels; expected 8-bit grey")
        image = cv2.cvtColor(image, cv2.COLOR_BGR2GRAY if image.shape[2] == 3 else cv2.COLOR_BGRA2GRAY)
    if image.shape != (calibration.height, calibration.width):
        raise DatasetError(path, f"image is {image.shape[1]}x{image.shape[0]}, {calibration.source} says {calibration.width}x{calibration.height}")
    return image


def read_indexed_poses(path: pathlib.Path | str) -> dict[int, np.ndarray]:
    """Rows `index timestamp tx ty tz qx qy qz qw` (as in the shared EuRoC V1_01 pairs'
    ground truth) to {index: T_world_body (4, 4)}, metres; quaternions in x y z w order."""
    from scipy.spatial.transform import Rotation

    poses = {}
    for row in np.atleast_2d(np.loadtxt(path, comments="#")):
        T = np.eye(4)
        T[:3, :3] = Rotation.from_quat(row[5:9]).as_matrix()
        T[:3, 3] = row[2:5]
        poses[int(row[0])] = T
    return poses
