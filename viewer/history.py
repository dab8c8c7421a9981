"""The debugger's snapshots: one or more per keyframe, one per variant computed there.

A step adds the keyframe's first snapshot (the variant it was stepped with). Switching the
variant at the newest keyframe re-optimizes the same window from the state the step left
(an engine checkpoint) and adds that variant's snapshot beside the first: every variant at
a keyframe starts from the same input, and returning to a variant shows its kept result
instead of re-optimizing an already changed state. At most `capacity` keyframes are kept,
and at most `max_bytes` of their arrays (oldest keyframes dropped first; the newest is
always kept). The bytes are those of the distinct array buffers the kept snapshots hold:
snapshots share arrays (a trajectory's prefix, unchanged landmarks), and a shared buffer
counts once (`ArrayLedger`).
"""

from __future__ import annotations

import collections
import dataclasses
from collections.abc import Iterator

import numpy as np
import scipy.sparse as sp

from backend.optim.variant import Variant
from backend.pipeline.snapshot import Snapshot

DEFAULT_MAX_BYTES = 60 * 2**20  # as ViewerSettings.history_mb


def arrays_of(value: object, *, _depth: int = 0) -> Iterator[np.ndarray | bytes]:
    """Every NumPy array and bytes object (the encoded keyframe image) reachable from `value`
    through dataclass fields, tuples, lists, dict values and SciPy sparse matrices (the
    Hessian's pattern): a snapshot's parts."""
    if isinstance(value, np.ndarray | bytes):
        yield value
    elif _depth > 8 or value is None or isinstance(value, str | int | float | bool):
        return
    elif sp.issparse(value):
        for name in ("data", "indices", "indptr", "row", "col"):
            part = getattr(value, name, None)
            if isinstance(part, np.ndarray):
                yield part
    elif dataclasses.is_dataclass(value) and not isinstance(value, type):
        for field in dataclasses.fields(value):
            yield from arrays_of(getattr(value, field.name), _depth=_depth + 1)
    elif isinstance(value, tuple | list):
        for item in value:
            yield from arrays_of(item, _depth=_depth + 1)
    elif isinstance(value, dict):
        for item in value.values():
            yield from arrays_of(item, _depth=_depth + 1)


def _owner(array: np.ndarray | bytes) -> np.ndarray | bytes:
    """The object that owns `array`'s memory (views lead back to it; bytes own theirs)."""
    while isinstance(array, np.ndarray) and isinstance(array.base, np.ndarray):
        array = array.base
    return array


def _size(owner: np.ndarray | bytes) -> int:
    return int(owner.nbytes) if isinstance(owner, np.ndarray) else len(owner)


class ArrayLedger:
    """Bytes of the distinct buffers (arrays, bytes) held by the objects added and not yet
    removed (each counted once however many snapshots share it)."""

    def __init__(self) -> None:
        self._count: dict[int, int] = {}
        self._size: dict[int, int] = {}
        self._held: dict[int, np.ndarray | bytes] = {}  # keeps each counted owner alive, so its id is not reused
        self.bytes = 0

    def add(self, value: object) -> None:
        for key, owner in self._owners(value).items():
            if key in self._count:
                self._count[key] += 1
            else:
                self._count[key], self._size[key], self._held[key] = 1, _size(owner), owner
                self.bytes += _size(owner)

    def remove(self, value: object) -> None:
        for key in self._owners(value):
            self._count[key] -= 1
            if self._count[key] == 0:
                self.bytes -= self._size.pop(key)
                del self._count[key], self._held[key]

    def clear(self) -> None:
        self._count.clear()
        self._size.clear()
        self._held.clear()
        self.bytes = 0

    @staticmethod
    def _owners(value: object) -> dict[int, np.ndarray | bytes]:
        owners = {}
        for array in arrays_of(value):
            owner = _owner(array)
            owners[id(owner)] = owner
        return owners


class SnapshotHistory:
    """Snapshots by keyframe and variant, in keyframe order."""

    def __init__(self, capacity: int, *, max_bytes: int = DEFAULT_MAX_BYTES) -> None:
        if capacity < 1:
            raise ValueError("capacity must be at least 1 keyframe")
        if max_bytes < 1:
            raise ValueError("max_bytes must be positive")
        self.capacity = capacity
        self.max_bytes = max_bytes
        self._by_keyframe: collections.OrderedDict[int, dict[Variant, Snapshot]] = collections.OrderedDict()
        self._stepped: dict[int, Variant] = {}  # the variant each keyframe was stepped with
        self._latest: dict[int, Variant] = {}  # the variant computed or chosen last there
        self._ledger = ArrayLedger()

    @property
    def bytes(self) -> int:
        """Bytes of the kept snapshots' arrays (shared buffers once)."""
        return self._ledger.bytes

    def __len__(self) -> int:
        """Number of keyframes kept."""
        return len(self._by_keyframe)

    def __bool__(self) -> bool:
        return bool(self._by_keyframe)

    def clear(self) -> None:
        self._by_keyframe.clear()
        self._stepped.clear()
        self._latest.clear()
        self._ledger.clear()

    def add_step(self, snapshot: Snapshot) -> None:
        """A new keyframe's first snapshot (replaces anything kept for that keyframe, e.g.
        after a reset)."""
        k = snapshot.keyframe
        for old in self._by_keyframe.pop(k, {}).values():
            self._ledger.remove(old)
        self._by_keyframe[k] = {snapshot.variant: snapshot}
        self._ledger.add(snapshot)
        self._stepped[k] = self._latest[k] = snapshot.variant
        self._trim()

    def add_variant(self, snapshot: Snapshot) -> None:
        """Another variant's snapshot of a kept keyframe (it becomes the latest there)."""
        kept = self._by_keyframe[snapshot.keyframe]
        if snapshot.variant in kept:
            self._ledger.remove(kept[snapshot.variant])
        kept[snapshot.variant] = snapshot
        self._ledger.add(snapshot)
        self._latest[snapshot.keyframe] = snapshot.variant
        self._trim()

    def _trim(self) -> None:
        """Drop the oldest keyframes beyond `capacity` or `max_bytes` (never the newest)."""
        while len(self._by_keyframe) > 1 and (len(self._by_keyframe) > self.capacity or self._ledger.bytes > self.max_bytes):
            old, snapshots = self._by_keyframe.popitem(last=False)
            for snapshot in snapshots.values():
                self._ledger.remove(snapshot)
            self._stepped.pop(old, None)
            self._latest.pop(old, None)

    def choose(self, keyframe: int, variant: Variant) -> None:
        """Make a computed variant the latest at `keyframe` (the user returned to it)."""
        if variant in self._by_keyframe.get(keyframe, {}):
            self._latest[keyframe] = variant

    @property
    def first_keyframe(self) -> int:
        return next(iter(self._by_keyframe))

    @property
    def newest_keyframe(self) -> int:
        return next(reversed(self._by_keyframe))

    def keyframes(self) -> list[int]:
        return list(self._by_keyframe)

    def variants_at(self, keyframe: int) -> dict[Variant, Snapshot]:
        """Every variant computed at `keyframe` (empty if not kept), stepped one first."""
        found = self._by_keyframe.get(keyframe, {})
        first = self._stepped.get(keyframe)
        return dict(sorted(found.items(), key=lambda item: item[0] != first))

    def get(self, keyframe: int, variant: Variant | None = None) -> Snapshot | None:
        """`variant`'s snapshot at `keyframe` if computed, else the latest there; None if
        the keyframe is not kept."""
        found = self._by_keyframe.get(keyframe)
        if not found:
            return None
        if variant is not None and variant in found:
            return found[variant]
        return found[self._latest[keyframe]]

    def newest(self, variant: Variant | None = None) -> Snapshot:
        return self.get(self.newest_keyframe, variant)  # type: ignore[return-value]

    def series(self, variant: Variant | None = None) -> list[Snapshot]:
        """One snapshot per kept keyframe: `variant`'s where computed, else the latest."""
        return [self.get(k, variant) for k in self._by_keyframe]  # type: ignore[misc]

    def __getitem__(self, index: int) -> Snapshot:
        """The latest snapshot of the index-th kept keyframe (`[-1]`: the newest)."""
        return self.get(self.keyframes()[index])  # type: ignore[return-value]
