"""The debugger's command queue: what the engine's worker thread runs next.

Commands from the browser coalesce, so that no burst of clicks or key presses queues work
the user must wait out: a Step (or Compute all, or a wake-up) already waiting makes a new
one redundant; a newer Show, Variant, A/B, Segmenter, Compare or Record replaces a waiting one of the
same kind (moved to the end, so the order of different kinds is kept); a Reset drops what
it would undo anyway (waiting Steps, Shows, Compute all, Compare, A/B). Reset and Pause
therefore act within one step's time, however many Steps were clicked before them.
Commands submitted by a program (`coalesce=False`, tests and benchmarks) run one by one.
"""

from __future__ import annotations

import dataclasses
import enum
import queue
import threading
import time
from typing import Any


class Command(enum.StrEnum):
    """What the worker can be asked to do (the value is the name `Debugger.submit` takes)."""

    STEP = "step"
    RESET = "reset"
    VARIANT = "variant"
    SHOW = "show"
    AB = "ab"
    ALL_VARIANTS = "all_variants"
    COMPARE = "compare"
    SEGMENTER = "segmenter"
    RECORD = "record"
    WAKE = "wake"
    AHEAD = "ahead"  # the worker's own: compute the next step while idle (viewer/session.py)
    STOP = "stop"


@dataclasses.dataclass(frozen=True)
class FromClient:
    """A command's argument with the browser tab that sent it (a `viser.ClientHandle`), so
    that an answer meant for that tab's user, such as a refusal, reaches it even while
    another tab's Play replaces the status line at every step."""

    value: object
    client: Any


def unwrap(arg: Any) -> tuple[Any, Any]:
    """A command's argument and the tab that sent it (None: a program or a shortcut)."""
    return (arg.value, arg.client) if isinstance(arg, FromClient) else (arg, None)


REDUNDANT_WHILE_WAITING = frozenset({Command.STEP, Command.ALL_VARIANTS, Command.WAKE})
LATEST_WINS = frozenset({Command.SHOW, Command.VARIANT, Command.AB, Command.SEGMENTER, Command.COMPARE, Command.RECORD})
UNDONE_BY_RESET = frozenset({Command.STEP, Command.SHOW, Command.ALL_VARIANTS, Command.COMPARE, Command.AB, Command.RESET})


class CommandQueue:
    """A FIFO of (Command, argument) with the coalescing rules above. `get` and `task_done`
    as in queue.Queue; `wait_done` blocks until every command put has been run."""

    def __init__(self) -> None:
        self._items: list[tuple[Command, object]] = []
        self._unfinished = 0
        self._changed = threading.Condition()

    def put(self, command: Command | str, arg: object = None, *, coalesce: bool = False) -> None:
        command = Command(command)
        with self._changed:
            if coalesce and command in REDUNDANT_WHILE_WAITING and any(c is command for c, _ in self._items):
                return
            if coalesce:
                drop = UNDONE_BY_RESET if command is Command.RESET else {command} if command in LATEST_WINS else set()
                kept = [(c, a) for c, a in self._items if c not in drop]
                self._unfinished -= len(self._items) - len(kept)
                self._items = kept
            self._items.append((command, arg))
            self._unfinished += 1
            self._changed.notify_all()

    def get(self, timeout: float | None = None) -> tuple[Command, object]:
        """The next command; queue.Empty after `timeout` seconds (None: wait for one)."""
        deadline = None if timeout is None else time.monotonic() + timeout
        with self._changed:
            while not self._items:
                left = None if deadline is None else deadline - time.monotonic()
                if left is not None and left <= 0:
                    raise queue.Empty
                self._changed.wait(left)
            return self._items.pop(0)

    def task_done(self) -> None:
        with self._changed:
            self._unfinished -= 1
            self._changed.notify_all()

    @property
    def unfinished(self) -> int:
        """Commands put and not yet run to the end."""
        return self._unfinished

    def pending(self) -> list[tuple[Command, object]]:
        """The commands waiting, in order (a copy)."""
        with self._changed:
            return list(self._items)

    def wait_done(self, timeout: float) -> bool:
        """Whether every command put has run, waiting up to `timeout` seconds for it."""
        with self._changed:
            return self._changed.wait_for(lambda: self._unfinished == 0, timeout)
