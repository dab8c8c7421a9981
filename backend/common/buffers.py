"""Append-only row buffers whose prefixes are shared, read-only, between snapshots."""

from __future__ import annotations

from typing import Any

import numpy as np

from backend.common.allocator import mapped_zeros, own_mapping


class RowBuffer:
    """Rows of shape `row_shape` appended one at a time (amortized O(1)).

    :meth:`prefix` returns a read-only view without copying. The owner promises never to
    write a row that an earlier prefix covers *after* that prefix was taken (for poses:
    only the sliding window, which lies beyond every earlier frozen prefix, is written).
    Growth allocates a new array, so views of the old one stay valid.
    """

    def __init__(self, row_shape: tuple[int, ...], *, dtype: type = float, capacity: int = 64) -> None:
        self._data: np.ndarray = mapped_zeros((capacity, *row_shape), dtype)
        self._n = 0

    def __len__(self) -> int:
        return self._n

    def __deepcopy__(self, memo: dict[int, Any]) -> RowBuffer:
        """A copy of the rows in use only (the spare capacity is not copied: a map's
        checkpoint would otherwise hold up to twice its rows; the copy grows on its next
        append)."""
        new = RowBuffer.__new__(RowBuffer)
        new._data = own_mapping(self._data[: max(self._n, 1)])
        new._n = self._n
        memo[id(self)] = new
        return new

    def append(self, row: np.ndarray | float) -> int:
        """Append a row; returns its index."""
        if self._n == len(self._data):
            grown = mapped_zeros((2 * len(self._data), *self._data.shape[1:]), self._data.dtype)
            grown[: self._n] = self._data[: self._n]
            self._data = grown
        self._data[self._n] = row
        self._n += 1
        return self._n - 1

    def __getitem__(self, index: Any) -> np.ndarray:
        return self._data[: self._n][index]

    def __setitem__(self, index: Any, value: np.ndarray | float | bool) -> None:
        self._data[: self._n][index] = value

    def prefix(self, n: int) -> np.ndarray:
        """Read-only view of rows [0, n)."""
        view = self._data[:n]
        view.setflags(write=False)
        return view
