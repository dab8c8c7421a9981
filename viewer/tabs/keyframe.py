"""The Keyframe tab: the keyframe's left image with its features and plane instances, and
what tracking did since the last keyframe."""

from __future__ import annotations

import viser

from backend.pipeline.snapshot import KeyframeImage
from viewer import images
from viewer.settings import ViewerSettings
from viewer.tabs.base import Shown, TabActions, open_large_view


class KeyframeTab:
    title = "Keyframe"
    icon = viser.Icon.PHOTO

    def __init__(self, actions: TabActions, settings: ViewerSettings) -> None:
        self.actions = actions
        self._shown_image: KeyframeImage | None = None  # decoded only to show it large

    def build(self, gui: viser.GuiApi) -> None:
        self.image = gui.add_image(images.blank(), label="left image", format="jpeg", jpeg_quality=90, visible=False)
        self.tracking_text = gui.add_markdown("no keyframe yet")
        self.legend = gui.add_markdown(images.KEYFRAME_LEGEND, visible=False)
        self.enlarge_button = gui.add_button("Open the image large")
        self.enlarge_button.on_click(lambda event: self.enlarge(event.client))

    def show(self, shown: Shown) -> None:
        snapshot = shown.snapshot
        self._shown_image = snapshot.image
        if snapshot.image is not None:
            images.set_encoded(self.image, snapshot.image.jpeg, image_format="jpeg")  # the snapshot's JPEG as it is, encoded once
            self.image.label = f"keyframe {snapshot.keyframe}: left image"
            self.tracking_text.content = images.tracking_markdown(snapshot.tracking)
        else:
            self.tracking_text.content = f"*{shown.source}: no image for this keyframe*"
        if self.image.visible != (snapshot.image is not None):
            self.image.visible = self.legend.visible = snapshot.image is not None

    def clear(self) -> None:
        self._shown_image = None
        self.image.image = images.blank()
        self.image.visible = self.legend.visible = False
        self.tracking_text.content = "no keyframe yet"

    def enlarge(self, client: viser.ClientHandle | None) -> None:
        """The image at its full size in a floating window of the clicking tab."""
        if client is None:
            return
        if self._shown_image is None:
            client.add_notification("No keyframe image", "This engine's snapshots have no image.", auto_close_seconds=5.0)
            return
        open_large_view(client, [(self.image.label or "keyframe image", images.keyframe_image(self._shown_image))], image_format="jpeg")
