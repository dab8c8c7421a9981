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
