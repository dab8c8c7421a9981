"""Reader of ROS bags (with `rosbags`): a ROS1 `.bag` file or a ROS2 bag folder
(`metadata.yaml` with `.db3` or `.mcap` files), as a `StereoSource` and `InertialSource`.

Topics (defaults as EuRoC's and TUM-VI's own bags name them; each overridable by
`ReaderOptions.topics`, the command line's `--topic NAME=TOPIC`):

- `cam0` `/cam0/image_raw`, `cam1` `/cam1/image_raw`: `sensor_msgs/Image`, raw (unrectified)
  8-bit images, `mono8` (`8UC1`; `rgb8`/`bgr8` are converted to grey as the EuRoC reader
  converts colour files). Stereo frames are the header stamps found on both topics (EuRoC's
  rule: images of one camera without a partner are ignored).
- `imu0` `/imu0`: `sensor_msgs/Imu`, gyro rad/s and accelerometer m/s² in the IMU frame
  (EuRoC's body frame), as the EuRoC reader gives `imu0/data.csv`. Optional as in EuRoC
  folders: without it (or without `imu0/sensor.yaml` in the calibration) stereo runs and
  VIO gets a one-line error.
- `groundtruth`: the first of these the bag has (or the topic given):
  `/vicon/firefly_sbx/firefly_sbx` (EuRoC V1/V2, `geometry_msgs/TransformStamped`),
  `/vrpn_client/raw_transform` (TUM-VI, TransformStamped) and `/leica/position` (EuRoC MH,
  `geometry_msgs/PointStamped`); `geometry_msgs/PoseStamped` is read too. A transform is the
  pose `T_world_S` of the tracked frame S; the body pose is `T_world_S T_BS⁻¹` with `T_BS`
  from the calibration folder's `vicon0/sensor.yaml` (Vicon, as in EuRoC's folders and what
  `backend.data.rosbag_writer` writes), `mocap0/sensor.yaml` (VRPN) when there, else S is the
  body. The poses are computed as the EuRoC reader computes its ground truth
  (`euroc.quaternion_poses`), so equal numbers give equal poses bit for bit.
  **Positions only** (PointStamped, EuRoC MH's Leica prism): the rotation is unknown, so
  neither the body's nor the camera's pose is (the prism sits ~10 cm from the camera, which
  turns with the unknown rotation). The bag then has no ground-truth poses
  (`ground_truth_valid` all False, no ATE); the positions are kept in
  `ground_truth_positions` and `warnings` says so in one line.

Timestamps: int64 nanoseconds from the messages' header stamps (not the record times).
Calibration: `ReaderOptions.calib`, required (a bag holds none): a folder with EuRoC
`cam0/sensor.yaml`, `cam1/sensor.yaml` and (for VIO) `imu0/sensor.yaml` (a folder holding
`mav0` works too), or a Kalibr `camchain.yaml` (the cameras, with the IMU as the body; the
IMU's noise from Kalibr's `imu.yaml` or TUM-VI's `imu_config.yaml` beside it). Frames and units as
`backend.data.euroc`: `body` is the IMU frame, `T_world_rect0` the rectified left camera's
ground-truth pose (NaN without one).

Streaming: opening reads the camera topics once for their header stamps and record times
(and checks every image's type, encoding and size), the IMU and ground truth whole (small);
an image is read again only when `rectified_pair` asks for it, by its record time.

Bad input is a one-line DatasetError naming the bag (or the calibration file): not a bag, a
damaged or truncated bag, a missing topic (with the topics the bag has), a message of an
unexpected type or encoding, no calibration.
"""

from __future__ import annotations

import dataclasses
import pathlib
from collections.abc import Iterator, Sequence
from typing import Any

import cv2
import numpy as np
from rosbags.highlevel import AnyReader
from rosbags.interfaces import Connection
from rosbags.typesys import Stores, get_typestore

from backend.data.calibration import (
    ImuCalibration,
    StereoRectification,
    read_camera_yaml,
    read_imu_yaml,
    read_kalibr_camchain,
    read_kalibr_imu,
    read_sensor_transform,
    stereo_rectification,
)
from backend.data.errors import DatasetError
from backend.data.euroc import QUATERNION_NORM_TOLERANCE, GroundTruth, RectifiedRecording, SensorPoses
from backend.data.motion import ImuData
from backend.data.plausibility import check_calibration
from backend.data.topics import TOPIC_NAMES

DEFAULT_TOPICS = {"cam0": "/cam0/image_raw", "cam1": "/cam1/image_raw", "imu0": "/imu0"}
KALIBR_IMU_FILES = ("imu.yaml", "imu_config.yaml")  # beside a camchain.yaml: Kalibr's name, TUM-VI's
GROUND_TRUTH_TOPICS = (  # (topic, calibration folder whose sensor.yaml T_BS places the tracked frame in the body)
    ("/vicon/firefly_sbx/firefly_sbx", "vicon0"),  # EuRoC V1/V2: TransformStamped
    ("/vrpn_client/raw_transform", "mocap0"),  # TUM-VI: TransformStamped
    ("/leica/position", "leica0"),  # EuRoC MH: PointStamped, positions only
)
IMAGE = "sensor_msgs/msg/Image"
IMU = "sensor_msgs/msg/Imu"
TRANSFORM = "geometry_msgs/msg/TransformStamped"
POSE = "geometry_msgs/msg/PoseStamped"
POINT = "geometry_msgs/msg/PointStamped"
GREY_ENCODINGS = ("mono8", "8UC1")
COLOUR_ENCODINGS = {"rgb8": cv2.COLOR_RGB2GRAY, "bgr8": cv2.COLOR_BGR2GRAY}


def is_ros1_bag(path: pathlib.Path) -> bool:
    """A `.bag` path (a missing one too: its reader then says so)."""
    return path.suffix.lower() == ".bag" and not path.is_dir()


def is_ros2_bag(path: pathlib.Path) -> bool:
    """A folder with a ROS2 bag's `metadata.yaml`."""
    return path.is_dir() and (path / "metadata.yaml").is_file()


class _Bag:
    """An open bag (rosbags' AnyReader) whose failures are DatasetErrors naming it. Opened
    on first use and again after unpickling (a pickled source carries no open file)."""

    def __init__(self, path: pathlib.Path) -> None:
        self.path = path
        self.kind = "ROS1 bag" if path.suffix.lower() == ".bag" else "ROS2 bag"
        self._reader: AnyReader | None = None
        self._connections: dict[str, list[Connection]] = {}  # by topic

    def __getstate__(self) -> dict[str, Any]:
        return {**self.__dict__, "_reader": None, "_connections": {}}  # both hold the open files

    def check_exists(self) -> None:
        if not self.path.exists():
            raise DatasetError(self.path, "no such file" if self.kind == "ROS1 bag" else "no such folder")

    def reader(self) -> AnyReader:
        if self._reader is None:
            self.check_exists()
            try:
                reader = AnyReader([self.path], default_typestore=get_typestore(Stores.ROS2_HUMBLE))
                reader.open()
            except Exception as error:  # rosbags' and its storage libraries' failures: the bag's fault
                raise self.error(error) from None
            self._reader = reader
        return self._reader

    def error(self, error: Exception, topic: str | None = None) -> DatasetError:
        where = f"topic {topic}: " if topic else ""
        return DatasetError(self.path, f"{where}not a readable {self.kind} ({type(error).__name__}: {error})")

    def topics(self) -> dict[str, str | None]:
        """Every topic of the bag with its message type."""
        return {name: info.msgtype for name, info in self.reader().topics.items()}

    def connections(self, topic: str, name: str, msgtypes: tuple[str, ...]) -> list[Connection]:
        """The connections of `topic` (read as `name`), all of one of `msgtypes`; else a
        DatasetError naming the topic and the bag's topics or the type found."""
        found = self._connections.get(topic) or [c for c in self.reader().connections if c.topic == topic]
        if not found:
            have = ", ".join(f"{t} ({m})" for t, m in sorted(self.topics().items())) or "none"
            raise DatasetError(self.path, f"no topic {topic} for {name} (topics in the bag: {have}); choose one with --topic {name}=TOPIC")
        wrong = [c.msgtype for c in found if c.msgtype not in msgtypes]
        if wrong:
            raise DatasetError(self.path, f"topic {topic} ({name}) holds {wrong[0]}, expected {' or '.join(msgtypes)}")
        self._connections[topic] = found
        return found

    def messages(self, connections: Sequence[Connection], *, start: int | None = None, stop: int | None = None) -> Iterator[tuple[int, Any]]:
        """(record time ns, message) of `connections` in record order, `start <= t < stop`."""
        reader = self.reader()
        topic = connections[0].topic if connections else None
        stream = reader.messages(connections, start=start, stop=stop)
        while True:
            try:
                item = next(stream, None)
                if item is None:
                    return
                connection, time_ns, raw = item
                message = reader.deserialize(raw, connection.msgtype)
            except Exception as error:  # a damaged chunk or message: the bag's fault
                raise self.error(error, topic) from None
            yield time_ns, message

    def close(self) -> None:
        if self._reader is not None:
            self._reader.close()
            self._reader = None
            self._connections = {}


def stamp_ns(message: Any) -> int:
    """A stamped message's header stamp, nanoseconds."""
    return int(message.header.stamp.sec) * 1_000_000_000 + int(message.header.stamp.nanosec)


@dataclasses.dataclass(frozen=True, eq=False)
class _ImageTopic:
    """One camera's images: header stamps (M,) int64 ns, sorted, and each one's record time."""

    name: str
    topic: str
    stamps_ns: np.ndarray
    record_ns: np.ndarray


class RosBagDataset(RectifiedRecording):
    """A ROS1 bag or ROS2 bag folder read as a stereo source with an IMU (module docstring
    for topics, frames, units and what is accepted). Raises DatasetError on bad input."""

    def __init__(self, path: pathlib.Path | str, *, calib: pathlib.Path | None = None, topics: tuple[tuple[str, str], ...] = (), max_ground_truth_gap_ns: int = 100_000_000) -> None:
        """`calib`: the calibration folder or camchain file (required; module docstring); `topics`: (name,
        topic) overrides of the default topics (names cam0, cam1, imu0, groundtruth)."""
        self.path = pathlib.Path(path)
        self._bag = _Bag(self.path)
        self._bag.check_exists()
        self._topics = _topic_table(self.path, topics)
        calib = _calibration_folder(self.path, calib)
        self.calibration_folder = calib
        if calib.is_file():  # a Kalibr camchain.yaml
            self.cam0, self.cam1 = read_kalibr_camchain(calib)
        else:
            self.cam0 = read_camera_yaml(calib / "cam0" / "sensor.yaml")
            self.cam1 = read_camera_yaml(calib / "cam1" / "sensor.yaml")
        check_calibration(self.cam0, self.cam1)  # implausible intrinsics or baseline: one line naming the file
        self.rectification: StereoRectification = stereo_rectification(self.cam0, self.cam1)
        self.warnings: tuple[str, ...] = ()

        left = self._image_topic("cam0")
        right = self._image_topic("cam1")
        common, index0, index1 = np.intersect1d(left.stamps_ns, right.stamps_ns, assume_unique=True, return_indices=True)
        if common.shape[0] == 0:
            raise DatasetError(self.path, f"no header stamp in common between {left.topic} and {right.topic} (stereo frames are the stamps found on both)")
        self.timestamps_ns: np.ndarray = common
        self._left, self._right = left, right
        self._record0, self._record1 = left.record_ns[index0], right.record_ns[index1]
        self.unpaired_images: tuple[int, int] = (left.stamps_ns.shape[0] - common.shape[0], right.stamps_ns.shape[0] - common.shape[0])

        self._imu_topic = self._topics.get("imu0", DEFAULT_TOPICS["imu0"])
        self._imu_calibration, self._imu, self._no_imu = self._read_imu(calib, explicit="imu0" in self._topics)

        self.ground_truth: GroundTruth | None = None
        self.ground_truth_positions: tuple[np.ndarray, np.ndarray] | None = None  # (stamps ns, (M, 3) metres) of a positions-only ground truth
        self.T_world_body: np.ndarray = np.full((common.shape[0], 4, 4), np.nan)
        self._read_ground_truth(calib, max_gap_ns=max_ground_truth_gap_ns)
        self.T_world_cam0: np.ndarray = self.T_world_body @ self.cam0.T_body_camera
        self.T_world_rect0: np.ndarray = self.T_world_cam0 @ self.rectification.T_cam0_rect0

    def raw_pair(self, index: int) -> tuple[np.ndarray, np.ndarray]:
        """Frame `index`'s raw cam0, cam1 images: grey uint8 (height, width), read from the bag now."""
        index = self._check_index(index)
        stamp = int(self.timestamps_ns[index])
        return self._read_image(self._left, stamp, int(self._record0[index])), self._read_image(self._right, stamp, int(self._record1[index]))

    @property
    def imu_calibration(self) -> ImuCalibration:
        """The calibration's `imu0/sensor.yaml`; DatasetError (one line) without IMU data."""
        if self._imu_calibration is None or self._imu is None:
            raise self._no_imu_error()
        return self._imu_calibration

    @property
    def imu_label(self) -> str:
        """Where the IMU samples come from, for messages."""
        return f"{self.path} topic {self._imu_topic}"

    def close(self) -> None:
        """Close the bag's files (reading an image again reopens it)."""
        self._bag.close()

    def _image_topic(self, name: str) -> _ImageTopic:
        """One camera's header stamps and record times; every image is checked (type,
        encoding, size against the calibration) but none is kept."""
        topic = self._topics.get(name, DEFAULT_TOPICS[name])
        connections = self._bag.connections(topic, name, (IMAGE,))
        stamps, records = [], []
        for record_ns, message in self._bag.messages(connections):
            self._check_image(message, topic)
            stamps.append(stamp_ns(message))
            records.append(record_ns)
        if not stamps:
            raise DatasetError(self.path, f"topic {topic} ({name}) has no messages")
        order = np.argsort(np.asarray(stamps, dtype=np.int64), kind="stable")
        stamps_ns = np.asarray(stamps, dtype=np.int64)[order]
        twice = np.flatnonzero(np.diff(stamps_ns) == 0)
        if twice.size:
            raise DatasetError(self.path, f"topic {topic} ({name}): two images stamped {stamps_ns[twice[0]]} ns")
        return _ImageTopic(name, topic, stamps_ns, np.asarray(records, dtype=np.int64)[order])

    def _check_image(self, message: Any, topic: str) -> None:
        encoding = str(message.encoding)
        if encoding not in GREY_ENCODINGS and encoding not in COLOUR_ENCODINGS:
            raise DatasetError(self.path, f"topic {topic}: image stamped {stamp_ns(message)} ns has encoding '{encoding}', expected mono8 (8-bit grey; rgb8, bgr8 are converted)")
        if (int(message.width), int(message.height)) != (self.cam0.width, self.cam0.height):
            raise DatasetError(self.path, f"topic {topic}: image stamped {stamp_ns(message)} ns is {message.width}x{message.height}, {self.cam0.source} says {self.cam0.width}x{self.cam0.height}")
        channels = 1 if encoding in GREY_ENCODINGS else 3
        if int(message.step) < channels * int(message.width) or len(message.data) < int(message.step) * int(message.height):
            raise DatasetError(self.path, f"topic {topic}: image stamped {stamp_ns(message)} ns holds {len(message.data)} bytes, too few for its step {message.step} and height {message.height}")

    def _read_image(self, camera: _ImageTopic, stamp: int, record_ns: int) -> np.ndarray:
        """The grey image stamped `stamp` of `camera`, found by its record time."""
        connections = self._bag.connections(camera.topic, camera.name, (IMAGE,))
        for _, message in self._bag.messages(connections, start=record_ns, stop=record_ns + 1):
            if stamp_ns(message) == stamp:
                return _grey(message)
        raise DatasetError(self.path, f"topic {camera.topic}: the image stamped {stamp} ns is no longer there (was the bag changed?)")

    def _read_imu(self, calib: pathlib.Path, *, explicit: bool) -> tuple[ImuCalibration | None, ImuData | None, tuple[pathlib.Path, str] | None]:
        """The IMU calibration and samples, or what is missing (path, reason) for the error
        VIO reports. A topic given with --topic must exist; the default may be absent."""
        topic = self._imu_topic
        if topic not in self._bag.topics() and not explicit:
            return None, None, (self.path, f"no topic {topic} (topics in the bag: {', '.join(sorted(self._bag.topics())) or 'none'})")
        connections = self._bag.connections(topic, "imu0", (IMU,))
        stamps, values = [], []
        for _, message in self._bag.messages(connections):
            stamps.append(stamp_ns(message))
            w, a = message.angular_velocity, message.linear_acceleration
            values.append((w.x, w.y, w.z, a.x, a.y, a.z))
        if not stamps:
            return None, None, (self.path, f"topic {topic} has no messages")
        stamps_ns = np.asarray(stamps, dtype=np.int64)
        order = np.argsort(stamps_ns, kind="stable")
        stamps_ns, samples = stamps_ns[order], np.asarray(values, dtype=np.float64)[order]
        _check_samples(self.path, topic, stamps_ns, samples, "IMU sample")
        imu = ImuData(timestamp_ns=stamps_ns, gyro=samples[:, 0:3], accel=samples[:, 3:6])
        if calib.is_file():  # Kalibr: the IMU's noise in a file beside the camchain
            kalibr = [calib.parent / name for name in KALIBR_IMU_FILES]
            found = next((path for path in kalibr if path.exists()), None)
            if found is None:
                return None, None, (calib, f"no IMU calibration beside it ({' or '.join(KALIBR_IMU_FILES)})")
            return read_kalibr_imu(found), imu, None
        yaml = calib / "imu0" / "sensor.yaml"
        if not yaml.exists():
            return None, None, (yaml, "missing file")
        return read_imu_yaml(yaml), ImuData(timestamp_ns=stamps_ns, gyro=samples[:, 0:3], accel=samples[:, 3:6]), None

    def _read_ground_truth(self, calib: pathlib.Path, *, max_gap_ns: int) -> None:
        """The ground truth topic (module docstring) into `ground_truth` and `T_world_body`,
        or `ground_truth_positions` and a warning for positions only."""
        chosen = _ground_truth_topic(self._bag, self._topics.get("groundtruth"))
        if chosen is None:
            return
        topic, sensor = chosen
        connections = self._bag.connections(topic, "groundtruth", (TRANSFORM, POSE, POINT))
        stamps, values = [], []
        for _, message in self._bag.messages(connections):
            stamps.append(stamp_ns(message))
            values.append(_pose_values(message))
        if not stamps:
            return
        stamps_ns = np.asarray(stamps, dtype=np.int64)
        order = np.argsort(stamps_ns, kind="stable")
        stamps_ns, poses = stamps_ns[order], np.asarray(values, dtype=np.float64)[order]
        if connections[0].msgtype == POINT:
            _check_samples(self.path, topic, stamps_ns, poses[:, :3], "ground-truth position")
            self.ground_truth_positions = (stamps_ns, poses[:, :3].copy())
            self.warnings += (f"{self.path}: {topic} holds positions only ({POINT}): the rotation is unknown, so there are no ground-truth poses and no ATE",)
            return
        _check_samples(self.path, topic, stamps_ns, poses, "ground-truth pose")
        self.ground_truth = _body_truth(self.path, topic, stamps_ns, poses, _sensor_in_body(calib, sensor))
        self.T_world_body = self.ground_truth.T_world_body_at(self.timestamps_ns, max_gap_ns=max_gap_ns)


def _topic_table(path: pathlib.Path, topics: tuple[tuple[str, str], ...]) -> dict[str, str]:
    """The overrides as {name: topic}; an unknown name is a DatasetError."""
    for name, topic in topics:
        if name not in TOPIC_NAMES:
            raise DatasetError(path, f"--topic {name}={topic}: unknown name '{name}' (a bag's are {', '.join(TOPIC_NAMES)})")
    return dict(topics)


def _calibration_folder(bag: pathlib.Path, calib: pathlib.Path | None) -> pathlib.Path:
    """The calibration folder holding `cam0/`, `cam1/` (and `imu0/`) sensor.yaml files, or a
    Kalibr camchain.yaml file."""
    if calib is None:
        raise DatasetError(bag, "a bag holds no camera calibration: pass --calib FOLDER (EuRoC sensor.yaml files: cam0/, cam1/, imu0/) or --calib camchain.yaml (Kalibr)")
    if not calib.exists():
        raise DatasetError(calib, "no such folder or file (--calib: a folder of EuRoC sensor.yaml files cam0/, cam1/, imu0/, or a Kalibr camchain.yaml)")
    if calib.is_file() and calib.suffix.lower() in (".yaml", ".yml"):
        return calib  # a Kalibr camchain.yaml
    if not calib.is_dir():
        raise DatasetError(calib, "not a folder (--calib: a folder of EuRoC sensor.yaml files cam0/, cam1/, imu0/)")
    return calib / "mav0" if (calib / "mav0").is_dir() else calib


def _ground_truth_topic(bag: _Bag, given: str | None) -> tuple[str, str | None] | None:
    """The ground truth's topic and its calibration folder name: the one `given` (with
    --topic; no calibration folder), else the first default topic the bag has, else None."""
    if given is not None:
        return given, None
    topics = bag.topics()
    return next(((topic, sensor) for topic, sensor in GROUND_TRUTH_TOPICS if topic in topics), None)


def _pose_values(message: Any) -> tuple[float, ...]:
    """(x, y, z, qw, qx, qy, qz) of a TransformStamped or PoseStamped; (x, y, z, nan…) of a PointStamped."""
    if message.__msgtype__ == TRANSFORM:
        p, q = message.transform.translation, message.transform.rotation
    elif message.__msgtype__ == POSE:
        p, q = message.pose.position, message.pose.orientation
    else:
        p = message.point
        return (p.x, p.y, p.z, np.nan, np.nan, np.nan, np.nan)
    return (p.x, p.y, p.z, q.w, q.x, q.y, q.z)


def _check_samples(path: pathlib.Path, topic: str, stamps_ns: np.ndarray, values: np.ndarray, what: str) -> None:
    """Finite values and distinct stamps, else a DatasetError naming the topic and stamp."""
    bad = np.flatnonzero(~np.isfinite(values).all(axis=1))
    if bad.size:
        raise DatasetError(path, f"topic {topic}: {what} stamped {stamps_ns[bad[0]]} ns holds NaN or an infinite value")
    twice = np.flatnonzero(np.diff(stamps_ns) == 0)
    if twice.size:
        raise DatasetError(path, f"topic {topic}: two messages stamped {stamps_ns[twice[0]]} ns")


def _sensor_in_body(calib: pathlib.Path, sensor: str | None) -> np.ndarray | None:
    """`T_BS` (4, 4) of the ground truth's tracked frame from `calib/<sensor>/sensor.yaml`;
    None (the transforms are the body's poses) without that file."""
    if sensor is None or not (calib / sensor / "sensor.yaml").is_file():
        return None
    return read_sensor_transform(calib / sensor / "sensor.yaml", default=np.eye(4))


def _body_truth(path: pathlib.Path, topic: str, stamps_ns: np.ndarray, poses: np.ndarray, T_body_sensor: np.ndarray | None) -> GroundTruth:
    """Body poses `T_world_body = T_world_S T_BS⁻¹` from the tracked frame's (x, y, z, qw, qx, qy, qz)."""
    norm = np.linalg.norm(poses[:, 3:7], axis=1)
    off = np.flatnonzero(np.abs(norm - 1.0) > QUATERNION_NORM_TOLERANCE)
    if off.size:
        raise DatasetError(path, f"topic {topic}: rotation stamped {stamps_ns[off[0]]} ns has quaternion norm {norm[off[0]]:.6g}, expected 1")
    samples = SensorPoses(timestamp_ns=stamps_ns, p_world_sensor=poses[:, :3], q_world_sensor_wxyz=poses[:, 3:7], T_body_sensor=T_body_sensor, extra=np.full((stamps_ns.shape[0], 9), np.nan))
    return samples.body_truth()


def _grey(message: Any) -> np.ndarray:
    """An image message (checked at open) as grey uint8 (height, width), a copy."""
    height, width, step = int(message.height), int(message.width), int(message.step)
    rows = np.asarray(message.data, dtype=np.uint8)[: step * height].reshape(height, step)
    encoding = str(message.encoding)
    if encoding in GREY_ENCODINGS:
        return rows[:, :width].copy()
    return cv2.cvtColor(np.ascontiguousarray(rows[:, : 3 * width].reshape(height, width, 3)), COLOUR_ENCODINGS[encoding])
