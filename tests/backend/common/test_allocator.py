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
