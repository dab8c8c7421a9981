"""A control that both the server and the pages write: the server puts in it what is shown,
a page puts in it what its user chose.

viser applies a page's new value to the control's handle as soon as the message arrives and
runs the control's callback later, on its thread pool; the callback reads the value there.
Anything the server writes in between (a keyframe shown because another tab plays, or
because Play is on) replaces the user's value before the callback has read it, and the
callback then acts on the server's value: the choice is lost. :class:`PageChoice` keeps a
page's value until its callback has read it (:meth:`take`); a value left unread for
`unread_s` (its page closed before viser ran the callback) no longer holds the control.
"""

from __future__ import annotations

import time
from typing import Generic, TypeVar

import viser

T = TypeVar("T")
UNREAD_CHOICE_S = 2.0  # how long a page's value waits for its callback


def set_value(handle: viser.GuiInputHandle[T], value: T) -> None:
    """`handle.value = value`, with the value's type checked: viser defines the setter of
    `value` apart from its getter (a method lies between them), so mypy takes the property
    for read-only."""
    handle.value = value  # type: ignore[misc]  # viser's setter, which mypy does not see (above)


class PageChoice(Generic[T]):
    """The server's and the pages' writes of one control (module docstring)."""

    def __init__(self, handle: viser.GuiInputHandle[T], *, unread_s: float = UNREAD_CHOICE_S) -> None:
        self.handle = handle
        self.unread_s = unread_s
        self._written: T = handle.value  # what the server last put in it, or the page's value its callback read

    def pending(self) -> bool:
        """Whether a page's value is in the control, not yet read by its callback (and not
        older than `unread_s`)."""
        return self.handle.value != self._written and time.time() - self.handle.update_timestamp < self.unread_s

    def show(self, value: T) -> None:
        """Put `value` in the control (what the server shows), unless a page's value waits
        for its callback."""
        if self.pending():
            return
        self.set(value)

    def set(self, value: T) -> None:
        """Put `value` in the control whatever a page chose (Reset; the server's own scrub)."""
        if self.handle.value != value:
            set_value(self.handle, value)
        self._written = value

    def take(self) -> T:
        """The control's value, read by the callback of a page's change: from now on the
        server may write the control again."""
        value = self.handle.value
        self._written = value
        return value
