"""The debugger: a viser server that drives an engine one keyframe at a time.

All engine calls run on one worker thread, fed by a command queue, so GUI callbacks never
block and never race. The GUI and scene are server-wide: every open tab shows the same
state (the camera is each tab's own). Snapshots are kept per keyframe and per variant
(:class:`viewer.history.SnapshotHistory`): the keyframe slider scrubs through them without
touching the engine, and every variant chosen at the newest keyframe re-optimizes that
window from the same engine state (a checkpoint taken after the step), so variants can be
compared at the same keyframe and returning to one shows its kept result.

Layout: the control panel (run, A/B, view, layers, export) is docked on the right; a
second panel docked on the left holds the larger views in tabs (keyframe image, Hessian,
variants at this keyframe, plots over time, report). The 3D view lies between them.
"""

from __future__ import annotations

import collections
import logging
import queue
import threading
import time
import traceback
from collections.abc import Callable
from typing import TypeVar

import numpy as np
import viser

from backend.data.source import RenderedTruth, StereoSource
from backend.frontend.segmenters import SegmenterError, SegmenterKind, make_segmenter, segmenter_kind
from backend.optim.variant import VARIANT_NAMES, Variant
from backend.pipeline.engine import EndOfSequence, Engine
from backend.pipeline.snapshot import Snapshot
from viewer.access import AccessSettings
from viewer.commands import Command, CommandQueue
from viewer.exports import export
from viewer.guard import start_server
from viewer.history import SnapshotHistory
from viewer.scene import SceneView
from viewer.session import Session
from viewer.settings import ViewerSettings
from viewer.status import StatusLine
from viewer.tabs import TABS, HessianTab, KeyframeTab, PlotsTab, ReportTab, Shown, Tab, VariantsTab
from viewer.tabs.plots import PlotDrawer
from viewer.views import CameraViews

log = logging.getLogger(__name__)
T = TypeVar("T")
AB_OFF = "off"
# The Segmenter menu: the oracle of rendered scenes reads the renderer's plane ids, and says so.
SEGMENTER_LABELS: dict[SegmenterKind, str] = {
    SegmenterKind.GEOMETRIC: "geometric",
    SegmenterKind.LEARNED: "learned",
    SegmenterKind.ORACLE: "oracle (ground truth)",
}
SHORTCUTS = "**keys**: space play/pause · → step · shift+← / shift+→ scrub · F frame all"


class Debugger:
    """Serve `engine` on `host:port` until :meth:`stop`."""

    def __init__(self, engine: Engine, *, host: str = "127.0.0.1", port: int = 8080, settings: ViewerSettings = ViewerSettings(), access: AccessSettings = AccessSettings()) -> None:
        self.engine = engine
        self.settings = settings
        self.access = access
        # Only this debugger's own pages connect, and only the messages its page sends reach
        # it, with checked values (viewer/guard.py).
        self.server, self.guard = start_server(host=host, port=port, access=access, label="coplanar")
        self.port = self.server.get_port()
        self.session = Session(engine, keep=settings.history)
        self._shown: Snapshot | None = None
        self._commands = CommandQueue()
        self._playing = threading.Event()
        self._stopped = threading.Event()
        self.steps_done = 0
        self._play_times: collections.deque[float] = collections.deque(maxlen=8)
        self._working = threading.Event()  # the worker is running a command
        self._worked_at = 0.0
        self.scene = SceneView(self.server)
        self._build_gui()
        self.views = CameraViews(self.server, shown=lambda: self._shown)
        self.server.on_client_connect(self.views.on_connect)
        self._worker = threading.Thread(target=self._run, name="coplanar-engine", daemon=True)
        self._worker.start()
        self.plots = PlotDrawer(self.plots_tab.image, working=self._working, playing=self._playing, worked_at=lambda: self._worked_at)

    # ------------------------------------------------------------------ GUI

    def _build_gui(self) -> None:
        gui = self.server.gui
        gui.configure_theme(control_width="large", show_share_button=self.access.share)
        gui.main_panel.dock_right()
        self.status = gui.add_markdown(f"**{self.engine.source}**: ready, press Step or Play")
        with gui.add_folder("Run"):
            self.variant = gui.add_dropdown("Variant", VARIANT_NAMES, initial_value=str(self.engine.variant))
            self.segmenter = None
            if hasattr(self.engine, "segmenter"):  # image pipelines: plane instances from stereo, the network or (rendered) the truth
                kinds = [SegmenterKind.GEOMETRIC, SegmenterKind.LEARNED]
                if isinstance(getattr(self.engine, "data_source", None), RenderedTruth):
                    kinds.append(SegmenterKind.ORACLE)
                current = SEGMENTER_LABELS[segmenter_kind(self.engine.segmenter)]
                self.segmenter = gui.add_dropdown("Segmenter", tuple(SEGMENTER_LABELS[k] for k in kinds), initial_value=current)
            self.step_button = gui.add_button("Step")
            self.play = gui.add_checkbox("Play", initial_value=False)
            self.rate = gui.add_slider("Rate (Hz)", min=0.5, max=30.0, step=0.5, initial_value=self.settings.rate_hz)
            self.achieved = gui.add_text("Achieved", initial_value="–", disabled=True)
            self.reset_button = gui.add_button("Reset")
            self.slider = gui.add_slider("Keyframe", min=0, max=1, step=1, initial_value=0, disabled=True)
            self.keyframe_label = gui.add_text("Shown", initial_value="none", disabled=True)
            # Last in the folder, so that showing it moves nothing a user clicks.
            self.progress = gui.add_progress_bar(100.0, animated=True, visible=False)
        self.status_line = StatusLine(self.status, self.progress)
        self.busy = self.status_line.busy
        with gui.add_folder("A/B run"):
            self.ab_variant = gui.add_dropdown("B variant", (AB_OFF, *VARIANT_NAMES), initial_value=AB_OFF)
            self.ab_note = gui.add_markdown(
                "A second engine runs the same input in lockstep from the state shown when B is chosen; its "
                "trajectory and newest camera are drawn in magenta, the differences are in the *Variants* tab."
            )
        with gui.add_folder("View"):
            self.follow = gui.add_checkbox("Follow keyframe", initial_value=False)
            self.frame_button = gui.add_button("Frame all")
            self.reset_view_button = gui.add_button("Default view")
            self.point_scale = gui.add_slider("Point size", min=0.25, max=4.0, step=0.25, initial_value=1.0)
        with gui.add_folder("Layers"):
            self.layer_boxes = {
                name: gui.add_checkbox(label, initial_value=getattr(self.scene.layers, name))
                for name, label in (
                    ("cameras", "Cameras"),
                    ("points", "Points"),
                    ("lines", "Lines"),
                    ("planes", "Planes"),
                    ("infinite_planes", "Infinite planes"),
                    ("inliers", "RANSAC in/outliers"),
                    ("ground_truth", "Ground truth"),
                    ("ab", "A/B run (B)"),
                )
            }
            self.layer_note = gui.add_markdown("")
            self.dense = None
            source = getattr(self.engine, "data_source", None)
            if isinstance(source, StereoSource):  # image pipelines: depth to fuse
                self.dense_box = gui.add_checkbox("Dense mesh (TSDF)", initial_value=False)
                from viewer.dense import DenseLayer

                self.dense = DenseLayer(self.server, source, gui.add_markdown(""))
        with gui.add_folder("Export"):
            self.export_button = gui.add_button("Download map (PLY)")
            self.export_files = gui.add_button("Download map files (zip: points, lines, planes, cameras)")
            self.export_trajectory = gui.add_button("Download trajectory (TUM)")
            self.export_keyframes = gui.add_button("Download keyframe poses (TUM)")
        gui.add_markdown(SHORTCUTS)

        # The side panel's tabs (viewer/tabs), each owning its controls.
        side = gui.add_panel()
        self.tabs: list[Tab] = []
        for cls in TABS:
            tab = cls(self, self.settings)
            with side.add_tab(cls.title, cls.icon):
                tab.build(gui)
            self.tabs.append(tab)
        self.keyframe_tab = self._tab(KeyframeTab)
        self.hessian_tab = self._tab(HessianTab)
        self.variants_tab = self._tab(VariantsTab)
        self.plots_tab = self._tab(PlotsTab)
        self.report_tab = self._tab(ReportTab)
        side.dock_left()
        side.set_width(560)
        self.side_panel = side
        self._connect_callbacks()

    def _connect_callbacks(self) -> None:
        gui = self.server.gui
        self.step_button.on_click(lambda _: self.enqueue(Command.STEP))
        self.reset_button.on_click(lambda _: self.enqueue(Command.RESET))

        @self.variant.on_update
        def _(event: viser.GuiEvent) -> None:
            if event.client is not None:
                self.enqueue(Command.VARIANT, Variant.parse(self.variant.value))

        if self.segmenter is not None:

            @self.segmenter.on_update
            def _(event: viser.GuiEvent) -> None:
                if event.client is not None:
                    kind = next(k for k, label in SEGMENTER_LABELS.items() if label == self.segmenter.value)
                    self.enqueue(Command.SEGMENTER, kind)

        @self.ab_variant.on_update
        def _(event: viser.GuiEvent) -> None:
            if event.client is not None:
                self.enqueue(Command.AB, self.ab_variant.value)

        @self.play.on_update
        def _(event: viser.GuiEvent) -> None:
            if self.play.value:
                self._play_times.clear()
                self._playing.set()
                self.enqueue(Command.WAKE)
            else:
                self._playing.clear()
                self.achieved.value = "–"

        @self.slider.on_update
        def _(event: viser.GuiEvent) -> None:
            if event.client is not None:  # a user scrubs: stop playing, or the next step jumps back
                if self.play.value:
                    self.play.value = False
                self.enqueue(Command.SHOW, int(self.slider.value))

        for name, box in self.layer_boxes.items():
            box.on_update(self._layer_callback(name, box))

        @self.point_scale.on_update
        def _(_: viser.GuiEvent) -> None:
            with self.server.atomic():
                self.scene.set_point_scale(float(self.point_scale.value))

        self.frame_button.on_click(lambda event: self.views.frame(event.client, keep_direction=True))
        self.reset_view_button.on_click(lambda event: self.views.frame(event.client, keep_direction=False))
        self.export_button.on_click(lambda event: self._export(event.client, "map"))
        if self.dense is not None:
            self.dense_box.on_update(lambda _: self.dense.set_enabled(self.dense_box.value, self._shown))
        self.export_files.on_click(lambda event: self._export(event.client, "files"))
        self.export_trajectory.on_click(lambda event: self._export(event.client, "trajectory"))
        self.export_keyframes.on_click(lambda event: self._export(event.client, "keyframes"))

        # Keyboard shortcuts (viser's command palette binds them for every tab).
        gui.add_command("Play / pause", hotkey="space").on_trigger(lambda _: setattr(self.play, "value", not self.play.value))
        gui.add_command("Step", hotkey="arrowright").on_trigger(lambda _: self.enqueue(Command.STEP))
        gui.add_command("Scrub back", hotkey="arrowleft", modifier="shift").on_trigger(lambda _: self._scrub(-1))
        gui.add_command("Scrub forward", hotkey="arrowright", modifier="shift").on_trigger(lambda _: self._scrub(+1))
        gui.add_command("Frame all", hotkey="F").on_trigger(lambda event: self.views.frame(event.client, keep_direction=True))

    def _tab(self, cls: type[T]) -> T:
        return next(t for t in self.tabs if isinstance(t, cls))

    def _layer_callback(self, name: str, box: viser.GuiCheckboxHandle) -> Callable[[viser.GuiEvent], None]:
        def callback(_: viser.GuiEvent) -> None:
            with self.server.atomic():
                self.scene.set_layer(name, bool(box.value))

        return callback

    def _scrub(self, delta: int) -> None:
        if not self.history or self.slider.disabled:
            return
        if self.play.value:
            self.play.value = False
        value = int(np.clip(int(self.slider.value) + delta, self.slider.min, self.slider.max))
        self.slider.value = value
        self.enqueue(Command.SHOW, value)

    # ------------------------------------------------------------------ status

    def _set_status(self, text: str) -> None:
        self.status_line.set(text)

    def _busy(self, text: str) -> None:
        self.status_line.working(text)

    def _idle(self) -> None:
        self.status_line.done()

    # ------------------------------------------------------------------ worker

    def _run(self) -> None:
        while not self._stopped.is_set():
            try:
                timeout = 1.0 / max(self.rate.value, 1e-3) if self._playing.is_set() else None
                command, arg = self._commands.get(timeout=timeout)
                from_timer = False
            except queue.Empty:
                command, arg = (Command.STEP if self._playing.is_set() else Command.WAKE), None
                from_timer = True
            if command is Command.STOP:
                return
            self._working.set()
            try:
                self._execute(command, arg)
            except Exception as exc:  # an error in a step pauses the run, the server stays up
                log.error("engine error:\n%s", traceback.format_exc())
                self._playing.clear()
                self.play.value = False
                self._idle()
                self._set_status(f"**error** in {command}: `{type(exc).__name__}: {exc}`. Paused; fix or Reset.")
            finally:
                self._idle()
                self._worked_at = time.monotonic()
                self._working.clear()
                if not from_timer:
                    self._commands.task_done()

    def _execute(self, command: Command, arg: object) -> None:
        if command is Command.STEP:
            self._step()
        elif command is Command.VARIANT:
            self._switch_variant(Variant.parse(arg))  # type: ignore[arg-type]
        elif command is Command.ALL_VARIANTS:
            self._all_variants()
        elif command is Command.AB:
            self._set_ab(str(arg))
        elif command is Command.RESET:
            self._reset()
        elif command is Command.SHOW:
            keyframe = int(arg)  # type: ignore[call-overload]
            snapshot = self.history.get(keyframe, self.engine.variant)
            if snapshot is not None:
                self._show(snapshot)
        elif command is Command.COMPARE:
            self._update_compare()
        elif command is Command.SEGMENTER:
            self._set_segmenter(SegmenterKind(arg))  # type: ignore[arg-type]

    @property
    def history(self) -> SnapshotHistory:
        """Snapshots per keyframe and variant (the session's)."""
        return self.session.history

    @property
    def engine_b(self) -> Engine | None:
        """The A/B run's second engine (None: off)."""
        return self.session.engine_b

    @property
    def history_b(self) -> dict[int, Snapshot]:
        return self.session.history_b

    def _step(self) -> None:
        self._busy(f"stepping: keyframe {self.history.newest_keyframe + 1 if self.history else 0} …")
        try:
            stepped = self.session.step()
        except EndOfSequence as end:
            self._playing.clear()
            self.play.value = False
            self._idle()
            self._set_status(f"**end of sequence**: {end}")
            return
        if stepped.b_stopped:
            self._ab_stopped(stepped.b_stopped)
        self.steps_done += 1
        if self._playing.is_set():
            self._play_times.append(time.perf_counter())
        self._publish(stepped.snapshot)

    def _switch_variant(self, name: Variant) -> None:
        """Show `name` at the newest keyframe: its kept result, or the window re-optimized
        with it from the state the step left."""
        snapshot = self.session.switch_variant(name, busy=self._busy)
        if snapshot is None:
            self._set_status(f"variant {name}: used from the first step")
            return
        self._publish(snapshot)

    def _all_variants(self) -> None:
        """Every variant at the newest keyframe from the same state; the selected one stays."""
        if not self.history:
            self._set_status("no keyframe yet: press Step first")
            return
        selected = self.engine.variant
        for name in self.session.missing_variants():
            self._switch_variant(name)
        self._switch_variant(selected)

    def _set_ab(self, name: str) -> None:
        if name == AB_OFF:
            self.session.stop_ab()
            self._ab_stopped("A/B run off")
            if self._shown is not None:
                self._show(self._shown)
            return
        variant = Variant.parse(name)
        if not self.session.can_checkpoint:  # a copy would share the engine's state
            self.session.stop_ab()
            self._ab_stopped(f"{self.engine.source}: this engine cannot be copied for an A/B run")
            self._set_status(f"**A/B run**: {self.engine.source} cannot be copied (no checkpoint)")
            return
        self._busy(f"starting the A/B run with {name} …")
        self.session.start_ab(variant)
        if self.ab_variant.value != name:
            self.ab_variant.value = name
        self._set_status(f"A/B run: B = {name}, started at keyframe {self.history.newest_keyframe if self.history else 0}; press Step")
        if self._shown is not None:
            self._show(self._shown)

    def _ab_stopped(self, why: str) -> None:
        """The A/B run has stopped (the session says so): its menu off and why."""
        if self.ab_variant.value != AB_OFF:
            self.ab_variant.value = AB_OFF
        self.variants_tab.note_ab(f"*{why}*")

    def _set_segmenter(self, kind: SegmenterKind) -> None:
        """Plane instances from the next keyframe on: stereo disparity, the network, or on
        rendered scenes the renderer's exact plane ids (the oracle, a reference)."""
        try:
            segmenter = make_segmenter(kind, source=getattr(self.engine, "data_source", None))
        except SegmenterError as e:
            if self.segmenter is not None:
                self.segmenter.value = SEGMENTER_LABELS[SegmenterKind.GEOMETRIC]
            self._set_status(f"**error**: {e}")
            return
        for engine in (self.engine, self.engine_b):
            if engine is not None:
                engine.segmenter = segmenter
        self._set_status(f"plane instances from the {SEGMENTER_LABELS[kind]} segmenter from the next keyframe on")

    def _reset(self) -> None:
        self._busy("resetting …")
        self.session.reset()
        if self.dense is not None:
            self.dense.clear()
        self._ab_stopped("A/B run off (reset)")
        self._shown = None
        self.views.forget()
        with self.server.atomic():
            self.scene.clear()
            self.slider.disabled = True
            self.keyframe_label.value = "none"
            for tab in self.tabs:
                tab.clear()
            self.layer_note.content = ""
            self.achieved.value = "–"
        self._idle()
        self._set_status(f"**{self.engine.source}**: reset, press Step or Play")

    # ------------------------------------------------------------------ drawing

    def _publish(self, snapshot: Snapshot) -> None:
        """Show a new or re-optimized snapshot; the slider follows the newest keyframe."""
        self._show(snapshot)
        first = self.history.first_keyframe
        with self.server.atomic():
            self.slider.disabled = len(self.history) < 2
            self.slider.max = max(snapshot.keyframe, first + 1)
            self.slider.min = first
            self.slider.value = snapshot.keyframe
            if len(self._play_times) >= 2 and self._playing.is_set():
                span = self._play_times[-1] - self._play_times[0]
                rate = (len(self._play_times) - 1) / span if span > 0 else float("nan")
                self.achieved.value = f"{rate:.1f} keyframes/s (asked {self.rate.value:g})"
        self._idle()
        self._set_status(
            f"**{self.engine.source}**: keyframe {snapshot.keyframe} · {snapshot.variant}"
            + (" · playing" if self._playing.is_set() else "")
            + (f"\n\n**{snapshot.message}**" if snapshot.message else "")
        )
        self._update_compare()

    def _show(self, snapshot: Snapshot) -> None:
        """Draw a snapshot: the scene first (its label last, so a client that sees the label
        has the whole scene), then the panels, which cost more to encode."""
        other = self.session.other_at(snapshot.keyframe)
        with self.server.atomic():
            self.scene.draw(snapshot, other=other)
            self.keyframe_label.value = f"{snapshot.keyframe} ({snapshot.variant})"
        self.server.flush()
        self._shown = snapshot
        self.views.update(snapshot, follow=bool(self.follow.value))
        with self.server.atomic():
            if self.variant.value != snapshot.variant:
                self.variant.value = snapshot.variant
            shown = Shown(snapshot, variants=self.history.variants_at(snapshot.keyframe), other=other, ab_on=self.engine_b is not None, source=self.engine.source)
            for tab in self.tabs:
                tab.show(shown)
            self.layer_note.content = f"*{snapshot.variant}: planes are detected and drawn faint for reference; this variant's optimizer does not use them*" if not snapshot.variant.uses_planes else ""
        self.server.flush()
        self.request_plots()
        if self.dense is not None:
            self.dense.request(snapshot)

    def _update_compare(self) -> None:
        self.hessian_tab.update_compare(self.engine, has_keyframes=bool(self.history))

    # ------------------------------------------------------------------ plots

    def request_plots(self) -> None:
        """Ask the plot thread for the plots of what is shown (the newest request wins)."""
        if not self.plots_tab.box.value or self._shown is None:
            return
        self.plots.request(self.history.series(self._shown.variant), self._shown.keyframe)

    @property
    def plot_updates(self) -> int:
        return self.plots.updates

    def wait_plots(self, timeout: float = 30.0) -> None:
        """Block until the plots show the latest request (for tests and benchmarks)."""
        self.plots.wait(timeout)

    # ------------------------------------------------------------------ large views

    # ------------------------------------------------------------------ export

    def _export(self, client: viser.ClientHandle | None, what: str) -> None:
        snapshot = self._shown
        is_newest = snapshot is not None and snapshot.keyframe == self.history.newest_keyframe
        export(client, what, snapshot, frame_trajectory=getattr(self.engine, "frame_trajectory", None), is_newest=is_newest)

    # ------------------------------------------------------------------ control

    def submit(self, command: Command | str, arg: object = None) -> None:
        """Queue a command ("step", "reset", "variant", "show", "ab", "all_variants", ...);
        unlike the GUI's, submitted commands do not coalesce: each one runs."""
        self._commands.put(command, arg)

    def enqueue(self, command: Command, arg: object = None) -> None:
        """Queue a command from a browser: a burst coalesces (viewer/commands.py)."""
        self._commands.put(command, arg, coalesce=True)

    def wait_idle(self, timeout: float = 60.0) -> None:
        """Block until every queued command has run (for tests and benchmarks)."""
        if not self._commands.wait_done(timeout):
            raise TimeoutError("the engine did not become idle")

    @property
    def shown(self) -> Snapshot | None:
        """The snapshot on screen."""
        return self._shown

    def stop(self) -> None:
        self._stopped.set()
        self._playing.clear()
        self._commands.put(Command.STOP)
        self._worker.join(timeout=10.0)
        self.plots.stop()
        if self.dense is not None:
            self.dense.stop()
        self.server.stop()
