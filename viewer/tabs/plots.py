"""The Plots tab: costs, iterations, errors and events over the kept keyframes (drawn in
the background by the debugger's plot thread)."""

from __future__ import annotations

import logging
import threading
import time
import traceback
from collections.abc import Callable

import viser

from backend.common.priority import lower_this_thread
from backend.pipeline.snapshot import Snapshot
from viewer import images
from viewer.plots import PlotCanvas
from viewer.settings import ViewerSettings
from viewer.tabs.base import Shown, TabActions

log = logging.getLogger(__name__)


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


PLOT_DEBOUNCE_S = 0.4  # plots are drawn once updates pause this long
PLOT_PLAY_PERIOD_S = 1.0  # and while playing, at most this often


class PlotDrawer:
    """Draws the plots into `image` on a thread of its own, off the engine's: once the
    worker has been idle for PLOT_DEBOUNCE_S and the step computed ahead (`ahead` set while
    it runs) is done (drawing takes 0.25-0.4 s of a shared CPU and holds the GIL: it must not
    slow a burst of steps, scrubbing or the step the next click takes), and while playing
    between two steps at most every PLOT_PLAY_PERIOD_S. The newest request wins. The thread
    runs at a lower OS priority (`backend.common.priority`, Linux), so that the engine and
    the browser come first."""

    def __init__(self, image: viser.GuiImageHandle, *, working: threading.Event, playing: threading.Event, worked_at: Callable[[], float], ahead: threading.Event) -> None:
        self.image = image
        self._working = working
        self._playing = playing
        self._worked_at = worked_at
        self._ahead = ahead
        self._request: tuple[list[Snapshot], int | None] | None = None
        self._event = threading.Event()
        self._drawing = threading.Event()
        self._stopped = threading.Event()
        self.updates = 0
        self._canvas = PlotCanvas()  # the figure kept between draws (used on the plot thread only)
        self._thread = threading.Thread(target=self._loop, name="coplanar-plots", daemon=True)
        self._thread.start()

    def request(self, series: list[Snapshot], current: int | None) -> None:
        self._request = (series, current)
        self._event.set()

    def _loop(self) -> None:
        lower_this_thread()  # drawing (0.25-0.4 s of CPU) yields to the engine's step and the browser
        last_draw = 0.0
        while not self._stopped.is_set():
            if not self._event.wait(timeout=0.5):
                continue
            now = time.monotonic()
            idle = not self._working.is_set() and not self._ahead.is_set() and now - self._worked_at() >= PLOT_DEBOUNCE_S
            due = self._playing.is_set() and not self._working.is_set() and now - last_draw >= PLOT_PLAY_PERIOD_S
            if not (idle or due):
                time.sleep(0.05)
                continue
            self._drawing.set()
            self._event.clear()
            request, self._request = self._request, None
            try:
                if request is not None and request[0]:
                    self.image.image = self._canvas.image(request[0], current=request[1])
                    self.updates += 1
            except Exception:  # a plot must never stop the debugger
                log.error("plot error:\n%s", traceback.format_exc())
            finally:
                self._drawing.clear()
            last_draw = time.monotonic()

    def wait(self, timeout: float = 30.0) -> None:
        """Block until the plots show the latest request (for tests and benchmarks)."""
        deadline = time.monotonic() + timeout
        while self._request is not None or self._event.is_set() or self._drawing.is_set():
            if time.monotonic() > deadline:
                raise TimeoutError("the plots were not drawn")
            time.sleep(0.01)

    def stop(self) -> None:
        self._stopped.set()
        self._event.set()
        self._thread.join(timeout=5.0)
