"""Pinhole camera: projection, normalization and the projection Jacobian; SE(3) pose stacks."""

from __future__ import annotations

import numpy as np

from backend.geometry import se3, so3
from backend.geometry.camera import PinholeCamera

CAM = PinholeCamera(fx=460.0, fy=450.0, cx=376.0, cy=240.0, width=752, height=480, baseline=0.11)


def _points_in_front(rng: np.random.Generator, n: int) -> np.ndarray:
    return np.stack([rng.uniform(-3, 3, n), rng.uniform(-2, 2, n), rng.uniform(0.2, 10, n)], axis=1)


def test_intrinsic_matrix() -> None:
    np.testing.assert_array_equal(CAM.K, [[460.0, 0.0, 376.0], [0.0, 450.0, 240.0], [0.0, 0.0, 1.0]])
    np.testing.assert_array_equal(CAM.offset_right, [0.11, 0.0, 0.0])


def test_principal_point_and_axes_follow_opencv() -> None:
    np.testing.assert_allclose(CAM.project(np.array([0.0, 0.0, 2.0])), [376.0, 240.0])
    # x right, y down: a point right of and below the axis lands right of and below the centre.
    u, v = CAM.project(np.array([0.5, 0.25, 2.0]))
    np.testing.assert_allclose([u, v], [376.0 + 460.0 * 0.25, 240.0 + 450.0 * 0.125])


def test_project_and_normalize_are_inverse() -> None:
    rng = np.random.default_rng(0)
    p = _points_in_front(rng, 200)
    uv = CAM.project(p)
    x_hat = CAM.normalize(uv)
    np.testing.assert_allclose(x_hat[:, 2], 1.0)
    np.testing.assert_allclose(x_hat * p[:, 2:3], p, atol=1e-12)
    # x̂ = K⁻¹ [u v 1]ᵀ
    np.testing.assert_allclose(x_hat, np.c_[uv, np.ones(200)] @ np.linalg.inv(CAM.K).T, atol=1e-12)
    uv2 = rng.uniform([0, 0], [751, 479], (100, 2))
    np.testing.assert_allclose(CAM.project(CAM.normalize(uv2)), uv2, atol=1e-10)
    # Scaling a camera-frame point does not move its pixel.
    np.testing.assert_allclose(CAM.project(3.7 * p), uv, atol=1e-10)


def test_project_accepts_stacks() -> None:
    rng = np.random.default_rng(1)
    p = _points_in_front(rng, 12).reshape(3, 4, 3)
    uv = CAM.project(p)
    assert uv.shape == (3, 4, 2)
    np.testing.assert_allclose(uv[1, 2], CAM.project(p[1, 2]))
    assert CAM.normalize(uv).shape == (3, 4, 3)
    assert CAM.project_jacobian(p).shape == (3, 4, 2, 3)


def test_project_jacobian_matches_central_differences() -> None:
    rng = np.random.default_rng(2)
    p = _points_in_front(rng, 50)
    J = CAM.project_jacobian(p)
    h = 1e-6
    J_num = np.empty_like(J)
    for i in range(3):
        d = np.zeros(3)
        d[i] = h
        J_num[:, :, i] = (CAM.project(p + d) - CAM.project(p - d)) / (2 * h)
    np.testing.assert_allclose(J, J_num, rtol=1e-6, atol=1e-4)


def test_in_image_bounds() -> None:
    uv = np.array([[0.0, 0.0], [751.0, 479.0], [-0.01, 10.0], [751.01, 10.0], [10.0, 479.5], [376.0, 240.0]])
    np.testing.assert_array_equal(CAM.in_image(uv), [True, True, False, False, False, True])


def test_poses_retract_and_inverse_transform() -> None:
    rng = np.random.default_rng(3)
    R = so3.exp(rng.uniform(-2, 2, (5, 3)))
    t = rng.uniform(-3, 3, (5, 3))
    poses = se3.Poses(R, t)
    assert len(poses) == 5
    delta = rng.uniform(-0.3, 0.3, (5, 6))
    moved = poses.retract(delta)
    np.testing.assert_allclose(moved.R_world_camera, R @ so3.exp(delta[:, :3]), atol=1e-14)
    np.testing.assert_allclose(moved.t_world_camera, t + delta[:, 3:])
    same = poses.retract(np.zeros(30))
    np.testing.assert_allclose(same.R_world_camera, R, atol=1e-15)
    np.testing.assert_array_equal(same.t_world_camera, t)
    # X_c = Rᵀ (X_w - t), the inverse of X_w = R X_c + t.
    p_c = _points_in_front(rng, 5)
    p_w = np.einsum("nij,nj->ni", R, p_c) + t
    np.testing.assert_allclose(poses.inverse_transform_points(np.arange(5), p_w), p_c, atol=1e-12)
    # copy is independent.
    c = poses.copy()
    c.t_world_camera[0] += 1.0
    assert not np.allclose(c.t_world_camera[0], poses.t_world_camera[0])
