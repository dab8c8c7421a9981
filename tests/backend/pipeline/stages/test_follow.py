"""The followed features' keypoints (backend/pipeline/stages/follow.py)."""

from __future__ import annotations

import numpy as np

from backend.frontend.points import Keypoints
from backend.pipeline.stages.follow import _pairs_within, with_followed_keypoints


def test_pairs_within_the_radius_are_the_dense_distance_matrix_s() -> None:
    """The k-d tree's pairs and distances are exactly those of the dense matrix it replaced
    (its order too), pixels at exactly the radius and repeated keypoints included."""
    rng = np.random.default_rng(3)
    at_radius = 0
    for trial in range(150):
        a = rng.uniform(0, 80, (int(rng.integers(0, 200)), 2))
        b = rng.uniform(0, 80, (int(rng.integers(1, 800)), 2))
        if trial % 3 == 0 and len(a) >= 5 and len(b) >= 5:
            a, b = np.round(a), np.round(b)
            b[:5] = a[:5] + [2.0, 0.0]
        d = np.linalg.norm(a[:, None, :] - b[None, :, :], axis=2)
        rows, cols = np.nonzero(d <= 2.0)
        at_radius += int(np.sum(d == 2.0))
        got = _pairs_within(a, b, 2.0)
        np.testing.assert_array_equal(got[0], rows)
        np.testing.assert_array_equal(got[1], cols)
        np.testing.assert_array_equal(got[2], d[rows, cols])
    assert at_radius > 100


def test_a_followed_pixel_takes_the_nearest_keypoint_or_gets_its_own() -> None:
    image = np.random.default_rng(0).integers(0, 255, (120, 160), dtype=np.uint8)
    kp = Keypoints(uv=np.array([[50.0, 60.0], [52.5, 60.0], [100.0, 40.0]]), descriptors=np.zeros((3, 32), np.uint8), octave=np.zeros(3, np.int32))
    uv = np.array([[51.0, 60.0], [100.5, 40.5], [80.0, 80.0], [2.0, 2.0]])  # near 0, near 2, no keypoint near, at the border
    grown, index = with_followed_keypoints(kp, uv, image)
    assert index[0] == 0 and index[1] == 2
    assert index[2] == 3 and np.allclose(grown.uv[3], uv[2])  # a new keypoint with its descriptor
    assert index[3] == -1  # too near the border for a descriptor
