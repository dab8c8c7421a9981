"""An EuRoC ASL folder written as a ROS1 bag or a ROS2 bag (with `rosbags`), for
`coplanar render --format rosbag1|rosbag2` and `scripts/euroc_to_bag.py`.

```
OUT/data.bag                    ROS1 (rosbag1)    or    OUT/data/{metadata.yaml, data_0.db3}   ROS2 (rosbag2)
OUT/calib/{cam0,cam1,imu0,vicon0}/sensor.yaml     the folder's calibration, copied (a bag holds none)
```

Topics, as EuRoC's and TUM-VI's own bags name them (`backend.data.rosbag`'s defaults):

- `/cam0/image_raw`, `/cam1/image_raw`: `sensor_msgs/Image`, `mono8`, the raw (unrectified)
  images of the stereo frames, decoded as the EuRoC reader decodes them (so the bag's pixels
  are the folder's, JPEG or PNG alike); camera rows outside the stereo set are left out.
- `/imu0`: `sensor_msgs/Imu`, gyro rad/s and accelerometer m/s² in the IMU frame (EuRoC's
  body frame); no orientation (`orientation_covariance[0] = -1`, ROS's "not provided").
- `/vicon/firefly_sbx/firefly_sbx`: `geometry_msgs/TransformStamped`, the rows of
  `state_groundtruth_estimate0/data.csv` when the folder has one: the pose of its sensor S
  in the world frame (`header.frame_id` "world", `child_frame_id` "body", metres; the
  quaternion as in the file), with that folder's `sensor.yaml` (S's `T_BS`, the identity in
  EuRoC, where S is the body) copied as `calib/vicon0/sensor.yaml`. That topic because it is
  where EuRoC's own bags (V1/V2) carry a full pose, the Vicon marker's, with its `T_BS` in
  `vicon0/sensor.yaml`, and where bag tools look for EuRoC's ground truth; `/leica/position`
  (MH) carries positions only, and `state_groundtruth_estimate0` is in no official bag.
  The reader turns the rows into body poses by the EuRoC reader's own computation, so the
  bag's ground truth is the folder's bit for bit.

Header stamps and the bag's record times are the folder's timestamps (ns). Messages are
written in time order, one image at a time (a long sequence is never held in memory).
"""

from __future__ import annotations

import dataclasses
import functools
import heapq
import pathlib
import shutil
from collections.abc import Callable, Iterator
from typing import Any, Literal

import numpy as np
from rosbags.rosbag1 import Writer as Writer1
from rosbags.rosbag2 import StoragePlugin
from rosbags.rosbag2 import Writer as Writer2
from rosbags.typesys import Stores, get_typestore
from rosbags.typesys.store import Typestore

from backend.data.euroc import EurocDataset, SensorPoses, read_sensor_poses
from backend.data.motion import ImuData

CAM0_TOPIC = "/cam0/image_raw"
CAM1_TOPIC = "/cam1/image_raw"
IMU_TOPIC = "/imu0"
GROUND_TRUTH_TOPIC = "/vicon/firefly_sbx/firefly_sbx"
IMAGE = "sensor_msgs/msg/Image"
IMU = "sensor_msgs/msg/Imu"
TRANSFORM = "geometry_msgs/msg/TransformStamped"
ROS2_BAG_VERSION: Literal[8, 9] = 8  # rosbag2 metadata version 8 (Iron's); version 9 adds nothing used here
Storage = Literal["sqlite3", "mcap"]


@dataclasses.dataclass(frozen=True)
class _Message:
    """One message to write: record time and header stamp (ns), topic, and how to build it."""

    stamp_ns: int
    order: int  # ties at one stamp: cam0, cam1, imu, ground truth
    topic: str
    build: Callable[[], object]

    def key(self) -> tuple[int, int]:
        return self.stamp_ns, self.order


class _Messages:
    """Builds ROS messages of one ROS version's type store."""

    def __init__(self, *, ros2: bool) -> None:
        self.ros2 = ros2
        self.store: Typestore = get_typestore(Stores.ROS2_HUMBLE if ros2 else Stores.ROS1_NOETIC)
        self._types = self.store.types

    def serialize(self, message: object, msgtype: str) -> memoryview:
        return self.store.serialize_cdr(message, msgtype) if self.ros2 else self.store.serialize_ros1(message, msgtype)

    def header(self, stamp_ns: int, frame_id: str, seq: int) -> Any:
        stamp = self._types["builtin_interfaces/msg/Time"](sec=stamp_ns // 1_000_000_000, nanosec=stamp_ns % 1_000_000_000)
        if self.ros2:
            return self._types["std_msgs/msg/Header"](stamp=stamp, frame_id=frame_id)
        return self._types["std_msgs/msg/Header"](seq=seq, stamp=stamp, frame_id=frame_id)

    def vector(self, xyz: np.ndarray) -> Any:
        return self._types["geometry_msgs/msg/Vector3"](x=float(xyz[0]), y=float(xyz[1]), z=float(xyz[2]))

    def image(self, stamp_ns: int, frame_id: str, seq: int, grey: np.ndarray) -> object:
        """A `mono8` image message of a uint8 (H, W) image."""
        height, width = grey.shape
        data = np.ascontiguousarray(grey, dtype=np.uint8).reshape(-1)
        return self._types[IMAGE](header=self.header(stamp_ns, frame_id, seq), height=height, width=width, encoding="mono8", is_bigendian=0, step=width, data=data)

    def imu(self, stamp_ns: int, seq: int, gyro: np.ndarray, accel: np.ndarray) -> object:
        """An IMU message: rad/s and m/s² in the IMU frame, orientation not provided."""
        no_orientation = np.zeros(9)
        no_orientation[0] = -1.0
        quaternion = self._types["geometry_msgs/msg/Quaternion"](x=0.0, y=0.0, z=0.0, w=1.0)
        return self._types[IMU](
            header=self.header(stamp_ns, "imu0", seq),
            orientation=quaternion,
            orientation_covariance=no_orientation,
            angular_velocity=self.vector(gyro),
            angular_velocity_covariance=np.zeros(9),
            linear_acceleration=self.vector(accel),
            linear_acceleration_covariance=np.zeros(9),
        )

    def transform(self, stamp_ns: int, seq: int, q_wxyz: np.ndarray, p_world: np.ndarray) -> object:
        """A pose in the world frame (quaternion (w, x, y, z), metres) as a TransformStamped world -> body."""
        w, x, y, z = q_wxyz
        rotation = self._types["geometry_msgs/msg/Quaternion"](x=float(x), y=float(y), z=float(z), w=float(w))
        transform = self._types["geometry_msgs/msg/Transform"](translation=self.vector(p_world), rotation=rotation)
        return self._types[TRANSFORM](header=self.header(stamp_ns, "world", seq), child_frame_id="body", transform=transform)


def convert(euroc_folder: pathlib.Path, out: pathlib.Path, *, ros2: bool = False, storage: Storage = "sqlite3") -> None:
    """Write the EuRoC folder `euroc_folder` as `out/data.bag` (ROS1) or the ROS2 bag folder
    `out/data` (`ros2`; `storage` sqlite3: `data.db3`, or mcap), and its calibration as
    `out/calib` (module docstring). `out` exists; neither entry may exist in it yet."""
    dataset = EurocDataset(euroc_folder)
    truth_dir = _mav0(euroc_folder) / "state_groundtruth_estimate0"
    truth = read_sensor_poses(truth_dir) if dataset.ground_truth is not None else None
    messages = _Messages(ros2=ros2)
    streams = [_image_stream(dataset, messages), _imu_stream(dataset, messages), _ground_truth_stream(truth, messages)]
    ordered = heapq.merge(*streams, key=_Message.key)
    if ros2:
        _write_ros2(out / "data", ordered, messages, storage)
    else:
        _write_ros1(out / "data.bag", ordered, messages)
    _copy_calibration(euroc_folder, out / "calib")


def _image_stream(dataset: EurocDataset, messages: _Messages) -> Iterator[_Message]:
    """cam0's and cam1's image messages, frame by frame: a pair is read when its messages
    are next to be written."""
    for i, stamp in enumerate(dataset.timestamps_ns.tolist()):
        pair = dataset.raw_pair(i)
        for camera, topic in enumerate((CAM0_TOPIC, CAM1_TOPIC)):
            yield _Message(stamp, camera, topic, functools.partial(messages.image, stamp, f"cam{camera}", i, pair[camera]))


def _imu_stream(dataset: EurocDataset, messages: _Messages) -> Iterator[_Message]:
    imu: ImuData | None = dataset.imu if dataset.has_imu else None
    if imu is None:
        return
    for i, stamp in enumerate(imu.timestamp_ns.tolist()):
        yield _Message(stamp, 2, IMU_TOPIC, functools.partial(messages.imu, stamp, i, imu.gyro[i], imu.accel[i]))


def _ground_truth_stream(truth: SensorPoses | None, messages: _Messages) -> Iterator[_Message]:
    if truth is None:
        return
    for i, stamp in enumerate(truth.timestamp_ns.tolist()):
        yield _Message(stamp, 3, GROUND_TRUTH_TOPIC, functools.partial(messages.transform, stamp, i, truth.q_world_sensor_wxyz[i], truth.p_world_sensor[i]))


MSGTYPES = {CAM0_TOPIC: IMAGE, CAM1_TOPIC: IMAGE, IMU_TOPIC: IMU, GROUND_TRUTH_TOPIC: TRANSFORM}


def _write_ros1(path: pathlib.Path, ordered: Iterator[_Message], messages: _Messages) -> None:
    with Writer1(path) as writer:
        connections = {}
        for message in ordered:
            if message.topic not in connections:
                connections[message.topic] = writer.add_connection(message.topic, MSGTYPES[message.topic], typestore=messages.store)
            writer.write(connections[message.topic], message.stamp_ns, messages.serialize(message.build(), MSGTYPES[message.topic]))


def _write_ros2(path: pathlib.Path, ordered: Iterator[_Message], messages: _Messages, storage: Storage) -> None:
    plugin = StoragePlugin.MCAP if storage == "mcap" else StoragePlugin.SQLITE3
    with Writer2(path, version=ROS2_BAG_VERSION, storage_plugin=plugin) as writer:
        connections = {}
        for message in ordered:
            if message.topic not in connections:
                connections[message.topic] = writer.add_connection(message.topic, MSGTYPES[message.topic], typestore=messages.store)
            writer.write(connections[message.topic], message.stamp_ns, messages.serialize(message.build(), MSGTYPES[message.topic]))


def _mav0(euroc_folder: pathlib.Path) -> pathlib.Path:
    return euroc_folder / "mav0" if (euroc_folder / "mav0").is_dir() else euroc_folder


def _copy_calibration(euroc_folder: pathlib.Path, calib: pathlib.Path) -> None:
    """`cam0`, `cam1` and (when there) `imu0` `sensor.yaml` of the folder into `calib`, and
    the ground truth's as `vicon0` (the frame the ground-truth topic's transforms track)."""
    mav0 = _mav0(euroc_folder)
    for sensor, target in (("cam0", "cam0"), ("cam1", "cam1"), ("imu0", "imu0"), ("state_groundtruth_estimate0", "vicon0")):
        source = mav0 / sensor / "sensor.yaml"
        if source.is_file():
            (calib / target).mkdir(parents=True)
            shutil.copyfile(source, calib / target / "sensor.yaml")
