"""viewer/worker.py: the engine's thread gives freed memory back once the user's commands
and the step ahead are done, and while playing no more often than every few seconds."""

from __future__ import annotations

import time

import pytest

from viewer import worker as worker_module
from viewer.commands import Command
from viewer.worker import Worker


@pytest.fixture
def trims(monkeypatch: pytest.MonkeyPatch) -> list[float]:
    calls: list[float] = []
    monkeypatch.setattr(worker_module, "release_free_memory", lambda: calls.append(time.monotonic()) or True)
    return calls


def _worker(ran: list[Command], *, idle: bool, period_s: float = 10.0) -> Worker:
    w = Worker(lambda command, arg: ran.append(command), period=lambda: period_s, failed=lambda c, e: None, done=lambda: None, idle=lambda: idle)
    w.start()
    return w


def test_trims_after_the_step_ahead_not_before(trims: list[float]) -> None:
    ran: list[Command] = []
    w = _worker(ran, idle=True)
    try:
        w.put(Command.STEP)
        w.wait_idle(timeout=10)
        assert ran == [Command.STEP, Command.AHEAD]
        assert len(trims) == 1  # once, when the step ahead had run too
        w.put(Command.SHOW)
        w.wait_idle(timeout=10)
        assert len(trims) == 2
    finally:
        w.stop()


def test_trims_at_most_every_few_seconds_while_playing(trims: list[float], monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(worker_module, "TRIM_PERIOD_PLAYING_S", 0.3)
    ran: list[Command] = []
    w = _worker(ran, idle=False, period_s=0.01)  # a step every 10 ms while playing
    try:
        w.playing.set()
        w.put(Command.WAKE)
        time.sleep(1.0)
        w.playing.clear()
        steps = ran.count(Command.STEP)
    finally:
        w.stop()
    assert steps > 20
    assert 2 <= len(trims) <= 5  # about one per 0.3 s, not one per step


def test_the_step_ahead_is_flagged_while_it_runs_and_only_it() -> None:
    """`ahead` is set while the worker computes the step ahead (the plot thread waits for it)
    and clear while it runs the user's commands and after."""
    seen: list[tuple[Command, bool, bool]] = []
    w: Worker | None = None

    def execute(command: Command, arg: object) -> None:
        assert w is not None
        seen.append((command, w.ahead.is_set(), w.working.is_set()))

    w = Worker(execute, period=lambda: 10.0, failed=lambda c, e: None, done=lambda: None, idle=lambda: True)
    w.start()
    try:
        w.put(Command.STEP)
        w.wait_idle(timeout=10)
        assert seen == [(Command.STEP, False, True), (Command.AHEAD, True, False)]
        assert not w.ahead.is_set()
    finally:
        w.stop()
