"""The debugger's status line and progress bar: what the worker is doing, shown only when
it takes long enough to notice (a quick step should not repaint the panel twice)."""

from __future__ import annotations

import threading
from typing import Protocol

import viser

PROGRESS_DELAY_S = 0.3


class ProgressBar(Protocol):
    """What the status line does with its progress bar (viser does not export the type of
    `add_progress_bar`'s handle)."""

    visible: bool


class StatusLine:
    """The status markdown and the progress bar under the run controls. `busy` is set while
    the worker works (for tests and benchmarks)."""

    def __init__(self, markdown: viser.GuiMarkdownHandle, progress: ProgressBar) -> None:
        self.markdown = markdown
        self.progress = progress
        self.busy = threading.Event()
        self._lock = threading.Lock()
        self._token: object | None = None
        self.timer: threading.Timer | None = None

    def set(self, text: str) -> None:
        """Write the status line; a pending progress message can no longer overwrite it."""
        with self._lock:
            self._token = None
            self.markdown.content = text

    def working(self, text: str) -> None:
        """Mark the worker busy; `text` and the progress bar appear only if the work takes
        longer than PROGRESS_DELAY_S."""
        self.busy.set()
        token = object()
        with self._lock:
            self._token = token

        def show() -> None:
            with self._lock:
                if self._token is token:
                    self.markdown.content = text
                    self.progress.visible = True

        self.timer = threading.Timer(PROGRESS_DELAY_S, show)
        self.timer.daemon = True
        self.timer.start()

    def done(self) -> None:
        """The worker is idle again: no late progress message, no progress bar."""
        self.busy.clear()
        with self._lock:
            self._token = None
        if self.timer is not None:
            self.timer.cancel()
            self.timer = None
        if self.progress.visible:
            self.progress.visible = False
