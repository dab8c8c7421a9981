"""Co-planar detection (paper §III-A, Eq. 4): RANSAC, acceptance at θ_cp, merging, hulls."""

from __future__ import annotations

import numpy as np
import pytest

from backend.mapping import coplanar
from backend.mapping.coplanar import CoplanarSettings, eq4_distance, match_plane, plane_hull, ransac_plane

# The test plane: n·X + d = 0 with a tilted unit normal.
N_TRUE = np.array([1.0, 2.0, 2.0]) / 3.0
D_TRUE = -1.5


def _plane_basis(n: np.ndarray) -> np.ndarray:
    """Two orthonormal vectors (2, 3) spanning the plane ⟂ n."""
    a = np.cross(n, [0.0, 0.0, 1.0] if abs(n[2]) < 0.9 else [1.0, 0.0, 0.0])
    a /= np.linalg.norm(a)
    return np.stack([a, np.cross(n, a)])


def _on_plane(rng: np.random.Generator, count: int, *, n: np.ndarray = N_TRUE, d: float = D_TRUE, extent: float = 3.0) -> np.ndarray:
    """`count` points (count, 3) exactly on the plane (n, d), uniform in a square of side 2·extent."""
    uv = rng.uniform(-extent, extent, (count, 2))
    return -d * n + uv @ _plane_basis(n)


def _off_plane(rng: np.random.Generator, count: int, distance: float) -> np.ndarray:
    """Points (count, 3) at `distance` metres or more from the test plane, on both sides."""
    side = np.where(rng.random(count) < 0.5, -1.0, 1.0)
    return _on_plane(rng, count) + (side * (distance + rng.uniform(0.0, 1.0, count)))[:, None] * N_TRUE


def _assert_same_plane(n: np.ndarray, d: float, *, atol: float = 1e-9) -> None:
    sign = np.sign(n @ N_TRUE)
    np.testing.assert_allclose(sign * n, N_TRUE, atol=atol)
    assert sign * d == pytest.approx(D_TRUE, abs=atol)
    assert np.linalg.norm(n) == pytest.approx(1.0, abs=1e-12)


# ------------------------------------------------------------------ RANSAC


def test_ransac_recovers_the_plane_and_exact_inlier_masks() -> None:
    rng = np.random.default_rng(0)
    inliers = _on_plane(rng, 40)
    outliers = _off_plane(rng, 6, 1.0)
    points = np.concatenate([inliers, outliers])
    seg_in = np.stack([_on_plane(rng, 8), _on_plane(rng, 8)], axis=1)
    seg_out = np.stack([_off_plane(rng, 2, 1.0), _off_plane(rng, 2, 1.0)], axis=1)
    segments = np.concatenate([seg_in, seg_out])
    cons = ransac_plane(points, segments, rng=np.random.default_rng(1))
    assert cons is not None
    _assert_same_plane(cons.n, cons.d)
    np.testing.assert_array_equal(cons.point_inlier, np.arange(46) < 40)
    np.testing.assert_array_equal(cons.line_inlier, np.arange(10) < 8)
    assert cons.point_inlier.dtype == bool and cons.line_inlier.dtype == bool
    assert cons.fraction == pytest.approx(48 / 56)
    assert cons.accepted  # 48/56 = 86% >= 80%


def test_ransac_points_only_and_segments_only() -> None:
    rng = np.random.default_rng(2)
    cons = ransac_plane(_on_plane(rng, 20), np.zeros((0, 2, 3)), rng=rng)
    assert cons is not None and cons.accepted
    _assert_same_plane(cons.n, cons.d)
    assert cons.line_inlier.shape == (0,)
    segs = np.stack([_on_plane(rng, 6), _on_plane(rng, 6)], axis=1)
    cons = ransac_plane(np.zeros((0, 3)), segs, rng=rng)
    assert cons is not None and cons.accepted
    _assert_same_plane(cons.n, cons.d)
    assert cons.point_inlier.shape == (0,) and cons.line_inlier.all()


@pytest.mark.parametrize(("n_in", "n_out", "accepted"), [(39, 11, False), (40, 10, True), (41, 9, True), (30, 20, False)])
def test_acceptance_at_theta_cp(n_in: int, n_out: int, accepted: bool) -> None:
    """Accepted exactly when the consensus is >= θ_cp = 80% of the candidate set."""
    assert coplanar.THETA_CP == 0.8
    rng = np.random.default_rng(n_in)
    points = np.concatenate([_on_plane(rng, n_in), _off_plane(rng, n_out, 1.0)])
    cons = ransac_plane(points, np.zeros((0, 2, 3)), rng=rng)
    assert cons is not None
    assert int(cons.point_inlier.sum()) == n_in
    assert cons.accepted is accepted
    assert cons.fraction == pytest.approx(n_in / (n_in + n_out))


def test_theta_cp_is_a_setting() -> None:
    rng = np.random.default_rng(3)
    points = np.concatenate([_on_plane(rng, 30), _off_plane(rng, 20, 1.0)])  # 60%
    assert not ransac_plane(points, np.zeros((0, 2, 3)), rng=np.random.default_rng(0)).accepted
    assert ransac_plane(points, np.zeros((0, 2, 3)), rng=np.random.default_rng(0), settings=CoplanarSettings(theta_cp=0.5)).accepted


def test_segment_with_one_endpoint_off_the_plane_is_an_outlier() -> None:
    """Eq. 4: a segment's distance is the larger of its endpoints' distances."""
    rng = np.random.default_rng(4)
    points = _on_plane(rng, 30)
    start = _on_plane(rng, 4)
    end = _on_plane(rng, 4)
    end[1] += 0.5 * N_TRUE  # second segment: one end 0.5 m off
    end[3] -= 0.2 * N_TRUE  # fourth: 0.2 m off on the other side (threshold 0.15 m)
    segments = np.stack([start, end], axis=1)
    cons = ransac_plane(points, segments, rng=rng)
    assert cons is not None
    _assert_same_plane(cons.n, cons.d)
    np.testing.assert_array_equal(cons.line_inlier, [True, False, True, False])
    assert cons.point_inlier.all()


def test_segments_crossing_a_plane_do_not_support_it() -> None:
    """Segments with only one endpoint on plane A give A no consensus (Eq. 4's max), so the
    plane with more supporting points wins."""
    rng = np.random.default_rng(6)
    n_a, d_a = N_TRUE, D_TRUE + 1.5  # parallel to the test plane B, 1.5 m away
    on_a = _on_plane(rng, 10, n=n_a, d=d_a)
    on_b = _on_plane(rng, 14)
    start = _on_plane(rng, 20, n=n_a, d=d_a)
    end = _on_plane(rng, 20, n=n_a, d=d_a) - rng.uniform(0.5, 1.0, (20, 1)) * N_TRUE  # beyond A, away from B
    segments = np.stack([start, end], axis=1)
    for n, d in ((n_a, d_a), (N_TRUE, D_TRUE)):  # no segment is an inlier of A or B
        assert np.all(eq4_distance(n, d, np.zeros((0, 3)), segments)[1] > 0.15)
    cons = ransac_plane(np.concatenate([on_a, on_b]), segments, rng=rng, settings=CoplanarSettings(iterations=1000))
    assert cons is not None
    _assert_same_plane(cons.n, cons.d)
    np.testing.assert_array_equal(cons.point_inlier, np.arange(24) >= 10)
    assert not cons.line_inlier.any()
    assert not cons.accepted  # 14 of 44


def test_eq4_distance() -> None:
    n, d = np.array([0.0, 0.0, 1.0]), -1.0  # z = 1
    points = np.array([[0.0, 0.0, 1.0], [5.0, -3.0, 1.25], [0.0, 0.0, 0.0]])
    segments = np.array([[[0, 0, 1.0], [1, 1, 1.0]], [[0, 0, 1.1], [2, 0, 0.7]], [[0, 0, 3.0], [0, 0, 1.5]]])
    dist_p, dist_l = eq4_distance(n, d, points, segments)
    np.testing.assert_allclose(dist_p, [0.0, 0.25, 1.0])
    np.testing.assert_allclose(dist_l, [0.0, 0.3, 2.0])
    dist_p, dist_l = eq4_distance(n, d, points, np.zeros((0, 2, 3)))
    assert dist_l.shape == (0,)


@pytest.mark.parametrize(
    "points",
    [
        np.zeros((0, 3)),
        np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0]]),
        np.array([[0.0, 0.0, 0.0], [1.0, 1.0, 1.0], [2.0, 2.0, 2.0], [3.0, 3.0, 3.0], [-1.5, -1.5, -1.5]]),  # < 8: choice sampler
        np.arange(30, dtype=float)[:, None] * np.array([[0.3, -0.2, 1.0]]) + 2.0,  # >= 8: triple sampler
        np.ones((12, 3)),  # all the same point
        np.array([[np.nan, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, np.inf]]),  # < 3 finite
    ],
    ids=["empty", "two", "collinear-few", "collinear-many", "coincident", "non-finite"],
)
def test_degenerate_input_gives_none(points: np.ndarray) -> None:
    assert ransac_plane(points, np.zeros((0, 2, 3)), rng=np.random.default_rng(0)) is None


def test_degenerate_landmarks_far_away_are_ignored_without_overflow() -> None:
    """A diverged map holds landmarks 1e160-1e200 m away (a street's VIO run crashed on
    them: the cross products overflowed and a plane with a zero normal entered the map).
    They are neither sampled nor inliers; the plane comes from the sane features, with no
    RuntimeWarning."""
    rng = np.random.default_rng(0)
    far = np.array([[1e200, 3e199, -2e200], [1e170, 1e170, 1e170], [np.inf, 0.0, 0.0]])
    points = np.concatenate([_on_plane(rng, 30), far])
    segments = np.concatenate([np.stack([_on_plane(rng, 4), _on_plane(rng, 4)], axis=1), np.array([[[1e160, 0.0, 0.0], [0.0, 1e161, 0.0]]])])
    with np.errstate(all="raise"):
        cons = ransac_plane(points, segments, rng=np.random.default_rng(1))
    assert cons is not None
    _assert_same_plane(cons.n, cons.d)
    np.testing.assert_array_equal(cons.point_inlier, np.arange(33) < 30)
    np.testing.assert_array_equal(cons.line_inlier, np.arange(5) < 4)
    with np.errstate(all="raise"):
        assert ransac_plane(far, segments[4:], rng=np.random.default_rng(1)) is None


def test_degenerate_collinear_segments_give_none() -> None:
    line = np.arange(10, dtype=float)[:, None] * np.array([[1.0, 1.0, 0.0]])
    segments = np.stack([line[:5], line[5:]], axis=1)
    assert ransac_plane(np.zeros((0, 3)), segments, rng=np.random.default_rng(0)) is None
    assert ransac_plane(line[:1], segments[:1], rng=np.random.default_rng(0)) is None


def test_distinct_triples() -> None:
    rng = np.random.default_rng(0)
    for n in (3, 4, 5, 17):
        t = coplanar._distinct_triples(rng, n, 2000)
        assert t.shape == (2000, 3)
        assert t.min() >= 0 and t.max() < n
        assert np.all((t[:, 0] != t[:, 1]) & (t[:, 0] != t[:, 2]) & (t[:, 1] != t[:, 2])), n
        # Every index appears in every slot over many draws (no index is unreachable).
        for col in range(3):
            assert set(np.unique(t[:, col])) == set(range(n)), (n, col)


# ------------------------------------------------------------------ association


def test_match_plane_merges_a_flipped_normal() -> None:
    planes_n = np.array([[1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])
    planes_d = np.array([-4.0, 4.0])
    assert match_plane(np.array([1.0, 0.0, 0.0]), -4.0, planes_n, planes_d) == 0
    assert match_plane(np.array([-1.0, 0.0, 0.0]), 4.0, planes_n, planes_d) == 0  # (-n, -d) is the same plane
    assert match_plane(np.array([0.0, -1.0, 0.0]), -4.1, planes_n, planes_d) == 1
    tilted = np.array([np.cos(np.deg2rad(5.0)), np.sin(np.deg2rad(5.0)), 0.0])
    assert match_plane(-tilted, 4.2, planes_n, planes_d) == 0


def test_match_plane_rejects() -> None:
    planes_n = np.array([[1.0, 0.0, 0.0]])
    planes_d = np.array([-4.0])
    assert match_plane(np.array([1.0, 0.0, 0.0]), -3.0, planes_n, planes_d) == -1  # 1 m away
    assert match_plane(np.array([-1.0, 0.0, 0.0]), -4.0, planes_n, planes_d) == -1  # flipped normal, same d: x = -4
    tilted = np.array([np.cos(np.deg2rad(20.0)), np.sin(np.deg2rad(20.0)), 0.0])
    assert match_plane(tilted, -4.0, planes_n, planes_d) == -1
    assert match_plane(np.array([1.0, 0.0, 0.0]), -4.0, np.zeros((0, 3)), np.zeros(0)) == -1


def test_match_plane_picks_the_closest_offset() -> None:
    planes_n = np.array([[1.0, 0.0, 0.0], [1.0, 0.0, 0.0], [-1.0, 0.0, 0.0]])
    planes_d = np.array([-4.2, -3.75, 3.95])
    assert match_plane(np.array([1.0, 0.0, 0.0]), -4.0, planes_n, planes_d) == 2
    assert match_plane(np.array([1.0, 0.0, 0.0]), -3.8, planes_n, planes_d) == 1


# ------------------------------------------------------------------ hull


def test_plane_hull_is_ccw_on_the_plane_and_contains_the_points() -> None:
    rng = np.random.default_rng(5)
    pts = _on_plane(rng, 60) + 0.05 * rng.standard_normal((60, 1)) * N_TRUE  # a little off the plane
    hull = plane_hull(N_TRUE, D_TRUE, pts)
    assert hull.ndim == 2 and hull.shape[1] == 3 and len(hull) >= 3
    np.testing.assert_allclose(hull @ N_TRUE + D_TRUE, 0.0, atol=1e-9)
    # Counter-clockwise seen from +n: every turn has a positive component along n.
    a, b, c = hull, np.roll(hull, -1, axis=0), np.roll(hull, -2, axis=0)
    turns = np.cross(b - a, c - b) @ N_TRUE
    assert np.all(turns > 0)
    # Every projected point is inside or on the polygon (left of every edge seen from +n).
    proj = pts - (pts @ N_TRUE + D_TRUE)[:, None] * N_TRUE
    side = np.einsum("j,mkj->mk", N_TRUE, np.cross((b - a)[None], proj[:, None, :] - a[None]))
    assert np.all(side >= -1e-9)
    # The hull vertices are projections of input points.
    dist = np.linalg.norm(hull[:, None, :] - proj[None], axis=2).min(axis=1)
    np.testing.assert_allclose(dist, 0.0, atol=1e-9)


def test_plane_hull_of_a_square_with_flipped_normal() -> None:
    """With the opposite normal the same points give the reversed orientation (CCW from -n)."""
    square = np.array([[4.0, -1.0, -1.0], [4.0, 1.0, -1.0], [4.0, 1.0, 1.0], [4.0, -1.0, 1.0], [4.0, 0.0, 0.0]])
    for n, d in ((np.array([1.0, 0.0, 0.0]), -4.0), (np.array([-1.0, 0.0, 0.0]), 4.0)):
        hull = plane_hull(n, d, square)
        assert len(hull) == 4
        np.testing.assert_allclose(hull[:, 0], 4.0, atol=1e-12)
        area_vec = sum(np.cross(hull[i], hull[(i + 1) % 4]) for i in range(4)) / 2
        assert area_vec @ n == pytest.approx(4.0)


@pytest.mark.parametrize(
    "points",
    [np.zeros((0, 3)), np.array([[4.0, 0, 0], [4.0, 1, 0]]), np.array([[4.0, 0, 0], [4.0, 1, 1], [4.0, 2, 2], [4.0, 3, 3]])],
    ids=["empty", "two", "collinear"],
)
def test_plane_hull_degenerate_is_empty(points: np.ndarray) -> None:
    hull = plane_hull(np.array([1.0, 0.0, 0.0]), -4.0, points)
    assert hull.shape == (0, 3)


# ------------------------------------------------------------------ detection on a keyframe


def _detect_floor_owned_by(plane_n: np.ndarray, plane_d: float, *, seed: int) -> tuple[coplanar.KeyframeDetection, coplanar.PlaneSet, np.ndarray]:
    """30 floor points (z = 0 within 1 cm) as one candidate set, the first 20 of them already
    on plane 0 = (plane_n, plane_d). Returns the detection, the planes and the assignment."""
    rng = np.random.default_rng(seed)
    floor = np.c_[rng.uniform(-2, 2, (30, 2)), rng.normal(0.0, 0.01, 30)]
    planes = coplanar.PlaneSet(n=[np.asarray(plane_n, float)], d=[plane_d], consensus=[(1.0, 40)])
    owner = np.where(np.arange(30) < 20, 0, -1)
    det = coplanar.detect_keyframe_planes(
        point_ids=np.arange(30),
        point_label=np.zeros(30, np.int64),
        p_world=floor,
        line_ids=np.zeros(0, np.int64),
        line_label=np.zeros(0, np.int64),
        segments_world=np.zeros((0, 2, 3)),
        point_plane=owner,
        line_plane=np.zeros(0, np.int64),
        planes=planes,
        rng=np.random.default_rng(3),
    )
    return det, planes, owner


def test_detection_merges_with_the_owners_plane_when_it_agrees() -> None:
    """Most inliers already belong to plane 0 and the consensus agrees with it: it is plane 0,
    and the rest of the inliers join it."""
    det, planes, owner = _detect_floor_owned_by([0.0, 0.0, 1.0], 0.02, seed=0)
    assert det.accepted == (True,) and det.plane == (0,)
    assert len(planes) == 1 and np.all(owner == 0)


def test_detection_does_not_merge_a_floor_into_the_wall_that_owns_its_points() -> None:
    """A floor candidate set whose points a wall plane had taken (a wall's inliers that reached
    the floor): the consensus is the floor, which disagrees with the wall by 90°. It is not
    merged into the wall (its points would be forced onto the wall in the -w solve): a new
    plane is made, and only the points without a plane join it."""
    det, planes, owner = _detect_floor_owned_by([0.0, 1.0, 0.0], 2.5, seed=1)
    assert det.accepted == (True,) and det.plane == (1,)
    assert len(planes) == 2
    assert abs(planes.n[1][2]) > 0.999 and abs(planes.d[1]) < 0.02
    np.testing.assert_array_equal(owner, np.where(np.arange(30) < 20, 0, 1))
