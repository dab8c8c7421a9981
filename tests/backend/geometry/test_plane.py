"""Planes `n·X + d = 0`: tangent basis, retraction, frame change and the least-squares fit."""

from __future__ import annotations

import numpy as np
import pytest

from backend.geometry import plane, so3


def _normals(rng: np.random.Generator, n: int) -> np.ndarray:
    """Random unit normals plus all six axis-aligned ones and some with tied components."""
    r = rng.standard_normal((n, 3))
    ties = np.array([[1, 1, 0], [1, 0, 1], [0, 1, 1], [1, 1, 1], [-1, 1, -1], [1e-9, 1, 0]], float)
    n_all = np.concatenate([np.eye(3), -np.eye(3), ties, r])
    return n_all / np.linalg.norm(n_all, axis=1, keepdims=True)


def test_tangent_basis_is_orthonormal_and_perpendicular_to_n() -> None:
    n = _normals(np.random.default_rng(0), 500)
    B = plane.tangent_basis(n)
    assert B.shape == (len(n), 3, 2)
    assert np.all(np.isfinite(B))
    np.testing.assert_allclose(np.swapaxes(B, 1, 2) @ B, np.broadcast_to(np.eye(2), (len(n), 2, 2)), atol=1e-12)
    np.testing.assert_allclose(np.einsum("ni,nij->nj", n, B), 0.0, atol=1e-12)
    # Right-handed frame [b1, b2, n].
    np.testing.assert_allclose(np.linalg.det(np.concatenate([B, n[:, :, None]], axis=2)), 1.0, atol=1e-12)


def test_tangent_basis_is_deterministic_and_works_for_one_normal() -> None:
    n = np.array([0.0, 0.0, 1.0])
    B = plane.tangent_basis(n)
    assert B.shape == (3, 2)
    np.testing.assert_array_equal(B, plane.tangent_basis(n.copy()))
    np.testing.assert_allclose(B, plane.tangent_basis(n[None])[0])


def test_retract_keeps_unit_normal_and_zero_is_identity() -> None:
    rng = np.random.default_rng(1)
    n = _normals(rng, 200)
    d = rng.uniform(-5, 5, len(n))
    n0, d0 = plane.retract(n, d, np.zeros((len(n), 3)))
    np.testing.assert_allclose(n0, n, atol=1e-15)
    np.testing.assert_array_equal(d0, d)
    delta = rng.uniform(-1, 1, (len(n), 3))
    n1, d1 = plane.retract(n, d, delta)
    np.testing.assert_allclose(np.linalg.norm(n1, axis=1), 1.0, atol=1e-14)
    np.testing.assert_allclose(d1, d + delta[:, 2])
    assert np.all(np.linalg.norm(n1 - n, axis=1) > 1e-3)  # the normal did move


def test_retract_moves_the_normal_along_the_tangent_basis_to_first_order() -> None:
    rng = np.random.default_rng(2)
    n = _normals(rng, 30)
    d = np.zeros(len(n))
    B = plane.tangent_basis(n)
    h = 1e-7
    for k in range(2):
        delta = np.zeros((len(n), 3))
        delta[:, k] = h
        n_p, _ = plane.retract(n, d, delta)
        n_m, _ = plane.retract(n, d, -delta)
        np.testing.assert_allclose((n_p - n_m) / (2 * h), B[:, :, k], atol=1e-7)


def test_to_camera_agrees_with_transforming_points() -> None:
    rng = np.random.default_rng(3)
    for _ in range(20):
        n_w = _normals(rng, 1)[-1]
        d_w = rng.uniform(-5, 5)
        R = so3.exp(rng.uniform(-3, 3, 3))
        t = rng.uniform(-5, 5, 3)
        # Points on the world plane: the foot point plus tangent combinations.
        B = plane.tangent_basis(n_w)
        X_w = -d_w * n_w + rng.uniform(-10, 10, (15, 2)) @ B.T
        np.testing.assert_allclose(X_w @ n_w + d_w, 0.0, atol=1e-12)
        X_c = (X_w - t) @ R  # Rᵀ (X_w - t)
        n_c, d_c = plane.to_camera(n_w, d_w, R, t)
        np.testing.assert_allclose(np.linalg.norm(n_c), 1.0, atol=1e-14)
        np.testing.assert_allclose(X_c @ n_c + d_c, 0.0, atol=1e-11)
        # A point off the plane keeps its signed distance.
        off = X_w[0] + 0.7 * n_w
        np.testing.assert_allclose(plane.signed_distance(n_c, d_c, R.T @ (off - t)), 0.7, atol=1e-12)


def test_to_camera_vectorized_over_poses() -> None:
    rng = np.random.default_rng(4)
    R = so3.exp(rng.uniform(-2, 2, (6, 3)))
    t = rng.uniform(-3, 3, (6, 3))
    n_w = np.tile([0.0, 0.6, 0.8], (6, 1))
    d_w = np.full(6, -2.0)
    n_c, d_c = plane.to_camera(n_w, d_w, R, t)
    for k in range(6):
        n1, d1 = plane.to_camera(n_w[k], d_w[k], R[k], t[k])
        np.testing.assert_allclose(n_c[k], n1)
        np.testing.assert_allclose(d_c[k], d1)


def test_fit_plane_recovers_a_known_plane_from_noisy_points() -> None:
    rng = np.random.default_rng(5)
    for _ in range(10):
        n_true = _normals(rng, 1)[-1]
        d_true = rng.uniform(-4, 4)
        B = plane.tangent_basis(n_true)
        X = -d_true * n_true + rng.uniform(-2, 2, (200, 2)) @ B.T + 1e-3 * rng.standard_normal((200, 1)) * n_true
        n, d = plane.fit_plane(X)
        assert isinstance(d, float)
        np.testing.assert_allclose(np.linalg.norm(n), 1.0, atol=1e-12)
        s = np.sign(n @ n_true)  # the sign of a fitted plane is arbitrary
        assert s * n @ n_true > 1 - 1e-5
        assert abs(s * d - d_true) < 1e-3
        assert np.sqrt(np.mean(plane.signed_distance(n, d, X) ** 2)) < 2e-3


def test_fit_plane_exact_for_three_points() -> None:
    p = np.array([[4.0, 0.0, 0.0], [4.0, 1.0, 0.0], [4.0, 0.0, 1.0]])
    n, d = plane.fit_plane(p)
    np.testing.assert_allclose(plane.signed_distance(n, d, p), 0.0, atol=1e-12)
    np.testing.assert_allclose(np.abs(n), [1.0, 0.0, 0.0], atol=1e-12)


@pytest.mark.parametrize(
    "points",
    [
        np.zeros((0, 3)),
        np.array([[0.0, 0.0, 0.0], [1.0, 2.0, 3.0]]),
        np.array([[0.0, 0.0, 0.0], [1.0, 1.0, 1.0], [2.0, 2.0, 2.0], [-3.0, -3.0, -3.0]]),  # collinear
        np.array([[1.0, 2.0, 3.0]] * 5),  # all identical
        np.zeros((4, 2)),  # wrong shape
    ],
    ids=["none", "two", "collinear", "identical", "2d"],
)
def test_fit_plane_rejects_degenerate_input(points: np.ndarray) -> None:
    with pytest.raises(ValueError):
        plane.fit_plane(points)
