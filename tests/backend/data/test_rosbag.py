"""ROS1 bags and ROS2 bag folders (backend/data/rosbag.py, rosbag_writer.py): a rendered
scene written by `coplanar render` as an EuRoC folder and as bags reads back the same
through every reader; bad bags are one-line DatasetErrors naming the file."""

from __future__ import annotations

import contextlib
import io
import json
import pathlib
import pickle
import shutil
from collections.abc import Callable
from typing import Any

import numpy as np
import pytest
from rosbags.highlevel import AnyReader
from rosbags.rosbag1 import Writer as Writer1
from rosbags.typesys import Stores, get_typestore

from app import cli
from backend.data.errors import DatasetError
from backend.data.euroc import EurocDataset
from backend.data.rosbag import RosBagDataset
from backend.data.rosbag_writer import convert
from backend.data.source import InertialSource, ReaderOptions, StereoSource, dataset_format, open_dataset

ROS1 = get_typestore(Stores.ROS1_NOETIC)


@pytest.fixture(scope="session")
def renders(tmp_path_factory: pytest.TempPathFactory) -> dict[str, tuple[pathlib.Path, ReaderOptions]]:
    """`coplanar render --scene boxes --duration 1` (21 pairs) as EuRoC, rosbag1 and rosbag2,
    and the EuRoC folder converted to a ROS2 bag with MCAP storage: {format: (path, options)}."""
    root = tmp_path_factory.mktemp("bags")
    for fmt in ("euroc", "rosbag1", "rosbag2"):
        with contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(io.StringIO()):
            assert cli.main(["render", "--scene", "boxes", "--duration", "1", "--format", fmt, "--out", str(root / fmt)]) == 0
    (root / "mcap").mkdir()
    convert(root / "euroc", root / "mcap", ros2=True, storage="mcap")
    return {
        "euroc": (root / "euroc", ReaderOptions()),
        "rosbag1": (root / "rosbag1" / "data.bag", ReaderOptions(calib=root / "rosbag1" / "calib")),
        "rosbag2": (root / "rosbag2" / "data", ReaderOptions(calib=root / "rosbag2" / "calib")),
        "mcap": (root / "mcap" / "data", ReaderOptions(calib=root / "mcap" / "calib")),
    }


def _open(renders: dict[str, tuple[pathlib.Path, ReaderOptions]], name: str) -> Any:
    path, options = renders[name]
    return open_dataset(path, options)


def rewrite_bag(source: pathlib.Path, target: pathlib.Path, edit: Callable[[str, Any], tuple[str, str, Any] | None]) -> None:
    """A ROS1 copy of the bag `source` with each message `edit(topic, message)`ed into
    (topic, msgtype, message), or left out (None)."""
    with AnyReader([source]) as reader, Writer1(target) as writer:
        connections: dict[tuple[str, str], Any] = {}
        for connection, time_ns, raw in reader.messages():
            edited = edit(connection.topic, reader.deserialize(raw, connection.msgtype))
            if edited is None:
                continue
            topic, msgtype, message = edited
            if (topic, msgtype) not in connections:
                connections[topic, msgtype] = writer.add_connection(topic, msgtype, typestore=ROS1)
            writer.write(connections[topic, msgtype], time_ns, ROS1.serialize_ros1(message, msgtype))


def _same(topic: str, message: Any) -> tuple[str, str, Any]:
    return topic, message.__msgtype__, message


def _one_line(error: pytest.ExceptionInfo[DatasetError], *words: str) -> None:
    text = str(error.value)
    assert "\n" not in text and all(w in text for w in words), text


def test_bags_are_recognized_by_their_files(renders: dict[str, tuple[pathlib.Path, ReaderOptions]], tmp_path: pathlib.Path) -> None:
    assert dataset_format(renders["rosbag1"][0]).label == "ROS1 bag"
    assert dataset_format(renders["rosbag2"][0]).label == "ROS2 bag"
    assert dataset_format(renders["mcap"][0]).label == "ROS2 bag"
    assert dataset_format(tmp_path / "missing.bag").label == "ROS1 bag"  # its reader then says what is wrong
    assert dataset_format(renders["euroc"][0]).label == "EuRoC folder"


@pytest.mark.parametrize("name", ["rosbag1", "rosbag2", "mcap"])
def test_a_bag_reads_as_its_euroc_folder(renders: dict[str, tuple[pathlib.Path, ReaderOptions]], name: str) -> None:
    folder: EurocDataset = _open(renders, "euroc")
    bag: RosBagDataset = _open(renders, name)
    assert isinstance(bag, RosBagDataset) and isinstance(bag, StereoSource) and len(bag) == len(folder) == 21
    np.testing.assert_array_equal(bag.timestamps_ns, folder.timestamps_ns)
    assert bag.camera == folder.camera and bag.imu_noise == folder.imu_noise
    np.testing.assert_array_equal(bag.T_body_rect0, folder.T_body_rect0)
    np.testing.assert_array_equal(bag.ground_truth_valid, folder.ground_truth_valid)
    assert bag.ground_truth_valid.sum() >= 20
    np.testing.assert_array_equal(bag.T_world_rect0, folder.T_world_rect0)  # bit for bit: one quaternion computation
    assert bag.ground_truth_frame == "body" and bag.T_truth_rect0 is not None
    np.testing.assert_array_equal(bag.T_truth_rect0, folder.T_body_rect0)
    for i in range(len(folder)):
        for a, b in zip(bag.rectified_pair(i), folder.rectified_pair(i)):
            np.testing.assert_array_equal(a, b)
    inertial: InertialSource = bag
    assert inertial.has_imu and len(inertial.imu) == len(folder.imu) > 100
    np.testing.assert_array_equal(inertial.imu.timestamp_ns, folder.imu.timestamp_ns)
    np.testing.assert_array_equal(inertial.imu.gyro, folder.imu.gyro)
    np.testing.assert_array_equal(inertial.imu.accel, folder.imu.accel)
    between = inertial.imu_between(int(bag.timestamps_ns[2]), int(bag.timestamps_ns[3]))
    np.testing.assert_array_equal(between.gyro, folder.imu_between(int(bag.timestamps_ns[2]), int(bag.timestamps_ns[3])).gyro)
    assert bag.warnings == () and bag.unpaired_images == (0, 0)


def test_an_image_is_read_from_the_bag_when_asked_for(renders: dict[str, tuple[pathlib.Path, ReaderOptions]]) -> None:
    bag: RosBagDataset = _open(renders, "rosbag1")
    asked: list[tuple[str, int | None, int | None]] = []
    messages = bag._bag.messages

    def spy(connections: Any, *, start: int | None = None, stop: int | None = None) -> Any:
        asked.append((connections[0].topic, start, stop))
        return messages(connections, start=start, stop=stop)

    bag._bag.messages = spy  # type: ignore[method-assign]
    left, right = bag.raw_pair(5)
    stamp = int(bag.timestamps_ns[5])
    assert asked == [("/cam0/image_raw", stamp, stamp + 1), ("/cam1/image_raw", stamp, stamp + 1)]  # record times = stamps here
    del bag._bag.messages  # the spy, back to the method
    # A pickled source carries no open file and reopens the bag when asked.
    again = pickle.loads(pickle.dumps(bag))
    bag.close()
    for a, b, c in zip(again.raw_pair(5), bag.raw_pair(5), (left, right)):  # a closed source reopens too
        np.testing.assert_array_equal(a, c)
        np.testing.assert_array_equal(b, c)


def test_topics_are_overridable(renders: dict[str, tuple[pathlib.Path, ReaderOptions]], tmp_path: pathlib.Path) -> None:
    renamed = {"/cam0/image_raw": "/left/image", "/cam1/image_raw": "/right/image", "/imu0": "/imu", "/vicon/firefly_sbx/firefly_sbx": "/mocap/pose"}
    target = tmp_path / "renamed.bag"
    rewrite_bag(renders["rosbag1"][0], target, lambda topic, message: (renamed[topic], message.__msgtype__, message))
    folder: EurocDataset = _open(renders, "euroc")
    calib = renders["rosbag1"][1].calib
    topics = (("cam0", "/left/image"), ("cam1", "/right/image"), ("imu0", "/imu"), ("groundtruth", "/mocap/pose"))
    bag: RosBagDataset = open_dataset(target, ReaderOptions(calib=calib, topics=topics))  # type: ignore[assignment]
    np.testing.assert_array_equal(bag.rectified_pair(3)[1], folder.rectified_pair(3)[1])
    np.testing.assert_array_equal(bag.imu.accel, folder.imu.accel)
    np.testing.assert_allclose(bag.T_world_rect0, folder.T_world_rect0, atol=1e-12)  # an overridden topic: no vicon0 T_BS, here the identity
    without = RosBagDataset(target, calib=calib, topics=topics[:2])
    assert not without.has_imu and not without.ground_truth_valid.any()  # the defaults are absent: no IMU, no ground truth
    with pytest.raises(DatasetError) as error:
        without.imu  # noqa: B018
    _one_line(error, str(target), "no topic /imu0", "/left/image", "IMU data is needed for VIO")
    with pytest.raises(DatasetError) as error:
        RosBagDataset(target, calib=calib, topics=(*topics[:2], ("imu0", "/imu9")))  # named, so it must be there
    _one_line(error, "no topic /imu9 for imu0", "/imu (sensor_msgs/msg/Imu)")


def test_a_vicon_marker_pose_is_moved_to_the_body_by_vicon0s_t_bs(renders: dict[str, tuple[pathlib.Path, ReaderOptions]], tmp_path: pathlib.Path) -> None:
    """As in EuRoC's V bags: the transforms are the marker's pose, `vicon0/sensor.yaml` its
    place in the body."""
    T_body_marker = np.eye(4)
    T_body_marker[:3, :3] = np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])
    T_body_marker[:3, 3] = [0.06, -0.02, -0.12]

    def to_marker(topic: str, message: Any) -> tuple[str, str, Any]:
        if message.__msgtype__ == "geometry_msgs/msg/TransformStamped":
            r, t = message.transform.rotation, message.transform.translation
            from scipy.spatial.transform import Rotation

            T = np.eye(4)
            T[:3, :3] = Rotation.from_quat([r.x, r.y, r.z, r.w]).as_matrix()
            T[:3, 3] = [t.x, t.y, t.z]
            T = T @ T_body_marker
            r.x, r.y, r.z, r.w = Rotation.from_matrix(T[:3, :3]).as_quat()
            t.x, t.y, t.z = T[:3, 3]
        return _same(topic, message)

    target = tmp_path / "marker.bag"
    rewrite_bag(renders["rosbag1"][0], target, to_marker)
    calib = tmp_path / "calib"
    shutil.copytree(renders["rosbag1"][1].calib, calib)  # type: ignore[arg-type]
    rows = ",\n         ".join(", ".join(repr(float(x)) for x in row) for row in T_body_marker)
    (calib / "vicon0" / "sensor.yaml").write_text(f"%YAML:1.0\nsensor_type: visual-inertial\nT_BS:\n  cols: 4\n  rows: 4\n  data: [{rows}]\n")
    folder: EurocDataset = _open(renders, "euroc")
    bag = RosBagDataset(target, calib=calib)
    np.testing.assert_allclose(bag.T_world_rect0, folder.T_world_rect0, atol=1e-9)
    shutil.rmtree(calib / "vicon0")
    assert np.nanmax(np.abs(RosBagDataset(target, calib=calib).T_world_rect0 - folder.T_world_rect0)) > 0.05  # without it: the marker's pose


def test_positions_only_ground_truth_gives_no_poses_and_says_so(renders: dict[str, tuple[pathlib.Path, ReaderOptions]], tmp_path: pathlib.Path) -> None:
    """EuRoC MH's Leica: geometry_msgs/PointStamped on /leica/position."""

    def to_leica(topic: str, message: Any) -> tuple[str, str, Any]:
        if message.__msgtype__ != "geometry_msgs/msg/TransformStamped":
            return _same(topic, message)
        t = message.transform.translation
        point = ROS1.types["geometry_msgs/msg/PointStamped"](header=message.header, point=ROS1.types["geometry_msgs/msg/Point"](x=t.x, y=t.y, z=t.z))
        return "/leica/position", "geometry_msgs/msg/PointStamped", point

    target = tmp_path / "leica.bag"
    rewrite_bag(renders["rosbag1"][0], target, to_leica)
    folder: EurocDataset = _open(renders, "euroc")
    bag = RosBagDataset(target, calib=renders["rosbag1"][1].calib)
    assert not bag.ground_truth_valid.any() and np.isnan(bag.T_world_rect0).all()
    assert bag.ground_truth_positions is not None and folder.ground_truth is not None
    np.testing.assert_array_equal(bag.ground_truth_positions[0], folder.ground_truth.timestamp_ns)
    np.testing.assert_allclose(bag.ground_truth_positions[1], folder.ground_truth.p_world_body, atol=1e-12)
    assert len(bag.warnings) == 1 and "/leica/position holds positions only" in bag.warnings[0] and "no ATE" in bag.warnings[0]
    out = tmp_path / "run"
    err = io.StringIO()
    with contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(err):
        assert cli.main(["run", "--dataset", str(target), "--calib", str(renders["rosbag1"][1].calib), "--variant", "P-wo", "--out", str(out)]) == 0
    metrics = json.loads((out / "metrics.json").read_text())
    assert metrics["warnings"] == list(bag.warnings) and metrics["ate_rmse_cm"] is None  # said in the run's record, not only on the terminal
    assert f"warning: {bag.warnings[0]}" in err.getvalue().splitlines()


@pytest.mark.parametrize(
    ("damage", "words"),
    [
        ("truncated", ["not a readable ROS1 bag", "index"]),
        ("garbage", ["not a readable ROS1 bag", "magic"]),
        ("no cam1", ["no topic /cam1/image_raw for cam1", "/cam0/image_raw (sensor_msgs/msg/Image)", "--topic cam1=TOPIC"]),
        ("mono16", ["topic /cam1/image_raw", "encoding 'mono16'", "expected mono8"]),
        ("imu as cam1", ["topic /imu0 (cam1) holds sensor_msgs/msg/Imu, expected sensor_msgs/msg/Image"]),
        ("cam0 as imu0", ["topic /cam0/image_raw (imu0) holds sensor_msgs/msg/Image, expected sensor_msgs/msg/Imu"]),  # a topic read before
        ("no calib", ["a bag holds no camera calibration: pass --calib"]),
    ],
)
def test_a_bad_ros1_bag_is_one_line_naming_it(renders: dict[str, tuple[pathlib.Path, ReaderOptions]], tmp_path: pathlib.Path, damage: str, words: list[str]) -> None:
    source, options = renders["rosbag1"]
    target = tmp_path / "bad.bag"
    if damage == "truncated":
        data = source.read_bytes()
        target.write_bytes(data[: len(data) // 2])
    elif damage == "garbage":
        target.write_bytes(b"not a bag\n")
    elif damage == "no cam1":
        rewrite_bag(source, target, lambda topic, message: None if topic == "/cam1/image_raw" else _same(topic, message))
    elif damage == "mono16":

        def sixteen_bit(topic: str, message: Any) -> tuple[str, str, Any]:
            if topic == "/cam1/image_raw" and message.header.seq == 7:
                message.encoding = "mono16"
            return _same(topic, message)

        rewrite_bag(source, target, sixteen_bit)
    else:
        shutil.copyfile(source, target)
    if damage == "imu as cam1":
        options = ReaderOptions(calib=options.calib, topics=(("cam1", "/imu0"),))
    if damage == "cam0 as imu0":
        options = ReaderOptions(calib=options.calib, topics=(("imu0", "/cam0/image_raw"),))
    if damage == "no calib":
        options = ReaderOptions()
    with pytest.raises(DatasetError) as error:
        open_dataset(target, options)
    _one_line(error, str(target), *words)


def test_a_bad_ros2_bag_or_calibration_is_one_line_naming_it(renders: dict[str, tuple[pathlib.Path, ReaderOptions]], tmp_path: pathlib.Path) -> None:
    source, options = renders["rosbag2"]
    target = tmp_path / "data"
    shutil.copytree(source, target)
    database = target / "data.db3"
    database.write_bytes(database.read_bytes()[: database.stat().st_size // 2])
    with pytest.raises(DatasetError) as error:
        open_dataset(target, options)
    _one_line(error, str(target), "not a readable ROS2 bag")
    camchain = tmp_path / "camchain.yaml"
    camchain.write_text("cam0: {}\n")
    for calib, words in (
        (camchain, ["missing key"]),
        (tmp_path / "nowhere", ["no such folder"]),
        (tmp_path, [str(tmp_path / "cam0" / "sensor.yaml"), "missing file"]),
    ):
        with pytest.raises(DatasetError) as error:
            open_dataset(source, ReaderOptions(calib=calib))
        _one_line(error, str(calib), *words)
    with pytest.raises(DatasetError) as error:
        open_dataset(source, ReaderOptions(calib=options.calib, topics=(("cam2", "/x"),)))
    _one_line(error, "--topic cam2=/x: unknown name 'cam2'")


def test_a_kalibr_camchain_calibrates_a_bag_as_the_sensor_yaml_files_do(renders: dict[str, tuple[pathlib.Path, ReaderOptions]], tmp_path: pathlib.Path) -> None:
    from backend.data.calibration import read_camera_yaml, read_imu_yaml
    from backend.data.tumvi_writer import camchain_yaml, imu_config_yaml

    bag, options = renders["rosbag1"]
    assert options.calib is not None
    cam0, cam1 = (read_camera_yaml(options.calib / name / "sensor.yaml") for name in ("cam0", "cam1"))
    (tmp_path / "camchain.yaml").write_text(camchain_yaml(cam0, cam1))
    by_folder = RosBagDataset(bag, calib=options.calib)
    with pytest.raises(DatasetError) as error:  # VIO needs the IMU's noise beside the camchain
        _ = RosBagDataset(bag, calib=tmp_path / "camchain.yaml").imu
    _one_line(error, "no IMU calibration beside it")
    (tmp_path / "imu_config.yaml").write_text(imu_config_yaml(read_imu_yaml(options.calib / "imu0" / "sensor.yaml")))
    by_camchain = RosBagDataset(bag, calib=tmp_path / "camchain.yaml")
    assert by_camchain.camera.fx == pytest.approx(by_folder.camera.fx, rel=1e-12) and by_camchain.camera.baseline == pytest.approx(by_folder.camera.baseline, rel=1e-9)
    np.testing.assert_allclose(by_camchain.T_body_rect0, by_folder.T_body_rect0, atol=1e-12)
    np.testing.assert_allclose(by_camchain.rectified_pair(3)[0], by_folder.rectified_pair(3)[0], atol=1)
    assert by_camchain.imu_noise == by_folder.imu_noise
