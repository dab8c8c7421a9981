"""Camera models, Kalibr files and equidistant (fisheye) rectification
(backend/data/calibration.py): a TUM-VI-like camchain reads with the IMU as the body and
rectifies to row-aligned pinhole images; radial-tangential rectification is OpenCV's own,
unchanged; every bad Kalibr file is one DatasetError line naming it."""

from __future__ import annotations

import pathlib

import cv2
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from backend.data.calibration import (
    CameraCalibration,
    CameraModel,
    read_camera_yaml,
    read_kalibr_camchain,
    read_kalibr_imu,
    stereo_rectification,
)
from backend.data.errors import DatasetError
from backend.data.euroc_writer import camera_sensor_yaml
from backend.geometry.camera import PinholeCamera

# TUM-VI's 512_16 calibration (cam0, cam1: intrinsics and equidistant k1..k4); the
# extrinsics are TUM-VI-like: cam0 looking along the IMU's -y, cam1 10 cm to its right.
CAM0_INTRINSICS = (190.97847715128717, 190.9733070521226, 254.93170605935475, 256.8974428996504)
CAM1_INTRINSICS = (190.44236969414825, 190.4344384721956, 252.59949716835982, 254.91723064636983)
CAM0_K = (0.0034823894022493434, 0.0007150348452162257, -0.0020532361418706202, 0.00020293673591811182)
CAM1_K = (0.0034003170790442797, 0.001766278153469831, -0.00266312569781606, 0.0003299517423931039)
T_CAM0_IMU = np.array(
    [
        [-0.9995250378696743, 0.0075019185074052044, -0.02989013031643309, 0.045574835649698026],
        [0.029615343885863205, -0.03439736061393144, -0.998969345370175, -0.071161801837997044],
        [-0.008522328211654736, -0.9993800792498829, 0.03415885127385616, -0.044681254117144367],
        [0.0, 0.0, 0.0, 1.0],
    ]
)
T_CAM1_CAM0 = np.eye(4)
T_CAM1_CAM0[:3, :3] = Rotation.from_rotvec([0.0025, -0.0007, 0.0008]).as_matrix()
T_CAM1_CAM0[:3, 3] = [-0.10106, -0.00198, 0.00117]


def _rows(T: np.ndarray) -> str:
    return "".join(f"  - [{', '.join(repr(float(x)) for x in row)}]\n" for row in T)


def tumvi_camchain(*, cam1_T: str = "T_cn_cnm1", distortion_model: str = "equidistant", camera_model: str = "pinhole") -> str:
    """A camchain in Kalibr's PyYAML layout (sequences at their key's indentation, a flow
    list wrapped over two lines), as TUM-VI's `dso/camchain.yaml`."""
    cam1_extrinsics = f"  {cam1_T}:\n" + _rows(T_CAM1_CAM0 if cam1_T == "T_cn_cnm1" else T_CAM1_CAM0 @ T_CAM0_IMU)
    return (
        "cam0:\n  T_cam_imu:\n" + _rows(T_CAM0_IMU) + "  cam_overlaps: [1]\n"
        f"  camera_model: {camera_model}\n"
        f"  distortion_coeffs: [{CAM0_K[0]!r}, {CAM0_K[1]!r}, {CAM0_K[2]!r},\n    {CAM0_K[3]!r}]\n"
        f"  distortion_model: {distortion_model}\n"
        f"  intrinsics: [{', '.join(map(repr, CAM0_INTRINSICS))}]\n"
        "  resolution: [512, 512]\n  rostopic: /cam0/image_raw\n"
        "  timeshift_cam_imu: 0.0\n"
        "cam1:\n" + cam1_extrinsics + "  cam_overlaps: [0]\n  camera_model: pinhole\n"
        f"  distortion_coeffs: [{', '.join(map(repr, CAM1_K))}]\n"
        "  distortion_model: equidistant\n"
        f"  intrinsics: [{', '.join(map(repr, CAM1_INTRINSICS))}]\n"
        "  resolution: [512, 512]\n  rostopic: /cam1/image_raw\n"
    )


@pytest.fixture
def camchain(tmp_path: pathlib.Path) -> pathlib.Path:
    path = tmp_path / "camchain.yaml"
    path.write_text(tumvi_camchain())
    return path


@pytest.mark.parametrize("cam1_T", ["T_cn_cnm1", "T_cam_imu"])
def test_kalibr_camchain_has_the_imu_as_the_body(tmp_path: pathlib.Path, cam1_T: str) -> None:
    path = tmp_path / "camchain.yaml"
    path.write_text(tumvi_camchain(cam1_T=cam1_T))
    cam0, cam1 = read_kalibr_camchain(path)
    for cam, intrinsics, k in ((cam0, CAM0_INTRINSICS, CAM0_K), (cam1, CAM1_INTRINSICS, CAM1_K)):
        assert cam.model == CameraModel.EQUIDISTANT and (cam.width, cam.height) == (512, 512)
        assert (cam.fx, cam.fy, cam.cx, cam.cy) == intrinsics
        np.testing.assert_array_equal(cam.distortion, k)
        assert cam.source == str(path)
    np.testing.assert_allclose(cam0.T_body_camera, np.linalg.inv(T_CAM0_IMU), atol=1e-12)
    np.testing.assert_allclose(np.linalg.inv(cam1.T_body_camera) @ cam0.T_body_camera, T_CAM1_CAM0, atol=1e-12)


def test_equidistant_rectification_is_row_aligned(camchain: pathlib.Path) -> None:
    cam0, cam1 = read_kalibr_camchain(camchain)
    rect = stereo_rectification(cam0, cam1)
    camera = rect.camera
    # The rectified camera of the module docstring: raw size, the smaller focal length, the mean principal point.
    assert (camera.width, camera.height) == (512, 512)
    assert camera.fx == camera.fy == min(*CAM0_INTRINSICS[:2], *CAM1_INTRINSICS[:2])
    assert (camera.cx, camera.cy) == pytest.approx((0.5 * (CAM0_INTRINSICS[2] + CAM1_INTRINSICS[2]), 0.5 * (CAM0_INTRINSICS[3] + CAM1_INTRINSICS[3])))
    assert camera.baseline == pytest.approx(np.linalg.norm(T_CAM1_CAM0[:3, 3]), abs=1e-12)
    # Points seen by both fisheyes land on one rectified row, at disparity f b / z.
    rng = np.random.default_rng(0)
    p_rect0 = np.column_stack([rng.uniform(-2, 2, 50), rng.uniform(-2, 2, 50), rng.uniform(1.0, 6.0, 50)])
    p_cam0 = p_rect0 @ rect.R_rect0_cam0  # R_rect0_cam0ᵀ p_rect0, row-wise
    p_cam1 = p_cam0 @ rect.T_cam1_cam0[:3, :3].T + rect.T_cam1_cam0[:3, 3]
    uv = []
    for cam, R, P, p in ((cam0, rect.R_rect0_cam0, rect.P_rect0, p_cam0), (cam1, rect.R_rect1_cam1, rect.P_rect1, p_cam1)):
        raw, _ = cv2.fisheye.projectPoints(p[:, None, :], np.zeros(3), np.zeros(3), cam.K, cam.distortion)
        uv.append(cv2.fisheye.undistortPoints(raw, cam.K, cam.distortion, R=R, P=P[:, :3])[:, 0, :])
    np.testing.assert_allclose(uv[0], camera.project(p_rect0), atol=1e-6)
    np.testing.assert_allclose(uv[1][:, 1], uv[0][:, 1], atol=1e-6)
    np.testing.assert_allclose(uv[0][:, 0] - uv[1][:, 0], camera.fx * camera.baseline / p_rect0[:, 2], atol=1e-6)


def test_equidistant_maps_look_up_the_raw_pixel_of_each_rectified_ray(camchain: pathlib.Path) -> None:
    cam0, cam1 = read_kalibr_camchain(camchain)
    rect = stereo_rectification(cam0, cam1)
    x0, y0, _, _ = rect.maps
    v, u = np.mgrid[0:512:37, 0:512:41]
    rays_rect0 = rect.camera.normalize(np.stack([u.ravel(), v.ravel()], axis=-1).astype(float))
    raw, _ = cv2.fisheye.projectPoints((rays_rect0 @ rect.R_rect0_cam0)[:, None, :], np.zeros(3), np.zeros(3), cam0.K, cam0.distortion)
    np.testing.assert_allclose(np.column_stack([x0[v, u].ravel(), y0[v, u].ravel()]), raw[:, 0, :], atol=1e-3)
    # Every rectified pixel, corners included, lies inside the 512x512 fisheye image.
    assert 0.0 <= x0.min() and x0.max() <= 511.0 and 0.0 <= y0.min() and y0.max() <= 511.0


def test_radial_tangential_rectification_is_opencvs_unchanged(tmp_path: pathlib.Path) -> None:
    """The EuRoC path: the same OpenCV calls as before the equidistant model, bit for bit."""
    camera = PinholeCamera(fx=458.654, fy=457.296, cx=367.215, cy=248.375, width=752, height=480)
    T1 = np.eye(4)
    T1[:3, :3] = Rotation.from_rotvec([0.01, -0.02, 0.005]).as_matrix()
    T1[:3, 3] = [0.11, 0.001, -0.002]
    for name, T in (("cam0", np.eye(4)), ("cam1", T1)):
        text = camera_sensor_yaml(camera, T, rate_hz=20.0, comment=name).replace("[0.0, 0.0, 0.0, 0.0]", "[-0.28340811, 0.07395907, 0.00019359, 1.76187114e-05]")
        (tmp_path / f"{name}.yaml").write_text(text)
    cam0, cam1 = read_camera_yaml(tmp_path / "cam0.yaml"), read_camera_yaml(tmp_path / "cam1.yaml")
    assert cam0.model == CameraModel.RADIAL_TANGENTIAL
    rect = stereo_rectification(cam0, cam1)
    T_cam1_cam0 = np.linalg.inv(cam1.T_body_camera) @ cam0.T_body_camera
    R1, R2, P1, P2, *_ = cv2.stereoRectify(cam0.K, cam0.distortion, cam1.K, cam1.distortion, (752, 480), T_cam1_cam0[:3, :3], T_cam1_cam0[:3, 3], flags=cv2.CALIB_ZERO_DISPARITY, alpha=0.0)
    for ours, theirs in ((rect.R_rect0_cam0, R1), (rect.R_rect1_cam1, R2), (rect.P_rect0, P1), (rect.P_rect1, P2)):
        np.testing.assert_array_equal(ours, theirs)
    np.testing.assert_array_equal(rect.maps[0], cv2.initUndistortRectifyMap(cam0.K, cam0.distortion, R1, P1, (752, 480), cv2.CV_32FC1)[0])
    assert rect.camera.fx == P1[0, 0] and rect.camera.baseline == -P2[0, 3] / P2[0, 0]


def test_an_equidistant_sensor_yaml_reads(tmp_path: pathlib.Path) -> None:
    camera = PinholeCamera(fx=190.0, fy=190.5, cx=255.0, cy=256.0, width=512, height=512)
    text = camera_sensor_yaml(camera, np.eye(4), rate_hz=20.0, comment="fisheye").replace("radial-tangential", "equidistant")
    (tmp_path / "sensor.yaml").write_text(text)
    cam = read_camera_yaml(tmp_path / "sensor.yaml")
    assert cam.model == CameraModel.EQUIDISTANT and cam.distortion.shape == (4,)
    (tmp_path / "sensor.yaml").write_text(text.replace("[0.0, 0.0, 0.0, 0.0]", "[0.0, 0.0, 0.0, 0.0, 0.0]"))
    with pytest.raises(DatasetError, match="'distortion_coefficients' must be a list of 4 numbers"):
        read_camera_yaml(tmp_path / "sensor.yaml")


def test_mixed_models_are_one_line_naming_cam1(camchain: pathlib.Path) -> None:
    cam0, cam1 = read_kalibr_camchain(camchain)
    radtan = CameraCalibration(cam1.fx, cam1.fy, cam1.cx, cam1.cy, 512, 512, np.zeros(4), cam1.T_body_camera, 20.0, source="cam1.yaml")
    with pytest.raises(DatasetError, match=r"^cam1.yaml: cam1's camera model pinhole-radtan differs from cam0's pinhole-equi"):
        stereo_rectification(cam0, radtan)


def test_a_vertical_fisheye_rig_is_refused(camchain: pathlib.Path) -> None:
    cam0, cam1 = read_kalibr_camchain(camchain)
    T = np.eye(4)
    T[:3, 3] = [0.0, 0.1, 0.0]  # cam1 below cam0
    below = CameraCalibration(cam1.fx, cam1.fy, cam1.cx, cam1.cy, 512, 512, cam1.distortion, cam0.T_body_camera @ T, 0.0, source="x", model=CameraModel.EQUIDISTANT)
    with pytest.raises(DatasetError, match="not to the right of cam0"):
        stereo_rectification(cam0, below)


BAD_CAMCHAINS = {
    "omni camera": (lambda t: t.replace("camera_model: pinhole", "camera_model: omni", 1), "cam0.camera_model 'omni' is not supported (only pinhole)"),
    "fov distortion": (lambda t: t.replace("distortion_model: equidistant", "distortion_model: fov", 1), "cam0.distortion_model 'fov' is not supported (only radial-tangential or equidistant)"),
    "no T_cam_imu": (lambda t: t.replace("T_cam_imu:", "T_imu_cam:", 1), "missing key 'cam0.T_cam_imu'"),
    "no cam1 pose": (lambda t: t.replace("T_cn_cnm1:", "T_other:"), "missing key 'cam1.T_cn_cnm1' (or 'cam1.T_cam_imu')"),
    "no cam1": (lambda t: t.replace("cam1:", "cam2:"), "missing key 'cam1'"),
    "no intrinsics": (lambda t: t.replace("  intrinsics:", "  focal:", 1), "missing key 'cam0.intrinsics'"),
    "five k": (lambda t: t.replace("    0.00020293673591811182]", "    0.00020293673591811182, 0.1]"), "'cam0.distortion_coeffs' must be a list of 4 numbers"),
    "three intrinsics": (lambda t: t.replace("[190.97847715128717, ", "[", 1), "'cam0.intrinsics' must be a list of 4 numbers"),
    "text intrinsic": (lambda t: t.replace("190.97847715128717", "f", 1), "'cam0.intrinsics' entry 1 must be a number, got 'f'"),
    "zero focal": (lambda t: t.replace("190.97847715128717", "0.0", 1), "'cam0.intrinsics' focal lengths fu, fv must be positive"),
    "bad resolution": (lambda t: t.replace("[512, 512]", "[512.5, 512]", 1), "'cam0.resolution' must be two positive integers"),
    "3x4 transform": (lambda t: t.replace("  - [0.0, 0.0, 0.0, 1.0]\n  cam_overlaps: [1]", "  cam_overlaps: [1]"), "'cam0.T_cam_imu' must be a 4x4 matrix"),
    "not a rotation": (lambda t: t.replace("-0.9995250378696743", "-1.9995250378696743"), "'cam0.T_cam_imu' rotation part is not a rotation matrix"),
    "not YAML": (lambda t: t.replace("  resolution: [512, 512]", "  resolution: [512, 512", 1), "not valid YAML"),
    "a list": (lambda t: "- cam0\n- cam1\n", "expected `key: value` entries at the top level"),
    "cam0 a name": (lambda t: "cam0: left\n" + t.split("cam1:", 1)[1].join(["cam1:", ""]), "'cam0' must hold `key: value` entries"),
}


@pytest.mark.parametrize("case", sorted(BAD_CAMCHAINS))
def test_bad_camchain_is_one_line_naming_the_file(tmp_path: pathlib.Path, case: str) -> None:
    edit, words = BAD_CAMCHAINS[case]
    path = tmp_path / "camchain.yaml"
    text = edit(tumvi_camchain())
    assert text != tumvi_camchain()
    path.write_text(text)
    with pytest.raises(DatasetError) as error:
        read_kalibr_camchain(path)
    message = str(error.value)
    assert message.startswith(str(path)) and words in message and "\n" not in message, message


def test_invalid_yaml_names_the_line(tmp_path: pathlib.Path) -> None:
    path = tmp_path / "camchain.yaml"
    path.write_text("cam0:\n  intrinsics: [1, 2\n  resolution: [1, 2]\n")
    with pytest.raises(DatasetError, match=r"camchain.yaml line \d: not valid YAML"):
        read_kalibr_camchain(path)


def test_missing_camchain_names_it(tmp_path: pathlib.Path) -> None:
    with pytest.raises(DatasetError, match="camchain.yaml: missing file"):
        read_kalibr_camchain(tmp_path / "camchain.yaml")


KALIBR_IMU = "accelerometer_noise_density: 0.0028\naccelerometer_random_walk: 0.00086\ngyroscope_noise_density: 0.00016\ngyroscope_random_walk: 2.2e-05\nrostopic: /imu0\nupdate_rate: 200.0\n"


@pytest.mark.parametrize("text", [KALIBR_IMU, "imu0:\n" + "".join(f"  {line}\n" for line in KALIBR_IMU.splitlines()), KALIBR_IMU.replace("2.2e-05", "2.2e-5")])
def test_kalibr_imu_noise(tmp_path: pathlib.Path, text: str) -> None:
    path = tmp_path / "imu_config.yaml"
    path.write_text(text)
    imu = read_kalibr_imu(path)
    assert imu.rate_hz == 200.0 and imu.noise.gyroscope_random_walk == 2.2e-05 and imu.noise.accelerometer_noise_density == 0.0028
    np.testing.assert_array_equal(imu.T_body_imu, np.eye(4))


@pytest.mark.parametrize(
    ("edit", "words"),
    [
        (lambda t: t.replace("update_rate: 200.0", "update_rate: 0"), "'update_rate' must be positive"),
        (lambda t: t.replace("gyroscope_noise_density: 0.00016\n", ""), "missing key 'gyroscope_noise_density'"),
        (lambda t: t.replace("0.00086", "-0.00086"), "'accelerometer_random_walk' must not be negative"),
        (lambda t: t.replace("0.00086", "yes"), "'accelerometer_random_walk' must be a number"),
    ],
)
def test_bad_kalibr_imu_is_one_line(tmp_path: pathlib.Path, edit, words: str) -> None:
    path = tmp_path / "imu_config.yaml"
    path.write_text(edit(KALIBR_IMU))
    with pytest.raises(DatasetError) as error:
        read_kalibr_imu(path)
    assert str(error.value).startswith(str(path)) and words in str(error.value)
