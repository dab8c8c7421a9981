"""Tests for backend.eval.trajectory."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from scipy.optimize import least_squares
from scipy.spatial.transform import Rotation

from backend.eval.trajectory import (
    TrajectoryError,
    ate_rmse,
    path_delta_pairs,
    relative_pose_error,
    trajectory_error,
    translational_rmse,
    umeyama_alignment,
)


def _random_trajectory(rng: np.random.Generator, n: int = 50) -> np.ndarray:
    """A smooth-ish random walk in metres, (n, 3)."""
    return np.cumsum(rng.normal(scale=0.5, size=(n, 3)), axis=0)


def _random_similarity(rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray, float]:
    rotation = Rotation.random(random_state=rng).as_matrix()
    translation = rng.uniform(-10.0, 10.0, size=3)
    scale = float(rng.uniform(0.3, 3.0))
    return rotation, translation, scale


def _apply(rotation: np.ndarray, translation: np.ndarray, scale: float, p: np.ndarray) -> np.ndarray:
    return scale * p @ rotation.T + translation


@pytest.mark.parametrize("seed", [0, 1, 2, 3])
def test_umeyama_recovers_known_similarity(seed: int) -> None:
    rng = np.random.default_rng(seed)
    p_src = _random_trajectory(rng)
    rotation, translation, scale = _random_similarity(rng)
    p_dst = _apply(rotation, translation, scale, p_src)

    r_est, t_est, s_est = umeyama_alignment(p_src, p_dst, with_scale=True)

    np.testing.assert_allclose(r_est, rotation, atol=1e-9)
    np.testing.assert_allclose(t_est, translation, atol=1e-9)
    assert s_est == pytest.approx(scale, abs=1e-9)
    assert np.linalg.det(r_est) == pytest.approx(1.0, abs=1e-12)


def test_umeyama_without_scale_returns_unit_scale_and_recovers_rigid() -> None:
    rng = np.random.default_rng(10)
    p_src = _random_trajectory(rng)
    rotation, translation, _ = _random_similarity(rng)
    p_dst = _apply(rotation, translation, 1.0, p_src)

    r_est, t_est, s_est = umeyama_alignment(p_src, p_dst, with_scale=False)

    assert s_est == 1.0
    np.testing.assert_allclose(r_est, rotation, atol=1e-9)
    np.testing.assert_allclose(t_est, translation, atol=1e-9)


def test_ate_per_alignment_mode_on_exact_similarity() -> None:
    rng = np.random.default_rng(20)
    p_gt = _random_trajectory(rng)
    rotation, translation, _ = _random_similarity(rng)
    scale = 1.7
    # p_gt = s R p_est + t, i.e. the estimate is p_gt mapped back.
    p_est = (p_gt - translation) @ rotation / scale

    assert ate_rmse(p_est, p_gt, align="sim3") < 1e-9
    assert ate_rmse(p_est, p_gt, align="se3") > 1e-2
    assert ate_rmse(p_est, p_gt, align="none") == translational_rmse(p_est, p_gt)
    expected_none = np.sqrt(np.mean(np.sum((p_est - p_gt) ** 2, axis=1)))
    assert translational_rmse(p_est, p_gt) == pytest.approx(expected_none, rel=1e-12)


def test_ate_se3_is_zero_for_rigid_motion() -> None:
    rng = np.random.default_rng(21)
    p_est = _random_trajectory(rng)
    rotation, translation, _ = _random_similarity(rng)
    p_gt = _apply(rotation, translation, 1.0, p_est)

    assert ate_rmse(p_est, p_gt, align="se3") < 1e-9
    assert ate_rmse(p_est, p_gt, align="none") > 1e-2


def test_ate_is_se3_by_default() -> None:
    rng = np.random.default_rng(22)
    p_est = _random_trajectory(rng)
    p_gt = _apply(*_random_similarity(rng), p_est) + rng.normal(scale=0.05, size=p_est.shape)

    assert ate_rmse(p_est, p_gt) == ate_rmse(p_est, p_gt, align="se3")
    assert ate_rmse(p_est, p_gt) != ate_rmse(p_est, p_gt, align="sim3")


@pytest.mark.parametrize("seed", [30, 31, 32])
def test_noisy_alignment_never_worse_than_weaker_alignment(seed: int) -> None:
    rng = np.random.default_rng(seed)
    p_gt = _random_trajectory(rng)
    rotation, translation, scale = _random_similarity(rng)
    p_est = _apply(rotation, translation, scale, p_gt) + rng.normal(scale=0.1, size=p_gt.shape)

    none = ate_rmse(p_est, p_gt, align="none")
    se3 = ate_rmse(p_est, p_gt, align="se3")
    sim3 = ate_rmse(p_est, p_gt, align="sim3")

    # Identity is a feasible SE(3), and every SE(3) is a feasible Sim(3).
    assert se3 <= none + 1e-12
    assert sim3 <= se3 + 1e-12
    assert sim3 > 0.0


def test_reflected_points_give_proper_rotation() -> None:
    rng = np.random.default_rng(40)
    p_src = _random_trajectory(rng)
    mirror = np.diag([1.0, 1.0, -1.0])
    p_dst = p_src @ mirror.T

    # The unconstrained orthogonal fit is the mirror itself (det -1).
    x = p_src - p_src.mean(axis=0)
    y = p_dst - p_dst.mean(axis=0)
    u, _, vt = np.linalg.svd(y.T @ x)
    assert np.linalg.det(u @ vt) == pytest.approx(-1.0)

    for with_scale in (False, True):
        rotation, _, scale = umeyama_alignment(p_src, p_dst, with_scale=with_scale)
        assert np.linalg.det(rotation) == pytest.approx(1.0, abs=1e-12)
        np.testing.assert_allclose(rotation @ rotation.T, np.eye(3), atol=1e-12)
        # Must match the best proper rotation from an independent solver.
        reference = Rotation.align_vectors(y, x)[0].as_matrix()
        np.testing.assert_allclose(rotation, reference, atol=1e-9)
        # With the sign flip the optimal scale is <y, R x> / <x, x>, not sum(d) / var.
        expected_scale = np.sum(y * (x @ reference.T)) / np.sum(x * x) if with_scale else 1.0
        assert scale == pytest.approx(expected_scale, abs=1e-9)
        assert 0.0 < scale < 1.0 or not with_scale


def test_trajectory_error_statistics() -> None:
    p_gt = np.zeros((4, 3))
    p_est = np.array([[1.0, 0.0, 0.0], [0.0, 2.0, 0.0], [0.0, 0.0, 3.0], [6.0, 8.0, 0.0]])

    err = trajectory_error(p_est, p_gt, align="none")

    assert isinstance(err, TrajectoryError)
    assert err.rmse_m == pytest.approx(np.sqrt((1 + 4 + 9 + 100) / 4))
    assert err.mean_m == pytest.approx(4.0)
    assert err.median_m == pytest.approx(2.5)
    assert err.max_m == pytest.approx(10.0)
    with pytest.raises(dataclasses.FrozenInstanceError):
        err.rmse_m = 0.0  # type: ignore[misc]


def test_trajectory_error_applies_alignment() -> None:
    rng = np.random.default_rng(50)
    p_est = _random_trajectory(rng)
    p_gt = _apply(*_random_similarity(rng), p_est)

    err = trajectory_error(p_est, p_gt, align="sim3")

    assert err.max_m < 1e-9
    assert err.rmse_m == ate_rmse(p_est, p_gt, align="sim3")


@pytest.mark.parametrize(
    ("p_est", "p_gt", "align", "match"),
    [
        (np.zeros((5, 3)), np.zeros((4, 3)), "se3", "same number of poses"),
        (np.zeros((5, 2)), np.zeros((5, 2)), "se3", r"shape \(N, 3\)"),
        (np.zeros(3), np.zeros(3), "none", r"shape \(N, 3\)"),
        (np.zeros((5, 3, 1)), np.zeros((5, 3, 1)), "none", r"shape \(N, 3\)"),
        (np.zeros((0, 3)), np.zeros((0, 3)), "none", "at least 1"),
        (np.zeros((1, 3)), np.zeros((1, 3)), "se3", "at least 2"),
        (np.zeros((2, 3)), np.zeros((2, 3)), "sim3", "at least 3"),
        (np.zeros((5, 3)), np.zeros((5, 3)), "affine", "align must be one of"),
    ],
)
def test_bad_input_raises(p_est: np.ndarray, p_gt: np.ndarray, align: str, match: str) -> None:
    with pytest.raises(ValueError, match=match):
        ate_rmse(p_est, p_gt, align=align)  # type: ignore[arg-type]


@pytest.mark.parametrize("bad", [np.nan, np.inf])
def test_non_finite_input_raises(bad: float) -> None:
    p = np.zeros((5, 3))
    p_bad = p.copy()
    p_bad[2, 1] = bad
    for fn in (
        lambda: translational_rmse(p_bad, p),
        lambda: ate_rmse(p, p_bad, align="sim3"),
        lambda: umeyama_alignment(p_bad, p, with_scale=False),
    ):
        with pytest.raises(ValueError, match="NaN or infinite"):
            fn()


def test_umeyama_bad_input_raises() -> None:
    with pytest.raises(ValueError, match="p_dst must have shape"):
        umeyama_alignment(np.zeros((4, 3)), np.zeros((4, 4)), with_scale=True)
    with pytest.raises(ValueError, match="at least 3"):
        umeyama_alignment(np.zeros((2, 3)), np.ones((2, 3)), with_scale=True)


def test_identical_points_do_not_crash() -> None:
    p_src = np.tile([1000.0, -3.0, 2.5], (6, 1))
    p_dst = np.tile([4.0, 5.0, 6.0], (6, 1))

    rotation, translation, scale = umeyama_alignment(p_src, p_dst, with_scale=True)

    assert scale == 1.0
    assert np.linalg.det(rotation) == pytest.approx(1.0, abs=1e-12)
    np.testing.assert_allclose(_apply(rotation, translation, scale, p_src), p_dst, atol=1e-9)
    for align in ("none", "se3", "sim3"):
        assert np.isfinite(ate_rmse(p_src, p_dst, align=align))


def test_collinear_points_do_not_crash() -> None:
    rng = np.random.default_rng(60)
    direction = np.array([1.0, 2.0, -0.5])
    p_est = np.outer(np.linspace(0.0, 5.0, 20), direction)
    p_gt = _apply(*_random_similarity(rng), p_est)

    rotation, _, _ = umeyama_alignment(p_est, p_gt, with_scale=True)

    assert np.linalg.det(rotation) == pytest.approx(1.0, abs=1e-12)
    assert ate_rmse(p_est, p_gt, align="sim3") < 1e-9
    assert ate_rmse(p_est, p_gt, align="se3") > 1e-2


def test_matches_scipy_align_vectors_reference() -> None:
    """Closed-form cross-check via scipy's Kabsch solver on centred points."""
    rng = np.random.default_rng(70)
    p_est = _random_trajectory(rng)
    p_gt = _apply(*_random_similarity(rng), p_est) + rng.normal(scale=0.2, size=p_est.shape)

    x = p_est - p_est.mean(axis=0)
    y = p_gt - p_gt.mean(axis=0)
    ref_rot = Rotation.align_vectors(y, x)[0].as_matrix()
    # Given R, the optimal scale is <y, R x> / <x, x>; t follows from the means.
    ref_scale = float(np.sum(y * (x @ ref_rot.T)) / np.sum(x * x))

    for with_scale, s in ((False, 1.0), (True, ref_scale)):
        ref_t = p_gt.mean(axis=0) - s * ref_rot @ p_est.mean(axis=0)
        rotation, translation, scale = umeyama_alignment(p_est, p_gt, with_scale=with_scale)
        np.testing.assert_allclose(rotation, ref_rot, atol=1e-9)
        np.testing.assert_allclose(translation, ref_t, atol=1e-9)
        assert scale == pytest.approx(s, abs=1e-9)

        ref_ate = np.sqrt(np.mean(np.sum((_apply(ref_rot, ref_t, s, p_est) - p_gt) ** 2, axis=1)))
        align = "sim3" if with_scale else "se3"
        assert ate_rmse(p_est, p_gt, align=align) == pytest.approx(ref_ate, abs=1e-9)


@pytest.mark.parametrize("align", ["se3", "sim3"])
def test_matches_brute_force_least_squares(align: str) -> None:
    """ATE must equal the minimum found by a generic nonlinear least-squares solver."""
    rng = np.random.default_rng(80)
    p_est = _random_trajectory(rng, n=30)
    p_gt = _apply(*_random_similarity(rng), p_est) + rng.normal(scale=0.2, size=p_est.shape)

    def residuals(params: np.ndarray) -> np.ndarray:
        rotation = Rotation.from_rotvec(params[:3]).as_matrix()
        scale = float(np.exp(params[6])) if align == "sim3" else 1.0
        return (_apply(rotation, params[3:6], scale, p_est) - p_gt).ravel()

    # Start from a deliberately wrong guess; try a few to avoid local minima.
    best = np.inf
    for start in rng.normal(size=(5, 7)):
        sol = least_squares(residuals, start, xtol=1e-15, ftol=1e-15, gtol=1e-15)
        best = min(best, float(np.sqrt(np.mean(np.sum(sol.fun.reshape(-1, 3) ** 2, axis=1)))))

    assert ate_rmse(p_est, p_gt, align=align) == pytest.approx(best, rel=1e-7)


@pytest.mark.parametrize("with_scale", [False, True])
def test_matches_evo_reference(with_scale: bool) -> None:
    """Cross-check against evo (GPL, test-time only) if it is installed."""
    evo_geometry = pytest.importorskip("evo.core.geometry")
    rng = np.random.default_rng(90)
    p_est = _random_trajectory(rng)
    p_gt = _apply(*_random_similarity(rng), p_est) + rng.normal(scale=0.2, size=p_est.shape)

    ref_rot, ref_t, ref_s = evo_geometry.umeyama_alignment(p_est.T, p_gt.T, with_scale)
    rotation, translation, scale = umeyama_alignment(p_est, p_gt, with_scale=with_scale)

    np.testing.assert_allclose(rotation, ref_rot, atol=1e-9)
    np.testing.assert_allclose(translation, ref_t, atol=1e-9)
    assert scale == pytest.approx(ref_s, abs=1e-9)
    ref_ate = np.sqrt(np.mean(np.sum((_apply(ref_rot, ref_t, ref_s, p_est) - p_gt) ** 2, axis=1)))
    align = "sim3" if with_scale else "se3"
    assert ate_rmse(p_est, p_gt, align=align) == pytest.approx(ref_ate, abs=1e-9)


def _random_poses(rng: np.random.Generator, n: int = 120) -> tuple[np.ndarray, np.ndarray]:
    """(n, 3, 3) rotations and (n, 3) positions of a random walk, steps of about 10 cm."""
    t = np.cumsum(rng.normal(scale=0.06, size=(n, 3)), axis=0)
    R = Rotation.from_rotvec(np.cumsum(rng.normal(scale=0.05, size=(n, 3)), axis=0)).as_matrix()
    return R, t


def test_path_delta_pairs() -> None:
    p = np.zeros((7, 3))
    p[:, 0] = [0.0, 0.5, 1.0, 1.25, 1.75, 2.0, 2.25]  # exact in binary
    np.testing.assert_array_equal(path_delta_pairs(p, 1.0), [[0, 2], [2, 5]])
    assert path_delta_pairs(p[:2], 1.0).shape == (0, 2)
    with pytest.raises(ValueError):
        path_delta_pairs(p, 0.0)


def test_relative_pose_error_is_zero_for_a_rigidly_moved_estimate() -> None:
    rng = np.random.default_rng(50)
    R, t = _random_poses(rng)
    rotation, translation, _ = _random_similarity(rng)
    rpe = relative_pose_error(rotation @ R, _apply(rotation, translation, 1.0, t), R, t, delta_m=1.0)
    assert rpe.pairs >= 3 and rpe.rmse_m < 1e-12 and rpe.delta_m == 1.0


def test_relative_pose_error_without_pairs_is_nan() -> None:
    R, t = _random_poses(np.random.default_rng(51), n=3)
    rpe = relative_pose_error(R, t, R, t, delta_m=100.0)
    assert rpe.pairs == 0 and np.isnan(rpe.rmse_m) and np.isnan(rpe.rmse_cm_per_m)


@pytest.mark.parametrize("pairs_from", ["estimate", "ground_truth"])
def test_relative_pose_error_matches_evo_rpe(pairs_from: str) -> None:
    """evo_rpe --delta 1 --delta_unit m (translation part, consecutive pairs), test-time only."""
    evo_metrics = pytest.importorskip("evo.core.metrics")
    from evo.core.trajectory import PosePath3D

    rng = np.random.default_rng(52)
    R_gt, t_gt = _random_poses(rng)
    noise = Rotation.from_rotvec(rng.normal(scale=0.01, size=(len(R_gt), 3))).as_matrix()
    R_est, t_est = R_gt @ noise, t_gt + rng.normal(scale=0.02, size=t_gt.shape)

    def path(R: np.ndarray, t: np.ndarray) -> PosePath3D:
        T = np.tile(np.eye(4), (len(R), 1, 1))
        T[:, :3, :3], T[:, :3, 3] = R, t
        return PosePath3D(poses_se3=list(T))

    ref = evo_metrics.RPE(evo_metrics.PoseRelation.translation_part, delta=1.0, delta_unit=evo_metrics.Unit.meters, all_pairs=False, pairs_from_reference=pairs_from == "ground_truth")
    ref.process_data((path(R_gt, t_gt), path(R_est, t_est)))
    rpe = relative_pose_error(R_est, t_est, R_gt, t_gt, delta_m=1.0, pairs_from=pairs_from)
    assert rpe.pairs == len(ref.error) >= 3
    assert rpe.rmse_m == pytest.approx(ref.get_statistic(evo_metrics.StatisticsType.rmse), rel=1e-9)
    assert rpe.max_m == pytest.approx(ref.get_statistic(evo_metrics.StatisticsType.max), rel=1e-9)
    assert rpe.rmse_cm_per_m == pytest.approx(100.0 * rpe.rmse_m)
