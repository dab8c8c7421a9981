"""TUM-VI's EuRoC-style export (backend/data/tumvi.py) on a rendered sequence converted by
backend/data/tumvi_writer.py: the registry recognizes it before EuRoC, the rectified camera,
baseline and poses are the rendered ones, the rectified images match the rendered pinhole
images (two resamplings apart), the 16-bit images and Kalibr files read back, and bad files
are one line naming them."""

from __future__ import annotations

import pathlib
import shutil

import cv2
import numpy as np
import pytest
from PIL import Image

from backend.data.calibration import CameraModel, read_kalibr_camchain, read_kalibr_imu
from backend.data.errors import DatasetError
from backend.data.euroc import EurocDataset
from backend.data.scenes import builtin_scene
from backend.data.source import dataset_format, open_dataset
from backend.data.synthetic import SequenceSettings, render_sequence
from backend.data.tumvi import TumviDataset
from backend.data.tumvi_writer import FISHEYE_DISTORTION, camchain_yaml, convert, fisheye_from_pinhole_map

MAX_MEDIAN_GREY_DIFFERENCE = 3.0  # grey levels, inside the valid region


@pytest.fixture(scope="module")
def folders(tmp_path_factory: pytest.TempPathFactory) -> tuple[pathlib.Path, pathlib.Path]:
    """The `room` scene rendered for 0.5 s (11 frames) as EuRoC, and its TUM-VI conversion."""
    base = tmp_path_factory.mktemp("tumvi")
    render_sequence(builtin_scene("room"), base / "euroc", settings=SequenceSettings(duration_s=0.5, seed=0))
    convert(base / "euroc", base / "tumvi")
    return base / "euroc", base / "tumvi"


@pytest.fixture(scope="module")
def pair(folders: tuple[pathlib.Path, pathlib.Path]) -> tuple[EurocDataset, TumviDataset]:
    return EurocDataset(folders[0]), TumviDataset(folders[1])


def test_the_export_is_recognized_before_euroc(folders: tuple[pathlib.Path, pathlib.Path]) -> None:
    euroc, tumvi = folders
    assert dataset_format(tumvi).label == dataset_format(tumvi / "mav0").label == "TUM-VI folder"
    assert dataset_format(euroc).label == "EuRoC folder"
    for path in (tumvi, tumvi / "mav0"):
        source = open_dataset(path)
        assert isinstance(source, TumviDataset) and len(source) == 11
    assert not any((tumvi / "mav0" / name / "sensor.yaml").exists() for name in ("cam0", "cam1", "imu0"))  # dso/ is the calibration


def test_camera_baseline_and_poses_are_the_rendered_ones(pair: tuple[EurocDataset, TumviDataset]) -> None:
    euroc, tumvi = pair
    assert tumvi.cam0.model == tumvi.cam1.model == CameraModel.EQUIDISTANT
    a, b = tumvi.camera, euroc.camera
    np.testing.assert_allclose([a.fx, a.fy, a.cx, a.cy, a.baseline], [b.fx, b.fy, b.cx, b.cy, b.baseline], atol=1e-6)
    assert (a.width, a.height) == (b.width, b.height)
    np.testing.assert_array_equal(tumvi.timestamps_ns, euroc.timestamps_ns)
    np.testing.assert_array_equal(tumvi.ground_truth_valid, euroc.ground_truth_valid)
    valid = euroc.ground_truth_valid
    np.testing.assert_allclose(tumvi.T_world_rect0[valid], euroc.T_world_rect0[valid], atol=1e-6)
    np.testing.assert_allclose(tumvi.T_body_rect0, euroc.T_body_rect0, atol=1e-6)
    assert tumvi.ground_truth_frame == "body"
    np.testing.assert_array_equal(tumvi.T_truth_rect0, tumvi.T_body_rect0)


def test_imu_samples_and_noise_come_through(pair: tuple[EurocDataset, TumviDataset]) -> None:
    euroc, tumvi = pair
    np.testing.assert_array_equal(tumvi.imu.timestamp_ns, euroc.imu.timestamp_ns)
    np.testing.assert_array_equal(tumvi.imu.gyro, euroc.imu.gyro)
    assert tumvi.imu_noise == euroc.imu_noise and tumvi.imu_calibration.rate_hz == euroc.imu_calibration.rate_hz
    assert tumvi.imu_label.endswith("mav0/imu0/data.csv")


def _valid_region(euroc: EurocDataset, tumvi: TumviDataset) -> np.ndarray:
    """Rectified pixels whose value comes from the rendered image only (not the black band or
    the interpolation with it), 2 px inside."""
    white = np.full((euroc.cam0.height, euroc.cam0.width), 255, np.uint8)
    x, y = fisheye_from_pinhole_map(tumvi.cam0, euroc.cam0)
    fisheye = cv2.remap(white, x, y, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT)
    rectified, _ = tumvi.rectification.rectify(fisheye, fisheye)
    return cv2.erode((rectified == 255).astype(np.uint8), np.ones((5, 5), np.uint8)).astype(bool)


def test_rectified_images_match_the_rendered_pinhole_images(pair: tuple[EurocDataset, TumviDataset]) -> None:
    euroc, tumvi = pair
    valid = _valid_region(euroc, tumvi)
    assert valid.mean() > 0.95
    for index in (0, 5, 10):
        for ours, rendered in zip(tumvi.rectified_pair(index), euroc.rectified_pair(index)):
            difference = np.abs(ours.astype(int) - rendered.astype(int))[valid]
            print(f"frame {index}: median |difference| {np.median(difference):.1f}, mean {difference.mean():.2f} grey levels")
            assert np.median(difference) <= MAX_MEDIAN_GREY_DIFFERENCE


def test_sixteen_bit_images_keep_their_high_byte(folders: tuple[pathlib.Path, pathlib.Path], pair: tuple[EurocDataset, TumviDataset]) -> None:
    _, tumvi = pair
    path0, _ = tumvi.image_paths(3)
    stored = np.asarray(Image.open(path0))
    assert stored.dtype == np.uint16 and stored.max() > 255
    left, _ = tumvi.raw_pair(3)
    np.testing.assert_array_equal(left, (stored >> 8).astype(np.uint8))


def test_kalibr_files_read_back(folders: tuple[pathlib.Path, pathlib.Path], pair: tuple[EurocDataset, TumviDataset]) -> None:
    euroc, _ = pair
    cam0, cam1 = read_kalibr_camchain(folders[1] / "dso" / "camchain.yaml")
    for fisheye, pinhole, k in ((cam0, euroc.cam0, FISHEYE_DISTORTION[0]), (cam1, euroc.cam1, FISHEYE_DISTORTION[1])):
        assert fisheye.model == CameraModel.EQUIDISTANT and (fisheye.fx, fisheye.fy, fisheye.cx, fisheye.cy) == (pinhole.fx, pinhole.fy, pinhole.cx, pinhole.cy)
        np.testing.assert_array_equal(fisheye.distortion, k)
        np.testing.assert_allclose(fisheye.T_body_camera, pinhole.T_body_camera, atol=1e-12)
    again = folders[1].parent / "again.yaml"
    again.write_text(camchain_yaml(cam0, cam1))
    for a, b in zip((cam0, cam1), read_kalibr_camchain(again)):
        np.testing.assert_array_equal(a.distortion, b.distortion)
        np.testing.assert_allclose(a.T_body_camera, b.T_body_camera, atol=1e-15)
    assert read_kalibr_imu(folders[1] / "dso" / "imu_config.yaml").noise == euroc.imu_noise


@pytest.mark.parametrize(
    ("damage", "named", "words"),
    [
        (lambda r: (r / "dso" / "imu_config.yaml").unlink(), "dso/imu_config.yaml", "missing file"),
        (lambda r: shutil.rmtree(r / "mav0" / "cam1"), "mav0/cam1", "missing folder"),
        (lambda r: (r / "mav0" / "mocap0" / "data.csv").write_text("#t\n1,2,3\n"), "mav0/mocap0/data.csv", "truncated row"),
        (lambda r: _edit(r / "dso" / "camchain.yaml", "distortion_model: equidistant", "distortion_model: fov"), "dso/camchain.yaml", "distortion_model 'fov' is not supported"),
    ],
)
def test_a_broken_export_is_one_line_naming_the_file(folders: tuple[pathlib.Path, pathlib.Path], tmp_path: pathlib.Path, damage, named: str, words: str) -> None:
    root = tmp_path / "export"
    shutil.copytree(folders[1], root)
    damage(root)
    with pytest.raises(DatasetError) as error:
        open_dataset(root)
    message = str(error.value)
    assert str(root / named) in message and words in message and "\n" not in message, message


def test_without_imu0_it_loads_for_stereo(folders: tuple[pathlib.Path, pathlib.Path], tmp_path: pathlib.Path) -> None:
    root = tmp_path / "export"
    shutil.copytree(folders[1], root)
    shutil.rmtree(root / "mav0" / "imu0")
    (root / "dso" / "imu_config.yaml").unlink()  # not read without imu0
    source = TumviDataset(root)
    assert not source.has_imu and len(source) == 11
    with pytest.raises(DatasetError, match="imu0: missing folder: IMU data is needed for VIO"):
        source.imu_noise  # noqa: B018


def _edit(path: pathlib.Path, old: str, new: str) -> None:
    text = path.read_text()
    assert old in text
    path.write_text(text.replace(old, new))
