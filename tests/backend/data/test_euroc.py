"""EuRoC ASL reader on small synthetic folders written in EuRoC's exact style: frames, IMU
slices, ground truth interpolation and frames, calibration, and every bad input as a
one-line DatasetError naming the file (and line)."""

from __future__ import annotations

import itertools
import pathlib
import shutil
from collections.abc import Callable

import cv2
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from backend.data.calibration import read_camera_yaml, read_imu_yaml
from backend.data.errors import DatasetError
from backend.data.euroc import EurocDataset

T0_NS = 1403715273262142976  # EuRoC-like epoch timestamps
FRAME_NS = 50_000_000  # 20 Hz
IMU_NS = 5_000_000  # 200 Hz
WIDTH, HEIGHT = 32, 24

# EuRoC V1_01's extrinsics (body = IMU frame).
T_BODY_CAM0 = np.array(
    [
        [0.0148655429818, -0.999880929698, 0.00414029679422, -0.0216401454975],
        [0.999557249008, 0.0149672133247, 0.025715529948, -0.064676986768],
        [-0.0257744366974, 0.00375618835797, 0.999660727178, 0.00981073058949],
        [0.0, 0.0, 0.0, 1.0],
    ]
)
T_BODY_CAM1 = np.array(
    [
        [0.0125552670891, -0.999755099723, 0.0182237714554, -0.0198435579556],
        [0.999598781151, 0.0130119051815, 0.0251588363115, 0.0453689425024],
        [-0.0253898008918, 0.0179005838253, 0.999517347078, 0.00786212447038],
        [0.0, 0.0, 0.0, 1.0],
    ]
)
INTRINSICS = {"cam0": [40.5, 40.25, 15.75, 12.25], "cam1": [40.0, 40.5, 16.25, 11.75]}
DISTORTION = {"cam0": [-0.28340811, 0.07395907, 0.00019359, 1.76187114e-05], "cam1": [-0.28368365, 0.07451284, -0.00010473, -3.55590700e-05]}

# Frames: cam0 has k = 0..10, cam1 lacks k = 3 and k = 10 -> 9 stereo frames.
CAM0_K = list(range(11))
CAM1_K = [k for k in range(10) if k != 3]
FRAME_K = [k for k in CAM0_K if k in CAM1_K]

# Ground truth: constant velocity and yaw rate, samples every 5 ms from 22.5 ms (after frame 0).
GT_START_NS = T0_NS + 22_500_000
GT_COUNT = 110
P0_WORLD = np.array([1.0, -2.0, 0.5])
V_WORLD = np.array([0.4, 0.3, -0.1])  # m/s
YAW_RATE = 0.8  # rad/s about world z
R_TILT = Rotation.from_rotvec([0.1, -0.2, 0.05])


def _body_pose(t_ns: int) -> np.ndarray:
    s = (t_ns - T0_NS) * 1e-9
    T = np.eye(4)
    T[:3, :3] = (Rotation.from_rotvec([0.0, 0.0, YAW_RATE * s]) * R_TILT).as_matrix()
    T[:3, 3] = P0_WORLD + V_WORLD * s
    return T


def _matrix(T: np.ndarray) -> str:
    rows = [", ".join(repr(float(x)) for x in row) for row in T]
    return "T_BS:\n  cols: 4\n  rows: 4\n  data: [" + ",\n         ".join(rows) + "]\n"


def _camera_yaml(name: str, T: np.ndarray) -> str:
    fu, fv, cu, cv = INTRINSICS[name]
    return (
        "%YAML:1.0\n"
        "# General sensor definitions.\n"
        "sensor_type: camera\n"
        f"comment: VI-Sensor {name} (MT9M034)\n\n"
        "# Sensor extrinsics wrt. the body-frame.\n" + _matrix(T) + "\n# Camera specific definitions.\n"
        "rate_hz: 20\n"
        f"resolution: [{WIDTH}, {HEIGHT}]\n"
        "camera_model: pinhole\n"
        f"intrinsics: [{fu}, {fv}, {cu}, {cv}] #fu, fv, cu, cv\n"
        "distortion_model: radial-tangential\n"
        f"distortion_coefficients: [{', '.join(repr(x) for x in DISTORTION[name])}]\n\n"
    )


IMU_YAML = (
    "%YAML:1.0\n"
    "#Default imu sensor yaml file\n"
    "sensor_type: imu\n"
    "comment: VI-Sensor IMU (ADIS16448)\n\n"
    "# Sensor extrinsics wrt. the body-frame.\n" + _matrix(np.eye(4)) + "rate_hz: 200\n\n"
    "# inertial sensor noise model parameters (static)\n"
    'gyroscope_noise_density: 1.6968e-04     # [ rad / s / sqrt(Hz) ]   ( gyro "white noise" )\n'
    "gyroscope_random_walk: 1.9393e-05       # [ rad / s^2 / sqrt(Hz) ] ( gyro bias diffusion )\n"
    'accelerometer_noise_density: 2.0000e-3  # [ m / s^2 / sqrt(Hz) ]   ( accel "white noise" )\n'
    "accelerometer_random_walk: 3.0000e-3    # [ m / s^3 / sqrt(Hz) ].  ( accel bias diffusion )\n"
)
GT_YAML = (
    "%YAML:1.0\n"
    "# Sensor extrinsics wrt. the body-frame. This is the transformation of the\n"
    "# tracking prima to the body frame.\n"
    "sensor_type: visual-inertial\n"
    "comment: The nonlinear least-squares batch solution over the Vicon pose and IMU measurements "
    "including time offset estimation. The orientation is only coarsly aligned with gravity.\n" + _matrix(np.eye(4))
)
IMU_HEADER = "#timestamp [ns],w_RS_S_x [rad s^-1],w_RS_S_y [rad s^-1],w_RS_S_z [rad s^-1],a_RS_S_x [m s^-2],a_RS_S_y [m s^-2],a_RS_S_z [m s^-2]"
GT_HEADER = (
    "#timestamp, p_RS_R_x [m], p_RS_R_y [m], p_RS_R_z [m], q_RS_w [], q_RS_x [], q_RS_y [], q_RS_z [], "
    "v_RS_R_x [m s^-1], v_RS_R_y [m s^-1], v_RS_R_z [m s^-1], b_w_RS_S_x [rad s^-1], b_w_RS_S_y [rad s^-1], "
    "b_w_RS_S_z [rad s^-1], b_a_RS_S_x [m s^-2], b_a_RS_S_y [m s^-2], b_a_RS_S_z [m s^-2]"
)
IMU_COUNT = 120  # 0..595 ms


def _image(name: str, k: int) -> np.ndarray:
    return np.random.default_rng([k, name == "cam1"]).integers(0, 256, (HEIGHT, WIDTH), dtype=np.uint8)


def write_euroc(root: pathlib.Path, *, ground_truth: bool = True) -> pathlib.Path:
    """A small EuRoC ASL folder under `root`; returns `root`."""
    mav0 = root / "mav0"
    for name, T, ks in (("cam0", T_BODY_CAM0, CAM0_K), ("cam1", T_BODY_CAM1, CAM1_K)):
        (mav0 / name / "data").mkdir(parents=True)
        (mav0 / name / "sensor.yaml").write_text(_camera_yaml(name, T))
        lines = ["#timestamp [ns],filename"]
        for k in ks:
            stamp = T0_NS + k * FRAME_NS
            lines.append(f"{stamp},{stamp}.png")
            cv2.imwrite(str(mav0 / name / "data" / f"{stamp}.png"), _image(name, k))
        # EuRoC's camera lists end lines with CRLF; exercise that on cam0.
        (mav0 / name / "data.csv").write_bytes(("\r\n" if name == "cam0" else "\n").join(lines).encode() + b"\n")
    (mav0 / "imu0").mkdir()
    (mav0 / "imu0" / "sensor.yaml").write_text(IMU_YAML)
    imu_lines = [IMU_HEADER] + [f"{T0_NS + i * IMU_NS},{0.001 * i!r},{-0.002 * i!r},0.03,9.81,{0.01 * i!r},-0.2" for i in range(IMU_COUNT)]
    (mav0 / "imu0" / "data.csv").write_text("\n".join(imu_lines) + "\n")
    if ground_truth:
        gt = mav0 / "state_groundtruth_estimate0"
        gt.mkdir()
        (gt / "sensor.yaml").write_text(GT_YAML)
        lines = [GT_HEADER]
        for i in range(GT_COUNT):
            t = GT_START_NS + i * IMU_NS
            T = _body_pose(t)
            q = Rotation.from_matrix(T[:3, :3]).as_quat(scalar_first=True)
            values = [*T[:3, 3], *q, *V_WORLD, -0.002, 0.021, 0.076, -0.025, 0.137, 0.076]
            lines.append(",".join([str(t)] + [repr(float(v)) for v in values]))
        (gt / "data.csv").write_text("\n".join(lines) + "\n")
    return root


@pytest.fixture
def euroc(tmp_path: pathlib.Path) -> pathlib.Path:
    return write_euroc(tmp_path / "V1_01_tiny")


def test_frames_are_the_common_timestamps(euroc: pathlib.Path) -> None:
    dataset = EurocDataset(euroc)
    assert len(dataset) == len(FRAME_K) == 9
    np.testing.assert_array_equal(dataset.timestamps_ns, [T0_NS + k * FRAME_NS for k in FRAME_K])
    assert dataset.timestamps_ns.dtype == np.int64
    assert dataset.unpaired_images == (2, 0)
    left, right = dataset.raw_pair(3)  # the fourth stereo frame is k = 4
    assert left.dtype == np.uint8 and left.shape == (HEIGHT, WIDTH)
    np.testing.assert_array_equal(left, _image("cam0", 4))
    np.testing.assert_array_equal(right, _image("cam1", 4))
    assert dataset.image_paths(-1)[1].name == f"{T0_NS + 9 * FRAME_NS}.png"
    rect0, rect1 = dataset.rectified_pair(0)
    assert rect0.shape == rect1.shape == (HEIGHT, WIDTH) and rect0.dtype == np.uint8
    with pytest.raises(IndexError):
        dataset.raw_pair(len(dataset))


def test_imu_between_frames(euroc: pathlib.Path) -> None:
    dataset = EurocDataset(euroc)
    assert len(dataset.imu) == IMU_COUNT
    t = dataset.timestamps_ns
    imu = dataset.imu_between(int(t[0]), int(t[1]))
    assert len(imu) == FRAME_NS // IMU_NS
    assert imu.timestamp_ns[0] > t[0] and imu.timestamp_ns[-1] == t[1]  # (t0, t1]
    np.testing.assert_allclose(imu.gyro[0], [0.01 * 0.1, -0.02 * 0.1, 0.03])
    np.testing.assert_allclose(imu.accel[0], [9.81, 0.01, -0.2])
    assert len(dataset.imu_between(int(t[2]), int(t[3]))) == 2 * FRAME_NS // IMU_NS  # across the missing k = 3
    assert len(dataset.imu_between(int(t[0]), int(t[0]))) == 0
    counts = [len(dataset.imu_between(int(a), int(b))) for a, b in itertools.pairwise(t)]
    assert sum(counts) == (t[-1] - t[0]) // IMU_NS


def test_ground_truth_interpolated_and_expressed_for_the_cameras(euroc: pathlib.Path) -> None:
    dataset = EurocDataset(euroc)
    valid = dataset.ground_truth_valid
    assert not valid[0] and valid[1:].all()  # frame 0 precedes the first ground-truth sample
    assert np.isnan(dataset.T_world_cam0[0]).all() and np.isnan(dataset.T_world_rect0[0]).all()
    for i in range(1, len(dataset)):
        T_world_body = _body_pose(int(dataset.timestamps_ns[i]))
        np.testing.assert_allclose(dataset.T_world_body[i], T_world_body, atol=1e-9)
        np.testing.assert_allclose(dataset.T_world_cam0[i], T_world_body @ T_BODY_CAM0, atol=1e-9)
    # The rectified left camera differs from cam0 by the rectifying rotation only.
    R_rect0_cam0 = dataset.rectification.R_rect0_cam0
    T_cam0_rect0 = np.eye(4)
    T_cam0_rect0[:3, :3] = R_rect0_cam0.T
    np.testing.assert_allclose(dataset.T_world_rect0[1:], dataset.T_world_cam0[1:] @ T_cam0_rect0, atol=1e-12)
    np.testing.assert_allclose(dataset.rectification.T_body_rect0, T_BODY_CAM0 @ T_cam0_rect0, atol=1e-12)
    np.testing.assert_allclose(dataset.T_world_rect0[1:, :3, 3], dataset.T_world_cam0[1:, :3, 3])
    assert 0.0 < np.degrees(np.arccos((np.trace(R_rect0_cam0) - 1.0) / 2.0)) < 5.0
    truth = dataset.ground_truth
    assert truth is not None and len(truth) == GT_COUNT
    np.testing.assert_allclose(truth.v_world[0], V_WORLD)
    np.testing.assert_allclose(truth.accel_bias[0], [-0.025, 0.137, 0.076])
    # A gap longer than allowed between samples: only frames on a sample would keep a pose.
    strict = EurocDataset(euroc, max_ground_truth_gap_ns=1_000_000)
    assert not strict.ground_truth_valid.any()


def test_ground_truth_is_optional(tmp_path: pathlib.Path) -> None:
    dataset = EurocDataset(write_euroc(tmp_path / "no_gt", ground_truth=False))
    assert dataset.ground_truth is None
    assert not dataset.ground_truth_valid.any()
    assert dataset.T_world_rect0.shape == (len(dataset), 4, 4)


def test_mav0_folder_itself_is_accepted(euroc: pathlib.Path) -> None:
    assert len(EurocDataset(euroc / "mav0")) == len(FRAME_K)


def test_calibration_values(euroc: pathlib.Path) -> None:
    dataset = EurocDataset(euroc)
    cam1 = dataset.cam1
    assert (cam1.fx, cam1.fy, cam1.cx, cam1.cy) == tuple(INTRINSICS["cam1"])
    assert (cam1.width, cam1.height, cam1.rate_hz) == (WIDTH, HEIGHT, 20.0)
    np.testing.assert_allclose(cam1.distortion, DISTORTION["cam1"])
    np.testing.assert_allclose(dataset.cam0.T_body_camera, T_BODY_CAM0, atol=1e-12)
    imu = dataset.imu_calibration
    assert imu.rate_hz == 200.0
    assert imu.noise.gyroscope_noise_density == pytest.approx(1.6968e-04)
    assert imu.noise.accelerometer_random_walk == pytest.approx(3.0e-3)
    np.testing.assert_allclose(imu.T_body_imu, np.eye(4))
    # Stereo: cam1 relative to cam0 from the two T_BS; the baseline is its length.
    T_cam1_cam0 = np.linalg.inv(T_BODY_CAM1) @ T_BODY_CAM0
    np.testing.assert_allclose(dataset.rectification.T_cam1_cam0, T_cam1_cam0, atol=1e-9)
    camera = dataset.camera
    assert camera.baseline == pytest.approx(np.linalg.norm(T_cam1_cam0[:3, 3]), rel=1e-9)
    assert camera.baseline == pytest.approx(0.110, abs=0.001)
    assert camera.fx == camera.fy > 0.0 and (camera.width, camera.height) == (WIDTH, HEIGHT)
    # A point in rect0 lands on the same row in rect1 (P2 = K [I | -b e_x]).
    p_rect0 = np.array([0.3, -0.2, 2.0])
    uv0 = camera.project(p_rect0)
    uv1 = camera.project(p_rect0 - camera.offset_right)
    assert uv0[1] == pytest.approx(uv1[1]) and uv0[0] - uv1[0] == pytest.approx(camera.fx * camera.baseline / 2.0)


def test_yaml_without_directive_is_read(tmp_path: pathlib.Path) -> None:
    path = tmp_path / "sensor.yaml"
    path.write_text(IMU_YAML.removeprefix("%YAML:1.0\n"))
    assert read_imu_yaml(path).rate_hz == 200.0
    path.write_text(_camera_yaml("cam0", T_BODY_CAM0).replace("\n", "\r\n"))
    assert read_camera_yaml(path).cx == INTRINSICS["cam0"][2]


# --- bad input: (mutation of a good folder, path the message must name, line or None, words)


def _edit(relative: str, old: str, new: str, count: int = 1) -> Callable[[pathlib.Path], None]:
    def edit(root: pathlib.Path) -> None:
        path = root / relative
        text = path.read_text()
        assert old in text, old
        path.write_text(text.replace(old, new, count))

    return edit


def _edit_line(relative: str, line: int, edit: Callable[[str], str]) -> Callable[[pathlib.Path], None]:
    def apply(root: pathlib.Path) -> None:
        path = root / relative
        lines = path.read_text().split("\n")
        lines[line - 1] = edit(lines[line - 1])
        path.write_text("\n".join(lines))

    return apply


def _remove(relative: str) -> Callable[[pathlib.Path], None]:
    def remove(root: pathlib.Path) -> None:
        path = root / relative
        if path.is_dir():
            shutil.rmtree(path)
        else:
            path.unlink()

    return remove


def _first_image(camera: str) -> str:
    return f"mav0/{camera}/data/{T0_NS}.png"


def _set_field(column: int, value: str) -> Callable[[str], str]:
    def edit(line: str) -> str:
        fields = line.split(",")
        fields[column] = value
        return ",".join(fields)

    return edit


def _swap_extrinsics(root: pathlib.Path) -> None:
    (root / "mav0/cam0/sensor.yaml").write_text(_camera_yaml("cam0", T_BODY_CAM1))
    (root / "mav0/cam1/sensor.yaml").write_text(_camera_yaml("cam1", T_BODY_CAM0))


def _shift_cam1(root: pathlib.Path) -> None:
    path = root / "mav0/cam1/data.csv"
    lines = path.read_text().split("\n")
    path.write_text("\n".join([lines[0]] + [_set_field(0, str(int(s.split(",")[0]) + 1))(s) for s in lines[1:] if s]) + "\n")


BAD_INPUTS = {
    "missing cam1": (_remove("mav0/cam1"), "mav0/cam1", None, "missing folder"),
    "truncated imu row": (_edit_line("mav0/imu0/data.csv", 5, lambda s: s.rsplit(",", 2)[0]), "mav0/imu0/data.csv", 5, "truncated row"),
    "truncated camera row": (_edit_line("mav0/cam1/data.csv", 4, lambda s: s.split(",")[0]), "mav0/cam1/data.csv", 4, "truncated row"),
    "truncated ground truth row": (_edit_line("mav0/state_groundtruth_estimate0/data.csv", 9, lambda s: s[: len(s) // 2]), "mav0/state_groundtruth_estimate0/data.csv", 9, "truncated row"),
    "too many columns": (_edit_line("mav0/imu0/data.csv", 3, lambda s: s + ",1.0"), "mav0/imu0/data.csv", 3, "too many columns"),
    "non-numeric imu value": (_edit_line("mav0/imu0/data.csv", 8, _set_field(5, "9.8l")), "mav0/imu0/data.csv", 8, "non-numeric value '9.8l' in column a_RS_S_y"),
    "empty imu field": (_edit_line("mav0/imu0/data.csv", 8, _set_field(1, "")), "mav0/imu0/data.csv", 8, "empty field in column w_RS_S_x"),
    "non-numeric timestamp": (_edit_line("mav0/cam0/data.csv", 2, _set_field(0, "14037x")), "mav0/cam0/data.csv", 2, "timestamp '14037x'"),
    "non-numeric ground truth": (_edit_line("mav0/state_groundtruth_estimate0/data.csv", 4, _set_field(5, "abc")), "mav0/state_groundtruth_estimate0/data.csv", 4, "column q_RS_x"),
    "timestamps going back": (_edit_line("mav0/imu0/data.csv", 6, _set_field(0, str(T0_NS))), "mav0/imu0/data.csv", 6, "not after"),
    "nan in imu": (_edit_line("mav0/imu0/data.csv", 17, _set_field(2, "nan")), "mav0/imu0/data.csv", 17, "NaN in column w_RS_S_y"),
    "inf in imu": (_edit_line("mav0/imu0/data.csv", 11, _set_field(4, "inf")), "mav0/imu0/data.csv", 11, "infinite value in column a_RS_S_x"),
    "zero quaternion": (
        _edit_line("mav0/state_groundtruth_estimate0/data.csv", 3, lambda s: ",".join(s.split(",")[:4] + ["0", "0", "0", "0"] + s.split(",")[8:])),
        "mav0/state_groundtruth_estimate0/data.csv",
        3,
        "quaternion",
    ),
    "image listed but absent": (_remove(_first_image("cam1")), "mav0/cam1/data.csv", 2, _first_image("cam1")),
    "image folder absent": (_remove("mav0/cam0/data"), "mav0/cam0/data", None, "missing folder"),
    "yaml without intrinsics": (_edit("mav0/cam0/sensor.yaml", "intrinsics:", "# intrinsics:"), "mav0/cam0/sensor.yaml", None, "missing key 'intrinsics'"),
    "yaml intrinsics too short": (_edit("mav0/cam1/sensor.yaml", "intrinsics: [40.0, ", "intrinsics: ["), "mav0/cam1/sensor.yaml", None, "'intrinsics' must be a list of 4 numbers"),
    "yaml intrinsic not a number": (_edit("mav0/cam1/sensor.yaml", "intrinsics: [40.0", "intrinsics: [forty"), "mav0/cam1/sensor.yaml", None, "'intrinsics' entry 1 must be a number"),
    "yaml without T_BS": (_edit("mav0/imu0/sensor.yaml", "T_BS:", "T_SB:"), "mav0/imu0/sensor.yaml", None, "missing key 'T_BS'"),
    "yaml T_BS 3x4": (_edit("mav0/cam0/sensor.yaml", "rows: 4", "rows: 3"), "mav0/cam0/sensor.yaml", None, "4x4 matrix"),
    "yaml T_BS not rigid": (_edit("mav0/cam1/sensor.yaml", "[0.0125552670891", "[1.0125552670891"), "mav0/cam1/sensor.yaml", None, "not a rotation"),
    "yaml missing imu noise": (_edit("mav0/imu0/sensor.yaml", "gyroscope_random_walk:", "gyro_random_walk:"), "mav0/imu0/sensor.yaml", None, "missing key 'gyroscope_random_walk'"),
    "yaml syntax": (_edit("mav0/cam0/sensor.yaml", "  rows: 4", "  rows 4"), "mav0/cam0/sensor.yaml", 9, "not valid OpenCV YAML"),
    "yaml tab": (_edit("mav0/imu0/sensor.yaml", "  cols: 4", "\tcols: 4"), "mav0/imu0/sensor.yaml", 8, "Tabs"),
    "yaml fov model": (_edit("mav0/cam0/sensor.yaml", "radial-tangential", "fov"), "mav0/cam0/sensor.yaml", None, "distortion_model 'fov' is not supported"),
    "yaml one fisheye": (_edit("mav0/cam0/sensor.yaml", "radial-tangential", "equidistant"), "mav0/cam1/sensor.yaml", None, "differs from cam0's pinhole-equi"),
    "yaml missing file": (_remove("mav0/cam1/sensor.yaml"), "mav0/cam1/sensor.yaml", None, "missing file"),
    "imu csv missing": (_remove("mav0/imu0/data.csv"), "mav0/imu0/data.csv", None, "missing file"),
    "resolution mismatch": (_edit("mav0/cam1/sensor.yaml", f"resolution: [{WIDTH}, {HEIGHT}]", "resolution: [64, 48]"), "mav0/cam1/sensor.yaml", None, "differs from cam0"),
    "cameras swapped": (_swap_extrinsics, "mav0/cam1/sensor.yaml", None, "not to the right of cam0"),
    "no common timestamps": (_shift_cam1, "mav0/cam1/data.csv", None, "no timestamp in common"),
}


def _assert_one_line(error: DatasetError, root: pathlib.Path, path: str, line: int | None, words: str) -> None:
    message = str(error)
    assert type(error) is DatasetError
    assert "\n" not in message and "\r" not in message
    assert str(root / path) in message, message
    if line is not None:
        assert f"{path} line {line}: " in message, message
    else:
        assert " line " not in message.split(": ", 1)[0], message
    assert words in message, message
    assert "Traceback" not in message and "OpenCV(" not in message


@pytest.mark.parametrize("case", list(BAD_INPUTS))
def test_bad_input_is_a_one_line_dataset_error(tmp_path: pathlib.Path, case: str) -> None:
    mutate, path, line, words = BAD_INPUTS[case]
    root = write_euroc(tmp_path / "seq")
    mutate(root)
    with pytest.raises(DatasetError) as caught:
        EurocDataset(root)
    _assert_one_line(caught.value, root, path, line, words)


def test_nan_message_matches_the_design(tmp_path: pathlib.Path, monkeypatch: pytest.MonkeyPatch) -> None:
    write_euroc(tmp_path / "seq")
    _edit_line("mav0/imu0/data.csv", 17, _set_field(2, "NaN"))(tmp_path / "seq")
    monkeypatch.chdir(tmp_path / "seq")
    with pytest.raises(DatasetError) as caught:
        EurocDataset(".")
    assert str(caught.value) == "mav0/imu0/data.csv line 17: NaN in column w_RS_S_y"


@pytest.mark.parametrize("kind", ["missing", "file", "no mav0"])
def test_bad_dataset_path(tmp_path: pathlib.Path, kind: str) -> None:
    path = tmp_path / "dataset"
    if kind == "file":
        path.write_text("not a folder")
    elif kind == "no mav0":
        (path / "cam0").mkdir(parents=True)
    with pytest.raises(DatasetError) as caught:
        EurocDataset(path)
    message = str(caught.value)
    assert message.startswith(f"{path}: ") and "\n" not in message
    assert {"missing": "no such folder", "file": "not a folder", "no mav0": "no mav0 folder"}[kind] in message


def test_unreadable_image_is_reported_when_loaded(euroc: pathlib.Path) -> None:
    image = euroc / _first_image("cam1")
    image.write_bytes(b"not a png")
    dataset = EurocDataset(euroc)
    with pytest.raises(DatasetError) as caught:
        dataset.raw_pair(0)
    _assert_one_line(caught.value, euroc, _first_image("cam1"), None, "not a readable image")
    cv2.imwrite(str(image), np.zeros((HEIGHT + 1, WIDTH), dtype=np.uint8))
    with pytest.raises(DatasetError) as caught:
        dataset.rectified_pair(0)
    _assert_one_line(caught.value, euroc, _first_image("cam1"), None, f"image is {WIDTH}x{HEIGHT + 1}")


def test_ground_truth_sensor_extrinsics(euroc: pathlib.Path) -> None:
    """The file holds `T_world_S`; the body pose is `T_world_S T_BS⁻¹` (identity without T_BS)."""
    truth_yaml = euroc / "mav0/state_groundtruth_estimate0/sensor.yaml"
    T_body_sensor = np.eye(4)
    T_body_sensor[:3, :3] = Rotation.from_rotvec([0.0, 0.3, 0.1]).as_matrix()
    T_body_sensor[:3, 3] = [0.1, -0.05, 0.02]
    truth_yaml.write_text(GT_YAML.replace(_matrix(np.eye(4)), _matrix(T_body_sensor)))
    dataset = EurocDataset(euroc)
    T_world_sensor = _body_pose(int(dataset.timestamps_ns[4]))
    # Body positions interpolate linearly between 5 ms samples, while the lever arm turns: 1e-7 m.
    np.testing.assert_allclose(dataset.T_world_body[4], T_world_sensor @ np.linalg.inv(T_body_sensor), atol=1e-6)
    truth_yaml.write_text("%YAML:1.0\nsensor_type: visual-inertial\ncomment: no extrinsics\n")
    np.testing.assert_allclose(EurocDataset(euroc).T_world_body[4], T_world_sensor, atol=1e-9)


# --- folders as users have them (DESIGN §8): no imu0, longer camera lists, JPEG images


def _assert_no_imu(dataset: EurocDataset, root: pathlib.Path, path: str, words: str) -> None:
    """`has_imu` False; asking for IMU data is one line naming `path`, and says VIO needs it."""
    assert dataset.has_imu is False
    for ask in (lambda: dataset.imu_between(int(dataset.timestamps_ns[0]), int(dataset.timestamps_ns[1])), lambda: dataset.imu):
        with pytest.raises(DatasetError) as caught:
            ask()
        _assert_one_line(caught.value, root, path, None, words)
        assert "IMU data is needed for VIO" in str(caught.value)


def test_folder_without_imu0_loads_for_stereo(euroc: pathlib.Path) -> None:
    with_imu = EurocDataset(euroc)
    assert with_imu.has_imu is True
    _remove("mav0/imu0")(euroc)
    dataset = EurocDataset(euroc)
    assert len(dataset) == len(FRAME_K)
    np.testing.assert_array_equal(dataset.timestamps_ns, with_imu.timestamps_ns)
    left, right = dataset.raw_pair(3)
    np.testing.assert_array_equal(left, _image("cam0", 4))
    np.testing.assert_array_equal(right, _image("cam1", 4))
    np.testing.assert_allclose(dataset.T_world_rect0[1:], with_imu.T_world_rect0[1:])
    _assert_no_imu(dataset, euroc, "mav0/imu0", "mav0/imu0: missing folder")
    with pytest.raises(DatasetError, match="imu0: missing folder"):
        dataset.imu_calibration  # noqa: B018


def test_imu0_with_a_header_only_is_no_imu_data(euroc: pathlib.Path) -> None:
    """A header-only (or all rows commented out) imu0/data.csv: no IMU data, as without imu0;
    its sensor.yaml is still read (and must be valid)."""
    (euroc / "mav0/imu0/data.csv").write_text(IMU_HEADER + "\n")
    dataset = EurocDataset(euroc)
    assert len(dataset) == len(FRAME_K)
    _assert_no_imu(dataset, euroc, "mav0/imu0/data.csv", "no data rows")
    assert dataset.imu_calibration.rate_hz == 200.0
    _edit("mav0/imu0/data.csv", "\n", "\n#")(euroc)  # header line then a commented line: the same
    assert EurocDataset(euroc).has_imu is False
    _edit("mav0/imu0/sensor.yaml", "T_BS:", "T_SB:")(euroc)
    with pytest.raises(DatasetError, match="missing key 'T_BS'"):
        EurocDataset(euroc)


def _append_rows(relative: str, stamps: list[int], suffix: str = ".png") -> Callable[[pathlib.Path], None]:
    def append(root: pathlib.Path) -> None:
        path = root / relative
        path.write_text(path.read_text() + "".join(f"{t},{t}{suffix}\n" for t in stamps))

    return append


def test_camera_rows_outside_the_stereo_set_are_ignored(euroc: pathlib.Path) -> None:
    """cam1 lists more timestamps than cam0 (after its end), with no image on disk; cam0 lists
    k = 3 and k = 10, absent from cam1, and their images are deleted: the stereo frames are the
    intersection and nothing outside it is looked for."""
    extra = [T0_NS + k * FRAME_NS for k in range(11, 16)]
    _append_rows("mav0/cam1/data.csv", extra)(euroc)
    for k in (3, 10):
        (euroc / f"mav0/cam0/data/{T0_NS + k * FRAME_NS}.png").unlink()
    dataset = EurocDataset(euroc)
    np.testing.assert_array_equal(dataset.timestamps_ns, [T0_NS + k * FRAME_NS for k in FRAME_K])
    assert dataset.unpaired_images == (2, len(extra))
    np.testing.assert_array_equal(dataset.raw_pair(-1)[1], _image("cam1", 9))


def test_image_missing_inside_the_stereo_set_is_one_line(euroc: pathlib.Path) -> None:
    """k = 5 is a stereo frame (line 7 of cam0/data.csv, header on line 1): its absent image is
    an error at load naming the list, the line and the image, not a dropped frame."""
    _append_rows("mav0/cam1/data.csv", [T0_NS + 20 * FRAME_NS])(euroc)  # an ignored row beside it
    image = f"mav0/cam0/data/{T0_NS + 5 * FRAME_NS}.png"
    (euroc / image).unlink()
    with pytest.raises(DatasetError) as caught:
        EurocDataset(euroc)
    _assert_one_line(caught.value, euroc, "mav0/cam0/data.csv", 7, f"image {euroc / image} is listed but absent")


def test_no_common_timestamp_names_both_lists(tmp_path: pathlib.Path) -> None:
    root = write_euroc(tmp_path / "seq")
    _shift_cam1(root)
    with pytest.raises(DatasetError) as caught:
        EurocDataset(root)
    _assert_one_line(caught.value, root, "mav0/cam1/data.csv", None, "no timestamp in common")
    assert str(root / "mav0/cam0/data.csv") in str(caught.value)


def test_jpeg_images_named_in_data_csv_load(euroc: pathlib.Path) -> None:
    """JPEG (as the shared MH_01 slice): the lists name .jpg files; frames decode to grayscale."""
    for camera in ("cam0", "cam1"):
        csv = euroc / f"mav0/{camera}/data.csv"
        for png in sorted((euroc / f"mav0/{camera}/data").glob("*.png")):
            cv2.imwrite(str(png.with_suffix(".jpg")), cv2.imread(str(png), cv2.IMREAD_GRAYSCALE), [cv2.IMWRITE_JPEG_QUALITY, 100])
            png.unlink()
        csv.write_bytes(csv.read_bytes().replace(b".png", b".jpg"))
    dataset = EurocDataset(euroc)
    assert len(dataset) == len(FRAME_K) and dataset.image_paths(0)[0].suffix == ".jpg"
    left, right = dataset.raw_pair(3)
    assert left.dtype == np.uint8 and left.shape == (HEIGHT, WIDTH)
    # JPEG is lossy even at quality 100 on noise: close, not equal.
    assert np.abs(left.astype(int) - _image("cam0", 4)).mean() < 4.0
    assert dataset.rectified_pair(0)[0].shape == (HEIGHT, WIDTH)


MH01_SLICE = pathlib.Path(__file__).resolve().parents[3] / ".." / "shared" / "data" / "euroc_mh01_slice"


@pytest.mark.skipif(not MH01_SLICE.is_dir(), reason="shared MH_01 slice absent")
def test_real_mh01_slice_without_imu0_and_with_jpeg() -> None:
    dataset = EurocDataset(MH01_SLICE)
    assert len(dataset) == 300 and dataset.has_imu is False
    assert dataset.image_paths(0)[0].suffix == ".jpg"
    assert dataset.ground_truth_valid.all()
    left, right = dataset.raw_pair(0)
    assert left.shape == right.shape == (480, 752) and left.dtype == np.uint8
    assert dataset.camera.baseline == pytest.approx(0.110, abs=0.001)
    with pytest.raises(DatasetError, match="imu0: missing folder: IMU data is needed for VIO"):
        dataset.imu_between(int(dataset.timestamps_ns[0]), int(dataset.timestamps_ns[1]))
