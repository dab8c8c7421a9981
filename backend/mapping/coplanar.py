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
MAX_COORDINATE_M = 1e6  # a feature farther from the origin than this (m) is a degenerate landmark, not geometry


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
    than three distinct, non-collinear samples). Features that are not finite or lie beyond
    `MAX_COORDINATE_M` (degenerate landmarks: a line almost through the camera's centre
    triangulates kilometres away) are neither sampled nor inliers: their products would
    overflow.
    """
    points = np.asarray(points, dtype=float).reshape(-1, 3)
    segments = np.asarray(segments, dtype=float).reshape(-1, 2, 3)
    sane_p = _sane(points)
    sane_l = np.all(_sane(segments.reshape(-1, 3)).reshape(-1, 2), axis=1)
    points = np.where(sane_p[:, None], points, np.nan)
    segments = np.where(sane_l[:, None, None], segments, np.nan)
    pool = np.concatenate([points[sane_p], segments[sane_l].reshape(-1, 3)])
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


def _sane(x: np.ndarray) -> np.ndarray:
    """(N,) whether rows of `x` (N, 3) are finite and within `MAX_COORDINATE_M` of the origin."""
    with np.errstate(invalid="ignore"):
        return np.all(np.abs(x) <= MAX_COORDINATE_M, axis=1)


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


def _agrees(n: np.ndarray, d: float, n_other: np.ndarray, d_other: float, settings: CoplanarSettings) -> bool:
    """Whether plane (n, d) and (n_other, d_other) agree in normal (either sign) within
    `merge_angle_deg` and in offset within `merge_offset_m`."""
    return match_plane(n, d, np.asarray(n_other, float).reshape(1, 3), np.array([float(d_other)]), settings=settings) == 0


def refit_plane(n_previous: np.ndarray, support_world: np.ndarray) -> tuple[np.ndarray, float] | None:
    """Least-squares plane through the support points (K, 3) (world, m), its normal on the
    side of `n_previous`; None with fewer than three finite points or a degenerate set."""
    pts = np.asarray(support_world, dtype=float).reshape(-1, 3)
    pts = pts[np.all(np.isfinite(pts), axis=1)]
    if len(pts) < 3:
        return None
    try:
        n, d = plane_geo.fit_plane(pts)
    except ValueError:
        return None
    return (-n, -d) if n @ n_previous < 0 else (n, d)


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


@dataclasses.dataclass
class PlaneSet:
    """The map's planes: world `n·X + d = 0` (m) and the consensus of each plane's last
    accepted detection (inlier fraction, candidates tested). Plane ids are list indices."""

    n: list[np.ndarray] = dataclasses.field(default_factory=list)
    d: list[float] = dataclasses.field(default_factory=list)
    consensus: list[tuple[float, int]] = dataclasses.field(default_factory=list)

    def __len__(self) -> int:
        return len(self.n)

    def arrays(self) -> tuple[np.ndarray, np.ndarray]:
        """Normals (K, 3) and offsets (K,)."""
        return np.array(self.n).reshape(-1, 3), np.array(self.d, dtype=float).reshape(-1)


@dataclasses.dataclass(frozen=True)
class KeyframeDetection:
    """The co-planar detection of one keyframe: per candidate set (one per instance that
    reached `min_candidates`) its instance label, size, consensus count, verdict and the
    plane id it merged into or created (-1: rejected); and per feature given the RANSAC
    state (`point_state`, `line_state`: 0 not tested, 1 inlier, 2 outlier)."""

    instance: tuple[int, ...]
    candidates: tuple[int, ...]
    inliers: tuple[int, ...]
    accepted: tuple[bool, ...]
    plane: tuple[int, ...]
    point_state: np.ndarray
    line_state: np.ndarray


def detect_keyframe_planes(
    *,
    point_ids: np.ndarray,
    point_label: np.ndarray,
    p_world: np.ndarray,
    line_ids: np.ndarray,
    line_label: np.ndarray,
    segments_world: np.ndarray,
    point_plane: np.ndarray,
    line_plane: np.ndarray,
    planes: PlaneSet,
    rng: np.random.Generator,
    settings: CoplanarSettings = CoplanarSettings(),
) -> KeyframeDetection:
    """The paper's two stages on one keyframe (§III-A). The triangulated features it sees,
    points `point_ids` at world `p_world` (P, 3) and segments `line_ids` at
    `segments_world` (L, 2, 3), carry the instance label of the segmentation
    (`point_label`, `line_label`, -1: none). Each instance with at least `min_candidates`
    features goes through RANSAC with Eq. 4's distance; at a consensus of θ_cp the plane is
    accepted and merges with the plane most of its inliers already belong to if that plane
    agrees with it in normal and offset, else with one that does (`match_plane`), else it
    is added to `planes`. Inliers
    without a plane join it: `point_plane` / `line_plane` (indexed by landmark id) are
    updated in place, and so is `planes`."""
    p_state = np.zeros(len(point_ids), np.uint8)
    l_state = np.zeros(len(line_ids), np.uint8)
    inst: list[int] = []
    cands: list[int] = []
    inl: list[int] = []
    acc: list[bool] = []
    pid: list[int] = []
    for q in np.unique(np.concatenate([point_label, line_label]).astype(int)):
        if q < 0:
            continue
        ip, il = np.flatnonzero(point_label == q), np.flatnonzero(line_label == q)
        total = len(ip) + len(il)
        if total < settings.min_candidates:
            continue
        cons = ransac_plane(p_world[ip], segments_world[il], rng=rng, settings=settings)
        inst.append(int(q))
        cands.append(total)
        inl.append(0 if cons is None else int(cons.point_inlier.sum() + cons.line_inlier.sum()))
        acc.append(cons is not None and cons.accepted)
        if cons is None:
            pid.append(-1)
            continue
        p_state[ip] = np.where(cons.point_inlier, 1, 2)
        l_state[il] = np.where(cons.line_inlier, 1, 2)
        if not cons.accepted:
            pid.append(-1)
            continue
        gp, gl = point_ids[ip[cons.point_inlier]], line_ids[il[cons.line_inlier]]
        owners = np.concatenate([point_plane[gp], line_plane[gl]])
        owners = owners[owners >= 0]
        j = int(np.bincount(owners).argmax()) if len(owners) * 2 > len(gp) + len(gl) else -1
        if j >= 0 and not _agrees(cons.n, cons.d, planes.n[j], planes.d[j], settings):
            j = -1  # the owners' plane is another surface (e.g. a wall whose inliers reached the floor)
        if j < 0:
            j = match_plane(cons.n, cons.d, *planes.arrays(), settings=settings)
        if j < 0:
            j = len(planes)
            planes.n.append(cons.n)
            planes.d.append(cons.d)
            planes.consensus.append((cons.fraction, total))
        else:
            planes.consensus[j] = (cons.fraction, total)
        pid.append(j)
        point_plane[gp[point_plane[gp] < 0]] = j
        line_plane[gl[line_plane[gl] < 0]] = j
    return KeyframeDetection(tuple(inst), tuple(cands), tuple(inl), tuple(acc), tuple(pid), p_state, l_state)


def associate_to_planes(
    p_world: np.ndarray,
    segments_world: np.ndarray,
    planes_n: np.ndarray,
    planes_d: np.ndarray,
    hulls: list[np.ndarray],
    *,
    threshold_m: float,
    margin_m: float = 0.5,
) -> tuple[np.ndarray, np.ndarray]:
    """New landmarks against the existing planes (paper §III-A, last step): each point
    (P, 3) and segment (L, 2, 3) joins the plane nearest by Eq. 4's distance, if that is
    below `threshold_m` and it lies within the plane's inlier hull grown by `margin_m`.
    Returns the plane of each point and segment (-1: none)."""
    out = []
    for kind, where, count in (("point", p_world, len(p_world)), ("line", segments_world, len(segments_world))):
        if count == 0 or len(planes_n) == 0:
            out.append(np.full(count, -1))
            continue
        if kind == "point":
            dist = np.abs(where @ planes_n.T + planes_d)
            centre = where
        else:
            dist = np.max(np.abs(where @ planes_n.T + planes_d), axis=1)
            centre = where.mean(axis=1)
        for q, hull in enumerate(hulls):
            inside = near_hull(centre, planes_n[q], planes_d[q], hull, margin=margin_m) if len(hull) else np.zeros(count, bool)
            dist[~inside, q] = np.inf
        best = np.argmin(dist, axis=1)
        ok = dist[np.arange(count), best] < threshold_m
        out.append(np.where(ok, best, -1))
    return out[0], out[1]


def near_hull(p_world: np.ndarray, n: np.ndarray, d: float, hull_world: np.ndarray, *, margin: float) -> np.ndarray:
    """Whether points project into the convex polygon `hull_world` (counter-clockwise seen
    from +n) grown by `margin` metres."""
    a = hull_world
    b = np.roll(hull_world, -1, axis=0)
    edge = b - a
    length = np.linalg.norm(edge, axis=1)
    # Signed distance to the left of each edge, seen from +n.
    side = np.einsum("j,mkj->mk", n, np.cross(edge[None], p_world[:, None, :] - a[None]))
    return np.all(side >= -margin * length[None], axis=1)
