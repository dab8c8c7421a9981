"""glibc's allocator for a long-running process with several threads (the debugger's server).

glibc gives each thread that allocates an arena of its own (up to 8 per core), and memory
freed in one arena serves only that arena's later requests: with the pipeline's reader and
worker threads, the debugger's worker, the plot thread and the web server, freed snapshots
and frames stay mapped as fragments in many arenas. Two arenas and returning free pages to
the system after each of the debugger's commands took the server from 551 to 460 MiB after
100 keyframes on room (every variant at every 10th); the pipeline's output does not change.

Both calls do nothing where the C library is not glibc (they return False).
"""

from __future__ import annotations

import ctypes
import ctypes.util
import functools
import mmap

import numpy as np

M_ARENA_MAX = -8  # mallopt's parameter number in glibc's malloc.h


@functools.cache
def _libc() -> ctypes.CDLL | None:
    """glibc, or None where the C library has no mallopt / malloc_trim (musl, macOS)."""
    try:
        libc = ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6")
    except OSError:
        return None
    if not all(hasattr(libc, name) for name in ("mallopt", "malloc_trim")):
        return None
    return libc


def limit_arenas(count: int = 2) -> bool:
    """Let threads share at most `count` arenas (threads that have not allocated yet, and
    arenas not yet created). Call before the process starts its threads. True if set."""
    libc = _libc()
    return bool(libc is not None and libc.mallopt(M_ARENA_MAX, int(count)) == 1)


def release_free_memory() -> bool:
    """Return the free pages of every arena to the system (`malloc_trim(0)`; 1-80 ms,
    more the more was freed). True if memory was released."""
    libc = _libc()
    return bool(libc is not None and libc.malloc_trim(0) == 1)


def mapped_zeros(shape: tuple[int, ...], dtype: np.dtype | type, *, min_bytes: int = 64 * 1024) -> np.ndarray:
    """A zero-filled array, in an anonymous memory mapping of its own when it has at least
    `min_bytes` (else from the heap, as `np.zeros`). Its pages go back to the system as soon
    as it and every view of it are freed, whatever else the heap holds: for large arrays
    that outlive the temporaries allocated around them (the debugger's kept snapshots, the
    map's buffers and their checkpoints), whose holes in glibc's heap would otherwise stay
    as fragments that later requests only partly fill. Writable; its `base` is the mapping."""
    dtype = np.dtype(dtype)
    nbytes = int(np.prod(shape, dtype=np.int64)) * dtype.itemsize
    if nbytes < min_bytes:
        return np.zeros(shape, dtype)
    return np.frombuffer(mmap.mmap(-1, nbytes), dtype=dtype).reshape(shape)


def own_mapping(array: np.ndarray, *, min_bytes: int = 64 * 1024) -> np.ndarray:
    """A C-contiguous copy of `array`, in a mapping of its own when large (`mapped_zeros`)."""
    a = np.asarray(array)
    out = mapped_zeros(a.shape, a.dtype, min_bytes=min_bytes)
    out[...] = a
    return out
