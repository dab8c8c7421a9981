"""The debugger: a viser server that drives an engine one keyframe at a time.

All engine calls run on one worker thread, fed by a command queue, so GUI callbacks never
block and never race. The GUI and scene are server-wide: every open tab shows the same
state. Snapshots are kept (up to `history`) and the keyframe slider scrubs through them
without touching the engine.
"""

from __future__ import annotations

import collections
import dataclasses
import logging
import queue
import threading
import time
import traceback
from collections.abc import Callable

import viser

from backend.export.ply import snapshot_ply_bytes
from backend.optim.problem import VARIANTS, parse_variant
from backend.pipeline.engine import Engine, EndOfSequence
from backend.pipeline.snapshot import Snapshot
from viewer import images
from viewer.scene import SceneView

log = logging.getLogger(__name__)
PROGRESS_DELAY_S = 0.3


@dataclasses.dataclass(frozen=True)
class ViewerSettings:
    """`history`: snapshots kept for scrubbing (oldest dropped first). `rate_hz`: default
    Play rate. `compare`: compute the -wo | -r | -w comparison after each step."""

    history: int = 500
    rate_hz: float = 5.0
    compare: bool = True


def _report_markdown(s: Snapshot) -> str:
    r = s.report
    t = r.timing_ms
    stages = " · ".join(f"{k} {v:.1f}" for k, v in t.items())
    det = s.detection
    rows = "\n".join(
        f"| {q} | {c} | {i} ({100.0 * i / max(c, 1):.0f}%) | {'accepted → plane ' + str(p) if a else 'rejected'} |"
        for q, c, i, a, p in zip(det.instance, det.candidates, det.inliers, det.accepted, det.plane)
    )
    detection = f"| instance | candidates | consensus | result |\n|---|---|---|---|\n{rows}" if rows else "no candidate set reached the size threshold"
    notes = f"**{s.message}**\n\n" if s.message else ""
    if s.tracking is not None and s.image is None:  # otherwise shown beside the image
        notes += images.tracking_markdown(s.tracking) + "\n\n"
    return (
        f"**keyframe {s.keyframe}** · {r.variant} · window {r.window} + {r.fixed_poses} fixed\n\n"
        f"{notes}"
        f"iterations {r.iterations} ({r.termination or ('converged' if r.converged else 'not converged')}"
        f"{f'; {r.dropped_landmarks} landmarks left out of a step' if r.dropped_landmarks else ''}) · "
        f"cost {r.initial_cost:.4g} → {r.final_cost:.4g}\n\n"
        f"time (ms): {stages}\n\n"
        f"**trajectory error**: RMSE {s.metrics.rmse_cm:.2f} cm · ATE (SE3) {s.metrics.ate_cm:.2f} cm\n\n"
        f"**map**: {len(s.points)} points · {len(s.lines)} lines · {len(s.planes)} planes\n\n"
        f"**co-planar detection** (θ_cp = 80 %)\n\n{detection}"
    )


class Debugger:
    """Serve `engine` on `host:port` until :meth:`stop`."""

    def __init__(self, engine: Engine, *, host: str = "127.0.0.1", port: int = 8080, settings: ViewerSettings = ViewerSettings()) -> None:
        self.engine = engine
        self.settings = settings
        self.server = viser.ViserServer(host=host, port=port, label="coplanar")
        self.port = self.server.get_port()
        self.history: collections.deque[Snapshot] = collections.deque(maxlen=settings.history)
        self._shown: Snapshot | None = None
        self._commands: queue.Queue[tuple[str, object]] = queue.Queue()
        self._playing = threading.Event()
        self._stopped = threading.Event()
        self.busy = threading.Event()
        self._progress_timer: threading.Timer | None = None
        self.steps_done = 0
        self.scene = SceneView(self.server)
        self._build_gui()
        self._worker = threading.Thread(target=self._run, name="coplanar-engine", daemon=True)
        self._worker.start()

    # ------------------------------------------------------------------ GUI

    def _build_gui(self) -> None:
        gui = self.server.gui
        gui.configure_theme(control_width="large", show_share_button=False)
        self.status = gui.add_markdown(f"**{self.engine.source}**: ready, press Step or Play")
        self.progress = gui.add_progress_bar(100.0, animated=True, visible=False)
        with gui.add_folder("Run"):
            self.variant = gui.add_dropdown("Variant", VARIANTS, initial_value=self.engine.variant)
            self.step_button = gui.add_button("Step")
            self.play = gui.add_checkbox("Play", initial_value=False)
            self.rate = gui.add_slider("Rate (Hz)", min=0.5, max=30.0, step=0.5, initial_value=self.settings.rate_hz)
            self.reset_button = gui.add_button("Reset")
            self.slider = gui.add_slider("Keyframe", min=0, max=1, step=1, initial_value=0, disabled=True)
            self.keyframe_label = gui.add_text("Shown", initial_value="none", disabled=True)
        with gui.add_folder("Keyframe image", visible=False) as self.image_folder:
            self.keyframe_image = gui.add_image(images.blank(), label="left image", format="jpeg", jpeg_quality=90)
            self.tracking_text = gui.add_markdown("")
            self.image_legend = gui.add_markdown(images.KEYFRAME_LEGEND)
        with gui.add_folder("Hessian"):
            self.hessian_legend = gui.add_markdown("no window optimized yet")
            self.hessian_image = gui.add_image(images.blank(), label="H = J^T J of the window", format="png")
            self.compare_box = gui.add_checkbox("Compare -wo | -r | -w", initial_value=self.settings.compare)
            self.compare_image = gui.add_image(images.blank(), label="newest window under -wo | -r | -w", format="png")
        with gui.add_folder("Report"):
            self.report = gui.add_markdown("")

        with gui.add_folder("Layers"):
            self.layer_boxes = {
                name: gui.add_checkbox(label, initial_value=getattr(self.scene.layers, name))
                for name, label in (
                    ("cameras", "Cameras"), ("points", "Points"), ("lines", "Lines"), ("planes", "Planes"),
                    ("infinite_planes", "Infinite planes"), ("inliers", "RANSAC in/outliers"), ("ground_truth", "Ground truth"),
                )
            }
        with gui.add_folder("Export"):
            self.export_button = gui.add_button("Download map (PLY)")
        self.step_button.on_click(lambda _: self._commands.put(("step", None)))
        self.reset_button.on_click(lambda _: self._commands.put(("reset", None)))

        @self.variant.on_update
        def _(event: viser.GuiEvent) -> None:
            if event.client is not None:
                self._commands.put(("variant", self.variant.value))

        @self.play.on_update
        def _(event: viser.GuiEvent) -> None:
            if self.play.value:
                self._playing.set()
                self._commands.put(("wake", None))
            else:
                self._playing.clear()

        @self.slider.on_update
        def _(event: viser.GuiEvent) -> None:
            if event.client is not None:  # a user scrubs: stop playing, or the next step jumps back
                if self.play.value:
                    self.play.value = False
                self._commands.put(("show", int(self.slider.value)))

        for name, box in self.layer_boxes.items():
            box.on_update(self._layer_callback(name, box))

        @self.export_button.on_click
        def _(event: viser.GuiEvent) -> None:
            snapshot = self._shown
            if snapshot is None or event.client is None:
                return
            data = snapshot_ply_bytes(snapshot)
            event.client.send_file_download(f"coplanar_map_kf{snapshot.keyframe:05d}_{snapshot.variant}.ply", data, save_immediately=True)

        self.compare_box.on_update(lambda _: self._commands.put(("compare", None)))

    def _layer_callback(self, name: str, box: viser.GuiCheckboxHandle) -> Callable[[viser.GuiEvent], None]:
        def callback(_: viser.GuiEvent) -> None:
            with self.server.atomic():
                self.scene.set_layer(name, bool(box.value))

        return callback

    # ------------------------------------------------------------------ worker

    def _run(self) -> None:
        while not self._stopped.is_set():
            try:
                timeout = 1.0 / max(self.rate.value, 1e-3) if self._playing.is_set() else None
                command, arg = self._commands.get(timeout=timeout)
                from_timer = False
            except queue.Empty:
                command, arg = ("step", None) if self._playing.is_set() else ("wake", None)
                from_timer = True
            if command == "stop":
                return
            try:
                self._execute(command, arg)
            except Exception as exc:  # an error in a step pauses the run, the server stays up
                log.error("engine error:\n%s", traceback.format_exc())
                self._playing.clear()
                self.play.value = False
                self.status.content = f"**error** in {command}: `{type(exc).__name__}: {exc}`. Paused; fix or Reset."
            finally:
                self._idle()
                if not from_timer:
                    self._commands.task_done()

    def _busy(self, text: str) -> None:
        """Mark the worker busy; `text` and the progress bar appear only if the work takes
        longer than PROGRESS_DELAY_S (a quick step should not repaint the panel twice)."""
        self.busy.set()

        def show() -> None:
            if self.busy.is_set():
                self.status.content = text
                self.progress.visible = True

        self._progress_timer = threading.Timer(PROGRESS_DELAY_S, show)
        self._progress_timer.daemon = True
        self._progress_timer.start()

    def _idle(self) -> None:
        self.busy.clear()
        if self._progress_timer is not None:
            self._progress_timer.cancel()
            self._progress_timer = None
        if self.progress.visible:
            self.progress.visible = False

    def _execute(self, command: str, arg: object) -> None:
        if command == "step":
            self._busy(f"stepping: keyframe {len(self.history) and self.history[-1].keyframe + 1} …")
            try:
                snapshot = self.engine.step()
            except EndOfSequence as end:
                self._playing.clear()
                self.play.value = False
                self.status.content = f"**end of sequence**: {end}"
                return
            self.steps_done += 1
            self._publish(snapshot)
        elif command == "variant":
            name = str(arg)
            parse_variant(name)
            self.engine.set_variant(name)
            if self.history:
                self._busy(f"re-optimizing the window with {name} …")
                snapshot = self.engine.reoptimize()
                self.history.pop()
                self._publish(snapshot)
            else:
                self.status.content = f"variant {name}: used from the first step"
        elif command == "reset":
            self._busy("resetting …")
            self.engine.reset()
            self.history.clear()
            self._shown = None
            self.slider.disabled = True
            self.status.content = f"**{self.engine.source}**: reset, press Step or Play"
        elif command == "show":
            index = int(arg) - (self.history[0].keyframe if self.history else 0)
            if 0 <= index < len(self.history):
                self._show(self.history[index])
        elif command == "compare":
            self._update_compare()

    def _publish(self, snapshot: Snapshot) -> None:
        """Keep a new snapshot and show it; then the slider follows the newest keyframe."""
        self.history.append(snapshot)
        self._show(snapshot)
        first = self.history[0].keyframe
        with self.server.atomic():
            self.slider.disabled = len(self.history) < 2
            self.slider.max = max(snapshot.keyframe, first + 1)
            self.slider.min = first
            self.slider.value = snapshot.keyframe
            self.status.content = (
                f"**{self.engine.source}**: keyframe {snapshot.keyframe} · {snapshot.variant}"
                + (" · playing" if self._playing.is_set() else "")
                + (f"\n\n**{snapshot.message}**" if snapshot.message else "")
            )
        self._update_compare()

    def _show(self, snapshot: Snapshot) -> None:
        """Draw a snapshot: the scene first (its label last, so a client that sees the label
        has the whole scene), then the panels, which cost more to encode."""
        with self.server.atomic():
            self.scene.draw(snapshot)
            self.keyframe_label.value = f"{snapshot.keyframe} ({snapshot.variant})"
        self.server.flush()
        self._shown = snapshot
        with self.server.atomic():
            if self.variant.value != snapshot.variant:
                self.variant.value = snapshot.variant
            if snapshot.image is not None:
                self.keyframe_image.image = images.keyframe_image(snapshot.image)
                self.keyframe_image.label = f"keyframe {snapshot.keyframe}: left image"
                self.tracking_text.content = images.tracking_markdown(snapshot.tracking)
            if self.image_folder.visible != (snapshot.image is not None):
                self.image_folder.visible = snapshot.image is not None
            if snapshot.hessian is not None:
                self.hessian_image.image = images.hessian_image(snapshot.hessian)
                self.hessian_legend.content = images.legend_markdown(snapshot.hessian)
            self.report.content = _report_markdown(snapshot)
        self.server.flush()

    def _update_compare(self) -> None:
        self.compare_image.visible = bool(self.compare_box.value)
        if not self.compare_box.value or not self.history:
            return
        with_lines, _ = parse_variant(self.engine.variant)
        family = ("PL-wo", "PL-r", "PL-w") if with_lines else ("P-wo", "P-r", "P-w")
        structures = self.engine.compare_hessians(family)
        if structures:
            self.compare_image.image = images.compare_image(structures)

    # ------------------------------------------------------------------ control

    def submit(self, command: str, arg: object = None) -> None:
        """Queue a command as the GUI would ("step", "reset", "variant", "show")."""
        self._commands.put((command, arg))

    def wait_idle(self, timeout: float = 60.0) -> None:
        """Block until every queued command has run (for tests and benchmarks)."""
        deadline = time.monotonic() + timeout
        while self._commands.unfinished_tasks:
            if time.monotonic() > deadline:
                raise TimeoutError("the engine did not become idle")
            time.sleep(0.005)

    def stop(self) -> None:
        self._stopped.set()
        self._playing.clear()
        self._commands.put(("stop", None))
        self._worker.join(timeout=10.0)
        self.server.stop()
