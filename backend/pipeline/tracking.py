"""Tracking (DESIGN §5.2): motion-only pose refinement against known world points and
lines, matching map points to keypoints by projection, and relocalization by PnP.

Refinement is Gauss-Newton on the pixel reprojection error of one pose `T_world_camera`,
with the optimizer's retraction (`R Exp(δθ)`, `t + δt`) and a Cauchy kernel; the landmarks
are held fixed. The analytic Jacobians are the optimizer's (`factors.point_reprojection`,
`factors.line_reprojection`).
"""

from __future__ import annotations

import dataclasses

import numpy as np

from backend.geometry import line as line_geo
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


def reprojection(
    camera: PinholeCamera, R_world_camera: np.ndarray, t_world_camera: np.ndarray, p_world: np.ndarray, uv: np.ndarray, *, offset_camera: np.ndarray | None = None
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Residuals (M, 2) in pixels, their Jacobians (M, 2, 6) w.r.t. the pose's `(δθ, δt)`
    and depths (M,) of world points (M, 3) observed at `uv` (M, 2) in the left image, or
    with `offset_camera` (3,) (metres, the left camera's frame; e.g. `camera.offset_right`)
    in the camera there (its depth)."""
    M = len(p_world)
    res, J, depth = factors.point_reprojection(
        camera,
        np.ascontiguousarray(p_world, dtype=float),
        np.zeros((M, 3, 1)),
        np.arange(M),
        R_world_camera[None],
        t_world_camera[None],
        np.zeros(M, dtype=np.int64),
        np.zeros((M, 3)) if offset_camera is None else np.tile(np.asarray(offset_camera, dtype=float), (M, 1)),
        uv,
    )
    return res, J[:, :, 1:], depth


def translation_std_m(J_whitened: np.ndarray) -> float:
    """The largest standard deviation (m) of a pose's translation from whitened residual
    Jacobians `J_whitened` (..., 6) w.r.t. `(δθ, δt)`: the square root of the largest
    eigenvalue of the translation block of `(JᵀJ)⁻¹` (Gauss-Newton's covariance); inf where
    JᵀJ is singular."""
    J = J_whitened.reshape(-1, 6)
    H = np.tensordot(J, J, axes=([0], [0]))
    try:
        return float(np.sqrt(np.max(np.linalg.eigvalsh(np.linalg.inv(H)[3:, 3:]))))
    except np.linalg.LinAlgError:
        return float("inf")


def _cauchy(s2: np.ndarray, c2: float) -> tuple[np.ndarray, np.ndarray]:
    """Cauchy ρ(s²) = c² log(1 + s²/c²) and its weight ρ'(s²)."""
    return c2 * np.log1p(s2 / c2), 1.0 / (1.0 + s2 / c2)


def line_reprojection(
    camera: PinholeCamera, R_world_camera: np.ndarray, t_world_camera: np.ndarray, m_world: np.ndarray, v_world: np.ndarray, segments_uv: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Endpoint-to-line residuals (M, 2) in pixels and their Jacobians (M, 2, 6) w.r.t. the
    pose's `(δθ, δt)` of world lines (Plücker, (M, 3) each) observed as left-image segments
    `segments_uv` (M, 4) = start and end pixels."""
    M = len(m_world)
    x_s, x_e = camera.normalize(segments_uv[:, :2]), camera.normalize(segments_uv[:, 2:])
    res, J = factors.line_reprojection(
        camera,
        np.ascontiguousarray(m_world, dtype=float),
        np.ascontiguousarray(v_world, dtype=float),
        np.zeros((M, 6, 1)),
        np.arange(M),
        R_world_camera[None],
        t_world_camera[None],
        np.zeros(M, dtype=np.int64),
        np.zeros((M, 3)),
        x_s,
        x_e,
    )
    return res, J[:, :, 1:]


def refine_pose(
    camera: PinholeCamera,
    R_world_camera: np.ndarray,
    t_world_camera: np.ndarray,
    p_world: np.ndarray,
    uv: np.ndarray,
    *,
    lines_world: tuple[np.ndarray, np.ndarray] | None = None,
    segments_uv: np.ndarray | None = None,
    sigma_px: float = 1.0,
    cauchy: float = 3.0,
    max_iterations: int = 10,
) -> PoseRefinement:
    """Refine one pose from world points (M, 3) and their left pixels (M, 2), and optionally
    world lines `lines_world = (m, v)` (L, 3) observed as left segments `segments_uv` (L, 4).

    Iteratively reweighted Gauss-Newton with a Cauchy kernel of scale `cauchy` (whitened
    units) on every point and line residual; a step that raises the cost is halved (at
    most 4 times). With fewer than three usable features, the pose is returned unchanged.
    `inliers` counts points whose whitened error is below 3 (lines are not counted).
    """
    R, t = np.array(R_world_camera, dtype=float), np.array(t_world_camera, dtype=float)
    c2 = cauchy**2
    n_lines = 0 if lines_world is None or segments_uv is None else len(segments_uv)

    def cost_of(R_: np.ndarray, t_: np.ndarray) -> tuple[float, np.ndarray, np.ndarray, np.ndarray]:
        res, J, depth = reprojection(camera, R_, t_, p_world, uv)
        valid = depth > 0
        if n_lines:
            assert lines_world is not None and segments_uv is not None
            res_l, J_l = line_reprojection(camera, R_, t_, lines_world[0], lines_world[1], segments_uv)
            res, J = np.concatenate([res, res_l]), np.concatenate([J, J_l])
            valid = np.concatenate([valid, np.all(np.isfinite(res_l), axis=1)])
        res = np.where(valid[:, None], res, 0.0) / sigma_px
        J = np.where(valid[:, None, None], J, 0.0)
        s2 = np.sum(res**2, axis=1)
        s2[~valid] = 1e6 * c2
        rho, w = _cauchy(s2, c2)
        return 0.5 * float(np.sum(rho)), res, J / sigma_px, np.where(valid, w, 0.0)

    if len(p_world) + n_lines < 3:
        return PoseRefinement(R, t, 0.0, 0.0, 0, 0)
    cost, res, J, w = cost_of(R, t)
    initial = cost
    iterations = 0
    for _ in range(max_iterations):
        Jw = J * w[:, None, None]
        H = np.tensordot(Jw, J, axes=([0, 1], [0, 1]))
        g = -np.tensordot(Jw, res, axes=([0, 1], [0, 1]))
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
    inliers = int(np.sum(np.sum(res[: len(p_world)] ** 2, axis=1) < 9.0))
    return PoseRefinement(R, t, initial, cost, iterations, inliers)


def match_by_projection(
    camera: PinholeCamera,
    R_world_camera: np.ndarray,
    t_world_camera: np.ndarray,
    p_world: np.ndarray,
    descriptors: np.ndarray,
    keypoints_uv: np.ndarray,
    keypoint_descriptors: np.ndarray,
    *,
    radius_px: float,
    max_hamming: int,
    ratio: float,
    min_depth_m: float = 0.1,
) -> np.ndarray:
    """Match map points (P, 3) world with ORB descriptors (P, 32) to the keypoints (N, 2)
    of an image taken from the predicted pose: a point's candidates are the keypoints
    within `radius_px` of its projection; the closest descriptor wins if its Hamming
    distance is `<= max_hamming` and `< ratio` times the second closest (one-to-one).
    Returns (P,) keypoint index per map point, -1 where unmatched."""
    from backend.frontend.radius_match import match_in_radius

    out = np.full(len(p_world), -1, dtype=np.int64)
    if len(p_world) == 0 or len(keypoints_uv) == 0:
        return out
    p_cam = (p_world - t_world_camera) @ R_world_camera
    front = p_cam[:, 2] > min_depth_m
    uv = np.full((len(p_world), 2), -1e6)
    uv[front] = camera.project(p_cam[front])
    visible = np.flatnonzero(front & camera.in_image(uv))
    if len(visible) == 0:
        return out
    out[visible] = match_in_radius(uv[visible], descriptors[visible], keypoints_uv, keypoint_descriptors, radius_px=radius_px, max_hamming=max_hamming, ratio=ratio)
    return out


def relocalize(
    camera: PinholeCamera,
    p_world: np.ndarray,
    descriptors: np.ndarray,
    keypoints_uv: np.ndarray,
    keypoint_descriptors: np.ndarray,
    *,
    max_hamming: int,
    ratio: float,
    min_inliers: int,
    seed: int = 0,
    candidates: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
    """Pose without a prediction: descriptor matches between map points and keypoints
    (no spatial gate), then PnP inside RANSAC (OpenCV, 3 px). Returns `(R_world_camera,
    t_world_camera, match)` with `match` (P,) the keypoint of each map point (-1: none or
    outlier), or None with fewer than `min_inliers` inliers. `candidates`: the two nearest
    keypoints of each map point as :func:`nearest_hamming` gives them for `descriptors`
    (rows, cols, distances), where the caller has them already (None: searched here)."""
    from backend.frontend.points import best_matches, nearest_hamming

    if len(p_world) < min_inliers or len(keypoints_uv) < min_inliers:
        return None
    # The ratio test needs the two nearest.
    rows, cols, dist = nearest_hamming(descriptors, keypoint_descriptors, k=2) if candidates is None else candidates
    near = dist <= max_hamming
    match = best_matches(rows[near], cols[near], dist[near], n_rows=len(p_world), max_distance=max_hamming, ratio=ratio)
    i = np.flatnonzero(match >= 0)
    if len(i) < min_inliers:
        return None
    pose = pnp_ransac(camera, p_world[i], keypoints_uv[match[i]], min_inliers=min_inliers, seed=seed)
    if pose is None:
        return None
    keep = np.full(len(p_world), -1, dtype=np.int64)
    keep[i[pose[2]]] = match[i[pose[2]]]
    return pose[0], pose[1], keep


def pnp_ransac(camera: PinholeCamera, p_world: np.ndarray, uv: np.ndarray, *, min_inliers: int, seed: int = 0) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
    """Camera pose from world points `p_world` (N, 3) seen at pixels `uv` (N, 2): EPnP inside
    RANSAC (OpenCV, 3 px, 200 iterations, seeded). Returns `(R_world_camera, t_world_camera,
    inlier mask (N,))`, or None with fewer than `min_inliers` inliers."""
    import cv2

    if len(p_world) < max(min_inliers, 4):
        return None
    cv2.setRNGSeed(seed)
    ok, rvec, tvec, inliers = cv2.solvePnPRansac(
        p_world.astype(np.float64),
        uv.astype(np.float64),
        camera.K,
        None,
        iterationsCount=200,
        reprojectionError=3.0,
        confidence=0.999,
        flags=cv2.SOLVEPNP_EPNP,
    )
    if not ok or inliers is None or len(inliers) < min_inliers:
        return None
    R_camera_world = cv2.Rodrigues(rvec)[0]
    mask = np.zeros(len(p_world), bool)
    mask[inliers.ravel()] = True
    return R_camera_world.T, -R_camera_world.T @ tvec.ravel(), mask


def merge_matches(match: np.ndarray, more: np.ndarray, *, n_keypoints: int) -> np.ndarray:
    """`match` (a keypoint index per map point, -1 for none) with the matches of `more` added
    where `match` has none and `more`'s keypoint is not already used by `match`."""
    used = np.zeros(n_keypoints, bool)
    used[match[match >= 0]] = True
    extra = np.flatnonzero((match < 0) & (more >= 0))
    extra = extra[~used[more[extra]]]
    merged = match.copy()
    merged[extra] = more[extra]
    return merged


def pixel_errors(camera: PinholeCamera, R: np.ndarray, t: np.ndarray, p_world: np.ndarray, uv: np.ndarray) -> np.ndarray:
    """Reprojection error norms (M,) in pixels; inf behind the camera."""
    p_cam = (p_world - t) @ R
    with np.errstate(divide="ignore", invalid="ignore"):
        err = np.linalg.norm(camera.project(p_cam) - uv, axis=1)
    return np.where(p_cam[:, 2] > 1e-6, err, np.inf)


def line_errors(camera: PinholeCamera, R: np.ndarray, t: np.ndarray, m_world: np.ndarray, v_world: np.ndarray, segments_uv: np.ndarray) -> np.ndarray:
    """Larger endpoint-to-line distance (M,) in pixels of world lines seen as segments (M, 4)."""
    if len(m_world) == 0:
        return np.zeros(0)
    m_c, _ = line_geo.to_camera(m_world, v_world, R, t)
    x_s, x_e = camera.normalize(segments_uv[:, :2]), camera.normalize(segments_uv[:, 2:])
    norm = np.linalg.norm(m_c[:, :2], axis=1)
    with np.errstate(divide="ignore", invalid="ignore"):
        err = camera.fx * np.maximum(np.abs(np.sum(x_s * m_c, axis=1)), np.abs(np.sum(x_e * m_c, axis=1))) / norm
    return np.where(np.isfinite(err), err, np.inf)
