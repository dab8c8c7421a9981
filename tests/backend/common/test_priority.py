"""A background thread lowers its own priority and nobody else's (backend/common/priority.py)."""

from __future__ import annotations

import os
import sys
import threading

import pytest

from backend.common.priority import lower_this_thread


@pytest.mark.skipif(sys.platform != "linux", reason="per-thread niceness is Linux's")
def test_a_thread_lowers_its_own_priority_and_not_the_process() -> None:
    main_before = os.getpriority(os.PRIO_PROCESS, threading.get_native_id())
    seen: dict[str, int | bool] = {}

    def background() -> None:
        tid = threading.get_native_id()
        seen["before"] = os.getpriority(os.PRIO_PROCESS, tid)
        seen["set"] = lower_this_thread(by=3)
        seen["after"] = os.getpriority(os.PRIO_PROCESS, tid)

    thread = threading.Thread(target=background)
    thread.start()
    thread.join()
    assert seen["set"] is True
    assert seen["after"] == min(int(seen["before"]) + 3, 19)
    assert os.getpriority(os.PRIO_PROCESS, threading.get_native_id()) == main_before  # the caller's thread only
    assert os.getpriority(os.PRIO_PROCESS, os.getpid()) == main_before


def test_nothing_to_lower_is_refused() -> None:
    assert lower_this_thread(by=0) is False
