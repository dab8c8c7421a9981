"""What every tab is and what it is given."""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
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


#: Gap between the large view and the panels docked beside it, in CSS pixels.
LARGE_VIEW_GAP_PX = 12
#: The large view's size where the browser has not said how large its 3D view is (CSS px).
LARGE_VIEW_FALLBACK_PX = (600, 700)
#: A 3D view taller than this in device pixels is taken to be on a high-density display
#: (devicePixelRatio 2, as a Retina laptop's): browser windows are rarely taller than
#: ~1300 CSS px, and a Retina laptop's 3D view is 1600-1900 device px tall.
HIGH_DENSITY_CANVAS_PX = 1350


def large_view_box(client: viser.ClientHandle) -> tuple[int, int]:
    """Width and height (CSS pixels) of a floating window that fills the client's 3D view,
    the area between the docked side panel and the control panel, less a gap all round:
    it covers neither panel, nor the status line at the top of the controls.

    The browser reports its 3D view in device pixels (viser's camera message: the WebGL
    canvas), which are CSS pixels times the page's pixel ratio; viser lowers that ratio to
    0.75-0.875 of the display's while rendering is slow, which only makes the window
    smaller. The display's own ratio is not reported: a view taller than
    :data:`HIGH_DENSITY_CANVAS_PX` is read as ratio 2, any other as 1, so on a display
    scaled by 125-150 % the window reaches past the 3D view by that much (drag its edge)."""
    width, height = int(client.camera.image_width), int(client.camera.image_height)
    if width <= 0 or height <= 0:
        return LARGE_VIEW_FALLBACK_PX
    if height > HIGH_DENSITY_CANVAS_PX:
        width, height = width // 2, height // 2
    return max(width - 2 * LARGE_VIEW_GAP_PX, 200), max(height - 2 * LARGE_VIEW_GAP_PX, 200)


def open_large_view(
    client: viser.ClientHandle,
    pictures: list[tuple[str, np.ndarray]],
    *,
    image_format: str,
    controls: Callable[[viser.GuiApi], None] | None = None,
) -> list[viser.GuiImageHandle]:
    """A floating window, for the clicking tab only, over the 3D view (between the side
    panel and the control panel, see :func:`large_view_box`), with `pictures` (label,
    image) as wide as the window allows (each can be enlarged further with the image's
    own expand icon), after the `controls` the caller adds; its Close button removes it.
    Returns the image handles, in the order of `pictures`."""
    panel = client.gui.add_panel()
    shown: list[viser.GuiImageHandle] = []
    with panel.add_tab("Large view", viser.Icon.ZOOM_IN):
        if controls is not None:
            controls(client.gui)
        for label, picture in pictures:
            if image_format == "png":
                shown.append(client.gui.add_image(picture, label=label, format="png"))
            else:
                shown.append(client.gui.add_image(picture, label=label, format="jpeg", jpeg_quality=95))
        close = client.gui.add_button("Close")
    close.on_click(lambda _: panel.remove())
    width, height = large_view_box(client)
    panel.float(x=LARGE_VIEW_GAP_PX, y=LARGE_VIEW_GAP_PX, width=width, height=height)
    return shown
