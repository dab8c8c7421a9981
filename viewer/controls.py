"""The debugger's control panel, docked on the right: the status line, Run (variant,
segmenter, Step, Play, rate, Reset, the keyframe slider), A/B run, View, Layers and Export,
and the keyboard shortcuts. Like the side panel's tabs (viewer/tabs) it owns its controls
and turns their events into the debugger's commands and actions (`ControlActions`); the
debugger writes what it shows into them."""

from __future__ import annotations

from collections.abc import Callable
from typing import Protocol, runtime_checkable

import numpy as np
import viser

from backend.data.source import RenderedTruth, StereoSource
from backend.frontend.segmentation import PlaneSegmenter
from backend.frontend.segmenters import SegmenterKind, segmenter_kind
from backend.optim.variant import VARIANT_NAMES, Variant
from backend.pipeline.engine import Engine
from backend.pipeline.snapshot import Snapshot
from viewer.commands import Command, FromClient
from viewer.dense import DenseLayer
from viewer.displacement_layer import DISPLACEMENT_OFF, DisplacementLayer
from viewer.history import SnapshotHistory
from viewer.page_choice import PageChoice, set_value
from viewer.scene import SceneView
from viewer.settings import ViewerSettings
from viewer.status import StatusLine

AB_OFF = "off"
# The Segmenter menu: the oracle of rendered scenes reads the renderer's plane ids, and says so.
SEGMENTER_LABELS: dict[SegmenterKind, str] = {
    SegmenterKind.GEOMETRIC: "geometric",
    SegmenterKind.LEARNED: "learned",
    SegmenterKind.ORACLE: "oracle (ground truth)",
}
SHORTCUTS = "**keys**: space play/pause · → step · shift+← / shift+→ scrub · F frame all"
LAYERS = (
    ("cameras", "Cameras"),
    ("points", "Points"),
    ("lines", "Lines"),
    ("planes", "Planes"),
    ("infinite_planes", "Infinite planes"),
    ("inliers", "RANSAC in/out"),
    ("ground_truth", "Ground truth"),
    ("ab", "A/B run (B)"),
)


@runtime_checkable
class Segmented(Protocol):
    """An engine whose plane instances come from a segmenter that can be switched (the image
    pipelines: stereo disparity, the network or, on rendered scenes, the truth)."""

    segmenter: PlaneSegmenter


class ControlActions(Protocol):
    """What the control panel asks of the debugger."""

    @property
    def history(self) -> SnapshotHistory:
        """The kept snapshots."""

    @property
    def shown(self) -> Snapshot | None:
        """The snapshot on screen."""

    def enqueue(self, command: Command, arg: object = None) -> None:
        """Queue a command for the engine's worker (as a browser's click)."""

    def on_play(self, playing: bool) -> None:
        """The Play box was ticked or cleared."""

    def frame(self, client: viser.ClientHandle | None, *, keep_direction: bool) -> None:
        """Frame the shown map in `client`'s view."""

    def export(self, client: viser.ClientHandle | None, what: str) -> None:
        """Send `what` of the shown snapshot to `client` (viewer/exports.py)."""


class ControlPanel:
    """The panel's controls, built in their folders when it is made; :meth:`connect` wires
    them and adds the shortcuts (once the debugger has built its side panel)."""

    def __init__(self, actions: ControlActions, server: viser.ViserServer, engine: Engine, scene: SceneView, settings: ViewerSettings) -> None:
        self.actions = actions
        self.server = server
        self.scene = scene
        gui = server.gui
        gui.main_panel.dock_right()
        self.status = gui.add_markdown(f"**{engine.source}**: ready, press Step or Play")
        with gui.add_folder("Run"):
            self.variant = gui.add_dropdown("Variant", VARIANT_NAMES, initial_value=str(engine.variant))
            self.variant_choice = PageChoice(self.variant)  # the variant shown, or a page's choice not yet read
            self.segmenter: viser.GuiDropdownHandle[str] | None = None
            if isinstance(engine, Segmented):  # image pipelines: plane instances from stereo, the network or (rendered) the truth
                kinds = [SegmenterKind.GEOMETRIC, SegmenterKind.LEARNED]
                if isinstance(getattr(engine, "data_source", None), RenderedTruth):
                    kinds.append(SegmenterKind.ORACLE)
                current = SEGMENTER_LABELS[segmenter_kind(engine.segmenter)]
                self.segmenter = gui.add_dropdown("Segmenter", tuple(SEGMENTER_LABELS[k] for k in kinds), initial_value=current)
            self.step_button = gui.add_button("Step")
            self.play = gui.add_checkbox("Play", initial_value=False)
            self.rate = gui.add_slider("Rate (Hz)", min=0.5, max=30.0, step=0.5, initial_value=settings.rate_hz)
            self.achieved = gui.add_text("Achieved", initial_value="–", disabled=True)
            self.reset_button = gui.add_button("Reset")
            self.slider = gui.add_slider("Keyframe", min=0, max=1, step=1, initial_value=0, disabled=True)
            self.slider_choice = PageChoice(self.slider)  # the keyframe shown, or where a page scrubbed to, not yet read
            self.keyframe_label = gui.add_text("Shown", initial_value="none", disabled=True)
            # Last in the folder, so that showing it moves nothing a user clicks.
            self.progress = gui.add_progress_bar(100.0, animated=True, visible=False)
        self.status_line = StatusLine(self.status, self.progress)
        with gui.add_folder("A/B run"):
            self.ab_variant = gui.add_dropdown("B variant", (AB_OFF, *VARIANT_NAMES), initial_value=AB_OFF)
            self.ab_note = gui.add_markdown(
                "A second engine runs the same input in lockstep from the state shown when B is chosen; its "
                "trajectory and newest camera are drawn in aquamarine, labelled B, the differences are in the *Variants* tab."
            )
        with gui.add_folder("View"):
            self.follow = gui.add_checkbox("Follow keyframe", initial_value=False)
            self.frame_button = gui.add_button("Frame all")
            self.reset_view_button = gui.add_button("Default view")
            self.point_scale = gui.add_slider("Point size", min=0.25, max=4.0, step=0.25, initial_value=1.0)
        with gui.add_folder("Layers"):
            self.layer_boxes = {name: gui.add_checkbox(label, initial_value=getattr(scene.layers, name)) for name, label in LAYERS}
            self.layer_note = gui.add_markdown("")
            # The shown map coloured by how far each landmark lies from itself in another
            # snapshot of the keyframe (viewer/displacement_layer.py).
            self.displacement_to = gui.add_dropdown("Displacement", (DISPLACEMENT_OFF,), initial_value=DISPLACEMENT_OFF, hint="colour the map by how far each landmark moved to another variant (or B)")
            self.displacement = DisplacementLayer(self.displacement_to, gui.add_markdown(""))
            self.dense: DenseLayer | None = None
            self.dense_box: viser.GuiCheckboxHandle | None = None
            source = getattr(engine, "data_source", None)
            if isinstance(source, StereoSource):  # image pipelines: depth to fuse
                self.dense_box = gui.add_checkbox("Dense mesh", initial_value=False, hint="the keyframes' depth fused into a TSDF at the estimated poses (a mesh)")
                self.dense = DenseLayer(server, source, gui.add_markdown(""))
        with gui.add_folder("Export"):
            self.export_button = gui.add_button("Download map (PLY)")
            self.export_files = gui.add_button("Download map files (zip)", hint="points, lines, planes and cameras, a PLY file each, in one zip")
            self.export_trajectory = gui.add_button("Download trajectory (TUM)")
            self.export_keyframes = gui.add_button("Download keyframe poses (TUM)")
        with gui.add_folder("Record"):
            self.record = gui.add_checkbox("Record", initial_value=False, hint="from now on (and the keyframes kept), every snapshot, variant and comparison, for coplanar serve --replay")
            self.record_note = gui.add_markdown("")
            self.download_recording = gui.add_button("Download recording (zip)", hint="the recording so far, one file: coplanar serve --replay FILE opens it")
        gui.add_markdown(SHORTCUTS)

    def connect(self) -> None:
        """What each control does; then the keyboard shortcuts (viser's command palette binds
        them for every tab)."""
        actions = self.actions
        self.step_button.on_click(lambda _: actions.enqueue(Command.STEP))
        self.reset_button.on_click(lambda _: actions.enqueue(Command.RESET))
        self.variant.on_update(self._variant_chosen)
        if self.segmenter is not None:
            self.segmenter.on_update(self._segmenter_chosen)
        self.ab_variant.on_update(self._ab_chosen)
        self.displacement_to.on_update(self._displacement_chosen)
        self.play.on_update(lambda _: actions.on_play(bool(self.play.value)))
        self.slider.on_update(self._slider_moved)
        for name, box in self.layer_boxes.items():
            box.on_update(self._layer_callback(name, box))
        self.point_scale.on_update(self._point_scale_moved)
        self.frame_button.on_click(lambda event: actions.frame(event.client, keep_direction=True))
        self.reset_view_button.on_click(lambda event: actions.frame(event.client, keep_direction=False))
        self.export_button.on_click(lambda event: actions.export(event.client, "map"))
        dense, dense_box = self.dense, self.dense_box
        if dense is not None and dense_box is not None:
            dense_box.on_update(lambda _: dense.set_enabled(dense_box.value, actions.shown))
        self.export_files.on_click(lambda event: actions.export(event.client, "files"))
        self.export_trajectory.on_click(lambda event: actions.export(event.client, "trajectory"))
        self.export_keyframes.on_click(lambda event: actions.export(event.client, "keyframes"))
        self.record.on_update(self._record_toggled)
        self.download_recording.on_click(lambda event: actions.export(event.client, "recording"))

        gui = self.server.gui
        gui.add_command("Play / pause", hotkey="space").on_trigger(lambda _: set_value(self.play, not self.play.value))
        gui.add_command("Step", hotkey="arrowright").on_trigger(lambda _: actions.enqueue(Command.STEP))
        gui.add_command("Scrub back", hotkey="arrowleft", modifier="shift").on_trigger(lambda _: self.scrub(-1))
        gui.add_command("Scrub forward", hotkey="arrowright", modifier="shift").on_trigger(lambda _: self.scrub(+1))
        gui.add_command("Frame all", hotkey="F").on_trigger(lambda event: actions.frame(event.client, keep_direction=True))

    def scrub(self, delta: int) -> None:
        """Show the keyframe `delta` after (or before) the slider's; stops playing."""
        if not self.actions.history or self.slider.disabled:
            return
        if self.play.value:
            set_value(self.play, False)
        value = int(np.clip(int(self.slider.value) + delta, self.slider.min, self.slider.max))
        self.slider_choice.set(value)
        self.actions.enqueue(Command.SHOW, value)

    def show_variant(self, variant: Variant | str) -> None:
        """Put `variant` in the Variant menu (the variant shown), unless a page has just chosen
        another that its callback has not read yet (viewer/page_choice.py: a keyframe shown
        meanwhile, another tab playing, would otherwise lose the choice)."""
        self.variant_choice.show(str(variant))

    def show_keyframe(self, keyframe: int) -> None:
        """Move the Keyframe slider to `keyframe` (the newest, stepped or re-optimized), unless
        a page has just scrubbed it and its callback has not read where to (a keyframe
        stepped meanwhile, with Play on, would otherwise take the user back to the newest)."""
        self.slider_choice.show(int(keyframe))

    def _variant_chosen(self, event: viser.GuiEvent) -> None:
        if event.client is not None:
            chosen = self.variant_choice.take()
            self.actions.enqueue(Command.VARIANT, FromClient(Variant.parse(chosen), event.client))

    def _segmenter_chosen(self, event: viser.GuiEvent) -> None:
        if event.client is not None and self.segmenter is not None:
            kind = next(k for k, label in SEGMENTER_LABELS.items() if label == self.segmenter.value)
            self.actions.enqueue(Command.SEGMENTER, kind)

    def _ab_chosen(self, event: viser.GuiEvent) -> None:
        if event.client is not None:
            self.actions.enqueue(Command.AB, self.ab_variant.value)

    def _record_toggled(self, event: viser.GuiEvent) -> None:
        if event.client is not None:
            self.actions.enqueue(Command.RECORD, bool(self.record.value))

    def _displacement_chosen(self, event: viser.GuiEvent) -> None:
        shown = self.actions.shown
        if event.client is not None and shown is not None:  # the shown snapshot drawn again, coloured by the choice
            self.actions.enqueue(Command.SHOW, shown.keyframe)

    def _slider_moved(self, event: viser.GuiEvent) -> None:
        if event.client is not None:  # a user scrubs: stop playing, or the next step jumps back
            if self.play.value:
                set_value(self.play, False)
            self.actions.enqueue(Command.SHOW, int(self.slider_choice.take()))

    def _layer_callback(self, name: str, box: viser.GuiCheckboxHandle) -> Callable[[viser.GuiEvent], None]:
        def callback(_: viser.GuiEvent) -> None:
            with self.server.atomic():
                self.scene.set_layer(name, bool(box.value))

        return callback

    def _point_scale_moved(self, _: viser.GuiEvent) -> None:
        with self.server.atomic():
            self.scene.set_point_scale(float(self.point_scale.value))
