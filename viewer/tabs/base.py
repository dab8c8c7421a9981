"""What every tab is and what it is given."""

from __future__ import annotations

import dataclasses
from typing import Protocol

import numpy as np
import viser

from backend.optim.variant import Variant
from backend.pipeline.snapshot import Snapshot
from viewer.commands import Command
from viewer.settings import ViewerSettings


@dataclasses.dataclass(frozen=True)
class Shown:
    """What a tab shows: the snapshot on screen, the variants kept at its keyframe, the A/B
    run's B at the same keyframe (None: none, or the A/B run is off: `ab_on`), the
    input's name, and the newest keyframe stepped (the snapshot's own where none is kept)."""

    snapshot: Snapshot
    variants: dict[Variant, Snapshot]
    other: Snapshot | None
    ab_on: bool
    source: str
    newest_keyframe: int


class TabActions(Protocol):
    """What a tab's own controls may ask of the debugger."""

    def enqueue(self, command: Command, arg: object = None) -> None:
        """Queue a command for the engine's worker (as a browser's click)."""

    def request_plots(self) -> None:
        """Draw the plots of what is shown (in the background)."""


class Tab(Protocol):
    """A tab of the side panel (viewer/tabs/__init__.py), made as `Tab(actions, settings)`."""

    title: str
    icon: viser.IconName

    def __init__(self, actions: TabActions, settings: ViewerSettings) -> None: ...

    def build(self, gui: viser.GuiApi) -> None:
        """Add the tab's controls (inside its tab of the side panel)."""

    def show(self, shown: Shown) -> None:
        """Show a snapshot (called inside the server's atomic update)."""

    def clear(self) -> None:
        """Back to the state before the first keyframe (Reset)."""


def open_large_view(client: viser.ClientHandle, pictures: list[tuple[str, np.ndarray]], *, image_format: str) -> None:
    """A floating window, for the clicking tab only, with `pictures` (label, image) at their
    full size; its Close button removes it."""
    panel = client.gui.add_panel()
    with panel.add_tab("Large view", viser.Icon.ZOOM_IN):
        for label, picture in pictures:
            if image_format == "png":
                client.gui.add_image(picture, label=label, format="png")
            else:
                client.gui.add_image(picture, label=label, format="jpeg", jpeg_quality=95)
        close = client.gui.add_button("Close")
    close.on_click(lambda _: panel.remove())
    width = max(int(np.asarray(pictures[0][1]).shape[1]), 600)
    panel.float(x=20, y=20, width=width + 40)
