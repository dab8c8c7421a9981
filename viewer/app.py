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
import copy
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
from backend.export.ply import snapshot_ply_bytes
from backend.frontend.segmenters import SegmenterError, SegmenterKind, make_segmenter, segmenter_kind
from backend.optim.variant import VARIANT_NAMES, VARIANTS, Variant
from backend.pipeline.engine import EndOfSequence, Engine
from backend.pipeline.snapshot import Snapshot
from viewer import panels
from viewer.access import AccessSettings
from viewer.commands import Command, CommandQueue
from viewer.guard import start_server
from viewer.history import SnapshotHistory
from viewer.plots import plots_image
from viewer.scene import SceneView
from viewer.settings import ViewerSettings
from viewer.tabs import TABS, HessianTab, KeyframeTab, PlotsTab, ReportTab, Shown, Tab, VariantsTab
from viewer.views import CameraViews

log = logging.getLogger(__name__)
T = TypeVar("T")
PROGRESS_DELAY_S = 0.3
PLOT_DEBOUNCE_S = 0.4  # plots are drawn once updates pause this long
PLOT_PLAY_PERIOD_S = 1.0  # and while playing, at most this often
AB_OFF = "off"
# The Segmenter menu: the oracle of rendered scenes reads the renderer's plane ids, and says so.
SEGMENTER_LABELS: dict[SegmenterKind, str] = {
    SegmenterKind.GEOMETRIC: "geometric", SegmenterKind.LEARNED: "learned", SegmenterKind.ORACLE: "oracle (ground truth)",
}
SHORTCUTS = "**keys**: space play/pause · → step · shift+← / shift+→ scrub · F frame all"


class Debugger:
    """Serve `engine` on `host:port` until :meth:`stop`."""

    def __init__(
        self, engine: Engine, *, host: str = "127.0.0.1", port: int = 8080, settings: ViewerSettings = ViewerSettings(), access: AccessSettings = AccessSettings()
    ) -> None:
        self.engine = engine
        self.settings = settings
        self.access = access
        # Only this debugger's own pages connect, and only the messages its page sends reach
        # it, with checked values (viewer/guard.py).
        self.server, self.guard = start_server(host=host, port=port, access=access, label="coplanar")
        self.port = self.server.get_port()
        self.history = SnapshotHistory(settings.history)
        self._shown: Snapshot | None = None
        self._commands = CommandQueue()
        self._playing = threading.Event()
        self._stopped = threading.Event()
        self.busy = threading.Event()
        self._status_lock = threading.Lock()
        self._busy_token: object | None = None
        self._progress_timer: threading.Timer | None = None
        self.steps_done = 0
        # Engine checkpoints at the newest keyframe: after its step ("base") and after
        # each variant's re-optimization there.
        self._states_keyframe: int | None = None
        self._states: dict[str, object] = {}
        # The A/B run: a second engine on the same input in lockstep (None: off).
        self.engine_b: Engine | None = None
        self.history_b: dict[int, Snapshot] = {}
        self._play_times: collections.deque[float] = collections.deque(maxlen=8)
        self._plot_request: tuple[list[Snapshot], int | None] | None = None
        self._plot_event = threading.Event()
        self._working = threading.Event()  # the worker is running a command
        self._plot_drawing = threading.Event()
        self._worked_at = 0.0
        self.plot_updates = 0
        self.scene = SceneView(self.server)
        self._build_gui()
        self.views = CameraViews(self.server, shown=lambda: self._shown)
        self.server.on_client_connect(self.views.on_connect)
        self._worker = threading.Thread(target=self._run, name="coplanar-engine", daemon=True)
        self._worker.start()
        self._plotter = threading.Thread(target=self._plot_loop, name="coplanar-plots", daemon=True)
        self._plotter.start()

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
        with gui.add_folder("A/B run"):
            self.ab_variant = gui.add_dropdown("B variant", (AB_OFF, *VARIANT_NAMES), initial_value=AB_OFF)
            self.ab_note = gui.add_markdown("A second engine runs the same input in lockstep from the state shown when B is chosen; its trajectory and newest camera are drawn in magenta, the differences are in the *Variants* tab.")
        with gui.add_folder("View"):
            self.follow = gui.add_checkbox("Follow keyframe", initial_value=False)
            self.frame_button = gui.add_button("Frame all")
            self.reset_view_button = gui.add_button("Default view")
            self.point_scale = gui.add_slider("Point size", min=0.25, max=4.0, step=0.25, initial_value=1.0)
        with gui.add_folder("Layers"):
            self.layer_boxes = {
                name: gui.add_checkbox(label, initial_value=getattr(self.scene.layers, name))
                for name, label in (
                    ("cameras", "Cameras"), ("points", "Points"), ("lines", "Lines"), ("planes", "Planes"),
                    ("infinite_planes", "Infinite planes"), ("inliers", "RANSAC in/outliers"), ("ground_truth", "Ground truth"),
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
        """Write the status line; a pending progress message can no longer overwrite it."""
        with self._status_lock:
            self._busy_token = None
            self.status.content = text

    def _busy(self, text: str) -> None:
        """Mark the worker busy; `text` and the progress bar appear only if the work takes
        longer than PROGRESS_DELAY_S (a quick step should not repaint the panel twice)."""
        self.busy.set()
        token = object()
        with self._status_lock:
            self._busy_token = token

        def show() -> None:
            with self._status_lock:
                if self._busy_token is token:
                    self.status.content = text
                    self.progress.visible = True

        self._progress_timer = threading.Timer(PROGRESS_DELAY_S, show)
        self._progress_timer.daemon = True
        self._progress_timer.start()

    def _idle(self) -> None:
        self.busy.clear()
        with self._status_lock:
            self._busy_token = None
        if self._progress_timer is not None:
            self._progress_timer.cancel()
            self._progress_timer = None
        if self.progress.visible:
            self.progress.visible = False

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

    def _step(self) -> None:
        self._busy(f"stepping: keyframe {self.history.newest_keyframe + 1 if self.history else 0} …")
        try:
            snapshot = self.engine.step()
        except EndOfSequence as end:
            self._playing.clear()
            self.play.value = False
            self._idle()
            self._set_status(f"**end of sequence**: {end}")
            return
        other = None
        if self.engine_b is not None:
            try:
                other = self.engine_b.step()
                self._keep_b(other)
            except EndOfSequence:
                self._stop_ab("B reached the end of the sequence")
        self.steps_done += 1
        self._states_keyframe = None
        self._states = {}
        if self._playing.is_set():
            self._play_times.append(time.perf_counter())
        self.history.add_step(snapshot)
        self._publish(snapshot)

    def _keep_b(self, snapshot: Snapshot) -> None:
        self.history_b[snapshot.keyframe] = snapshot
        while len(self.history_b) > self.settings.history:
            self.history_b.pop(next(iter(self.history_b)))

    def _switch_variant(self, name: Variant) -> None:
        """Show `name` at the newest keyframe: its kept result, or the window re-optimized
        with it from the state the step left."""
        if not self.history:
            self.engine.set_variant(name)
            self._set_status(f"variant {name}: used from the first step")
            return
        k = self.history.newest_keyframe
        has_states = hasattr(self.engine, "checkpoint")
        if has_states and self._states_keyframe != k:
            self._states_keyframe = k
            base = self.engine.checkpoint()  # restore() copies it again, so one serves both
            self._states = {"base": base, self.engine.variant: base}
        kept = self.history.variants_at(k).get(name)
        if has_states and kept is not None and name in self._states:
            self.engine.restore(self._states[name])
            self.engine.set_variant(name)
            self.history.choose(k, name)
            self._publish(kept)
            return
        self._busy(f"re-optimizing the window with {name} …")
        if has_states:
            self.engine.restore(self._states["base"])
        self.engine.set_variant(name)
        snapshot = self.engine.reoptimize()
        if has_states:
            self._states[name] = self.engine.checkpoint()
        self.history.add_variant(snapshot)
        self._publish(snapshot)

    def _all_variants(self) -> None:
        """Every variant at the newest keyframe from the same state; the selected one stays."""
        if not self.history:
            self._set_status("no keyframe yet: press Step first")
            return
        selected = self.engine.variant
        for name in VARIANTS:
            if name not in self.history.variants_at(self.history.newest_keyframe):
                self._switch_variant(name)
        self._switch_variant(selected)

    def _set_ab(self, name: str) -> None:
        if name == AB_OFF:
            self._stop_ab("A/B run off")
            if self._shown is not None:
                self._show(self._shown)
            return
        variant = Variant.parse(name)
        if not hasattr(self.engine, "checkpoint"):  # a copy would share the engine's state
            self._stop_ab(f"{self.engine.source}: this engine cannot be copied for an A/B run")
            self._set_status(f"**A/B run**: {self.engine.source} cannot be copied (no checkpoint)")
            return
        self._busy(f"starting the A/B run with {name} …")
        engine_b = copy.copy(self.engine)
        engine_b.restore(self.engine.checkpoint())
        engine_b.set_variant(variant)
        self.engine_b = engine_b
        if self.ab_variant.value != name:
            self.ab_variant.value = name
        self.history_b = {}
        if self.history:
            self._keep_b(engine_b.reoptimize())
        self._set_status(f"A/B run: B = {name}, started at keyframe {self.history.newest_keyframe if self.history else 0}; press Step")
        if self._shown is not None:
            self._show(self._shown)

    def _stop_ab(self, why: str) -> None:
        self.engine_b = None
        self.history_b = {}
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
        self.engine.reset()
        if self.dense is not None:
            self.dense.clear()
        self.history.clear()
        self._stop_ab("A/B run off (reset)")
        self._states_keyframe = None
        self._states = {}
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
        other = self.history_b.get(snapshot.keyframe) if self.engine_b is not None else None
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
            self.layer_note.content = (
                f"*{snapshot.variant}: planes are detected and drawn faint for reference; this variant's optimizer does not use them*"
                if not snapshot.variant.uses_planes else ""
            )
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
        self._plot_request = (self.history.series(self._shown.variant), self._shown.keyframe)
        self._plot_event.set()

    def _plot_loop(self) -> None:
        """Draw the plots off the engine's thread while it waits: once it has been idle
        for PLOT_DEBOUNCE_S (drawing takes about 150 ms of a shared CPU and must not slow
        a burst of steps or scrubbing), and while playing between two steps at most every
        PLOT_PLAY_PERIOD_S."""
        last_draw = 0.0
        while not self._stopped.is_set():
            if not self._plot_event.wait(timeout=0.5):
                continue
            now = time.monotonic()
            idle = not self._working.is_set() and now - self._worked_at >= PLOT_DEBOUNCE_S
            due = self._playing.is_set() and not self._working.is_set() and now - last_draw >= PLOT_PLAY_PERIOD_S
            if not (idle or due):
                time.sleep(0.05)
                continue
            self._plot_drawing.set()
            self._plot_event.clear()
            request, self._plot_request = self._plot_request, None
            try:
                if request is not None and request[0]:
                    self.plots_tab.image.image = plots_image(request[0], current=request[1])
                    self.plot_updates += 1
            except Exception:  # a plot must never stop the debugger
                log.error("plot error:\n%s", traceback.format_exc())
            finally:
                self._plot_drawing.clear()
            last_draw = time.monotonic()

    def wait_plots(self, timeout: float = 30.0) -> None:
        """Block until the plots show the latest request (for tests and benchmarks)."""
        deadline = time.monotonic() + timeout
        while self._plot_request is not None or self._plot_event.is_set() or self._plot_drawing.is_set():
            if time.monotonic() > deadline:
                raise TimeoutError("the plots were not drawn")
            time.sleep(0.01)

    # ------------------------------------------------------------------ large views

    # ------------------------------------------------------------------ export

    def _export(self, client: viser.ClientHandle | None, what: str) -> None:
        snapshot = self._shown
        if client is None:
            return
        if snapshot is None:
            client.add_notification("Nothing to export", "No keyframe is shown yet: press Step first.", auto_close_seconds=5.0, color="yellow")
            return
        stem = f"coplanar_kf{snapshot.keyframe:05d}_{snapshot.variant}"
        if what == "map":
            client.send_file_download(f"coplanar_map_kf{snapshot.keyframe:05d}_{snapshot.variant}.ply", snapshot_ply_bytes(snapshot), save_immediately=True)
        elif what == "files":
            from backend.common.optional import MissingLibraryError
            from backend.export.map_files import map_files_zip

            try:
                data = map_files_zip(snapshot)
            except MissingLibraryError as e:
                client.add_notification("Export needs open3d", str(e), auto_close_seconds=10.0, color="red")
                return
            client.send_file_download(f"coplanar_map_kf{snapshot.keyframe:05d}_{snapshot.variant}.zip", data, save_immediately=True)
        elif what == "keyframes":
            client.send_file_download(f"{stem}_keyframes.txt", panels.tum_bytes(snapshot.estimate), save_immediately=True)
        else:
            frames = getattr(self.engine, "frame_trajectory", None)
            if frames is None or snapshot.keyframe != self.history.newest_keyframe:
                # Per-frame poses exist for the engine's current state only (the newest keyframe).
                client.send_file_download(f"{stem}_keyframes.txt", panels.tum_bytes(snapshot.estimate), save_immediately=True)
                client.add_notification("Keyframe poses exported", "Every-frame poses exist only for the newest keyframe and engines that track frames; the keyframe poses were written.", auto_close_seconds=6.0)
                return
            client.send_file_download(f"{stem}_trajectory.txt", panels.tum_bytes(frames().estimate), save_immediately=True)

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
        self._plot_event.set()
        self._plotter.join(timeout=5.0)
        if self.dense is not None:
            self.dense.stop()
        self.server.stop()
