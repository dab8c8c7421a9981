"""The pipeline's worker threads, and per-thread copies of OpenCV's stateful detectors.

A keyframe's image-only work (plane segmentation, the right image's line segments) runs on
two shared worker threads beside the pipeline's thread: OpenCV and ONNX Runtime release the
GIL, so on a 2-core machine the work overlaps. Nothing on a worker reads the map, so the
results are those of running it in place.

OpenCV's line segment detector and LBD keep their working images in the object, so one
object must never serve two threads at once: `per_thread(key, make)` gives each thread its
own, built once per thread and key.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable
from concurrent.futures import Future, ThreadPoolExecutor
from typing import Any, TypeVar

T = TypeVar("T")

_EXECUTOR: ThreadPoolExecutor | None = None
_EXECUTOR_LOCK = threading.Lock()
_LOCAL = threading.local()


def submit(function: Callable[[], T]) -> Future[T]:
    """Run `function` on one of the two shared worker threads; `.result()` waits and raises
    its error."""
    global _EXECUTOR
    with _EXECUTOR_LOCK:
        if _EXECUTOR is None:
            _EXECUTOR = ThreadPoolExecutor(max_workers=2, thread_name_prefix="coplanar-worker")
        executor = _EXECUTOR
    return executor.submit(function)


def submit_timed(function: Callable[[], T]) -> Future[tuple[T, float]]:
    """As :func:`submit`; the result comes with the call's own time on the worker (ms)."""

    def timed() -> tuple[T, float]:
        t0 = time.perf_counter()
        value = function()
        return value, 1e3 * (time.perf_counter() - t0)

    return submit(timed)


def per_thread(key: Any, make: Callable[[], T]) -> T:
    """This thread's object for `key`, made by `make()` on the thread's first call."""
    cache: dict[Any, Any] | None = getattr(_LOCAL, "cache", None)
    if cache is None:
        cache = _LOCAL.cache = {}
    if key not in cache:
        cache[key] = make()
    return cache[key]
