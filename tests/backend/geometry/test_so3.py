"""SO(3) helpers: the exponential/logarithm pair and the right Jacobians."""

from __future__ import annotations

import numpy as np
import pytest

from backend.geometry import so3


def _random_axes(rng: np.random.Generator, n: int) -> np.ndarray:
    a = rng.standard_normal((n, 3))
    return a / np.linalg.norm(a, axis=1, keepdims=True)


def _assert_rotation(R: np.ndarray, atol: float = 1e-12) -> None:
    eye = np.broadcast_to(np.eye(3), R.shape)
    np.testing.assert_allclose(np.swapaxes(R, -1, -2) @ R, eye, atol=atol)
    np.testing.assert_allclose(np.linalg.det(R), 1.0, atol=atol)


def test_hat_is_the_cross_product_matrix() -> None:
    rng = np.random.default_rng(0)
    w, x = rng.standard_normal((2, 20, 3))
    np.testing.assert_allclose(np.einsum("nij,nj->ni", so3.hat(w), x), np.cross(w, x), atol=1e-14)
    np.testing.assert_allclose(so3.hat(w), -np.swapaxes(so3.hat(w), 1, 2))


@pytest.mark.parametrize("angle", [0.0, 1e-12, 1e-9, 1e-7, 1e-5, 1e-3, 0.1, 1.0, 2.0, 3.0])
def test_exp_is_a_rotation_and_log_inverts_it(angle: float) -> None:
    rng = np.random.default_rng(1)
    w = angle * _random_axes(rng, 50)
    R = so3.exp(w)
    _assert_rotation(R)
    np.testing.assert_allclose(so3.log(R), w, rtol=0, atol=1e-12)


def test_exp_of_a_stack_matches_exp_of_each_and_rotates_about_the_axis() -> None:
    rng = np.random.default_rng(2)
    w = rng.uniform(-2, 2, (4, 5, 3))
    R = so3.exp(w)
    assert R.shape == (4, 5, 3, 3)
    np.testing.assert_allclose(R[2, 3], so3.exp(w[2, 3]), atol=1e-15)
    # The axis is fixed; a vector ⟂ axis turns by |w| (Rodrigues).
    axis = w[1, 1] / np.linalg.norm(w[1, 1])
    np.testing.assert_allclose(R[1, 1] @ axis, axis, atol=1e-12)
    perp = np.cross(axis, [1.0, 0.0, 0.0])
    perp /= np.linalg.norm(perp)
    np.testing.assert_allclose(np.arccos(np.clip(perp @ R[1, 1] @ perp, -1, 1)), np.linalg.norm(w[1, 1]), atol=1e-9)


def test_exp_of_hat_is_orthonormal_with_unit_determinant() -> None:
    rng = np.random.default_rng(3)
    w = rng.uniform(-4.0, 4.0, (200, 3))  # includes angles beyond π
    R = so3.exp(w)
    _assert_rotation(R)
    # Same as the matrix exponential of hat(w).
    import scipy.linalg

    for k in range(0, 200, 40):
        np.testing.assert_allclose(R[k], scipy.linalg.expm(so3.hat(w[k])), atol=1e-12)


@pytest.mark.parametrize("eps", [1e-2, 1e-3])
def test_log_near_pi_generic_branch(eps: float) -> None:
    rng = np.random.default_rng(4)
    w = (np.pi - eps) * _random_axes(rng, 100)
    np.testing.assert_allclose(so3.log(so3.exp(w)), w, atol=1e-8)


@pytest.mark.parametrize("eps", [1e-4, 1e-5, 1e-6])
def test_log_very_near_pi(eps: float) -> None:
    rng = np.random.default_rng(5)
    w = (np.pi - eps) * _random_axes(rng, 100)
    np.testing.assert_allclose(so3.log(so3.exp(w)), w, atol=1e-7)


def test_log_at_exactly_pi_returns_an_equivalent_rotation_vector() -> None:
    rng = np.random.default_rng(6)
    axes = np.concatenate([np.eye(3), -np.eye(3), _random_axes(rng, 50)])
    R = so3.exp(np.pi * axes)
    w = so3.log(R)
    np.testing.assert_allclose(np.linalg.norm(w, axis=1), np.pi, atol=1e-7)
    # ±π about the axis: the same rotation.
    assert np.all(np.abs(np.abs(np.sum(w * axes, axis=1)) - np.pi) < 1e-7)
    np.testing.assert_allclose(so3.exp(w), R, atol=1e-7)


def test_right_jacobian_inv_is_the_inverse_of_right_jacobian() -> None:
    rng = np.random.default_rng(7)
    angles = np.r_[0.0, 1e-9, 1e-6, 1e-5 * (1 - 1e-9), 1e-5, 1e-4, rng.uniform(0.0, 3.0, 60)]
    w = angles[:, None] * _random_axes(rng, len(angles))
    eye = np.broadcast_to(np.eye(3), (len(w), 3, 3))
    np.testing.assert_allclose(so3.right_jacobian(w) @ so3.right_jacobian_inv(w), eye, atol=1e-9)
    np.testing.assert_allclose(so3.right_jacobian_inv(w) @ so3.right_jacobian(w), eye, atol=1e-9)


@pytest.mark.parametrize("angle", [0.0, 1e-6, 0.3, 1.5, 2.8])
def test_log_of_right_perturbation_is_linearized_by_right_jacobian_inv(angle: float) -> None:
    """Log(Exp(w) Exp(δ)) ≈ w + J_r⁻¹(w) δ: central differences in δ."""
    rng = np.random.default_rng(8)
    w = angle * _random_axes(rng, 1)[0]
    h = 1e-6
    J_num = np.empty((3, 3))
    for i in range(3):
        d = np.zeros(3)
        d[i] = h
        J_num[:, i] = (so3.log(so3.exp(w) @ so3.exp(d)) - so3.log(so3.exp(w) @ so3.exp(-d))) / (2 * h)
    np.testing.assert_allclose(so3.right_jacobian_inv(w), J_num, atol=1e-7)
    # And the forward statement: Exp(w + δ) ≈ Exp(w) Exp(J_r(w) δ).
    delta = 1e-5 * rng.standard_normal(3)
    lhs = so3.exp(w + delta)
    rhs = so3.exp(w) @ so3.exp(so3.right_jacobian(w) @ delta)
    np.testing.assert_allclose(lhs, rhs, atol=1e-9)


def test_project_to_so3_returns_the_rotation_of_a_perturbed_matrix() -> None:
    rng = np.random.default_rng(9)
    R = so3.exp(rng.uniform(-2, 2, (10, 3)))
    M = R + 1e-3 * rng.standard_normal((10, 3, 3))
    P = so3.project_to_so3(M)
    _assert_rotation(P)
    assert np.max(np.abs(P - R)) < 5e-3
    np.testing.assert_allclose(so3.project_to_so3(R), R, atol=1e-12)
