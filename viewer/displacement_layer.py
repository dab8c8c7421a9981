"""The *Displacement* control of the Layers folder: which snapshot of the shown keyframe the
map is compared with (another variant computed there, or the A/B run's B), and the colour
key with the figures of the comparison (viewer/displacement.py computes them,
viewer/scene.py colours the map)."""

from __future__ import annotations

from collections.abc import Mapping

import viser

from backend.optim.variant import Variant
from backend.pipeline.snapshot import Snapshot
from viewer.displacement import Displacement, summary_markdown

DISPLACEMENT_OFF = "off"
B_OPTION = "B (A/B run)"


def comparable(shown: Snapshot, *, variants: Mapping[Variant, Snapshot], other: Snapshot | None) -> dict[str, Snapshot]:
    """The snapshots of `shown`'s keyframe it can be compared with, by their menu name: the
    other variants computed there (`variants`), and B's (`other`) during an A/B run."""
    options = {str(v): s for v, s in variants.items() if v != shown.variant and s.keyframe == shown.keyframe}
    if other is not None and other.keyframe == shown.keyframe:
        options[B_OPTION] = other
    return options


class DisplacementLayer:
    """The menu (`dropdown`) and its note (`note`, markdown); the debugger asks for the
    snapshot to compare with before drawing (:meth:`target`) and shows the result after
    (:meth:`show`). A choice not available at a keyframe stays chosen (it returns where it
    is), and the note says so."""

    def __init__(self, dropdown: viser.GuiDropdownHandle[str], note: viser.GuiMarkdownHandle) -> None:
        self.dropdown = dropdown
        self.note = note

    def target(self, shown: Snapshot, *, variants: Mapping[Variant, Snapshot], other: Snapshot | None) -> Snapshot | None:
        """The snapshot the map is compared with (None: off, or not available here)."""
        choice = str(self.dropdown.value)
        return None if choice == DISPLACEMENT_OFF else comparable(shown, variants=variants, other=other).get(choice)

    def show(self, shown: Snapshot, *, variants: Mapping[Variant, Snapshot], other: Snapshot | None, displacement: Displacement | None) -> None:
        """The menu's options for `shown`'s keyframe (the choice kept) and the note: the
        colour key and the figures, or why the map is coloured by plane."""
        choice = str(self.dropdown.value)
        options = [DISPLACEMENT_OFF, *comparable(shown, variants=variants, other=other)]
        if choice not in options:
            options.append(choice)
        if tuple(self.dropdown.options) != tuple(options):
            self.dropdown.options = tuple(options)
        self.note.content = self._note(shown, choice=choice, displacement=displacement)

    @staticmethod
    def _note(shown: Snapshot, *, choice: str, displacement: Displacement | None) -> str:
        if choice == DISPLACEMENT_OFF:
            return ""
        if displacement is None:
            return f"*{choice} is not computed at keyframe {shown.keyframe}: the map is coloured by plane.*"
        return summary_markdown(displacement, shown=str(shown.variant), other=choice)
