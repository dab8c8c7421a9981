"""The debugger's snapshots: one or more per keyframe, one per variant computed there.

A step adds the keyframe's first snapshot (the variant it was stepped with). Switching the
variant at the newest keyframe re-optimizes the same window from the state the step left
(an engine checkpoint) and adds that variant's snapshot beside the first: every variant at
a keyframe starts from the same input, and returning to a variant shows its kept result
instead of re-optimizing an already changed state. At most `capacity` keyframes are kept
(oldest dropped first).
"""

from __future__ import annotations

import collections

from backend.optim.variant import Variant
from backend.pipeline.snapshot import Snapshot


class SnapshotHistory:
    """Snapshots by keyframe and variant, in keyframe order."""

    def __init__(self, capacity: int) -> None:
        if capacity < 1:
            raise ValueError("capacity must be at least 1 keyframe")
        self.capacity = capacity
        self._by_keyframe: collections.OrderedDict[int, dict[Variant, Snapshot]] = collections.OrderedDict()
        self._stepped: dict[int, Variant] = {}  # the variant each keyframe was stepped with
        self._latest: dict[int, Variant] = {}  # the variant computed or chosen last there

    def __len__(self) -> int:
        """Number of keyframes kept."""
        return len(self._by_keyframe)

    def __bool__(self) -> bool:
        return bool(self._by_keyframe)

    def clear(self) -> None:
        self._by_keyframe.clear()
        self._stepped.clear()
        self._latest.clear()

    def add_step(self, snapshot: Snapshot) -> None:
        """A new keyframe's first snapshot (replaces anything kept for that keyframe, e.g.
        after a reset)."""
        k = snapshot.keyframe
        self._by_keyframe.pop(k, None)
        self._by_keyframe[k] = {snapshot.variant: snapshot}
        self._stepped[k] = self._latest[k] = snapshot.variant
        while len(self._by_keyframe) > self.capacity:
            old, _ = self._by_keyframe.popitem(last=False)
            self._stepped.pop(old, None)
            self._latest.pop(old, None)

    def add_variant(self, snapshot: Snapshot) -> None:
        """Another variant's snapshot of a kept keyframe (it becomes the latest there)."""
        self._by_keyframe[snapshot.keyframe][snapshot.variant] = snapshot
        self._latest[snapshot.keyframe] = snapshot.variant

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
