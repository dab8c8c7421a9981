"""The Hessian tab: the window's H = JᵀJ pattern, and the newest window under the three
plane modes of the shown variant's features (-wo | -r | -w)."""

from __future__ import annotations

import viser

from backend.optim.structure import HessianStructure
from backend.pipeline.engine import Engine
from viewer import images
from viewer.commands import Command
from viewer.settings import ViewerSettings
from viewer.tabs.base import Shown, TabActions, open_large_view


class HessianTab:
    title = "Hessian"
    icon = viser.Icon.GRID_DOTS

    def __init__(self, actions: TabActions, settings: ViewerSettings) -> None:
        self.actions = actions
        self._compare_initially = settings.compare
        self._encoded = images.EncodedHessians()
        self._shown_structure: HessianStructure | None = None  # rendered again only to show it large

    def build(self, gui: viser.GuiApi) -> None:
        self.legend = gui.add_markdown("no window optimized yet")
        self.image = gui.add_image(images.blank(), label="H = J^T J of the window", format="png")
        self.compare_box = gui.add_checkbox("Compare -wo | -r | -w", initial_value=self._compare_initially)
        self.compare_image = gui.add_image(images.blank(), label="newest window under -wo | -r | -w", format="png")
        self.enlarge_button = gui.add_button("Open the Hessians large")
        self.compare_box.on_update(lambda _: self.actions.enqueue(Command.COMPARE))
        self.enlarge_button.on_click(lambda event: self.enlarge(event.client))

    def show(self, shown: Shown) -> None:
        if shown.snapshot.hessian is not None:
            self._shown_structure = shown.snapshot.hessian
            images.set_encoded(self.image, self._encoded.png(shown.snapshot.hessian), image_format="png")
            self.legend.content = images.legend_markdown(shown.snapshot.hessian)

    def clear(self) -> None:
        self._shown_structure = None
        self.image.image = images.blank()
        self.legend.content = "no window optimized yet"
        self.compare_image.image = images.blank()

    def update_compare(self, engine: Engine, *, has_keyframes: bool) -> None:
        """The comparison of the engine's newest window (on the engine's thread)."""
        self.compare_image.visible = bool(self.compare_box.value)
        if not self.compare_box.value or not has_keyframes:
            return
        structures = engine.compare_hessians(engine.variant.family())
        if structures:
            self.compare_image.image = images.compare_image(structures)

    def enlarge(self, client: viser.ClientHandle | None) -> None:
        if client is None:
            return
        window = images.hessian_image(self._shown_structure) if self._shown_structure is not None else images.blank()
        open_large_view(client, [("H = JᵀJ of the window", window), ("the newest window under -wo | -r | -w", self.compare_image.image)], image_format="png")
