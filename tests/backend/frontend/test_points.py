"""Descriptor search of backend.frontend.points: the fast nearest-neighbour search agrees
with the exhaustive Hamming distances."""

from __future__ import annotations

import numpy as np

from backend.frontend.points import best_matches, hamming_distances, nearest_hamming


def test_nearest_hamming_finds_the_two_nearest_of_the_exhaustive_distances() -> None:
    rng = np.random.default_rng(3)
    a = rng.integers(0, 256, (300, 32), dtype=np.uint8)
    b = rng.integers(0, 256, (200, 32), dtype=np.uint8)
    b[:50] = a[:50] ^ (rng.random((50, 32)) < 0.05).astype(np.uint8)  # 50 near-duplicates
    full = hamming_distances(a, b)
    rows, cols, dist = nearest_hamming(a, b, k=2)
    np.testing.assert_array_equal(rows, np.repeat(np.arange(300), 2))
    np.testing.assert_array_equal(dist, full[rows, cols])  # distances are the exhaustive ones
    np.testing.assert_array_equal(dist.reshape(-1, 2), np.sort(full, axis=1)[:, :2])  # and the two smallest, nearest first
    # The ratio test gives the same matches from the two nearest as from every candidate.
    r_all, c_all = np.nonzero(full <= 60)
    expected = best_matches(r_all, c_all, full[r_all, c_all], n_rows=300, max_distance=60, ratio=0.9)
    near = dist <= 60
    np.testing.assert_array_equal(best_matches(rows[near], cols[near], dist[near], n_rows=300, max_distance=60, ratio=0.9), expected)
    assert np.count_nonzero(expected[:50] == np.arange(50)) >= 45


def test_nearest_hamming_with_fewer_candidates_than_k_or_none() -> None:
    a = np.zeros((3, 32), np.uint8)
    b = np.full((1, 32), 1, np.uint8)
    rows, cols, dist = nearest_hamming(a, b, k=2)
    np.testing.assert_array_equal(rows, [0, 1, 2])
    np.testing.assert_array_equal(cols, [0, 0, 0])
    np.testing.assert_array_equal(dist, [32, 32, 32])
    for x, y in ((a[:0], b), (a, b[:0])):
        assert all(len(v) == 0 for v in nearest_hamming(x, y))


def _faint_wall(contrast: int) -> np.ndarray:
    """A near-uniform wall (grey 150, a little noise) with six rectangles `contrast` grey
    levels darker: 24 corners."""
    rng = np.random.default_rng(5)
    image = np.clip(150.0 + rng.normal(0.0, 1.0, (480, 752)), 0, 255)
    for k in range(6):
        r, c = 60 + 150 * (k // 3), 80 + 220 * (k % 3)
        image[r : r + 90, c : c + 120] -= contrast
    return image.astype(np.uint8)


def test_a_bare_image_is_searched_again_with_a_lower_fast_threshold() -> None:
    """ORB-SLAM's fallback: a frame with few corners at the FAST threshold (10 grey levels)
    is searched at the lower one, which finds the corners of faint marks (8 levels)."""
    from backend.frontend.points import PointSettings, detect_points

    image = _faint_wall(8)
    plain = detect_points(image, settings=PointSettings(sparse_below=0))
    found = detect_points(image, settings=PointSettings())
    assert len(plain.uv) < 5
    assert len(found.uv) >= 20
    corners = np.array([(80 + 220 * (k % 3) + dc, 60 + 150 * (k // 3) + dr) for k in range(6) for dr in (0, 90) for dc in (0, 120)], float)
    near = np.min(np.linalg.norm(found.uv[:, None] - corners[None], axis=2), axis=0)
    assert np.count_nonzero(near < 3.0) >= 20  # the marks' corners, not noise


def test_a_textured_image_keeps_the_usual_threshold() -> None:
    from backend.frontend.points import PointSettings, detect_points

    rng = np.random.default_rng(6)
    image = (rng.random((480, 752)) * 255).astype(np.uint8)
    a = detect_points(image, settings=PointSettings())
    b = detect_points(image, settings=PointSettings(sparse_below=0))
    np.testing.assert_array_equal(a.uv, b.uv)
    np.testing.assert_array_equal(a.descriptors, b.descriptors)


def test_keypoints_are_orbs_own_positions_octaves_and_descriptors() -> None:
    """Each kept keypoint is one ORB found: its position (float32, as OpenCV holds it), its
    octave and its descriptor, and the strongest ORB keypoint is among them."""
    import cv2

    from backend.frontend.points import PointSettings, detect_points

    rng = np.random.default_rng(8)
    image = cv2.GaussianBlur((rng.random((480, 752)) * 255).astype(np.uint8), (3, 3), 0)
    s = PointSettings()
    orb = cv2.ORB_create(nfeatures=int(s.oversample * s.n_features), scaleFactor=s.scale_factor, nlevels=s.n_levels, fastThreshold=s.fast_threshold, edgeThreshold=19, patchSize=31)
    kps, desc = orb.detectAndCompute(image, None)
    found = detect_points(image, settings=s)
    assert 0 < len(found.uv) <= s.n_features and found.uv.dtype == np.float64 and found.octave.dtype == np.int32
    by_position = {(np.float32(kp.pt[0]), np.float32(kp.pt[1]), kp.octave): k for k, kp in enumerate(kps)}
    index = [by_position[(np.float32(u), np.float32(v), int(o))] for (u, v), o in zip(found.uv, found.octave)]
    np.testing.assert_array_equal(found.descriptors, desc[index])
    assert int(np.argmax([kp.response for kp in kps])) in index


def _best_matches_by_sorting(rows: np.ndarray, cols: np.ndarray, dist: np.ndarray, *, n_rows: int, max_distance: float, ratio: float) -> np.ndarray:
    """The definition, by sorting (the implementation before the compiled pass)."""
    out = np.full(n_rows, -1, dtype=np.int64)
    if rows.size == 0:
        return out
    order = np.lexsort((dist, rows))
    r, c, d = rows[order], cols[order], dist[order].astype(float)
    first = np.ones(r.size, bool)
    first[1:] = r[1:] != r[:-1]
    head = np.flatnonzero(first)
    second = np.full(head.size, np.inf)
    has_second = ~np.append(first[1:], True)[head]
    second[has_second] = d[head[has_second] + 1]
    ok = (d[head] <= max_distance) & (d[head] < ratio * second)
    head = head[ok]
    by_col = head[np.lexsort((d[head], c[head]))]
    keep = np.ones(by_col.size, bool)
    keep[1:] = c[by_col][1:] != c[by_col][:-1]
    out[r[by_col[keep]]] = c[by_col[keep]]
    return out


def test_best_matches_is_the_sorted_definition_with_ties_and_nan() -> None:
    """The compiled pass gives what sorting the pairs gives, ties and NaN distances included
    (Hamming distances tie often; the flow follower's pixel distances are floats)."""
    rng = np.random.default_rng(11)
    for trial in range(300):
        n_rows, n_cols, P = int(rng.integers(1, 40)), int(rng.integers(1, 40)), int(rng.integers(1, 400))
        rows, cols = rng.integers(0, n_rows, P), rng.integers(0, n_cols, P)
        if trial % 2:
            dist = rng.integers(0, 12, P).astype(np.int32)  # many ties
        else:
            dist = rng.integers(0, 20, P) + rng.random(P).round(1)
            dist[rng.random(P) < 0.1] = np.nan
        for max_distance, ratio in ((8, 0.9), (15, 1.01), (30, 0.7)):
            expected = _best_matches_by_sorting(rows, cols, dist, n_rows=n_rows, max_distance=max_distance, ratio=ratio)
            np.testing.assert_array_equal(best_matches(rows, cols, dist, n_rows=n_rows, max_distance=max_distance, ratio=ratio), expected, err_msg=f"trial {trial}")
