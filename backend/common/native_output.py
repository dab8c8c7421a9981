"""What C libraries print straight to the process's stderr, kept off it where the caller
reports the failure itself (the one-line error policy, DESIGN §8)."""

from __future__ import annotations

import contextlib
import os
import sys
from collections.abc import Iterator


@contextlib.contextmanager
def native_stderr_silenced() -> Iterator[None]:
    """The process's stderr (file descriptor 2) sent to /dev/null for the block: C
    libraries print there directly (libpng on a broken image, open3d's RPly on a full
    disk), while the caller reports the failure in one line of its own."""
    fd = 2  # the descriptor C code writes to, whatever Python's sys.stderr is at the time
    for stream in (sys.stderr, sys.__stderr__):
        if stream is not None:
            stream.flush()
    try:
        saved = os.dup(fd)
    except OSError:  # no stderr at all: nothing to silence
        yield
        return
    devnull = os.open(os.devnull, os.O_WRONLY)
    try:
        os.dup2(devnull, fd)
        yield
    finally:
        os.dup2(saved, fd)
        os.close(saved)
        os.close(devnull)
