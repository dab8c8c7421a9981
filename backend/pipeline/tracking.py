"""Motion-only pose refinement against known world points (the tracking step of DESIGN §5).

Gauss-Newton on the pixel reprojection error of one pose `T_world_camera`, with the
optimizer's retraction (`R Exp(δθ)`, `t + δt`) and a Cauchy kernel; the points are held
fixed. The analytic Jacobian is the optimizer's (`factors.point_reprojection`).
"""

from __future__ import annotations

import dataclasses

import numpy as np

from backend.geometry import so3
from backend.geometry.camera import PinholeCamera
from backend.optim import factors


@dataclasses.dataclass(frozen=True)
class PoseRefinement:
    """Refined pose, initial and final robust cost (½ Σ ρ(r²/σ²)), iterations, inlier count
    (whitened reprojection error below `3 σ`)."""

    R_world_camera: np.ndarray
    t_world_camera: np.ndarray
    initial_cost: float
    final_cost: float
    iterations: int
    inliers: int


def reprojection(camera: PinholeCamera, R_world_camera: np.ndarray, t_world_camera: np.ndarray, p_world: np.ndarray, uv: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Residuals (M, 2) in pixels, their Jacobians (M, 2, 6) w.r.t. the pose's `(δθ, δt)`
    and depths (M,) of world points (M, 3) observed at `uv` (M, 2) in the left image."""
    M = len(p_world)
    res, J, depth = factors.point_reprojection(
        camera, np.ascontiguousarray(p_world, dtype=float), np.zeros((M, 3, 1)), np.arange(M),
        R_world_camera[None], t_world_camera[None], np.zeros(M, dtype=np.int64), np.zeros((M, 3)), uv,
    )
    return res, J[:, :, 1:], depth


def _cauchy(s2: np.ndarray, c2: float) -> tuple[np.ndarray, np.ndarray]:
    """Cauchy ρ(s²) = c² log(1 + s²/c²) and its weight ρ'(s²)."""
    return c2 * np.log1p(s2 / c2), 1.0 / (1.0 + s2 / c2)


def refine_pose(
    camera: PinholeCamera,
    R_world_camera: np.ndarray,
    t_world_camera: np.ndarray,
    p_world: np.ndarray,
    uv: np.ndarray,
    *,
    sigma_px: float = 1.0,
    cauchy: float = 3.0,
    max_iterations: int = 10,
) -> PoseRefinement:
    """Refine one pose from world points (M, 3) and their pixels (M, 2).

    Iteratively reweighted Gauss-Newton with a Cauchy kernel of scale `cauchy` (whitened
    units); a step that raises the cost is halved (at most 4 times). With fewer than three
    usable points, the pose is returned unchanged.
    """
    R, t = np.array(R_world_camera, dtype=float), np.array(t_world_camera, dtype=float)
    c2 = cauchy**2

    def cost_of(R_: np.ndarray, t_: np.ndarray) -> tuple[float, np.ndarray, np.ndarray, np.ndarray]:
        res, J, depth = reprojection(camera, R_, t_, p_world, uv)
        res = res / sigma_px
        s2 = np.sum(res**2, axis=1)
        s2[depth <= 0] = 1e6 * c2
        rho, w = _cauchy(s2, c2)
        return 0.5 * float(np.sum(rho)), res, J / sigma_px, np.where(depth > 0, w, 0.0)

    if len(p_world) < 3:
        return PoseRefinement(R, t, 0.0, 0.0, 0, 0)
    cost, res, J, w = cost_of(R, t)
    initial = cost
    iterations = 0
    for _ in range(max_iterations):
        H = np.einsum("m,mki,mkj->ij", w, J, J)
        g = -np.einsum("m,mki,mk->i", w, J, res)
        try:
            delta = np.linalg.solve(H + 1e-9 * np.eye(6), g)
        except np.linalg.LinAlgError:
            break
        step = 1.0
        for _ in range(5):
            R_new, t_new = R @ so3.exp(step * delta[:3]), t + step * delta[3:]
            new = cost_of(R_new, t_new)
            if new[0] <= cost:
                break
            step *= 0.5
        else:
            break
        iterations += 1
        improvement = cost - new[0]
        R, t = R_new, t_new
        cost, res, J, w = new
        if improvement <= 1e-10 * max(cost, 1e-300) or np.max(np.abs(step * delta)) < 1e-10:
            break
    inliers = int(np.sum(np.sum(res**2, axis=1) < 9.0))
    return PoseRefinement(R, t, initial, cost, iterations, inliers)
