"""Reader of KITTI odometry sequences: a folder `sequences/NN/` holding

```
image_0/NNNNNN.png, image_1/NNNNNN.png   left and right grey images, already rectified
calib.txt                                `P0: 12 numbers` ... `P3:`, `Tr:` (3x4, row-major)
times.txt                                one time per frame, seconds
```

with the ground truth, optional, in `<root>/poses/NN.txt` (two levels up from the sequence
folder): per frame 12 numbers, the left camera's pose `T_world_cam0` (3x4, row-major). KITTI's
world is the first frame's left camera (x right, y down, z forward), not a z-up frame.

Frames and units: timestamps int64 nanoseconds (times.txt's decimals read exactly); poses
`T_world_rect0` (4, 4) in metres, `p_world = R p_rect0 + t`. The images are rectified
already, so rect0 is KITTI's cam0: the camera is P0's `fx, fy, cx, cy` at the images' size
and the baseline `-P1[0,3] / P1[0,0]` metres. The ground truth gives the poses of that same
camera (`ground_truth_frame` "cam0", `T_truth_rect0` the identity). A pose row of twelve
`nan` means no ground truth for that frame (what `kitti_writer` writes where the rendered
truth has none); without a poses file no frame has one.

Bad input (DESIGN §8) is a one-line DatasetError naming the file (and its 1-based line): a
missing or malformed calib.txt (no P0 or P1, a non-number, a degenerate camera), a missing
times.txt or one whose count differs from the images, a missing image, a poses file with a
row of the wrong length or a count differing from times.txt. Images load lazily, by frame
index; one that is unreadable when read is a DatasetError naming it.

KITTI odometry has no IMU: `has_imu` is False and asking for IMU data (VIO) is a one-line
DatasetError, as for an EuRoC folder without `imu0`.
"""

from __future__ import annotations

import decimal
import os
import pathlib

import cv2
import numpy as np
from PIL import Image, UnidentifiedImageError

from backend.data.calibration import MAX_RESOLUTION_PX
from backend.data.errors import DatasetError, read_bytes, read_text
from backend.data.euroc import _decode_quietly
from backend.data.motion import ImuData, ImuNoise
from backend.data.plausibility import check_rectified_camera
from backend.geometry.camera import PinholeCamera

MATRIX_KEYS = ("P0", "P1", "P2", "P3", "Tr")  # the calib.txt entries read (3x4 each); others are ignored
REQUIRED_KEYS = ("P0", "P1")
POSE_FIELDS = 12
ROTATION_TOLERANCE = 1e-2  # max |RᵀR - I| of a ground-truth rotation (KITTI's are rounded to ~1e-6)
NO_IMU = "KITTI odometry has no IMU data: IMU data is needed for VIO (stereo runs without it)"


class KittiSequence:
    """A KITTI odometry sequence folder `sequences/NN` (module docstring for the layout,
    frames, units and what is an error). Raises DatasetError on bad input."""

    ground_truth_frame: str = "cam0"  # the frame whose poses poses/NN.txt gives: KITTI's left camera

    def __init__(self, folder: pathlib.Path | str) -> None:
        self.root = pathlib.Path(folder)
        _require_folder(self.root)
        times_path = self.root / "times.txt"
        self.timestamps_ns: np.ndarray = read_times(times_path)
        self.projections: dict[str, np.ndarray] = read_calib(self.root / "calib.txt")
        self._images = tuple(_image_files(self.root / name, len(self.timestamps_ns), times_path) for name in ("image_0", "image_1"))
        width, height = _image_size(self._images[0][0])
        self._camera = camera_from_projections(self.root / "calib.txt", self.projections, width=width, height=height)
        self.poses_path = poses_file(self.root)
        self.T_world_rect0: np.ndarray = read_poses(self.poses_path, len(self.timestamps_ns)) if self.poses_path.exists() else np.full((len(self), 4, 4), np.nan)
        self.T_truth_rect0: np.ndarray = np.eye(4)  # the rectified left camera in the ground truth's frame: the same camera

    def __len__(self) -> int:
        return int(self.timestamps_ns.shape[0])

    @property
    def camera(self) -> PinholeCamera:
        """The rectified left camera (P0's intrinsics, pixels) with the baseline in metres."""
        return self._camera

    @property
    def ground_truth_valid(self) -> np.ndarray:
        """(N,) bool: frames with a ground-truth pose."""
        return ~np.isnan(self.T_world_rect0[:, 0, 0])

    def image_paths(self, index: int) -> tuple[pathlib.Path, pathlib.Path]:
        """Files of frame `index`'s left (image_0) and right (image_1) images."""
        index = range(len(self))[index]  # IndexError outside
        return self._images[0][index], self._images[1][index]

    def rectified_pair(self, index: int) -> tuple[np.ndarray, np.ndarray]:
        """Frame `index`'s left and right images: grey uint8 (H, W), pixels of `camera`."""
        left, right = self.image_paths(index)
        size = (self._camera.width, self._camera.height)
        return _load_gray(left, size=size), _load_gray(right, size=size)

    @property
    def has_imu(self) -> bool:
        """False: KITTI odometry has no IMU."""
        return False

    @property
    def imu(self) -> ImuData:
        """DatasetError (one line): there is no IMU data."""
        raise self._no_imu_error()

    def imu_between(self, t0_ns: int, t1_ns: int) -> ImuData:
        """DatasetError (one line): there is no IMU data."""
        raise self._no_imu_error()

    @property
    def imu_noise(self) -> ImuNoise:
        """DatasetError (one line): there is no IMU."""
        raise self._no_imu_error()

    @property
    def T_body_rect0(self) -> np.ndarray:
        """DatasetError (one line): there is no IMU body frame."""
        raise self._no_imu_error()

    @property
    def imu_label(self) -> str:
        """Where IMU samples would come from, for messages."""
        return f"{self.root} (KITTI: no IMU)"

    def _no_imu_error(self) -> DatasetError:
        return DatasetError(self.root, NO_IMU)


def poses_file(sequence: pathlib.Path) -> pathlib.Path:
    """Where the ground truth of `sequence` (`<root>/sequences/NN`) lies: `<root>/poses/NN.txt`
    (the path made absolute without following links, so `.` and `..` work)."""
    folder = pathlib.Path(os.path.abspath(sequence))
    return folder.parent.parent / "poses" / f"{folder.name}.txt"


def _require_folder(path: pathlib.Path) -> None:
    if not path.exists():
        raise DatasetError(path, "no such folder")
    if not path.is_dir():
        raise DatasetError(path, "not a folder (expected a KITTI odometry sequence folder sequences/NN)")


def _numbers(path: pathlib.Path, line: int, texts: list[str], *, what: str) -> np.ndarray:
    """`texts` as float64; a DatasetError naming the file, line and `what` for a non-number."""
    values = np.empty(len(texts))
    for i, text in enumerate(texts):
        try:
            values[i] = float(text)
        except ValueError:
            raise DatasetError(path, f"{what}: non-numeric value '{text}'", line=line) from None
    return values


def read_calib(path: pathlib.Path) -> dict[str, np.ndarray]:
    """calib.txt's P0..P3 and Tr (those present) as (3, 4); P0 and P1 are required, each
    entry has 12 finite numbers. Lines `KEY: numbers`; other keys are ignored."""
    found: dict[str, np.ndarray] = {}
    for number, raw in enumerate(read_text(path).split("\n"), start=1):
        text = raw.strip()
        if not text:
            continue
        key, colon, rest = text.partition(":")
        key = key.strip()
        if not colon:
            raise DatasetError(path, f"expected 'KEY: numbers', got '{text[:40]}'", line=number)
        if key not in MATRIX_KEYS:
            continue
        if key in found:
            raise DatasetError(path, f"{key} given twice", line=number)
        values = _numbers(path, number, rest.split(), what=key)
        if values.shape[0] != 12:
            raise DatasetError(path, f"{key} has {values.shape[0]} numbers, expected 12 (3x4, row-major)", line=number)
        if not np.all(np.isfinite(values)):
            raise DatasetError(path, f"{key} holds a non-finite number", line=number)
        found[key] = values.reshape(3, 4)
    for key in REQUIRED_KEYS:
        if key not in found:
            raise DatasetError(path, f"no {key} line (expected '{key}: 12 numbers', the {'left' if key == 'P0' else 'right'} camera's projection)")
    return found


def camera_from_projections(path: pathlib.Path, projections: dict[str, np.ndarray], *, width: int, height: int) -> PinholeCamera:
    """The rectified left camera: P0's `fx, fy, cx, cy` (pixels) at `width` x `height`, and
    the baseline `-P1[0,3] / P1[0,0]` (metres). A degenerate camera (a focal length not
    above 0, the right camera not to the left's right) or an implausible one
    (backend/data/plausibility.py) is a DatasetError naming `path`."""
    P0, P1 = projections["P0"], projections["P1"]
    fx, fy, cx, cy = float(P0[0, 0]), float(P0[1, 1]), float(P0[0, 2]), float(P0[1, 2])
    if not (fx > 0.0 and fy > 0.0 and P1[0, 0] > 0.0):
        raise DatasetError(path, f"degenerate camera: focal lengths P0 fx {fx:g}, fy {fy:g}, P1 fx {P1[0, 0]:g} must be above 0")
    baseline = float(-P1[0, 3] / P1[0, 0])
    if not baseline > 0.0:
        raise DatasetError(path, f"P1 gives a baseline of {baseline + 0.0:g} m (-P1[0,3] / P1[0,0]); expected the right camera to the left's right (P1[0,3] < 0)")
    camera = PinholeCamera(fx=fx, fy=fy, cx=cx, cy=cy, width=width, height=height, baseline=baseline)
    check_rectified_camera(camera, where=path)  # a focal length, principal point or baseline no camera has
    return camera


def seconds_to_ns(text: str) -> int:
    """A decimal number of seconds (`0.103659`, `1.036594e-01`) as whole nanoseconds, read
    exactly (no float rounding); ValueError for anything else."""
    try:
        seconds = decimal.Decimal(text)
    except decimal.InvalidOperation:
        raise ValueError(text) from None
    if not seconds.is_finite():
        raise ValueError(text)
    return int((seconds * 1_000_000_000).to_integral_value(rounding=decimal.ROUND_HALF_EVEN))


def read_times(path: pathlib.Path) -> np.ndarray:
    """times.txt: one time per line (seconds, blank lines skipped) as int64 nanoseconds,
    strictly increasing; at least one."""
    stamps: list[int] = []
    for number, raw in enumerate(read_text(path).split("\n"), start=1):
        text = raw.strip()
        if not text:
            continue
        try:
            ns = seconds_to_ns(text)
        except ValueError:
            raise DatasetError(path, f"'{text[:40]}' is not a time in seconds", line=number) from None
        if not -(2**63) <= ns < 2**63:
            raise DatasetError(path, f"time {text} s is out of range", line=number)
        if stamps and ns <= stamps[-1]:
            raise DatasetError(path, f"time {text} s is not after the previous line's", line=number)
        stamps.append(ns)
    if not stamps:
        raise DatasetError(path, "no times (expected one time in seconds per frame)")
    return np.array(stamps, dtype=np.int64)


def _image_files(folder: pathlib.Path, count: int, times_path: pathlib.Path) -> list[pathlib.Path]:
    """`folder`'s images 000000.png .. of `count` frames; each must exist, and the folder
    holds no more PNG images than times.txt has times."""
    try:
        present = set(os.listdir(folder))
    except FileNotFoundError:
        raise DatasetError(folder, "missing folder") from None
    except NotADirectoryError:
        raise DatasetError(folder, "not a folder") from None
    except OSError as error:
        raise DatasetError(folder, f"cannot list ({error.strerror or error})") from None
    names = [f"{i:06d}.png" for i in range(count)]
    for i, name in enumerate(names):
        if name not in present:
            raise DatasetError(folder / name, f"missing image of frame {i} ({times_path.name} lists {count} frames)")
    images = sum(1 for name in present if name.lower().endswith(".png"))
    if images != count:
        raise DatasetError(times_path, f"{count} times, but {folder} holds {images} PNG images")
    return [folder / name for name in names]


def _image_size(path: pathlib.Path) -> tuple[int, int]:
    """(width, height) of an image, from its header; at most MAX_RESOLUTION_PX per side."""
    try:
        with Image.open(path) as image:
            width, height = int(image.size[0]), int(image.size[1])
    except (UnidentifiedImageError, OSError) as error:
        raise DatasetError(path, f"not a readable image ({getattr(error, 'strerror', None) or error})") from None
    if not (0 < width <= MAX_RESOLUTION_PX and 0 < height <= MAX_RESOLUTION_PX):
        raise DatasetError(path, f"image is {width}x{height}; expected at most {MAX_RESOLUTION_PX} pixels per side")
    return width, height


def _load_gray(path: pathlib.Path, *, size: tuple[int, int]) -> np.ndarray:
    """A grey uint8 image (H, W) of `size` (width, height); 8-bit colour is read as grey,
    any other depth or size is a DatasetError naming the file."""
    encoded = np.frombuffer(read_bytes(path, what="image"), dtype=np.uint8)
    image = _decode_quietly(encoded)
    if image is None:
        raise DatasetError(path, "not a readable image")
    if image.dtype != np.uint8:
        raise DatasetError(path, f"image has {image.dtype.itemsize * 8}-bit pixels; expected 8-bit grey")
    if image.ndim == 3:
        if image.shape[2] not in (3, 4):
            raise DatasetError(path, f"image has {image.shape[2]} channels; expected 8-bit grey")
        image = cv2.cvtColor(image, cv2.COLOR_BGR2GRAY if image.shape[2] == 3 else cv2.COLOR_BGRA2GRAY)
    if (image.shape[1], image.shape[0]) != size:
        raise DatasetError(path, f"image is {image.shape[1]}x{image.shape[0]}, the sequence's first image is {size[0]}x{size[1]}")
    return image


def _pose_row(path: pathlib.Path, number: int, text: str) -> np.ndarray:
    """One poses row: (4, 4) `T_world_cam0`, all NaN for a row of twelve `nan`; a row of
    another length, a partly non-finite row or a rotation that is not one is an error."""
    fields = text.split()
    if len(fields) != POSE_FIELDS:
        raise DatasetError(path, f"{len(fields)} numbers, expected {POSE_FIELDS} (a 3x4 pose, row-major)", line=number)
    values = _numbers(path, number, fields, what="pose")
    T = np.full((4, 4), np.nan)
    if np.all(np.isnan(values)):
        return T  # no ground truth for this frame
    if not np.all(np.isfinite(values)):
        raise DatasetError(path, "a non-finite number in the pose (a frame without ground truth is twelve nan)", line=number)
    T[:3, :] = values.reshape(3, 4)
    T[3, :] = (0.0, 0.0, 0.0, 1.0)
    R = T[:3, :3]
    if np.max(np.abs(R.T @ R - np.eye(3))) > ROTATION_TOLERANCE or np.linalg.det(R) <= 0.0:
        raise DatasetError(path, "the pose's 3x3 part is not a rotation", line=number)
    return T


def read_poses(path: pathlib.Path, count: int) -> np.ndarray:
    """poses/NN.txt as (count, 4, 4) `T_world_cam0` (metres; NaN where a row is twelve
    `nan`); exactly `count` rows (times.txt's), blank lines skipped."""
    rows: list[np.ndarray] = []
    for number, raw in enumerate(read_text(path).split("\n"), start=1):
        text = raw.strip()
        if text:
            rows.append(_pose_row(path, number, text))
    if len(rows) != count:
        raise DatasetError(path, f"{len(rows)} poses, but times.txt has {count} times (one pose per frame)")
    return np.stack(rows) if rows else np.zeros((0, 4, 4))
