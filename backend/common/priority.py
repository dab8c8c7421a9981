"""A thread's scheduling priority: background work that must yield the CPU to what a user
waits for (the debugger's plots, drawn while the user looks, against the engine's next step
and the browser taking in the scene).

Linux schedules threads as tasks with a niceness each, and a thread may raise its own (lower
its priority) without privileges; it cannot lower it again without them, so a thread that
calls :func:`lower_this_thread` stays in the background for its life. Elsewhere (macOS,
Windows) the call does nothing: `os.setpriority` there acts on the whole process.
"""

from __future__ import annotations

import os
import sys
import threading

BACKGROUND_NICENESS = 10  # Linux's CFS then gives a busy foreground thread about 9 times this one's CPU share


def lower_this_thread(*, by: int = BACKGROUND_NICENESS) -> bool:
    """Raise the calling thread's niceness by `by` (Linux only). True if it was set."""
    if sys.platform != "linux" or by <= 0:
        return False
    tid = threading.get_native_id()
    try:
        os.setpriority(os.PRIO_PROCESS, tid, min(os.getpriority(os.PRIO_PROCESS, tid) + int(by), 19))
    except OSError:
        return False
    return True
