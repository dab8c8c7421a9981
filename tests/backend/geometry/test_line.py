"""3D lines: Plücker coordinates, the orthonormal representation, frame changes, images."""

from __future__ import annotations

import numpy as np

from backend.geometry import line, so3
from backend.geometry.camera import PinholeCamera

CAM = PinholeCamera(fx=460.0, fy=455.0, cx=376.0, cy=240.0, width=752, height=480)


def _segments(rng: np.random.Generator, n: int) -> tuple[np.ndarray, np.ndarray]:
    p = rng.uniform(-5, 5, (n, 3))
    q = p + rng.uniform(-2, 2, (n, 3))
    return p, q


def _pose(rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    return so3.exp(rng.uniform(-3, 3, 3)), rng.uniform(-4, 4, 3)


def _assert_same_line_positive_scale(m1, v1, m2, v2, atol=1e-10) -> None:
    """(m2, v2) = λ (m1, v1) with one λ > 0 per line."""
    lam = np.linalg.norm(np.concatenate([m2, v2], -1), axis=-1) / np.linalg.norm(np.concatenate([m1, v1], -1), axis=-1)
    np.testing.assert_allclose(lam[..., None] * m1, m2, atol=atol)
    np.testing.assert_allclose(lam[..., None] * v1, v2, atol=atol)


def test_points_on_the_line_satisfy_p_cross_v_equals_m() -> None:
    rng = np.random.default_rng(0)
    p, q = _segments(rng, 50)
    m, v = line.from_points(p, q)
    np.testing.assert_allclose(v, q - p)
    np.testing.assert_allclose(np.sum(m * v, axis=1), 0.0, atol=1e-10)  # Plücker constraint
    for s in (-3.0, 0.0, 0.4, 1.0, 7.5):
        X = p + s * (q - p)
        np.testing.assert_allclose(np.cross(X, v), m, atol=1e-10)
    # A point off the line does not.
    off = p + np.cross(q - p, rng.standard_normal((50, 3)))
    assert np.all(np.linalg.norm(np.cross(off, v) - m, axis=1) > 1e-6)


def test_orthonormal_round_trip_preserves_the_line_up_to_positive_scale() -> None:
    rng = np.random.default_rng(1)
    p, q = _segments(rng, 100)
    m, v = line.from_points(p, q)
    U, phi = line.to_orthonormal(m, v)
    assert U.shape == (100, 3, 3) and phi.shape == (100,)
    np.testing.assert_allclose(np.swapaxes(U, 1, 2) @ U, np.broadcast_to(np.eye(3), U.shape), atol=1e-12)
    np.testing.assert_allclose(np.linalg.det(U), 1.0, atol=1e-12)
    m2, v2 = line.from_orthonormal(U, phi)
    np.testing.assert_allclose(np.sum(m2**2, 1) + np.sum(v2**2, 1), 1.0, atol=1e-12)
    _assert_same_line_positive_scale(m, v, m2, v2)
    # Scaling the input (by a positive factor) gives the same orthonormal form.
    U3, phi3 = line.to_orthonormal(2.5 * m, 2.5 * v)
    np.testing.assert_allclose(U3, U, atol=1e-12)
    np.testing.assert_allclose(phi3, phi, atol=1e-12)


def test_orthonormal_form_of_a_line_through_the_origin() -> None:
    v = np.array([0.3, -0.2, 0.9])
    U, phi = line.to_orthonormal(np.zeros(3), v)
    assert np.all(np.isfinite(U))
    np.testing.assert_allclose(U.T @ U, np.eye(3), atol=1e-12)
    np.testing.assert_allclose(np.linalg.det(U), 1.0, atol=1e-12)
    m2, v2 = line.from_orthonormal(U, phi)
    np.testing.assert_allclose(m2, 0.0, atol=1e-12)
    np.testing.assert_allclose(v2, v / np.linalg.norm(v), atol=1e-12)


def test_retract_zero_is_identity_and_u_stays_in_so3() -> None:
    rng = np.random.default_rng(2)
    m, v = line.from_points(*_segments(rng, 40))
    U, phi = line.to_orthonormal(m, v)
    U0, phi0 = line.retract(U, phi, np.zeros((40, 4)))
    np.testing.assert_allclose(U0, U, atol=1e-15)
    np.testing.assert_array_equal(phi0, phi)
    for _ in range(20):  # repeated large updates
        U, phi = line.retract(U, phi, rng.uniform(-1, 1, (40, 4)))
    np.testing.assert_allclose(np.swapaxes(U, 1, 2) @ U, np.broadcast_to(np.eye(3), U.shape), atol=1e-12)
    np.testing.assert_allclose(np.linalg.det(U), 1.0, atol=1e-12)
    m2, v2 = line.from_orthonormal(U, phi)
    np.testing.assert_allclose(np.sum(m2 * v2, axis=1), 0.0, atol=1e-12)  # still a valid line


def test_retract_follows_the_documented_update() -> None:
    rng = np.random.default_rng(3)
    U, phi = line.to_orthonormal(*line.from_points(*_segments(rng, 5)))
    delta = rng.uniform(-0.5, 0.5, (5, 4))
    U1, phi1 = line.retract(U, phi, delta)
    np.testing.assert_allclose(U1, U @ so3.exp(delta[:, :3]), atol=1e-14)
    np.testing.assert_allclose(phi1, phi + delta[:, 3])


def test_to_camera_matches_transforming_two_points_and_to_world_inverts_it() -> None:
    rng = np.random.default_rng(4)
    for _ in range(20):
        R, t = _pose(rng)
        p, q = _segments(rng, 10)
        m_w, v_w = line.from_points(p, q)
        m_c, v_c = line.to_camera(m_w, v_w, R, t)
        # X_c = Rᵀ (X_w - t) for both points gives the same Plücker pair (same scale: v_c = Rᵀ v_w).
        m_ref, v_ref = line.from_points((p - t) @ R, (q - t) @ R)
        np.testing.assert_allclose(m_c, m_ref, atol=1e-10)
        np.testing.assert_allclose(v_c, v_ref, atol=1e-10)
        m_back, v_back = line.to_world(m_c, v_c, R, t)
        np.testing.assert_allclose(m_back, m_w, atol=1e-10)
        np.testing.assert_allclose(v_back, v_w, atol=1e-10)
        # to_world applied to camera-frame points matches as well.
        m_w2, v_w2 = line.to_world(*line.from_points(p, q), R, t)
        m_ref2, v_ref2 = line.from_points(p @ R.T + t, q @ R.T + t)
        np.testing.assert_allclose(m_w2, m_ref2, atol=1e-10)
        np.testing.assert_allclose(v_w2, v_ref2, atol=1e-10)


def test_to_camera_vectorized_over_poses() -> None:
    rng = np.random.default_rng(5)
    R = so3.exp(rng.uniform(-2, 2, (7, 3)))
    t = rng.uniform(-3, 3, (7, 3))
    m, v = line.from_points(*_segments(rng, 7))
    m_c, v_c = line.to_camera(m, v, R, t)
    for k in range(7):
        a, b = line.to_camera(m[k], v[k], R[k], t[k])
        np.testing.assert_allclose(m_c[k], a, atol=1e-12)
        np.testing.assert_allclose(v_c[k], b, atol=1e-12)


def test_image_line_passes_through_the_projections_of_points_on_the_line() -> None:
    rng = np.random.default_rng(6)
    R = so3.exp(np.array([0.1, -0.2, 0.05]))
    t = np.array([0.2, -0.1, 0.3])
    for _ in range(30):
        # Two points in front of the camera, then their world positions.
        P_c = np.stack([rng.uniform(-1.5, 1.5, 2), rng.uniform(-1, 1, 2), rng.uniform(2, 6, 2)], axis=1)
        P_w = P_c @ R.T + t
        m_w, v_w = line.from_points(P_w[0], P_w[1])
        l = line.image_line(line.to_camera(m_w, v_w, R, t)[0])
        l = l / np.linalg.norm(l)
        # The projections of both points and of any point between them.
        X_c = np.stack([P_c[0], P_c[1], 0.3 * P_c[0] + 0.7 * P_c[1]])
        x_hat = CAM.normalize(CAM.project(X_c))
        np.testing.assert_allclose(x_hat @ l, 0.0, atol=1e-12)
        # A pixel displaced off the segment is not on the line.
        normal_px = np.array([l[0] / CAM.fx, l[1] / CAM.fy])  # the pixel line is K⁻ᵀ l
        uv_off = CAM.project(X_c[2]) + 5.0 * normal_px / np.linalg.norm(normal_px)
        assert abs(CAM.normalize(uv_off) @ l) > 1e-4


def test_from_two_planes_gives_the_intersection_line() -> None:
    rng = np.random.default_rng(7)
    for _ in range(50):
        n1, n2 = rng.standard_normal((2, 3))
        n1 /= np.linalg.norm(n1)
        n2 /= np.linalg.norm(n2)
        d1, d2 = rng.uniform(-5, 5, 2)
        m, v = line.from_two_planes(n1, d1, n2, d2)
        np.testing.assert_allclose(v, np.cross(n1, n2), atol=1e-14)
        # Points on both planes: the minimum-norm solution plus multiples of the direction.
        A = np.stack([n1, n2])
        X0 = np.linalg.lstsq(A, -np.array([d1, d2]), rcond=None)[0]
        for s in (-2.0, 0.0, 3.0):
            X = X0 + s * v
            np.testing.assert_allclose(A @ X, -np.array([d1, d2]), atol=1e-10)
            np.testing.assert_allclose(np.cross(X, v), m, atol=1e-9)
        # The closest point to the origin lies on both planes.
        c = line.closest_point_to_origin(m, v)
        np.testing.assert_allclose(A @ c, -np.array([d1, d2]), atol=1e-9)


def test_from_two_planes_vectorized() -> None:
    rng = np.random.default_rng(8)
    n1 = rng.standard_normal((6, 3))
    n2 = rng.standard_normal((6, 3))
    d1, d2 = rng.standard_normal((2, 6))
    m, v = line.from_two_planes(n1, d1, n2, d2)
    for k in range(6):
        a, b = line.from_two_planes(n1[k], d1[k], n2[k], d2[k])
        np.testing.assert_allclose(m[k], a)
        np.testing.assert_allclose(v[k], b)
