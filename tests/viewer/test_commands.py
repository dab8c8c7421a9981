"""The debugger's command queue (viewer/commands.py): bursts from the browser coalesce,
programs' commands all run."""

from __future__ import annotations

import queue
import threading

import pytest

from viewer.commands import Command, CommandQueue


def _drain(q: CommandQueue) -> list[tuple[Command, object]]:
    out = []
    while True:
        try:
            out.append(q.get(timeout=0))
        except queue.Empty:
            return out
        q.task_done()


def test_a_burst_of_steps_is_one_waiting_step() -> None:
    q = CommandQueue()
    for _ in range(200):
        q.put("step", coalesce=True)
    assert q.pending() == [(Command.STEP, None)] and q.unfinished == 1


def test_a_newer_show_or_variant_replaces_the_waiting_one_at_the_end() -> None:
    q = CommandQueue()
    q.put(Command.SHOW, 3, coalesce=True)
    q.put(Command.STEP, coalesce=True)
    q.put(Command.VARIANT, "P-r", coalesce=True)
    q.put(Command.SHOW, 5, coalesce=True)
    q.put(Command.VARIANT, "P-w", coalesce=True)
    assert q.pending() == [(Command.STEP, None), (Command.SHOW, 5), (Command.VARIANT, "P-w")]


def test_reset_drops_what_it_undoes_and_keeps_the_rest() -> None:
    q = CommandQueue()
    q.put(Command.STEP, coalesce=True)
    q.put(Command.SEGMENTER, "learned", coalesce=True)
    q.put(Command.SHOW, 2, coalesce=True)
    q.put(Command.AB, "P-r", coalesce=True)
    q.put(Command.RESET, coalesce=True)
    q.put(Command.STEP, coalesce=True)  # a Step after Reset runs after it
    assert q.pending() == [(Command.SEGMENTER, "learned"), (Command.RESET, None), (Command.STEP, None)]
    assert q.unfinished == 3
    assert [c for c, _ in _drain(q)] == [Command.SEGMENTER, Command.RESET, Command.STEP]
    assert q.wait_done(timeout=0)


def test_submitted_commands_all_run_in_order() -> None:
    q = CommandQueue()
    for k in range(3):
        q.put("step")
        q.put("show", k)
    q.put("reset")
    assert [c for c, _ in q.pending()] == [Command.STEP, Command.SHOW] * 3 + [Command.RESET]


def test_get_waits_and_times_out() -> None:
    q = CommandQueue()
    with pytest.raises(queue.Empty):
        q.get(timeout=0.05)
    threading.Timer(0.05, lambda: q.put(Command.WAKE)).start()
    assert q.get(timeout=5) == (Command.WAKE, None)
    assert not q.wait_done(timeout=0.01)  # taken, not yet done
    q.task_done()
    assert q.wait_done(timeout=0)


def test_unknown_commands_are_errors() -> None:
    with pytest.raises(ValueError):
        CommandQueue().put("jump")
