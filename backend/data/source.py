"""What an engine may ask of its input, and the readers that open an input by its files.

Three protocols, each a set of attributes a source has or has not (never probed by name
elsewhere):

- :class:`StereoSource`: every input. Timestamps, the rectified left camera with its
  baseline, rectified stereo pairs by index, the ground-truth pose of the rectified left
  camera where there is one, and the frame the dataset's own ground truth gives poses of
  (`ground_truth_frame`, with the rectified left camera in it: `T_truth_rect0`), so that the
  written trajectories can be in that frame. Stereo SLAM needs nothing else.
- :class:`InertialSource`: also the IMU (samples, noise densities, where the IMU sits
  relative to the rectified camera). VIO needs it; a source without IMU data raises a
  one-line DatasetError when asked.
- :class:`GroundTruthSamples`: the ground truth as its file gives it (timed samples, at
  their own times, not interpolated at the frames'), where a source has such a file: the
  written trajectories are evaluated against the sample nearest each frame, as evo pairs a
  trajectory with that file (`backend.export.output_frame`).
- :class:`RenderedTruth`: the exact truth of a rendered scene (per-pixel plane ids and
  depth, the planes, the continuous trajectory and the IMU biases), for the oracle
  segmenter, the dense check and the VIO reports. Real recordings do not have it.

The readers are a registry (`DATASET_FORMATS`): :func:`open_dataset` opens a path with the
first format that recognizes its files. TUM-VI's EuRoC-style exports (before EuRoC: they hold
`mav0` too), EuRoC ASL folders, KITTI odometry sequence folders, rendered scene files and
ROS1 / ROS2 bags (`rosbag.py`) are its entries; a new format is one reader module plus one
entry here.

Frames and units: timestamps in nanoseconds; poses `T_world_rect0` (4, 4) in metres, world
z up; images uint8 grey (H, W) in the pixels of `camera`.
"""

from __future__ import annotations

import dataclasses
import pathlib
from collections.abc import Callable
from typing import Any, Protocol, runtime_checkable

import numpy as np

from backend.data.errors import DatasetError
from backend.data.motion import ImuData, ImuNoise
from backend.geometry.camera import PinholeCamera


@runtime_checkable
class StereoSource(Protocol):
    """Every engine's input (module docstring)."""

    timestamps_ns: np.ndarray  # (N,) int64
    T_world_rect0: np.ndarray  # (N, 4, 4); NaN where there is no ground truth
    # The frame whose poses the dataset's own ground-truth file gives: "body" (the IMU body:
    # EuRoC, TUM-VI, rendered scenes) or "cam0" (KITTI's left camera); and the rectified left
    # camera in that frame (4, 4), metres: `T_world_truth = T_world_rect0 · T_truth_rect0⁻¹`.
    ground_truth_frame: str

    @property
    def T_truth_rect0(self) -> np.ndarray: ...  # an attribute or a property

    @property
    def camera(self) -> PinholeCamera: ...

    @property
    def ground_truth_valid(self) -> np.ndarray: ...  # (N,) bool

    def __len__(self) -> int: ...

    def rectified_pair(self, index: int) -> tuple[np.ndarray, np.ndarray]: ...


class InertialSource(StereoSource, Protocol):
    """A stereo source with an IMU (module docstring). Not runtime-checkable on purpose:
    asking a folder without IMU data for it is the one-line error VIO reports."""

    @property
    def has_imu(self) -> bool: ...

    @property
    def imu(self) -> ImuData: ...

    def imu_between(self, t0_ns: int, t1_ns: int) -> ImuData: ...

    @property
    def imu_noise(self) -> ImuNoise: ...

    @property
    def T_body_rect0(self) -> np.ndarray: ...  # (4, 4): the rectified left camera in the IMU body frame

    @property
    def imu_label(self) -> str: ...  # where the IMU samples come from, for messages


@runtime_checkable
class GroundTruthSamples(Protocol):
    """A source whose ground truth is a file of timed samples (module docstring)."""

    def ground_truth_samples(self) -> tuple[np.ndarray, np.ndarray]:
        """The file's samples: timestamps (M,) int64 ns, strictly increasing, and poses
        `T_world_truth` (M, 4, 4) of `ground_truth_frame`, metres; M is 0 without ground truth."""
        ...


@runtime_checkable
class RenderedTruth(Protocol):
    """The exact truth of a rendered scene (module docstring). `isinstance` asks a source for
    every member here (in no fixed order), so none may be a property that raises on a
    reader: an EuRoC folder's `imu`, without `imu0`, would (tested)."""

    plane_table: dict[int, np.ndarray]  # plane id -> (n, d)
    trajectory: Any  # continuous body trajectory: position, rotation, velocity at times (s)
    bias_gyro: np.ndarray  # (M,) per IMU sample, rad/s
    bias_accel: np.ndarray  # (M,) per IMU sample, m/s²

    def views(self, index: int) -> tuple[Any, Any]: ...  # left and right View (image, depth, plane ids)

    def left_depth(self, index: int) -> np.ndarray: ...

    def left_plane_ids(self, index: int) -> np.ndarray: ...


@dataclasses.dataclass(frozen=True)
class ReaderOptions:
    """What a reader may need besides the path (the command line's `--calib` and `--topic`).
    `calib`: a calibration for inputs that hold none (a ROS bag: a folder of EuRoC
    `sensor.yaml` files, `cam0/`, `cam1/`, `imu0/`, or a Kalibr `camchain.yaml`); None where
    the input holds its own. `topics`: (name, topic) pairs overriding a bag's default topic
    names, e.g. (("cam0", "/left/image_raw"),). Readers that need neither ignore them."""

    calib: pathlib.Path | None = None
    topics: tuple[tuple[str, str], ...] = ()

    def topic(self, name: str, default: str) -> str:
        """The topic for `name`: the override given, else `default`."""
        return dict(self.topics).get(name, default)


@dataclasses.dataclass(frozen=True)
class DatasetFormat:
    """One reader of the registry: its name, whether a path holds its files, how to open
    it (with the reader options), and the label an engine's name gives such an input (e.g.
    "EuRoC folder")."""

    name: str
    recognizes: Callable[[pathlib.Path], bool]
    open: Callable[[pathlib.Path, ReaderOptions], StereoSource]
    label: str


def _is_euroc(path: pathlib.Path) -> bool:
    return (path / "mav0").is_dir() or (path.name == "mav0" and path.is_dir())


def _open_euroc(path: pathlib.Path, options: ReaderOptions) -> StereoSource:
    from backend.data.euroc import EurocDataset

    return EurocDataset(path)


def _is_tumvi(path: pathlib.Path) -> bool:
    from backend.data.tumvi import tumvi_root

    return tumvi_root(path) is not None


def _open_tumvi(path: pathlib.Path, options: ReaderOptions) -> StereoSource:
    from backend.data.tumvi import TumviDataset

    return TumviDataset(path)


KITTI_FILES = ("calib.txt", "times.txt", "image_0")


def _is_kitti(path: pathlib.Path) -> bool:
    """A KITTI odometry sequence folder: at least two of calib.txt, times.txt and image_0/, so
    that a folder missing one of them is reported by the KITTI reader, naming it."""
    return path.is_dir() and sum((path / name).exists() for name in KITTI_FILES) >= 2


def _open_kitti(path: pathlib.Path, options: ReaderOptions) -> StereoSource:
    from backend.data.kitti import KittiSequence

    return KittiSequence(path)


def _is_scene_file(path: pathlib.Path) -> bool:
    return path.is_file() and path.suffix.lower() == ".json"


def _open_scene_file(path: pathlib.Path, options: ReaderOptions) -> StereoSource:
    from backend.data.scenes import SceneFileError, load_scene
    from backend.data.synthetic import SyntheticSequence

    try:
        return SyntheticSequence(load_scene(path))
    except SceneFileError as e:
        raise DatasetError(e.path, e.reason) from None


def _is_ros1_bag(path: pathlib.Path) -> bool:
    from backend.data.rosbag import is_ros1_bag

    return is_ros1_bag(path)


def _is_ros2_bag(path: pathlib.Path) -> bool:
    from backend.data.rosbag import is_ros2_bag

    return is_ros2_bag(path)


def _open_rosbag(path: pathlib.Path, options: ReaderOptions) -> StereoSource:
    from backend.data.rosbag import RosBagDataset

    return RosBagDataset(path, calib=options.calib, topics=options.topics)


EUROC_FORMAT = DatasetFormat("EuRoC ASL folder (holding mav0)", _is_euroc, _open_euroc, "EuRoC folder")
DATASET_FORMATS: tuple[DatasetFormat, ...] = (
    DatasetFormat("TUM-VI export in EuRoC format (mav0 with mocap0, dso/camchain.yaml)", _is_tumvi, _open_tumvi, "TUM-VI folder"),
    EUROC_FORMAT,
    DatasetFormat("KITTI odometry sequence folder (sequences/NN: calib.txt, times.txt, image_0, image_1)", _is_kitti, _open_kitti, "KITTI sequence"),
    DatasetFormat("rendered scene file (.json, frames rendered on demand)", _is_scene_file, _open_scene_file, "rendered scene file"),
    DatasetFormat("ROS1 bag (.bag file; needs --calib)", _is_ros1_bag, _open_rosbag, "ROS1 bag"),
    DatasetFormat("ROS2 bag (folder with metadata.yaml; needs --calib)", _is_ros2_bag, _open_rosbag, "ROS2 bag"),
)


def dataset_format(path: pathlib.Path | str) -> DatasetFormat:
    """The first format that recognizes `path`; EuRoC when none does (its reader then says
    in one line what is missing)."""
    path = pathlib.Path(path)
    return next((fmt for fmt in DATASET_FORMATS if fmt.recognizes(path)), EUROC_FORMAT)


def open_dataset(path: pathlib.Path | str, options: ReaderOptions = ReaderOptions()) -> StereoSource:
    """The input at `path`, read by the format that recognizes it (:func:`dataset_format`),
    and checked for what no parser rejects (backend/data/plausibility.py): a DatasetError
    where the data cannot be right (cam0 and cam1 swapped), warnings in its `warnings` where
    they may be (pairs out of step, ground truth that covers few frames)."""
    from backend.data.plausibility import check_ground_truth, check_pairs

    source = dataset_format(path).open(pathlib.Path(path), options)
    where = str(path)
    found = check_pairs(source, where=where)
    if isinstance(source, GroundTruthSamples):
        truth_ns, _ = source.ground_truth_samples()
        found += check_ground_truth(np.asarray(source.timestamps_ns), truth_ns, np.asarray(source.ground_truth_valid), where=where)
    if found:
        source.warnings = (*getattr(source, "warnings", ()), *found)  # type: ignore[attr-defined]  # printed and written to metrics.json
    return source
