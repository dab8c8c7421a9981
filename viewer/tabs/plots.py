"""The Plots tab: costs, iterations, errors and events over the kept keyframes (drawn in
the background by the debugger's plot thread)."""

from __future__ import annotations

import viser

from viewer import images
from viewer.settings import ViewerSettings
from viewer.tabs.base import Shown, TabActions


class PlotsTab:
    title = "Plots"
    icon = viser.Icon.CHART_LINE

    def __init__(self, actions: TabActions, settings: ViewerSettings) -> None:
        self.actions = actions
        self._plots_initially = settings.plots

    def build(self, gui: viser.GuiApi) -> None:
        self.box = gui.add_checkbox("Update plots", initial_value=self._plots_initially)
        self.image = gui.add_image(images.blank(), label="over the kept keyframes (red line: shown)", format="png")
        self.box.on_update(lambda _: self.actions.request_plots())

    def show(self, shown: Shown) -> None:
        pass  # the plot thread draws them once updates pause (Debugger._plot_loop)

    def clear(self) -> None:
        self.image.image = images.blank()
