"""The grid search of :func:`match_in_radius` against its definition: every keypoint
within the radius a candidate, Hamming distances, then :func:`best_matches`."""

from __future__ import annotations

import numpy as np
import pytest

from backend.frontend.points import best_matches, hamming_distances
from backend.frontend.radius_match import match_in_radius


def _by_definition(query_uv: np.ndarray, query_desc: np.ndarray, kp_uv: np.ndarray, kp_desc: np.ndarray, *, radius_px: float, max_hamming: int, ratio: float) -> np.ndarray:
    diff = query_uv[:, None, :] - kp_uv[None, :, :]
    rows, cols = np.nonzero(diff[..., 0] ** 2 + diff[..., 1] ** 2 <= radius_px**2)
    dist = hamming_distances(query_desc, kp_desc)[rows, cols]
    return best_matches(rows, cols, dist, n_rows=len(query_uv), max_distance=max_hamming, ratio=ratio)


@pytest.mark.parametrize("seed", range(40))
def test_the_matches_are_those_of_the_definition(seed: int) -> None:
    """Queries with a true keypoint near them among clutter that repeats a few descriptors
    (equal Hamming distances), some on whole pixels (keypoints exactly on the radius)."""
    rng = np.random.default_rng(seed)
    n_query, n_clutter = int(rng.integers(1, 300)), int(rng.integers(0, 500))
    radius = float(rng.choice([3.0, 10.0, 25.0, 80.0]))
    query_uv = rng.uniform(-20.0, 770.0, (n_query, 2))  # some projections outside the keypoints' extent
    words = rng.integers(0, 256, (8, 32), dtype=np.uint8)
    query_desc = words[rng.integers(0, 8, n_query)] ^ (rng.random((n_query, 32)) < 0.05).astype(np.uint8)
    seen = rng.random(n_query) < 0.7
    kp_uv = np.concatenate([query_uv[seen] + rng.normal(0.0, radius / 2, (int(seen.sum()), 2)), rng.uniform(0.0, 752.0, (n_clutter, 2))])
    kp_desc = np.concatenate([query_desc[seen] ^ (rng.random((int(seen.sum()), 32)) < 0.02).astype(np.uint8), words[rng.integers(0, 8, n_clutter)]])
    if seed % 2 == 0:
        query_uv, kp_uv = np.round(query_uv), np.round(kp_uv)
    if len(kp_uv) == 0:
        kp_uv, kp_desc = np.zeros((1, 2)), words[:1]
    order = rng.permutation(len(kp_uv))
    kp_uv, kp_desc = kp_uv[order], kp_desc[order]
    expected = _by_definition(query_uv, query_desc, kp_uv, kp_desc, radius_px=radius, max_hamming=50, ratio=0.9)
    got = match_in_radius(query_uv, query_desc, kp_uv, kp_desc, radius_px=radius, max_hamming=50, ratio=0.9)
    np.testing.assert_array_equal(got, expected)


def test_a_keypoint_on_the_radius_is_a_candidate_and_one_beyond_is_not() -> None:
    desc = np.zeros((3, 32), np.uint8)
    desc[1, :4] = 0xFF  # 32 bits from the query: the keypoint at 5 px is the closer descriptor
    kp_uv = np.array([[105.0, 100.0], [100.0, 103.0], [100.0, 300.0]])
    query_uv = np.array([[100.0, 100.0]])
    kp_desc = np.stack([desc[0], desc[1], desc[0]])
    # Within 5 px both keypoints are candidates: 0 bits against 32, the nearer descriptor wins.
    assert match_in_radius(query_uv, desc[:1], kp_uv, kp_desc, radius_px=5.0, max_hamming=50, ratio=0.9).tolist() == [0]
    # Within 4.9 px only the keypoint at 3 px is: its 32 bits pass alone (no second candidate).
    assert match_in_radius(query_uv, desc[:1], kp_uv, kp_desc, radius_px=4.9, max_hamming=50, ratio=0.9).tolist() == [1]
    assert match_in_radius(query_uv, desc[:1], kp_uv, kp_desc, radius_px=4.9, max_hamming=31, ratio=0.9).tolist() == [-1]


def test_hamming_distance_counts_every_bit_of_every_word() -> None:
    rng = np.random.default_rng(3)
    query_desc = rng.integers(0, 256, (1, 32), dtype=np.uint8)
    for bits in (0, 1, 63, 64, 65, 200, 256):
        kp_desc = np.unpackbits(query_desc, axis=1)
        kp_desc[0, :bits] ^= 1
        kp_desc = np.packbits(kp_desc, axis=1)
        got = match_in_radius(np.zeros((1, 2)), query_desc, np.zeros((1, 2)), kp_desc, radius_px=1.0, max_hamming=bits, ratio=0.9)
        assert got.tolist() == [0], bits
        assert match_in_radius(np.zeros((1, 2)), query_desc, np.zeros((1, 2)), kp_desc, radius_px=1.0, max_hamming=bits - 1, ratio=0.9).tolist() == [-1]


def test_empty_inputs_and_unequal_descriptors() -> None:
    desc = np.zeros((2, 32), np.uint8)
    assert match_in_radius(np.zeros((0, 2)), desc[:0], np.zeros((2, 2)), desc, radius_px=5.0, max_hamming=50, ratio=0.9).tolist() == []
    assert match_in_radius(np.zeros((2, 2)), desc, np.zeros((0, 2)), desc[:0], radius_px=5.0, max_hamming=50, ratio=0.9).tolist() == [-1, -1]
    with pytest.raises(ValueError, match="descriptor lengths differ"):
        match_in_radius(np.zeros((2, 2)), desc, np.zeros((2, 2)), np.zeros((2, 64), np.uint8), radius_px=5.0, max_hamming=50, ratio=0.9)
