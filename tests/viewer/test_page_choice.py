"""The guard of a control that the server and the pages both write (viewer/page_choice.py),
on a stand-in handle: viser's handles hold `value` and `update_timestamp` the same way."""

from __future__ import annotations

import time
from dataclasses import dataclass

from viewer.page_choice import UNREAD_CHOICE_S, PageChoice


@dataclass
class _Handle:
    value: int
    update_timestamp: float = 0.0


def _page_writes(handle: _Handle, value: int, *, age_s: float = 0.0) -> None:
    handle.value = value
    handle.update_timestamp = time.time() - age_s


def test_the_server_writes_what_it_shows_when_no_page_chose() -> None:
    handle = _Handle(0)
    choice = PageChoice(handle)  # type: ignore[arg-type]
    choice.show(3)
    assert handle.value == 3 and not choice.pending()


def test_a_page_value_holds_until_its_callback_reads_it() -> None:
    handle = _Handle(3)
    choice = PageChoice(handle)  # type: ignore[arg-type]
    _page_writes(handle, 1)
    assert choice.pending()
    choice.show(4)  # a keyframe shown before the callback ran
    assert handle.value == 1
    assert choice.take() == 1
    choice.show(4)  # read: the server writes again
    assert handle.value == 4


def test_a_value_never_read_stops_holding_the_control() -> None:
    handle = _Handle(3)
    choice = PageChoice(handle)  # type: ignore[arg-type]
    _page_writes(handle, 1, age_s=UNREAD_CHOICE_S + 1.0)
    assert not choice.pending()
    choice.show(4)
    assert handle.value == 4


def test_set_overrides_a_pending_page_value() -> None:
    handle = _Handle(3)
    choice = PageChoice(handle)  # type: ignore[arg-type]
    _page_writes(handle, 1)
    choice.set(0)  # Reset
    assert handle.value == 0 and not choice.pending()
