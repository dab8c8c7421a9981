"""The Hessian tab: the window's H = JᵀJ pattern, and the shown keyframe's window, as its
step left it, under the three plane modes of the shown variant's features (-wo | -r | -w)."""

from __future__ import annotations

from collections.abc import Callable, Mapping

import viser

from backend.optim.structure import HessianStructure
from backend.optim.variant import Variant
from backend.pipeline.snapshot import Snapshot
from viewer import images
from viewer.commands import Command
from viewer.settings import ViewerSettings
from viewer.tabs.base import Shown, TabActions, open_large_view

COMPARES_KEPT = 64


class HessianTab:
    title = "Hessian"
    icon = viser.Icon.GRID_DOTS

    def __init__(self, actions: TabActions, settings: ViewerSettings) -> None:
        self.actions = actions
        self._compare_initially = settings.compare
        self._encoded = images.EncodedHessians()
        self._shown_structure: HessianStructure | None = None  # rendered again only to show it large
        # (keyframe, with lines) -> the comparison image, PNG: computed once, from the step's
        # state; the newest COMPARES_KEPT of the keyframes the history keeps (the pixels are
        # ~0.5 MB, the PNG a few tens of kB: sent as it is, decoded only to show it large)
        self._compares: dict[tuple[int, bool], bytes] = {}
        self._compare_shown: bytes | None = None

    def build(self, gui: viser.GuiApi) -> None:
        self.legend = gui.add_markdown("no window optimized yet")
        self.image = gui.add_image(images.blank(), label="H = J^T J of the window", format="png")
        self.compare_box = gui.add_checkbox("Compare modes", initial_value=self._compare_initially, hint="Compare: this keyframe's window, as its step left it, under -wo | -r | -w")
        self.compare_note = gui.add_markdown("")
        self.compare_image = gui.add_image(images.blank(), label="this keyframe's window under -wo | -r | -w", format="png")
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
        self._compares = {}
        self.image.image = images.blank()
        self.legend.content = "no window optimized yet"
        self._show_compare(None)
        self.compare_note.content = ""

    def update_compare(
        self, shown: Snapshot | None, *, newest: int | None, first_kept: int, compute: Callable[[tuple[Variant, ...]], Mapping[Variant, HessianStructure]], replay: bool = False
    ) -> None:
        """The comparison for the keyframe `shown` is at (on the engine's thread): its
        window as the step left it under the three plane modes of the shown variant's
        features, kept per keyframe, so that it does not change with the variant chosen
        there; computed (`compute`) only at the `newest` keyframe, where the engine's state
        is. Kept for the newest COMPARES_KEPT keyframes from `first_kept` (the history's
        oldest) on. `replay`: the comparisons come from a recording, which may lack some."""
        on = bool(self.compare_box.value)
        self.compare_image.visible = on
        if not on or shown is None:
            self.compare_note.content = ""
            return
        key = (shown.keyframe, shown.variant.with_lines)
        image = self._compares.get(key)
        if image is None and shown.keyframe == newest:
            structures = compute(shown.variant.family())
            if structures:
                image = self._compares[key] = images.compare_png(structures)
        kept = sorted(k for k in self._compares if k[0] >= first_kept)[-COMPARES_KEPT:]
        self._compares = {k: self._compares[k] for k in kept}
        self._show_compare(image)
        if image is None and replay:
            self.compare_note.content = f"*not in the recording for keyframe {shown.keyframe} ({'PL' if shown.variant.with_lines else 'P'}): it was kept before Record was ticked, or not made*"
        elif image is None:
            self.compare_note.content = (
                f"*not kept for keyframe {shown.keyframe}: the comparison is made at the newest keyframe, from the state its step left, "
                f"while this box is on, and kept for the last {COMPARES_KEPT} keyframes*"
            )
        else:
            self.compare_note.content = f"keyframe {shown.keyframe}'s window as its step left it, under each plane mode of {'PL' if shown.variant.with_lines else 'P'}"

    def _show_compare(self, png: bytes | None) -> None:
        """The comparison image sent as it was encoded (None: blank)."""
        if png is None:
            self.compare_image.image = images.blank()
        elif png is not self._compare_shown:
            images.set_encoded(self.compare_image, png, image_format="png")
        self._compare_shown = png

    def enlarge(self, client: viser.ClientHandle | None) -> None:
        """Open the shown window's Hessian large for `client` (viewer/tabs/base.py
        open_large_view): at images.LARGE_PX with its groups' boundaries labelled and the
        colour key, a *Zoom on* dropdown to show a group or a pair of groups alone, the
        legend table, and the comparison."""
        if client is None:
            return
        structure = self._shown_structure
        if structure is None:
            open_large_view(client, [("no window optimized yet", images.blank())], image_format="png")
            return
        choices = images.zoom_choices(structure)
        zoom: list[viser.GuiDropdownHandle] = []

        def controls(gui: viser.GuiApi) -> None:
            gui.add_markdown(images.legend_markdown(structure))
            zoom.append(gui.add_dropdown("Zoom on", tuple(choices), initial_value="whole window", hint="Show a group's block alone, or two groups with their coupling blocks"))

        window = images.large_hessian_image(structure)
        compare = images.blank() if self._compare_shown is None else images.decode_png(self._compare_shown)
        shown = open_large_view(client, [(LARGE_LABEL, window), ("this keyframe's window under -wo | -r | -w", compare)], image_format="png", controls=controls)
        zoom[0].on_update(lambda _: setattr(shown[0], "image", images.large_hessian_image(structure, kinds=choices[str(zoom[0].value)])))


LARGE_LABEL = "H = JᵀJ of the window: group boundaries labelled with their parameter indices"
