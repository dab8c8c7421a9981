"""One BLAS thread for the library's own numerical work, wherever `backend` is imported.

The pipeline's solves are many small dense products and factorizations (6×6 to a few hundred
square). A multi-threaded OpenBLAS spends more on waking and synchronizing its threads than
on the arithmetic, and on a 2-core machine shared with the pipeline's other work the same
P-wo window solve took 65-750 ms against 25-57 ms with one thread. The command line sets
`OPENBLAS_NUM_THREADS=1` before NumPy loads; a notebook or a script that imports `backend`
after NumPy cannot, so the library's entry points (`optimize`, the engines' `step`) run under
`single_threaded_blas`, which limits every BLAS library loaded in the process (NumPy's,
SciPy's, OpenCV's) to one thread for the call and restores the caller's setting afterwards,
through threadpoolctl. The caller's own NumPy work outside those calls keeps its threads.

`COPLANAR_BLAS_THREADS` (an integer ≥ 1) chooses another count for the library's calls.
"""

from __future__ import annotations

import functools
import os
import sys
import threading
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from typing import ParamSpec, TypeVar

from threadpoolctl import ThreadpoolController

P = ParamSpec("P")
R = TypeVar("R")

ENV_VARIABLE = "COPLANAR_BLAS_THREADS"


def _threads_wanted() -> int:
    """The BLAS thread count for the library's calls: `COPLANAR_BLAS_THREADS`, else 1. A value
    that is not a positive integer is refused with the variable's name."""
    raw = os.environ.get(ENV_VARIABLE, "").strip()
    if not raw:
        return 1
    try:
        value = int(raw)
    except ValueError:
        value = 0
    if value < 1:
        raise ValueError(f"{ENV_VARIABLE}={raw!r}: expected a positive integer (BLAS threads for coplanar's solves)")
    return value


class _Limiter:
    """The process's one limiter. The BLAS setting is process-wide, so one thread at a time
    owns it: the first call in limits every loaded BLAS library and restores it on its way
    out (in the same thread, as threadpoolctl requires for OpenBLAS). Nested calls (a solve
    inside an engine step) and calls from other threads while it is held (the debugger's
    worker beside a script) run under the limit already set and change nothing. The
    controller (the list of loaded BLAS libraries) is built at the first call, after the
    library's imports, and again when a call finds modules imported since (threadpoolctl's
    scan of the loaded objects costs ~0.3 ms; the limit itself ~10 µs)."""

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._owned = False
        self._controller: ThreadpoolController | None = None
        self._modules_seen = -1

    def _claim(self) -> ThreadpoolController | None:
        """The controller if this call is to own the limit; None when another call holds it."""
        with self._lock:
            if self._owned:
                return None
            modules = len(sys.modules)  # a new extension module may have brought its own BLAS
            if self._controller is None or modules != self._modules_seen:
                self._controller = ThreadpoolController()
                self._modules_seen = modules
            self._owned = True
            return self._controller

    def _release(self) -> None:
        with self._lock:
            self._owned = False

    @contextmanager
    def limit(self) -> Iterator[None]:
        threads = _threads_wanted()
        controller = self._claim()
        if controller is None:
            yield
            return
        try:
            with controller.limit(limits=threads, user_api="blas"):
                yield
        finally:
            self._release()


_LIMITER = _Limiter()


def single_threaded_blas(function: Callable[P, R]) -> Callable[P, R]:
    """Decorator for the library's entry points: `function` runs with one BLAS thread (or
    `COPLANAR_BLAS_THREADS`), the caller's setting restored when it returns or raises."""

    @functools.wraps(function)
    def wrapper(*args: P.args, **kwargs: P.kwargs) -> R:
        with _LIMITER.limit():
            return function(*args, **kwargs)

    return wrapper
