"""The debugger's snapshot store: per keyframe and per variant, bounded by keyframes."""

from __future__ import annotations

import dataclasses

import pytest

from backend.pipeline.sim_engine import SimEngine, SimSettings
from viewer.history import SnapshotHistory


@pytest.fixture(scope="module")
def steps() -> list:
    engine = SimEngine(SimSettings(window=4, max_iterations=2))
    return [engine.step() for _ in range(4)]


def _as(snapshot, variant: str):
    return dataclasses.replace(snapshot, report=dataclasses.replace(snapshot.report, variant=variant))


def test_every_variant_of_a_keyframe_is_kept_and_the_stepped_one_first(steps) -> None:
    h = SnapshotHistory(10)
    for s in steps:
        h.add_step(s)
    k = steps[-1].keyframe
    for v in ("P-wo", "PL-r"):
        h.add_variant(_as(steps[-1], v))
    assert list(h.variants_at(k)) == ["PL-w", "P-wo", "PL-r"]
    assert h.get(k).variant == "PL-r"  # the latest computed
    assert h.get(k, "P-wo").variant == "P-wo"
    assert h.get(k, "P-w").variant == "PL-r"  # not computed here: the latest
    h.choose(k, "PL-w")
    assert h.get(k).variant == "PL-w" and h[-1].variant == "PL-w"
    assert h.get(steps[0].keyframe, "P-wo").variant == "PL-w"  # older keyframes keep theirs
    assert [s.keyframe for s in h.series("P-wo")] == [s.keyframe for s in steps]
    assert h.series("P-wo")[-1].variant == "P-wo"


def test_capacity_drops_the_oldest_keyframe_with_its_variants(steps) -> None:
    h = SnapshotHistory(2)
    h.add_step(steps[0])
    h.add_variant(_as(steps[0], "P-w"))
    for s in steps[1:]:
        h.add_step(s)
    assert len(h) == 2 and h.keyframes() == [steps[-2].keyframe, steps[-1].keyframe]
    assert h.variants_at(steps[0].keyframe) == {}
    assert h.get(steps[0].keyframe) is None
    h.clear()
    assert not h and len(h) == 0
    with pytest.raises(ValueError):
        SnapshotHistory(0)


def test_the_byte_cap_drops_the_oldest_keyframes_and_counts_shared_arrays_once() -> None:
    """Snapshots of a real run share arrays (the trajectory's prefix); the history counts a
    shared buffer once, and a cap below the run's size keeps the newest keyframes that fit."""
    from viewer.history import ArrayLedger

    engine = SimEngine(SimSettings(window=4, max_iterations=2))
    snaps = [engine.step() for _ in range(12)]
    unlimited = SnapshotHistory(100)
    for s in snaps:
        unlimited.add_step(s)
    separately = 0
    for s in snaps:
        ledger = ArrayLedger()
        ledger.add(s)
        separately += ledger.bytes
    assert 0 < unlimited.bytes < separately  # shared buffers counted once
    cap = unlimited.bytes // 2
    capped = SnapshotHistory(100, max_bytes=cap)
    for s in snaps:
        capped.add_step(s)
    assert capped.bytes <= cap and 1 <= len(capped) < len(snaps)
    assert capped.keyframes() == [s.keyframe for s in snaps[-len(capped) :]]  # the newest kept
    capped.add_variant(_as(snaps[-1], "P-wo"))
    assert capped.bytes <= cap and capped.newest_keyframe == snaps[-1].keyframe
    tiny = SnapshotHistory(100, max_bytes=1)
    for s in snaps:
        tiny.add_step(s)
    assert tiny.keyframes() == [snaps[-1].keyframe]  # the newest is always kept
    tiny.clear()
    assert tiny.bytes == 0
