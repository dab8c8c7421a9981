"""Step 2 of a Monte-Carlo keyframe: landmarks with two or more views and enough parallax
are triangulated from the keyframes' estimated poses; and lines that a variant does not
optimize are re-triangulated after the solve.

Poses `T_world_camera` (world frame z up, metres); pixels of `camera`."""

from __future__ import annotations

import numpy as np

from backend.eval import sequences
from backend.geometry import so3
from backend.geometry.camera import PinholeCamera
from backend.geometry.se3 import Poses
from backend.mapping.triangulation import triangulate_lines, triangulate_points
from backend.pipeline.sim_stages.state import FrameObs, SimLandmarks

MAX_REPROJECTION_SIGMAS = 3.0  # a new point's RMS reprojection error must stay below this many pixel σ


def triangulate_new(
    landmarks: SimLandmarks,
    observations: dict[int, FrameObs],
    k: int,
    *,
    camera: PinholeCamera,
    poses: Poses,
    min_parallax_deg: float,
    pixel_sigma: float,
) -> tuple[np.ndarray, np.ndarray]:
    """Triangulate the untriangulated landmarks keyframe k sees, from all their stored
    views, where they have two or more and enough parallax (`min_parallax_deg`: the largest
    ray angle for points, the spread of back-projection planes for lines); a point must
    also lie in front of every view and reproject within MAX_REPROJECTION_SIGMAS ·
    `pixel_sigma` (RMS, px). Writes them into `landmarks`; returns the ids of the new
    points and lines. `poses`: the keyframes' estimated poses."""
    cam = camera
    R, t = poses.R_world_camera, poses.t_world_camera
    min_sin = np.sin(np.deg2rad(min_parallax_deg))
    obs = observations[k]

    cand = obs.point_id[~landmarks.p_ok[obs.point_id]]
    new_points = np.zeros(0, int)
    if len(cand):
        kf, lm, uv = landmarks.views(observations, "point", cand)
        order = np.lexsort((kf, lm))
        kf, lm, uv = kf[order], lm[order], uv[order]
        ids, start, count = np.unique(lm, return_index=True, return_counts=True)
        if np.any(count >= 2):
            x = cam.normalize(uv)
            rays = np.einsum("mij,mj->mi", R[kf], x)
            rays /= np.linalg.norm(rays, axis=1, keepdims=True)
            parallax = np.zeros(len(ids))
            np.maximum.at(parallax, np.repeat(np.arange(len(ids)), count), np.linalg.norm(so3.cross(np.repeat(rays[start], count, axis=0), rays), axis=1))
            good = (parallax >= min_sin) & (count >= 2)
            xs = [x[a : a + c] for a, c, g in zip(start, count, good) if g]
            ks = [kf[a : a + c] for a, c, g in zip(start, count, good) if g]
            ids = ids[good]
            if len(ids):
                X = triangulate_points(xs, ks, R, t)
                ok = np.all(np.isfinite(X), axis=1)
                for i, (xi, ki) in enumerate(zip(xs, ks)):
                    if ok[i]:
                        p_c = np.einsum("nji,nj->ni", R[ki], X[i] - t[ki])
                        err = cam.project(p_c) - cam.project(xi)
                        ok[i] = bool(np.all(p_c[:, 2] > sequences.MIN_DEPTH_M) and np.sqrt(np.mean(err**2)) < MAX_REPROJECTION_SIGMAS * pixel_sigma + 1e-9)
                new_points = ids[ok]
                landmarks.p_world[new_points] = X[ok]
                landmarks.p_ok[new_points] = True

    cand = obs.line_id[~landmarks.l_ok[obs.line_id]]
    new_lines = np.zeros(0, int)
    if len(cand):
        kf, lm, uv = landmarks.views(observations, "line", cand)
        ids, inverse, count = np.unique(lm, return_inverse=True, return_counts=True)
        keep = count[inverse] >= 2
        if np.any(keep):
            ids_k, local = np.unique(lm[keep], return_inverse=True)
            m, v, spread = triangulate_lines(cam.normalize(uv[keep, :2]), cam.normalize(uv[keep, 2:]), local, kf[keep], len(ids_k), R, t)
            ok = (spread >= min_sin) & (np.linalg.norm(v, axis=1) > 1e-12)
            new_lines = ids_k[ok]
            norm = np.linalg.norm(v[ok], axis=1, keepdims=True)
            landmarks.l_m[new_lines], landmarks.l_v[new_lines] = m[ok] / norm, v[ok] / norm
            landmarks.l_ok[new_lines] = True
    return new_points, new_lines


def retriangulate_lines(landmarks: SimLandmarks, observations: dict[int, FrameObs], ids: np.ndarray, *, camera: PinholeCamera, poses: Poses) -> None:
    """Lines `ids` again from all their stored views and the keyframes' current `poses`
    (for a variant that does not optimize lines); a degenerate line keeps its old value."""
    kf, lm, uv = landmarks.views(observations, "line", ids)
    ids_k, local = np.unique(lm, return_inverse=True)
    m, v, spread = triangulate_lines(camera.normalize(uv[:, :2]), camera.normalize(uv[:, 2:]), local, kf, len(ids_k), poses.R_world_camera, poses.t_world_camera)
    ok = np.linalg.norm(v, axis=1) > 1e-12
    norm = np.linalg.norm(v[ok], axis=1, keepdims=True)
    landmarks.l_m[ids_k[ok]], landmarks.l_v[ids_k[ok]] = m[ok] / norm, v[ok] / norm
