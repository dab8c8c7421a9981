"""The debugger's worker: the one thread that runs every engine call, one command at a time,
fed by the command queue (viewer/commands.py), so that GUI callbacks never block and never
race. While playing, a step is due whenever no command comes within the play period; an
error in a command pauses the run, and the server stays up."""

from __future__ import annotations

import logging
import queue
import threading
import time
import traceback
from collections.abc import Callable

from backend.common.allocator import release_free_memory
from viewer.commands import Command, CommandQueue

log = logging.getLogger(__name__)

# Free memory goes back to the system whenever the worker falls idle (after the step ahead),
# and while playing at most this often (a trim costs 1-80 ms).
TRIM_PERIOD_PLAYING_S = 5.0


class Worker:
    """Runs `execute(command, arg)` on its thread (:meth:`start`) for every command put, and
    a Step every `period()` seconds while `playing` is set and no command comes. After
    every command it calls `done()`; a command that raises is logged, stops playing and is
    handed to `failed(command, error)` first. `working` is set while a command runs and
    `worked_at` is when the last one ended (the plot thread waits for a pause). When a
    command has run, no other waits and `idle()` says so, the worker queues its own
    `Command.AHEAD` (the next step computed ahead; skipped if a command comes first), so
    `wait_idle` also waits for it; it does not count as work for `working` and
    `worked_at`, and `ahead` is set while it runs (the plots wait for it: drawing beside it
    held the GIL and slowed it past the next click)."""

    def __init__(
        self,
        execute: Callable[[Command, object], None],
        *,
        period: Callable[[], float],
        failed: Callable[[Command, Exception], None],
        done: Callable[[], None],
        idle: Callable[[], bool] | None = None,
    ) -> None:
        self.commands = CommandQueue()
        self.playing = threading.Event()
        self.working = threading.Event()
        self.ahead = threading.Event()  # set while the step ahead runs
        self.worked_at = 0.0
        self._execute = execute
        self._period = period
        self._failed = failed
        self._done = done
        self._idle = idle
        self._stopped = threading.Event()
        self._trimmed_at = 0.0
        self._thread = threading.Thread(target=self._run, name="coplanar-engine", daemon=True)

    def start(self) -> None:
        self._thread.start()

    def put(self, command: Command | str, arg: object = None, *, coalesce: bool = False) -> None:
        """Queue a command; `coalesce`: as a browser's (viewer/commands.py)."""
        self.commands.put(command, arg, coalesce=coalesce)

    def wait_idle(self, timeout: float) -> None:
        """Block until every queued command has run; TimeoutError after `timeout` seconds."""
        if not self.commands.wait_done(timeout):
            raise TimeoutError("the engine did not become idle")

    def stop(self) -> None:
        """Stop playing and the thread, once the command it runs has ended (up to 10 s)."""
        self._stopped.set()
        self.playing.clear()
        self.commands.put(Command.STOP)
        self._thread.join(timeout=10.0)

    def _run(self) -> None:
        while not self._stopped.is_set():
            try:
                timeout = self._period() if self.playing.is_set() else None
                command, arg = self.commands.get(timeout=timeout)
                from_timer = False
            except queue.Empty:
                command, arg = (Command.STEP if self.playing.is_set() else Command.WAKE), None
                from_timer = True
            if command is Command.STOP:
                return
            if command is Command.AHEAD and (self.playing.is_set() or self.commands.pending()):
                self.commands.task_done()  # a command came meanwhile: it goes first
                continue
            if command is not Command.AHEAD:  # the plots wait for a pause in the user's commands and for the step ahead
                self.working.set()
            else:
                self.ahead.set()
            try:
                self._execute(command, arg)
            except Exception as exc:  # an error in a step pauses the run, the server stays up
                log.error("engine error:\n%s", traceback.format_exc())
                self.playing.clear()
                self._failed(command, exc)
            finally:
                self.ahead.clear()
                if command is not Command.AHEAD:
                    self._done()
                    self.worked_at = time.monotonic()
                    self.working.clear()
                if command is not Command.AHEAD and not self.playing.is_set() and self._idle is not None and not self.commands.pending() and self._idle():
                    self.commands.put(Command.AHEAD)  # before task_done: wait_idle waits for it too
                elif not self.commands.pending() and (not self.playing.is_set() or time.monotonic() - self._trimmed_at > TRIM_PERIOD_PLAYING_S):
                    release_free_memory()  # what the commands freed, back to the system (backend/common/allocator.py)
                    self._trimmed_at = time.monotonic()
                if not from_timer:
                    self.commands.task_done()
