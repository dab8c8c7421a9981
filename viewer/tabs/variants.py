"""The Variants tab: every variant kept at the shown keyframe side by side, computing all
six there, and the A/B run's differences."""

from __future__ import annotations

import viser

from viewer import panels
from viewer.commands import Command
from viewer.settings import ViewerSettings
from viewer.tabs.base import Shown, TabActions


class VariantsTab:
    title = "Variants"
    icon = viser.Icon.ARROWS_DIFF

    def __init__(self, actions: TabActions, settings: ViewerSettings) -> None:
        self.actions = actions

    def build(self, gui: viser.GuiApi) -> None:
        self.all_button = gui.add_button("Compute all six at the newest keyframe")
        self.text = gui.add_markdown("no keyframe yet")
        self.ab_text = gui.add_markdown("")
        self.all_button.on_click(lambda _: self.actions.enqueue(Command.ALL_VARIANTS))

    def show(self, shown: Shown) -> None:
        self.text.content = panels.variants_markdown(shown.variants, shown=shown.snapshot, newest_keyframe=shown.newest_keyframe)
        self.ab_text.content = panels.ab_markdown(shown.snapshot, shown.other) if shown.ab_on else ""

    def clear(self) -> None:
        self.text.content = "no keyframe yet"  # the A/B note stays: it says why the run stopped

    def note_ab(self, text: str) -> None:
        """Say why the A/B run stopped (or that it is off)."""
        self.ab_text.content = text
