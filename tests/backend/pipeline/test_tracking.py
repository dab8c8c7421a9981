"""Motion-only pose refinement: reprojection Jacobian and robust Gauss-Newton."""

from __future__ import annotations

import numpy as np
import pytest

from backend.geometry import so3
from backend.geometry.camera import PinholeCamera
from backend.pipeline.tracking import merge_matches, refine_pose, reprojection

CAMERA = PinholeCamera(fx=460.0, fy=460.0, cx=376.0, cy=240.0, width=752, height=480)
R_TRUE = so3.exp(np.array([0.1, -0.2, 0.05])) @ np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]])
T_TRUE = np.array([0.3, -0.2, 0.1])


def _scene(count: int = 60, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """World points (count, 3) in front of the true pose and their exact pixels (count, 2)."""
    rng = np.random.default_rng(seed)
    p_cam = np.column_stack([rng.uniform(-2.0, 2.0, count), rng.uniform(-1.2, 1.2, count), rng.uniform(3.0, 7.0, count)])
    p_world = p_cam @ R_TRUE.T + T_TRUE
    uv = CAMERA.project(p_cam)
    assert np.all(CAMERA.in_image(uv))
    return p_world, uv


def _perturbed(rot_rad: float = 0.05, pos_m: float = 0.1) -> tuple[np.ndarray, np.ndarray]:
    axis = np.array([1.0, -2.0, 0.5]) / np.linalg.norm([1.0, -2.0, 0.5])
    return R_TRUE @ so3.exp(rot_rad * axis), T_TRUE + pos_m * np.array([0.6, -0.8, 0.0])


def _angle(R_a: np.ndarray, R_b: np.ndarray) -> float:
    return float(np.linalg.norm(so3.log(R_a.T @ R_b)))


def test_reprojection_residual_and_depth() -> None:
    p_world, uv = _scene(10)
    res, J, depth = reprojection(CAMERA, R_TRUE, T_TRUE, p_world, uv + np.array([1.5, -2.0]))
    assert res.shape == (10, 2) and J.shape == (10, 2, 6) and depth.shape == (10,)
    np.testing.assert_allclose(res, np.tile([-1.5, 2.0], (10, 1)), atol=1e-9)
    np.testing.assert_allclose(depth, ((p_world - T_TRUE) @ R_TRUE)[:, 2])


def test_reprojection_jacobian_matches_central_differences() -> None:
    """∂r/∂(δθ, δt) for the retraction R Exp(δθ), t + δt (world δt)."""
    p_world, uv = _scene(12, seed=1)
    R, t = _perturbed(0.03, 0.05)
    _, J, _ = reprojection(CAMERA, R, t, p_world, uv)
    eps = 1e-6
    J_num = np.zeros_like(J)
    for c in range(6):
        d = np.zeros(6)
        d[c] = eps
        rp, _, _ = reprojection(CAMERA, R @ so3.exp(d[:3]), t + d[3:], p_world, uv)
        rm, _, _ = reprojection(CAMERA, R @ so3.exp(-d[:3]), t - d[3:], p_world, uv)
        J_num[:, :, c] = (rp - rm) / (2 * eps)
    scale = np.maximum(np.abs(J_num).max(), 1.0)
    np.testing.assert_allclose(J / scale, J_num / scale, atol=1e-6)
    assert np.abs(J).max() > 10.0  # not trivially zero


def test_refine_pose_converges_to_the_true_pose() -> None:
    p_world, uv = _scene()
    R0, t0 = _perturbed()
    ref = refine_pose(CAMERA, R0, t0, p_world, uv)
    assert _angle(ref.R_world_camera, R_TRUE) < 1e-6
    np.testing.assert_allclose(ref.t_world_camera, T_TRUE, atol=1e-6)
    assert ref.final_cost < 1e-8 < ref.initial_cost
    assert 1 <= ref.iterations <= 10
    assert ref.inliers == len(p_world)
    # The inputs are not modified.
    np.testing.assert_array_equal(R0, _perturbed()[0])
    np.testing.assert_array_equal(t0, _perturbed()[1])


def test_refine_pose_is_robust_to_gross_outliers() -> None:
    p_world, uv = _scene(100, seed=2)
    rng = np.random.default_rng(3)
    bad = rng.choice(100, 20, replace=False)
    uv = uv.copy()
    uv[bad] += rng.uniform(40.0, 120.0, (20, 2)) * np.where(rng.random((20, 2)) < 0.5, -1.0, 1.0)
    R0, t0 = _perturbed()
    ref = refine_pose(CAMERA, R0, t0, p_world, uv)
    # Without the kernel (least squares) the outliers pull the pose off by ~3° and ~19 cm.
    assert _angle(ref.R_world_camera, R_TRUE) < np.deg2rad(0.02)
    assert np.linalg.norm(ref.t_world_camera - T_TRUE) < 0.002
    assert ref.inliers == 80  # exactly the clean points are within 3 σ
    assert ref.final_cost < ref.initial_cost


def test_refine_pose_with_noise_stays_close() -> None:
    p_world, uv = _scene(80, seed=4)
    uv = uv + np.random.default_rng(5).standard_normal(uv.shape)
    ref = refine_pose(CAMERA, *_perturbed(), p_world, uv)
    assert _angle(ref.R_world_camera, R_TRUE) < np.deg2rad(0.2)
    assert np.linalg.norm(ref.t_world_camera - T_TRUE) < 0.03


@pytest.mark.parametrize("count", [0, 1, 2])
def test_refine_pose_with_too_few_points_returns_the_pose(count: int) -> None:
    p_world, uv = _scene(count) if count else (np.zeros((0, 3)), np.zeros((0, 2)))
    R0, t0 = _perturbed()
    ref = refine_pose(CAMERA, R0, t0, p_world, uv)
    np.testing.assert_array_equal(ref.R_world_camera, R0)
    np.testing.assert_array_equal(ref.t_world_camera, t0)
    assert ref.iterations == 0 and ref.inliers == 0


def test_refine_pose_ignores_points_behind_the_camera() -> None:
    p_world, uv = _scene(40, seed=6)
    behind = T_TRUE - 3.0 * R_TRUE[:, 2] + 0.1 * np.arange(5)[:, None]  # 3 m behind the camera
    p_all = np.concatenate([p_world, behind])
    uv_all = np.concatenate([uv, np.full((5, 2), 200.0)])
    ref = refine_pose(CAMERA, *_perturbed(0.02, 0.05), p_all, uv_all)
    assert _angle(ref.R_world_camera, R_TRUE) < 1e-5
    np.testing.assert_allclose(ref.t_world_camera, T_TRUE, atol=1e-5)


def test_merge_matches_adds_only_unmatched_points_to_unused_keypoints() -> None:
    """Point 0 keeps its match; point 2 gets the other's keypoint 5; point 3 would take
    keypoint 1, already point 0's, so it stays unmatched; the input is not changed."""
    match = np.array([1, -1, -1, -1])
    more = np.array([4, -1, 5, 1])
    merged = merge_matches(match, more, n_keypoints=6)
    assert merged.tolist() == [1, -1, 5, -1]
    assert match.tolist() == [1, -1, -1, -1]
