"""Trajectory accuracy metrics: translational RMSE, Umeyama alignment and ATE.

All positions are ``(N, 3)`` float arrays in metres, one row per pose. Row ``i``
of the estimate and row ``i`` of the ground truth must describe the same
instant; timestamp association is the caller's job.

Frames: ``p_est_world`` is expressed in the estimator's world frame and
``p_gt_world`` in the ground-truth world frame. Alignment maps the estimate
into the ground-truth frame, ``p_gt ≈ s R p_est + t``, so all errors are
reported in ground-truth metres.
"""

from __future__ import annotations

import dataclasses
from typing import Literal, get_args

import numpy as np

AlignMode = Literal["none", "se3", "sim3"]

# Fewest poses for which each alignment is meaningful. With fewer poses the
# alignment can always fit the data exactly and the error says nothing.
_MIN_POSES: dict[str, int] = {"none": 1, "se3": 2, "sim3": 3}


@dataclasses.dataclass(frozen=True)
class TrajectoryError:
    """Statistics of the per-pose position error norms, in metres."""

    rmse_m: float
    mean_m: float
    median_m: float
    max_m: float


def translational_rmse(p_est_world: np.ndarray, p_gt_world: np.ndarray) -> float:
    """Root-mean-square position error in metres, without any alignment.

    Args:
        p_est_world: (N, 3) estimated positions in metres.
        p_gt_world: (N, 3) ground-truth positions in metres, same frame as the
            estimate.
    """
    p_est, p_gt = _validate_pair(p_est_world, p_gt_world, "p_est_world", "p_gt_world", 1)
    return _rmse(np.linalg.norm(p_est - p_gt, axis=1))


def umeyama_alignment(
    p_src: np.ndarray,
    p_dst: np.ndarray,
    *,
    with_scale: bool,
) -> tuple[np.ndarray, np.ndarray, float]:
    """Least-squares similarity transform with ``p_dst ≈ s R p_src + t``.

    Implements Umeyama, "Least-squares estimation of transformation parameters
    between two point patterns", IEEE PAMI 1991. The rotation is always proper
    (det +1), also when the best orthogonal fit would be a reflection.

    Degenerate geometry does not raise: for identical or collinear points the
    rotation is still a valid (non-unique) minimiser, and when ``p_src`` has
    (numerically) zero spread the scale falls back to 1.

    Args:
        p_src: (N, 3) source positions in metres, source frame.
        p_dst: (N, 3) destination positions in metres, destination frame.
        with_scale: Estimate the scale ``s``; if False, ``s`` is exactly 1.

    Returns:
        ``(R, t, s)``: (3, 3) rotation from source to destination frame,
        (3,) translation in destination metres, and the unitless scale.
    """
    min_poses = _MIN_POSES["sim3" if with_scale else "se3"]
    src, dst = _validate_pair(p_src, p_dst, "p_src", "p_dst", min_poses)

    mu_src = src.mean(axis=0)
    mu_dst = dst.mean(axis=0)
    x = src - mu_src
    y = dst - mu_dst

    # Cross-covariance Sigma_xy = 1/n sum (y_i - mu_y)(x_i - mu_x)^T (eq. 38).
    cov = y.T @ x / src.shape[0]
    u, d, vt = np.linalg.svd(cov)

    # Flip the weakest axis if U V^T would be a reflection (eq. 39/43).
    signs = np.ones(3)
    if np.linalg.det(u) * np.linalg.det(vt) < 0.0:
        signs[2] = -1.0
    rotation = u @ np.diag(signs) @ vt

    scale = 1.0
    if with_scale:
        var_src = float(np.mean(np.sum(x**2, axis=1)))  # eq. 36
        tiny = np.finfo(np.float64).eps * max(1.0, float(np.max(np.abs(src)))) ** 2
        if var_src > tiny:
            scale = float(np.dot(d, signs) / var_src)  # eq. 42

    translation = mu_dst - scale * rotation @ mu_src  # eq. 41
    return rotation, translation, scale


def trajectory_error(
    p_est_world: np.ndarray,
    p_gt_world: np.ndarray,
    *,
    align: AlignMode = "se3",
) -> TrajectoryError:
    """Absolute trajectory error statistics in metres after alignment.

    Args:
        p_est_world: (N, 3) estimated positions in metres, estimator world frame.
        p_gt_world: (N, 3) ground-truth positions in metres, ground-truth frame.
        align: ``"none"`` compares the positions as given, ``"se3"`` first
            applies the best rigid transform to the estimate, ``"sim3"`` the
            best similarity transform (for monocular scale ambiguity). Needs
            at least 1, 2 and 3 poses respectively.
    """
    if align not in _MIN_POSES:
        raise ValueError(f"align must be one of {get_args(AlignMode)}, got {align!r}")
    p_est, p_gt = _validate_pair(p_est_world, p_gt_world, "p_est_world", "p_gt_world", _MIN_POSES[align])

    if align != "none":
        rotation, translation, scale = umeyama_alignment(p_est, p_gt, with_scale=align == "sim3")
        p_est = scale * p_est @ rotation.T + translation

    errors = np.linalg.norm(p_est - p_gt, axis=1)
    return TrajectoryError(
        rmse_m=_rmse(errors),
        mean_m=float(np.mean(errors)),
        median_m=float(np.median(errors)),
        max_m=float(np.max(errors)),
    )


def ate_rmse(
    p_est_world: np.ndarray,
    p_gt_world: np.ndarray,
    *,
    align: AlignMode = "se3",
) -> float:
    """Absolute trajectory error RMSE in metres after alignment.

    See :func:`trajectory_error` for the arguments.
    """
    return trajectory_error(p_est_world, p_gt_world, align=align).rmse_m


@dataclasses.dataclass(frozen=True)
class RelativeError:
    """Statistics of relative translation errors over `pairs` pose pairs, in metres per
    pair (pairs about `delta_m` metres of travelled path apart; NaN without pairs)."""

    rmse_m: float
    mean_m: float
    median_m: float
    max_m: float
    pairs: int
    delta_m: float

    @property
    def rmse_cm_per_m(self) -> float:
        """RMSE in centimetres per metre travelled: 100 rmse_m / delta_m."""
        return 100.0 * self.rmse_m / self.delta_m


def path_delta_pairs(p_world: np.ndarray, delta_m: float) -> np.ndarray:
    """Consecutive index pairs `(i, j)` (K, 2) along a trajectory, each ending where the path
    travelled since the pair's start first reaches `delta_m` metres; the next pair starts
    there. This is evo's ``filter_pairs_by_path`` (``evo_rpe --delta D --delta_unit m``,
    consecutive pairs).

    Args:
        p_world: (N, 3) positions in metres, in time order.
        delta_m: path length per pair in metres, more than 0.
    """
    if not delta_m > 0.0:
        raise ValueError(f"delta_m must be positive, got {delta_m}")
    p = np.asarray(p_world, dtype=np.float64)
    if p.ndim != 2 or p.shape[1] != 3:
        raise ValueError(f"p_world must have shape (N, 3), got {p.shape}")
    ids = [0] if len(p) else []
    path = 0.0
    for i in range(1, len(p)):
        path += float(np.linalg.norm(p[i] - p[i - 1]))
        if path >= delta_m:
            ids.append(i)
            path = 0.0
    return np.array(list(zip(ids, ids[1:])), dtype=np.int64).reshape(-1, 2)


def relative_pose_error(
    R_est_world: np.ndarray,
    t_est_world: np.ndarray,
    R_gt_world: np.ndarray,
    t_gt_world: np.ndarray,
    *,
    delta_m: float = 1.0,
    pairs_from: Literal["estimate", "ground_truth"] = "estimate",
) -> RelativeError:
    """Translational relative pose error per `delta_m` metres travelled.

    For each pair ``(i, j)`` of :func:`path_delta_pairs` (path measured on the estimate by
    default, as evo does unless ``--pairs_from_reference``), the error pose is
    ``E = (Q_i⁻¹ Q_j)⁻¹ (P_i⁻¹ P_j)`` with ``Q`` the ground-truth and ``P`` the estimated
    poses ``T_world_camera``; the error is ``‖translation(E)‖``. This is evo's
    ``evo_rpe tum GT EST --delta 1 --delta_unit m`` (translation part, consecutive pairs)
    for ``delta_m = 1``. Relative poses do not change under a rigid alignment of the
    estimate, so none is applied.

    Args:
        R_est_world, t_est_world: (N, 3, 3) and (N, 3) estimated poses, metres.
        R_gt_world, t_gt_world: (N, 3, 3) and (N, 3) ground-truth poses of the same instants.
        delta_m: path length per pair in metres.
        pairs_from: trajectory whose path selects the pairs.
    """
    p_est, p_gt = _validate_pair(t_est_world, t_gt_world, "t_est_world", "t_gt_world", 1)
    R_est = np.asarray(R_est_world, dtype=np.float64)
    R_gt = np.asarray(R_gt_world, dtype=np.float64)
    for name, R in (("R_est_world", R_est), ("R_gt_world", R_gt)):
        if R.shape != (len(p_est), 3, 3):
            raise ValueError(f"{name} must have shape ({len(p_est)}, 3, 3), got {R.shape}")
    if pairs_from not in ("estimate", "ground_truth"):
        raise ValueError(f"pairs_from must be 'estimate' or 'ground_truth', got {pairs_from!r}")
    pairs = path_delta_pairs(p_est if pairs_from == "estimate" else p_gt, delta_m)
    if len(pairs) == 0:
        nan = float("nan")
        return RelativeError(nan, nan, nan, nan, 0, float(delta_m))
    i, j = pairs[:, 0], pairs[:, 1]
    # Relative motions T_i⁻¹ T_j: rotation R_iᵀ R_j, translation R_iᵀ (t_j - t_i).
    Rq = np.einsum("nki,nkj->nij", R_gt[i], R_gt[j])
    tq = np.einsum("nki,nk->ni", R_gt[i], p_gt[j] - p_gt[i])
    tp = np.einsum("nki,nk->ni", R_est[i], p_est[j] - p_est[i])
    # E = Q_rel⁻¹ P_rel: its translation is Rqᵀ (tp - tq).
    errors = np.linalg.norm(np.einsum("nki,nk->ni", Rq, tp - tq), axis=1)
    return RelativeError(
        rmse_m=_rmse(errors),
        mean_m=float(np.mean(errors)),
        median_m=float(np.median(errors)),
        max_m=float(np.max(errors)),
        pairs=int(len(pairs)),
        delta_m=float(delta_m),
    )


def _rmse(errors: np.ndarray) -> float:
    return float(np.sqrt(np.mean(errors**2)))


def _validate_pair(a: np.ndarray, b: np.ndarray, name_a: str, name_b: str, min_poses: int) -> tuple[np.ndarray, np.ndarray]:
    """Return both inputs as float64 (N, 3) arrays or raise ValueError."""
    a = np.asarray(a, dtype=np.float64)
    b = np.asarray(b, dtype=np.float64)
    for name, p in ((name_a, a), (name_b, b)):
        if p.ndim != 2 or p.shape[1] != 3:
            raise ValueError(f"{name} must have shape (N, 3), got {p.shape}")
        if not np.all(np.isfinite(p)):
            raise ValueError(f"{name} contains NaN or infinite values")
    if a.shape[0] != b.shape[0]:
        raise ValueError(f"{name_a} and {name_b} must have the same number of poses, got {a.shape[0]} and {b.shape[0]}")
    if a.shape[0] < min_poses:
        raise ValueError(f"need at least {min_poses} poses, got {a.shape[0]}")
    return a, b
