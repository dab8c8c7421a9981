"""The Report tab: the shown keyframe's solve, tracking, planes and accuracy as text."""

from __future__ import annotations

import viser

from viewer import panels
from viewer.settings import ViewerSettings
from viewer.tabs.base import Shown, TabActions


class ReportTab:
    title = "Report"
    icon = viser.Icon.FILE_DESCRIPTION

    def __init__(self, actions: TabActions, settings: ViewerSettings) -> None:
        self.actions = actions

    def build(self, gui: viser.GuiApi) -> None:
        self.markdown = gui.add_markdown("")

    def show(self, shown: Shown) -> None:
        self.markdown.content = panels.report_markdown(shown.snapshot)

    def clear(self) -> None:
        self.markdown.content = ""
