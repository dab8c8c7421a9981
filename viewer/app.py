"""The debugger: a viser server that drives an engine one keyframe at a time.

All engine calls run on one worker thread (viewer/worker.py), fed by a command queue, so
GUI callbacks never block and never race. The GUI and scene are server-wide: every open tab
shows the same state (the camera is each tab's own). Snapshots are kept per keyframe and per
variant (:class:`viewer.history.SnapshotHistory`): the keyframe slider scrubs through them
without touching the engine, and every variant chosen at the newest keyframe re-optimizes
that window from the same engine state (a checkpoint taken after the step), so variants can
be compared at the same keyframe and returning to one shows its kept result.

Layout: the control panel (run, A/B, view, layers, export: viewer/controls.py) is docked on
the right; a second panel docked on the left holds the larger views in tabs (keyframe image,
Hessian, variants at this keyframe, plots over time, report). The 3D view lies between them.
"""

from __future__ import annotations

import collections
import time
from typing import Any, TypeVar

import viser

from backend.export.output_frame import TrajectoryFrame, output_frame
from backend.frontend.segmenters import SegmenterError, SegmenterKind, make_segmenter
from backend.optim.variant import Variant
from backend.pipeline.engine import EndOfSequence, Engine
from backend.pipeline.replay_engine import NotRecorded
from backend.pipeline.snapshot import FrameTrajectory, Snapshot
from viewer import exports, panels
from viewer.access import AccessSettings
from viewer.commands import Command, unwrap
from viewer.controls import AB_OFF, SEGMENTER_LABELS, ControlPanel, Segmented
from viewer.guard import start_server
from viewer.history import SnapshotHistory
from viewer.page_choice import set_value
from viewer.scene import SceneView
from viewer.session import Session
from viewer.settings import ViewerSettings
from viewer.tabs import TABS, HessianTab, KeyframeTab, PlotsTab, ReportTab, Shown, Tab, VariantsTab
from viewer.tabs.plots import PlotDrawer
from viewer.views import CameraViews
from viewer.worker import Worker

T = TypeVar("T")
REFUSAL_NOTICE_S = 10.0  # how long a refusal stays in the notification of the tab that asked


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
        self.session = Session(engine, keep=settings.history, max_bytes=int(settings.history_mb * 2**20))
        self._shown: Snapshot | None = None
        self.worker = Worker(self._execute, period=lambda: 1.0 / max(self.rate.value, 1e-3), failed=self._failed, done=self._idle, idle=self.session.wants_ahead)
        self._commands, self._playing = self.worker.commands, self.worker.playing  # (tests and benchmarks reach them)
        self.steps_done = 0
        self._play_times: collections.deque[float] = collections.deque(maxlen=8)
        self.scene = SceneView(self.server)
        self._build_gui()
        self.views = CameraViews(self.server, shown=lambda: self._shown)
        self.server.on_client_connect(self.views.on_connect)
        self.worker.start()
        self.plots = PlotDrawer(self.plots_tab.image, working=self.worker.working, playing=self._playing, worked_at=lambda: self.worker.worked_at, ahead=self.worker.ahead)

    # ------------------------------------------------------------------ GUI

    def _build_gui(self) -> None:
        gui = self.server.gui
        gui.configure_theme(control_width="large", show_share_button=self.access.share)
        c = self.controls = ControlPanel(self, self.server, self.engine, self.scene, self.settings)
        # The controls the debugger writes into, by name (tests and the command line read them too).
        self.status, self.status_line, self.busy, self.progress = c.status, c.status_line, c.status_line.busy, c.progress
        self.variant, self.segmenter, self.ab_variant, self.reset_button = c.variant, c.segmenter, c.ab_variant, c.reset_button
        self.play, self.rate, self.achieved, self.slider, self.keyframe_label = c.play, c.rate, c.achieved, c.slider, c.keyframe_label
        self.follow, self.point_scale, self.layer_note, self.dense = c.follow, c.point_scale, c.layer_note, c.dense

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
        c.connect()
        if getattr(self.engine, "replay", False):  # nothing to run a second engine on
            self.ab_variant.disabled = True
            c.ab_note.content = "*A replay shows what was recorded: no second run.*"

    def _tab(self, cls: type[T]) -> T:
        return next(t for t in self.tabs if isinstance(t, cls))

    def on_play(self, playing: bool) -> None:
        """The Play box changed: steps on the worker's timer from now on, or none."""
        if playing:
            self._play_times.clear()
            self._playing.set()
            self.enqueue(Command.WAKE)
        else:
            self._playing.clear()
            set_value(self.achieved, "–")

    def frame(self, client: viser.ClientHandle | None, *, keep_direction: bool) -> None:
        """Frame the shown map in `client`'s view (viewer/views.py)."""
        self.views.frame(client, keep_direction=keep_direction)

    # ------------------------------------------------------------------ status

    def _set_status(self, text: str) -> None:
        self.status_line.set(text)

    def _busy(self, text: str) -> None:
        self.status_line.working(text)

    def _idle(self) -> None:
        self.status_line.done()

    # ------------------------------------------------------------------ worker

    def _execute(self, command: Command, arg: Any) -> None:
        """Run `command` (on the worker's thread); `arg` as its sender gave it (a name, a
        number or an enum member), converted here. A command that changes what the next step
        would be, or reads the engine's newest state, first puts aside the step computed
        ahead (viewer/session.py)."""
        if command not in (Command.STEP, Command.SHOW, Command.WAKE, Command.AHEAD):
            self.session.cancel_ahead()
        if command is Command.AHEAD:
            self.session.step_ahead()
        elif command is Command.STEP:
            self._step()
        elif command is Command.VARIANT:
            name, client = unwrap(arg)
            if self._scrubbed_back():
                self._variant_at_shown(Variant.parse(name), client=client)
            else:
                self._switch_variant(Variant.parse(name))
        elif command is Command.ALL_VARIANTS:
            self._all_variants()
        elif command is Command.AB:
            self._set_ab(str(arg))
        elif command is Command.RESET:
            self._reset()
        elif command is Command.SHOW:
            keyframe = int(arg)
            same = self._shown is not None and self._shown.keyframe == keyframe  # drawn again (Displacement): the variant shown stays
            snapshot = self.history.get(keyframe, self._shown.variant if same and self._shown is not None else self.engine.variant)
            if snapshot is not None:
                self._show_kept(snapshot)
        elif command is Command.COMPARE:
            self._update_compare()
        elif command is Command.SEGMENTER:
            self._set_segmenter(SegmenterKind(arg))
        elif command is Command.RECORD:
            self._set_recording(bool(arg))

    def _failed(self, command: Command, exc: Exception) -> None:
        """A command raised (the worker logged it and stopped playing): paused, and why."""
        set_value(self.play, False)
        self._idle()
        self._set_status(f"**error** in {command}: `{type(exc).__name__}: {exc}`. Paused; fix or Reset.")

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
            set_value(self.play, False)
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
        try:
            snapshot = self.session.switch_variant(name, busy=self._busy)
        except NotRecorded as e:  # a replay: only what was recorded
            shown = self._shown
            if shown is not None:
                self.engine.set_variant(shown.variant)
                with self.server.atomic():
                    self.controls.show_variant(shown.variant)
            self._set_status(f"**{e}**; still showing {shown.variant if shown is not None else 'nothing'}.")
            return
        if snapshot is None:
            self._set_status(f"variant {name}: used from the first step")
            return
        self._publish(snapshot)

    def _scrubbed_back(self) -> bool:
        """Whether the keyframe shown is older than the newest stepped."""
        return self._shown is not None and bool(self.history) and self._shown.keyframe != self.history.newest_keyframe

    def _variant_at_shown(self, name: Variant, *, client: viser.ClientHandle | None = None) -> None:
        """A variant chosen at an older keyframe: its kept result there, or why there is none
        (variants are re-optimized from the engine's state, which is at the newest keyframe);
        the view stays at the keyframe shown, and the run goes on with the engine's variant.
        The refusal is in the status line and, for the tab that chose (`client`), in a
        notification that stays after the next step has replaced the status line."""
        shown = self._shown
        assert shown is not None
        kept = self.history.variants_at(shown.keyframe).get(name)
        if kept is not None:
            self._show_kept(kept)
            return
        with self.server.atomic():
            self.controls.show_variant(shown.variant)
        newest = self.history.newest_keyframe
        why = f"Variants are re-optimized from the engine's state, which is at the newest keyframe ({newest}); move the slider there to add {name}."
        self._set_status(f"**{name} was not computed at keyframe {shown.keyframe}**: {why[0].lower()}{why[1:]} Still showing {shown.variant}.")
        if client is not None:
            client.add_notification(f"{name} was not computed at keyframe {shown.keyframe}", f"{why} Still showing {shown.variant}.", auto_close_seconds=REFUSAL_NOTICE_S, color="yellow")

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
            set_value(self.ab_variant, name)
        self._set_status(f"A/B run: B = {name}, started at keyframe {self.history.newest_keyframe if self.history else 0}; press Step")
        if self._shown is not None:
            self._show(self._shown)

    def _ab_stopped(self, why: str) -> None:
        """The A/B run has stopped (the session says so): its menu off and why."""
        if self.ab_variant.value != AB_OFF:
            set_value(self.ab_variant, AB_OFF)
        self.variants_tab.note_ab(f"*{why}*")

    def _set_segmenter(self, kind: SegmenterKind) -> None:
        """Plane instances from the next keyframe on: stereo disparity, the network, or on
        rendered scenes the renderer's exact plane ids (the oracle, a reference)."""
        try:
            segmenter = make_segmenter(kind, source=getattr(self.engine, "data_source", None))
        except SegmenterError as e:
            if self.segmenter is not None:
                set_value(self.segmenter, SEGMENTER_LABELS[SegmenterKind.GEOMETRIC])
            self._set_status(f"**error**: {e}")
            return
        for engine in (self.engine, self.engine_b):
            if isinstance(engine, Segmented):
                engine.segmenter = segmenter
        self._set_status(f"plane instances from the {SEGMENTER_LABELS[kind]} segmenter from the next keyframe on")

    def _set_recording(self, on: bool) -> None:
        """Record from now on (viewer/session.py), or stop; the recording stays for download."""
        if on and not self.session.recording:
            self.session.start_recording()
        elif not on:
            self.session.stop_recording()
        if bool(self.controls.record.value) != self.session.recording:
            set_value(self.controls.record, self.session.recording)
        self._update_record_note()

    def _update_record_note(self) -> None:
        recorder = self.session.recorder
        if recorder is None:
            text = ""
        else:
            state = "recording" if self.session.recording else "recorded (stopped)"
            text = f"{state}: {recorder.keyframes} keyframes, {recorder.size_bytes / 2**20:.1f} MB"
        if self.controls.record_note.content != text:
            self.controls.record_note.content = text

    def _reset(self) -> None:
        self._busy("resetting …")
        self.session.reset()
        if bool(self.controls.record.value):
            set_value(self.controls.record, False)
        self._update_record_note()
        if self.dense is not None:
            self.dense.clear()
        self._ab_stopped("A/B run off (reset)")
        self._shown = None
        self.views.forget()
        with self.server.atomic():
            self.scene.clear()
            self.slider.disabled = True
            self.slider.min, self.slider.max = 0, 1
            self.controls.slider_choice.set(0)
            set_value(self.keyframe_label, "none")
            for tab in self.tabs:
                tab.clear()
            self.layer_note.content = ""
            set_value(self.achieved, "–")
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
            self.controls.show_keyframe(snapshot.keyframe)
            if len(self._play_times) >= 2 and self._playing.is_set():
                span = self._play_times[-1] - self._play_times[0]
                rate = (len(self._play_times) - 1) / span if span > 0 else float("nan")
                set_value(self.achieved, f"{rate:.1f} keyframes/s (asked {self.rate.value:g})")
        self._idle()
        self._set_status(self._status_of(snapshot))
        self._update_compare()
        self._update_record_note()

    def _show_kept(self, snapshot: Snapshot) -> None:
        """Show a kept snapshot (scrubbing; a variant kept at an older keyframe): the slider
        stays, the status line and the comparison follow it."""
        self._show(snapshot)
        self._set_status(self._status_of(snapshot))
        self._update_compare()

    def _status_of(self, snapshot: Snapshot) -> str:
        """The status line for `snapshot` on screen: its keyframe and variant, and the newest
        keyframe when it is an older one (scrubbed back)."""
        newest = self.history.newest_keyframe if self.history else snapshot.keyframe
        return (
            f"**{self.engine.source}**: keyframe {snapshot.keyframe} · {snapshot.variant}"
            + (f" · scrubbed back (newest {newest})" if snapshot.keyframe != newest else "")
            + (" · playing" if self._playing.is_set() else "")
            + (f"\n\n**{snapshot.message}**" if snapshot.message else "")
            + (f"\n\n{note}" if (note := panels.vio_start_note(snapshot)) and note != f"VIO not initialized yet: {snapshot.message}" else "")
        )

    def _show(self, snapshot: Snapshot) -> None:
        """Draw a snapshot: the scene first (its label last, so a client that sees the label
        has the whole scene), then the panels, which cost more to encode."""
        other = self.session.other_at(snapshot.keyframe)
        variants = self.history.variants_at(snapshot.keyframe)
        compare = self.controls.displacement.target(snapshot, variants=variants, other=other)
        with self.server.atomic():
            self.scene.draw(snapshot, other=other, compare=compare)
            set_value(self.keyframe_label, f"{snapshot.keyframe} ({snapshot.variant})")
        self.server.flush()
        self._shown = snapshot
        self.views.update(snapshot, follow=bool(self.follow.value))
        with self.server.atomic():
            self.controls.show_variant(snapshot.variant)
            newest = self.history.newest_keyframe if self.history else snapshot.keyframe
            shown = Shown(snapshot, variants=variants, other=other, ab_on=self.engine_b is not None, source=self.engine.source, newest_keyframe=newest)
            for tab in self.tabs:
                tab.show(shown)
            self.layer_note.content = _unused_note(snapshot)
            self.controls.displacement.show(snapshot, variants=variants, other=other, displacement=self.scene.displacement)
        self.server.flush()
        self.request_plots()
        if self.dense is not None:
            self.dense.request(snapshot)

    def _update_compare(self) -> None:
        newest, first = (self.history.newest_keyframe, self.history.first_keyframe) if self.history else (None, 0)
        replay = bool(getattr(self.engine, "replay", False))
        self.hessian_tab.update_compare(self._shown, newest=newest, first_kept=first, compute=self.session.compare_hessians, replay=replay)

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

    # ------------------------------------------------------------------ export

    def export(self, client: viser.ClientHandle | None, what: str) -> None:
        """Send `what` of the shown snapshot to `client` (viewer/exports.py), or "recording":
        the recording so far (viewer/session.py)."""
        if what == "recording":
            exports.send_recording(client, self.session.recorder)
            return
        snapshot = self._shown
        is_newest = snapshot is not None and snapshot.keyframe == self.history.newest_keyframe
        frame = output_frame(getattr(self.engine, "data_source", None), choice=TrajectoryFrame.TRUTH)
        has_frames = hasattr(self.engine, "frame_trajectory")
        exports.export(client, what, snapshot, frame_trajectory=self._frame_trajectory if has_frames else None, is_newest=is_newest, frame=frame)

    def _frame_trajectory(self) -> FrameTrajectory:
        """Every frame's pose up to the newest keyframe stepped (not one computed ahead)."""
        trajectory = self.session.frame_trajectory()
        assert trajectory is not None  # asked only of engines that have one
        return trajectory

    # ------------------------------------------------------------------ control

    def submit(self, command: Command | str, arg: object = None) -> None:
        """Queue a command ("step", "reset", "variant", "show", "ab", "all_variants", ...);
        unlike the GUI's, submitted commands do not coalesce: each one runs."""
        self.worker.put(command, arg)

    def enqueue(self, command: Command, arg: object = None) -> None:
        """Queue a command from a browser: a burst coalesces (viewer/commands.py)."""
        self.worker.put(command, arg, coalesce=True)

    def wait_idle(self, timeout: float = 60.0) -> None:
        """Block until every queued command has run (for tests and benchmarks)."""
        self.worker.wait_idle(timeout)

    @property
    def shown(self) -> Snapshot | None:
        """The snapshot on screen."""
        return self._shown

    def stop(self) -> None:
        self.worker.stop()
        self.plots.stop()
        if self.dense is not None:
            self.dense.stop()
        self.server.stop()


def _unused_note(snapshot: Snapshot) -> str:
    """What the 3D view draws for reference only under the shown variant (faint planes under
    -wo, thin faded lines under P), or "" where the optimizer uses everything drawn."""
    unused = [what for what, used in (("planes", snapshot.variant.uses_planes), ("lines", snapshot.variant.with_lines)) if not used]
    if not unused:
        return ""
    return f"*{snapshot.variant}: {' and '.join(unused)} are detected and drawn faint for reference; this variant's optimizer does not use them*"
