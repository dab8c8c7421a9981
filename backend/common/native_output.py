"""What C libraries print straight to the process's stderr, kept off it where the caller
reports the failure itself (the one-line error policy, DESIGN §8).

Silencing redirects the process-wide descriptor 2, also while another thread writes: the
image reader silences it on its own thread while the command line prints its last line.
`STDERR_LOCK` is held while it is redirected; whoever must be heard (the command's
`error:` or `interrupted` line) writes under it (:func:`say`)."""

from __future__ import annotations

import contextlib
import os
import sys
import threading
from collections.abc import Iterator

#: Held while descriptor 2 is redirected; take it to write a line that must not be lost.
STDERR_LOCK = threading.RLock()


def say(line: str) -> None:
    """Print `line` on stderr, never into a silenced descriptor (module docstring)."""
    with STDERR_LOCK:
        print(line, file=sys.stderr, flush=True)


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
    from backend.common.optional import interrupts_held

    devnull = os.open(os.devnull, os.O_WRONLY)
    with STDERR_LOCK, interrupts_held():  # a Ctrl-C waits for the descriptor to be put back
        try:
            os.dup2(devnull, fd)
            yield
        finally:
            os.dup2(saved, fd)
            os.close(saved)
            os.close(devnull)
