"""Co-planar detection (paper §III-A, Eq. 4): RANSAC over the triangulated points and line
segments of one plane instance, acceptance at a consensus of θ_cp, and association with the
planes already in the map.

Distances are Eq. 4's: a point's perpendicular distance to the plane, a segment's larger
endpoint distance. Planes are `n·X + d = 0` in the world frame, metres.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from backend.geometry import plane as plane_geo

THETA_CP = 0.8


@dataclasses.dataclass(frozen=True)
class CoplanarSettings:
    """`threshold_m`: Eq. 4 inlier distance (m). `min_candidates`: smallest candidate set
    that is tested (the paper's "certain threshold"). `theta_cp`: consensus fraction to
    accept. `iterations`: RANSAC hypotheses. Merge: planes whose normals differ by less
    than `merge_angle_deg` and offsets by less than `merge_offset_m` are the same plane."""

    threshold_m: float = 0.15
    min_candidates: int = 10
    theta_cp: float = THETA_CP
    iterations: int = 100
    merge_angle_deg: float = 10.0
    merge_offset_m: float = 0.3


@dataclasses.dataclass(frozen=True)
class Consensus:
    """Result of RANSAC on one candidate set: the refined plane, boolean inlier masks for
    the points and segments given, and whether the consensus reached θ_cp."""

    n: np.ndarray
    d: float
    point_inlier: np.ndarray
    line_inlier: np.ndarray
    accepted: bool

    @property
    def fraction(self) -> float:
        total = len(self.point_inlier) + len(self.line_inlier)
        return (int(self.point_inlier.sum()) + int(self.line_inlier.sum())) / max(total, 1)


def eq4_distance(n: np.ndarray, d: float, points: np.ndarray, segments: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Paper Eq. 4 for plane (n, d): |n·X + d| for points (P, 3), and the larger of the two
    endpoint distances for segments (L, 2, 3)."""
    dist_p = np.abs(points @ n + d)
    dist_l = np.max(np.abs(segments @ n + d), axis=1) if len(segments) else np.zeros(0)
    return dist_p, dist_l


def ransac_plane(points: np.ndarray, segments: np.ndarray, *, rng: np.random.Generator, settings: CoplanarSettings = CoplanarSettings()) -> Consensus | None:
    """RANSAC plane over points (P, 3) and segments (L, 2, 3) (world, m).

    Hypotheses are planes through three samples of the pooled points and segment
    endpoints; the largest consensus under Eq. 4 wins and is refitted by least squares on
    its points and endpoints. Returns None where no non-degenerate hypothesis exists (fewer
    than three distinct, non-collinear samples).
    """
    points = np.asarray(points, dtype=float).reshape(-1, 3)
    segments = np.asarray(segments, dtype=float).reshape(-1, 2, 3)
    pool = np.concatenate([points, segments.reshape(-1, 3)])
    pool = pool[np.all(np.isfinite(pool), axis=1)]
    if len(pool) < 3:
        return None
    sample = np.stack([rng.choice(len(pool), 3, replace=False) for _ in range(settings.iterations)]) if len(pool) < 8 else _distinct_triples(rng, len(pool), settings.iterations)
    a, b, c = pool[sample[:, 0]], pool[sample[:, 1]], pool[sample[:, 2]]
    normals = np.cross(b - a, c - a)
    norm = np.linalg.norm(normals, axis=1)
    valid = norm > 1e-9
    if not np.any(valid):
        return None
    normals = normals[valid] / norm[valid, None]
    offsets = -np.sum(normals * a[valid], axis=1)
    # Eq. 4 for every hypothesis at once: (H, P) point and (H, L) segment distances.
    count = np.sum(np.abs(points @ normals.T + offsets).T < settings.threshold_m, axis=1)
    if len(segments):
        ends = np.abs(segments.reshape(-1, 3) @ normals.T + offsets).reshape(len(segments), 2, -1)
        count = count + np.sum(np.max(ends, axis=1).T < settings.threshold_m, axis=1)
    best = int(np.argmax(count))
    n, d = normals[best], float(offsets[best])
    dist_p, dist_l = eq4_distance(n, d, points, segments)
    in_p, in_l = dist_p < settings.threshold_m, dist_l < settings.threshold_m
    support = np.concatenate([points[in_p], segments[in_l].reshape(-1, 3)])
    try:
        n_fit, d_fit = plane_geo.fit_plane(support)
        if n_fit @ n < 0:
            n_fit, d_fit = -n_fit, -d_fit
        dist_p, dist_l = eq4_distance(n_fit, d_fit, points, segments)
        in_p, in_l = dist_p < settings.threshold_m, dist_l < settings.threshold_m
        n, d = n_fit, d_fit
    except ValueError:
        pass
    total = len(points) + len(segments)
    accepted = (int(in_p.sum()) + int(in_l.sum())) >= settings.theta_cp * total
    return Consensus(n=n, d=float(d), point_inlier=in_p, line_inlier=in_l, accepted=bool(accepted))


def _distinct_triples(rng: np.random.Generator, n: int, count: int) -> np.ndarray:
    """`count` triples of distinct indices in [0, n), uniformly (n >= 3)."""
    i = rng.integers(0, n, count)
    j = (i + rng.integers(1, n, count)) % n
    k = rng.integers(0, n - 2, count)
    lo, hi = np.minimum(i, j), np.maximum(i, j)
    k = k + (k >= lo)
    k = k + (k >= hi)
    return np.stack([i, j, k], axis=1)


def match_plane(n: np.ndarray, d: float, planes_n: np.ndarray, planes_d: np.ndarray, *, settings: CoplanarSettings = CoplanarSettings()) -> int:
    """Index of the existing plane that agrees with (n, d) in normal (either sign) and
    offset, the closest in offset if several do; -1 if none."""
    if len(planes_n) == 0:
        return -1
    dots = planes_n @ n
    sign = np.where(dots < 0, -1.0, 1.0)
    angle_ok = np.abs(dots) > np.cos(np.deg2rad(settings.merge_angle_deg))
    offset = np.abs(sign * planes_d - d)
    ok = angle_ok & (offset < settings.merge_offset_m)
    if not np.any(ok):
        return -1
    return int(np.flatnonzero(ok)[np.argmin(offset[ok])])


def plane_hull(n: np.ndarray, d: float, p_world: np.ndarray) -> np.ndarray:
    """Convex hull (H, 3) of world points projected onto the plane, counter-clockwise seen
    from the +n side; empty where fewer than three points span an area."""
    p = np.asarray(p_world, dtype=float).reshape(-1, 3)
    p = p[np.all(np.isfinite(p), axis=1)]
    if len(p) < 3:
        return np.zeros((0, 3))
    B = plane_geo.tangent_basis(n[None])[0]  # (3, 2), orthonormal, ⟂ n
    origin = -d * n
    uv = (p - origin) @ B
    try:
        from scipy.spatial import ConvexHull, QhullError

        hull = ConvexHull(uv)
    except (QhullError, ValueError):
        return np.zeros((0, 3))
    ring = uv[hull.vertices]  # counter-clockwise in (u, v)
    if np.cross(B[:, 0], B[:, 1]) @ n < 0:
        ring = ring[::-1]
    return origin + ring @ B.T
