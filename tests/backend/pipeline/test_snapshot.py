"""Snapshots' point positions: float32, and a point solved out to infinity left out."""

from __future__ import annotations

import warnings

import numpy as np

from backend.pipeline.snapshot import drawable_points


def test_points_beyond_float32_or_not_finite_are_left_out_without_a_warning() -> None:
    p_world = np.array([[1.0, 2.0, 3.0], [1e39, 0.0, 1.0], [0.5, np.nan, 0.0], [-4.0, 5.0, 6.0], [0.0, 0.0, -2e39]])
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # the float32 cast of 1e39 would warn (overflow)
        ids, p32 = drawable_points(p_world, np.array([0, 1, 2, 3, 4]))
    assert ids.tolist() == [0, 3]
    assert p32.dtype == np.float32
    np.testing.assert_array_equal(p32, np.float32([[1.0, 2.0, 3.0], [-4.0, 5.0, 6.0]]))


def test_finite_points_are_kept_in_the_order_given() -> None:
    p_world = np.arange(15, dtype=float).reshape(5, 3)
    ids, p32 = drawable_points(p_world, np.array([4, 1, 2]))
    assert ids.tolist() == [4, 1, 2]
    np.testing.assert_array_equal(p32, p_world[[4, 1, 2]].astype(np.float32))
