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
    p_est, p_gt = _validate_pair(
        p_est_world, p_gt_world, "p_est_world", "p_gt_world", _MIN_POSES[align]
    )

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


def _rmse(errors: np.ndarray) -> float:
    return float(np.sqrt(np.mean(errors**2)))


def _validate_pair(
    a: np.ndarray, b: np.ndarray, name_a: str, name_b: str, min_poses: int
) -> tuple[np.ndarray, np.ndarray]:
    """Return both inputs as float64 (N, 3) arrays or raise ValueError."""
    a = np.asarray(a, dtype=np.float64)
    b = np.asarray(b, dtype=np.float64)
    for name, p in ((name_a, a), (name_b, b)):
        if p.ndim != 2 or p.shape[1] != 3:
            raise ValueError(f"{name} must have shape (N, 3), got {p.shape}")
        if not np.all(np.isfinite(p)):
            raise ValueError(f"{name} contains NaN or infinite values")
    if a.shape[0] != b.shape[0]:
        raise ValueError(
            f"{name_a} and {name_b} must have the same number of poses, "
            f"got {a.shape[0]} and {b.shape[0]}"
        )
    if a.shape[0] < min_poses:
        raise ValueError(f"need at least {min_poses} poses, got {a.shape[0]}")
    return a, b
