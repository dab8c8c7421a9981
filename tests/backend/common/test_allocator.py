"""backend/common/allocator.py: freed memory goes back to the system, as the debugger's
server relies on to stay small over a long session."""

from __future__ import annotations

import threading

import numpy as np
import pytest

from backend.common import allocator

pytestmark = pytest.mark.skipif(allocator._libc() is None, reason="not glibc")


def _rss_mib() -> float:
    with open("/proc/self/status") as f:
        return next(int(line.split()[1]) / 1024.0 for line in f if line.startswith("VmRSS:"))


def test_freed_fragments_are_returned_to_the_system() -> None:
    # 160 MiB of small blocks (below malloc's mmap threshold: they come from an arena), all
    # freed but the last, which pins the heap's top so that only a trim can return the rest.
    kept: list[np.ndarray] = []

    def allocate() -> None:
        blocks = [np.ones(1024) for _ in range(20_000)]
        kept.append(blocks[-1])
        del blocks

    thread = threading.Thread(target=allocate)  # an arena of its own, as the debugger's threads have
    thread.start()
    thread.join()
    before = _rss_mib()
    assert allocator.release_free_memory()
    assert _rss_mib() < before - 100.0


def test_arenas_can_be_limited() -> None:
    assert allocator.limit_arenas(8)  # glibc's own default on few cores; harmless for the rest of the tests


def test_a_large_kept_array_gives_its_pages_back_when_freed_whatever_the_heap_holds() -> None:
    # A kept snapshot's array between temporaries: freed, its pages go back at once, with no
    # trim, although blocks allocated after it stay in use.
    freed = np.ones(3 * 2**20)  # 24 MiB, mapped by malloc and freed: glibc then raises its mmap
    del freed  # threshold to that size, so that a plain 16 MiB copy would come from the heap
    source = np.arange(16 * 2**20 // 8, dtype=np.float64).reshape(-1, 2)  # 16 MiB
    before = _rss_mib()
    kept = allocator.own_mapping(source)
    pins = [np.ones(64) for _ in range(1000)]  # heap blocks allocated after it, still in use (0.5 MiB)
    assert _rss_mib() > before + 14.0
    assert float(kept.sum()) == float(source.sum()) and list(kept[12345]) == list(source[12345])  # no large temporaries: they would grow the heap
    layout = (bool(kept.flags.c_contiguous), bool(kept.flags.writeable), kept.dtype == source.dtype)  # no flags object left holding the array
    assert layout == (True, True, True)
    view = kept[::2]
    del kept
    assert _rss_mib() > before + 14.0  # a view keeps the mapping
    del view
    assert _rss_mib() < before + 4.0
    assert len(pins) == 1000


def test_small_arrays_stay_on_the_heap_and_zeros_are_zeros() -> None:
    small = allocator.own_mapping(np.arange(10))
    assert small.base is None and list(small) == list(range(10))
    rows = np.random.default_rng(0).normal(size=(50_000, 3))
    np.testing.assert_array_equal(allocator.own_mapping(rows), rows)
    big = allocator.mapped_zeros((300, 300), np.float32)
    assert big.shape == (300, 300) and big.dtype == np.float32 and not big.any() and big.base is not None
