"""Linear triangulation of points and lines from noise-free calibrated views."""

from __future__ import annotations

import numpy as np
import pytest

from backend.geometry import so3
from backend.geometry.camera import PinholeCamera
from backend.mapping.triangulation import backprojection_planes, triangulate_lines, triangulate_points

CAMERA = PinholeCamera(fx=460.0, fy=460.0, cx=376.0, cy=240.0, width=752, height=480)


def _poses() -> tuple[np.ndarray, np.ndarray]:
    """Four cameras (R (4, 3, 3), t (4, 3)) near the origin looking roughly along +x."""
    R0 = np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]])  # camera z = world x, y down = world -z
    yaw = np.deg2rad([0.0, 8.0, -6.0, 3.0])
    R = np.stack([so3.exp(np.array([0.0, 0.0, a])) @ R0 @ so3.exp(np.array([0.02 * i, -0.01 * i, 0.03])) for i, a in enumerate(yaw)])
    t = np.array([[0.0, -0.5, 0.0], [0.1, 0.6, 0.2], [-0.3, 0.0, -0.4], [0.2, 0.3, 0.5]])
    return R, t


def _normalized(R: np.ndarray, t: np.ndarray, p_world: np.ndarray) -> np.ndarray:
    """Noise-free normalized coordinates (3-vectors) of p_world (..., 3) in pose (R, t)."""
    p_cam = np.einsum("ji,...j->...i", R, p_world - t)
    uv = CAMERA.project(p_cam)
    assert np.all(p_cam[..., 2] > 0.1) and np.all(CAMERA.in_image(uv))
    return CAMERA.normalize(uv)


def test_triangulate_points_is_exact_without_noise() -> None:
    R, t = _poses()
    rng = np.random.default_rng(0)
    p_true = np.column_stack([rng.uniform(3.0, 6.0, 8), rng.uniform(-1.0, 1.0, 8), rng.uniform(-0.8, 0.8, 8)])
    views = [np.array([0, 1]), np.array([0, 1, 2, 3]), np.array([3, 1, 2]), np.array([2, 0]), np.array([1, 3]), np.array([0, 2, 3]), np.array([3, 0]), np.array([0, 1, 2])]
    x = [np.stack([_normalized(R[k], t[k], p_true[i]) for k in ks]) for i, ks in enumerate(views)]
    X = triangulate_points(x, views, R, t)
    assert X.shape == (8, 3)
    np.testing.assert_allclose(X, p_true, atol=1e-8)
    # Two-component normalized coordinates work the same.
    np.testing.assert_allclose(triangulate_points([xi[:, :2] for xi in x], views, R, t), p_true, atol=1e-8)


def test_triangulate_lines_is_exact_without_noise() -> None:
    R, t = _poses()
    p = np.array([[4.0, -1.0, -0.5], [5.0, 0.5, 0.7], [3.5, 0.2, -0.6]])
    q = np.array([[4.0, 1.0, 0.8], [4.5, -0.5, 0.7], [5.5, 0.2, 0.6]])
    views = [np.array([0, 1, 2]), np.array([1, 3]), np.array([0, 1, 2, 3])]
    landmark = np.concatenate([np.full(len(v), i) for i, v in enumerate(views)])
    pose = np.concatenate(views)
    # Observed endpoints: other points of the line than p and q (the segment need not match).
    a = p[landmark] + 0.2 * (q - p)[landmark]
    b = p[landmark] + 0.9 * (q - p)[landmark]
    xs = np.stack([_normalized(R[k], t[k], a[m]) for m, k in enumerate(pose)])
    xe = np.stack([_normalized(R[k], t[k], b[m]) for m, k in enumerate(pose)])
    m, v, spread = triangulate_lines(xs, xe, landmark, pose, 3, R, t)
    v_true = (q - p) / np.linalg.norm(q - p, axis=1, keepdims=True)
    m_true = np.cross(p, v_true)
    scale = np.linalg.norm(v, axis=1, keepdims=True)
    sign = np.sign(np.sum(v * v_true, axis=1, keepdims=True))
    np.testing.assert_allclose(sign * v / scale, v_true, atol=1e-8)
    np.testing.assert_allclose(sign * m / scale, m_true, atol=1e-8)  # m = p × v with v's own scale and sign
    assert np.all(spread > np.sin(np.deg2rad(1.0)))
    assert np.all(spread <= 1.0 + 1e-12)


def test_backprojection_planes_contain_centre_and_segment() -> None:
    R, t = _poses()
    a, b = np.array([4.0, -1.0, -0.5]), np.array([5.0, 0.5, 0.7])
    xs = np.stack([_normalized(R[k], t[k], a) for k in range(4)])
    xe = np.stack([_normalized(R[k], t[k], b) for k in range(4)])
    planes = backprojection_planes(xs, xe, R, t)
    assert planes.shape == (4, 4)
    np.testing.assert_allclose(np.linalg.norm(planes[:, :3], axis=1), 1.0)
    for X in (t, np.tile(a, (4, 1)), np.tile(b, (4, 1))):
        np.testing.assert_allclose(np.sum(planes[:, :3] * X, axis=1) + planes[:, 3], 0.0, atol=1e-9)


def test_triangulate_lines_from_one_centre_is_degenerate() -> None:
    """Two views from the same centre give the same back-projection plane: spread 0."""
    R, t = _poses()
    R2 = np.stack([R[0], so3.exp(np.array([0.0, 0.05, 0.1])) @ R[0]])
    t2 = np.stack([t[0], t[0]])
    a, b = np.array([4.0, -1.0, -0.5]), np.array([5.0, 0.5, 0.7])
    xs = np.stack([_normalized(R2[k], t2[k], a) for k in range(2)])
    xe = np.stack([_normalized(R2[k], t2[k], b) for k in range(2)])
    _, _, spread = triangulate_lines(xs, xe, np.array([0, 0]), np.array([0, 1]), 1, R2, t2)
    assert spread[0] == pytest.approx(0.0, abs=1e-9)


def test_triangulate_lines_single_view_has_zero_spread() -> None:
    R, t = _poses()
    xs = _normalized(R[0], t[0], np.array([4.0, -1.0, -0.5]))[None]
    xe = _normalized(R[0], t[0], np.array([5.0, 0.5, 0.7]))[None]
    m, v, spread = triangulate_lines(xs, xe, np.array([0]), np.array([0]), 1, R, t)
    assert spread[0] == 0.0
    assert m.shape == (1, 3) and v.shape == (1, 3)
