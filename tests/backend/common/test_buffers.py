"""Append-only row buffers: prefixes shared between snapshots stay valid and unchanged."""

from __future__ import annotations

import numpy as np
import pytest

from backend.common.buffers import RowBuffer


def _row(i: int) -> np.ndarray:
    return np.full((3, 3), float(i)) + np.eye(3)


def test_append_returns_indices_and_rows_read_back() -> None:
    buf = RowBuffer((3, 3), capacity=2)
    assert len(buf) == 0
    assert [buf.append(_row(i)) for i in range(5)] == [0, 1, 2, 3, 4]
    assert len(buf) == 5
    np.testing.assert_array_equal(buf[3], _row(3))
    np.testing.assert_array_equal(buf[:], np.stack([_row(i) for i in range(5)]))
    np.testing.assert_array_equal(buf[[4, 0]], np.stack([_row(4), _row(0)]))
    assert buf[:].shape == (5, 3, 3)  # no rows beyond the length


def test_indexing_stops_at_the_length() -> None:
    buf = RowBuffer((), dtype=np.int64, capacity=8)
    buf.append(7)
    assert buf[:].tolist() == [7]
    assert buf[-1] == 7
    with pytest.raises(IndexError):
        buf[1]
    assert buf[:].dtype == np.int64


def test_prefix_is_read_only() -> None:
    buf = RowBuffer((3,), capacity=4)
    for i in range(3):
        buf.append(np.full(3, i))
    view = buf.prefix(2)
    assert view.shape == (2, 3)
    assert not view.flags.writeable
    with pytest.raises(ValueError):
        view[0, 0] = 99.0
    # The buffer itself stays writable.
    buf[2] = np.full(3, 5.0)
    np.testing.assert_array_equal(buf[2], [5.0, 5.0, 5.0])


def test_prefix_survives_growth_and_later_writes() -> None:
    buf = RowBuffer((3,), capacity=2)
    for i in range(2):
        buf.append(np.full(3, i))
    early = buf.prefix(2)
    early_copy = early.copy()
    for i in range(2, 40):  # several reallocations
        buf.append(np.full(3, i))
    middle = buf.prefix(20)
    middle_copy = middle.copy()
    # Writes beyond every prefix (the sliding window).
    buf[20:] = -1.0
    buf[39] = np.array([7.0, 8.0, 9.0])
    for i in range(40, 70):
        buf.append(np.full(3, i))
    np.testing.assert_array_equal(early, early_copy)
    np.testing.assert_array_equal(middle, middle_copy)
    np.testing.assert_array_equal(middle, np.repeat(np.arange(20.0)[:, None], 3, axis=1))
    # The buffer holds everything written, across reallocations.
    assert len(buf) == 70
    np.testing.assert_array_equal(buf[:20], middle_copy)
    np.testing.assert_array_equal(buf[20:39], -1.0)
    np.testing.assert_array_equal(buf[39], [7.0, 8.0, 9.0])
    np.testing.assert_array_equal(buf[40:, 0], np.arange(40.0, 70.0))
    # A later prefix is also read-only and sees the current rows.
    late = buf.prefix(70)
    assert not late.flags.writeable
    np.testing.assert_array_equal(late, buf[:])


def test_prefix_views_do_not_copy() -> None:
    buf = RowBuffer((2,), capacity=16)
    for i in range(10):
        buf.append(np.array([i, -i]))
    a, b = buf.prefix(4), buf.prefix(8)
    assert np.shares_memory(a, b)
    assert np.shares_memory(a, buf[:])
