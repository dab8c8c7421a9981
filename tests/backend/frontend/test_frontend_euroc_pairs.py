"""Front end on the four real EuRoC V1_01 stereo pairs in the shared data folder."""

from __future__ import annotations

import functools
import pathlib

import cv2
import numpy as np
import pytest

from backend.data.calibration import (
    StereoRectification,
    read_camera_yaml,
    stereo_rectification,
)
from backend.frontend.lines import stereo_segments
from backend.frontend.points import stereo_points

PAIRS = pathlib.Path(__file__).resolve().parents[3] / ".." / "shared" / "data" / "euroc_v101_pairs" / "ForLoopClosureDetector"


@functools.cache
def _rectification() -> StereoRectification:
    if not (PAIRS / "sensorLeft.yaml").is_file():
        pytest.skip(f"EuRoC pairs not found in {PAIRS.resolve()}")
    return stereo_rectification(read_camera_yaml(PAIRS / "sensorLeft.yaml"), read_camera_yaml(PAIRS / "sensorRight.yaml"))


def _rectified_pair(i: int) -> tuple[np.ndarray, np.ndarray]:
    rectification = _rectification()
    left = cv2.imread(str(PAIRS / f"left_img_{i}.png"), cv2.IMREAD_GRAYSCALE)
    right = cv2.imread(str(PAIRS / f"right_img_{i}.png"), cv2.IMREAD_GRAYSCALE)
    assert left is not None and right is not None
    return rectification.rectify(left, right)


@pytest.mark.parametrize("i", range(4))
def test_real_pair_points_and_lines_are_triangulated(i: int) -> None:
    left, right = _rectified_pair(i)
    camera = _rectification().camera
    points = stereo_points(left, right, camera=camera)
    z = points.p_cam[points.matched, 2]
    assert np.sum((z > 0.3) & (z < 20.0)) >= 100
    segments = stereo_segments(left, right, camera=camera)
    m = segments.matched
    z_start, z_end = segments.p_start_cam[m, 2], segments.p_end_cam[m, 2]
    assert np.sum((z_start > 0.3) & (z_start < 20.0) & (z_end > 0.3) & (z_end < 20.0)) >= 10
