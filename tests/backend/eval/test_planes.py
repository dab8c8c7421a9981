"""Matching estimated planes to ground-truth planes."""

from __future__ import annotations

import numpy as np

from backend.eval.planes import recovered_planes


def test_recovered_planes_by_normal_and_offset() -> None:
    n_true = np.array([[0.0, 0.0, 1.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])
    d_true = np.array([0.0, -4.0, 2.0])
    tilt = np.radians(5.0)
    n_est = np.array([[0.0, np.sin(tilt), np.cos(tilt)], [-1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])
    d_est = np.array([0.05, 4.02, 2.5])  # the wall x = 4 with the flipped normal; y = -2 off by 0.5 m
    np.testing.assert_array_equal(recovered_planes(n_est, d_est, n_true, d_true), [True, True, False])
    np.testing.assert_array_equal(recovered_planes(n_est, d_est, n_true, d_true, max_angle_deg=3.0), [False, True, False])
    assert not recovered_planes(np.zeros((0, 3)), np.zeros(0), n_true, d_true).any()
