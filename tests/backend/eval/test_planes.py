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


def test_recovered_planes_by_patch_does_not_depend_on_the_origin() -> None:
    """A floor seen in a strip 2.2 m from the origin, tilted 2.6° about the strip: 10 cm
    off at the origin, 2 cm over the strip it was mapped from. Moved 2 cm further up it is
    still recovered by its patch; a patch that reaches 15 cm above the floor is not."""
    n_true, d_true = np.array([[0.0, 0.0, 1.0]]), np.array([0.0])
    tilt = np.radians(2.6)
    n_est = np.array([[0.0, -np.sin(tilt), np.cos(tilt)]])
    y0 = -2.2
    d_est = np.array([np.sin(tilt) * y0])  # the plane passes through z = 0 at y = y0
    assert abs(d_est[0]) > 0.099
    strip = np.array([[x, y, 0.0] for x in (-2.0, 1.5) for y in (y0 - 0.35, y0 + 0.35)])
    strip[:, 2] = -(n_est[0, :2] @ strip[:, :2].T + d_est[0]) / n_est[0, 2]  # on the estimated plane
    assert recovered_planes(n_est, d_est - 0.02, n_true, d_true, max_offset_m=0.05, hulls_est_world=[strip + [0, 0, 0.02]]).all()
    assert not recovered_planes(n_est, d_est, n_true, d_true, max_offset_m=0.05).any()
    high = strip.copy()
    high[0, 2] = 0.15
    assert not recovered_planes(n_est, d_est, n_true, d_true, hulls_est_world=[high]).any()
    assert recovered_planes(n_est, d_est, n_true, d_true, hulls_est_world=[np.zeros((0, 3))], max_offset_m=0.2).all()
