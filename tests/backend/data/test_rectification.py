"""Stereo rectification on real EuRoC V1_01 pairs (`../shared/data/euroc_v101_pairs`): after
rectification, ORB matches between left and right lie on the same image row."""

from __future__ import annotations

import pathlib

import cv2
import numpy as np
import pytest

from backend.data.calibration import StereoRectification, read_camera_yaml, stereo_rectification

PAIRS = pathlib.Path(__file__).resolve().parents[3] / ".." / "shared" / "data" / "euroc_v101_pairs" / "ForLoopClosureDetector"
MAX_DISPARITY_PX = 150.0
MAX_MEDIAN_ROW_ERROR_PX = 0.5


@pytest.fixture(scope="module")
def rectification() -> StereoRectification:
    if not (PAIRS / "sensorLeft.yaml").is_file():
        pytest.skip(f"real EuRoC pairs not found at {PAIRS.resolve()}")
    return stereo_rectification(read_camera_yaml(PAIRS / "sensorLeft.yaml"), read_camera_yaml(PAIRS / "sensorRight.yaml"))


def _pair_indices() -> list[int]:
    return sorted(int(p.stem.rsplit("_", 1)[1]) for p in PAIRS.glob("left_img_*.png")) or [0]


def row_errors(left: np.ndarray, right: np.ndarray) -> np.ndarray:
    """|v_L - v_R| (px) of cross-checked ORB matches with 0 <= u_L - u_R <= 150 px. (ORB puts
    its finest-level keypoints on whole pixels, so the median is often exactly 0 once rows agree.)"""
    orb = cv2.ORB_create(2000)
    keypoints_l, descriptors_l = orb.detectAndCompute(left, None)
    keypoints_r, descriptors_r = orb.detectAndCompute(right, None)
    matches = cv2.BFMatcher(cv2.NORM_HAMMING, crossCheck=True).match(descriptors_l, descriptors_r)
    uv_l = np.array([keypoints_l[m.queryIdx].pt for m in matches])
    uv_r = np.array([keypoints_r[m.trainIdx].pt for m in matches])
    disparity = uv_l[:, 0] - uv_r[:, 0]
    keep = (disparity >= 0.0) & (disparity <= MAX_DISPARITY_PX)
    return np.abs(uv_l[keep, 1] - uv_r[keep, 1])


def test_baseline_and_rectified_camera(rectification: StereoRectification) -> None:
    camera = rectification.camera
    assert camera.baseline == pytest.approx(0.110, abs=0.002)  # EuRoC's stereo baseline
    assert (camera.width, camera.height) == (752, 480)
    assert camera.fx == camera.fy and 400.0 < camera.fx < 460.0
    for R in (rectification.R_rect0_cam0, rectification.R_rect1_cam1):
        np.testing.assert_allclose(R @ R.T, np.eye(3), atol=1e-9)
    # rect1 = rect0 shifted along +x: cam1's centre in rect0 is (baseline, 0, 0).
    c_cam0 = -rectification.T_cam1_cam0[:3, :3].T @ rectification.T_cam1_cam0[:3, 3]
    np.testing.assert_allclose(rectification.R_rect0_cam0 @ c_cam0, [camera.baseline, 0.0, 0.0], atol=1e-9)


@pytest.mark.parametrize("index", _pair_indices())
def test_orb_matches_lie_on_the_same_row(rectification: StereoRectification, index: int) -> None:
    left = cv2.imread(str(PAIRS / f"left_img_{index}.png"), cv2.IMREAD_GRAYSCALE)
    right = cv2.imread(str(PAIRS / f"right_img_{index}.png"), cv2.IMREAD_GRAYSCALE)
    if left is None or right is None:
        pytest.skip(f"pair {index} not readable in {PAIRS.resolve()}")
    raw = row_errors(left, right)
    rectified = row_errors(*rectification.rectify(left, right))
    near = rectified[rectified < 5.0]
    print(
        f"pair {index}: median |dv| raw {np.median(raw):.3f} px ({raw.size} matches), rectified {np.median(rectified):.3f} px ({rectified.size} matches; mean of those under 5 px {near.mean():.3f} px)"
    )
    assert rectified.size >= 50
    assert np.median(rectified) < MAX_MEDIAN_ROW_ERROR_PX
    assert np.median(rectified) < np.median(raw)
