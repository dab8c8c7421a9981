"""The debugger's keyframe-image panel, without a browser: the GUI handles' state after
steps and scrubbing, over the Monte-Carlo engine and over an engine whose snapshots carry
an image (as the stereo pipeline's do)."""

from __future__ import annotations

import dataclasses
import socket
from collections.abc import Iterator

import cv2
import numpy as np
import pytest

from backend.optim.structure import HessianStructure
from backend.pipeline.overlay import POINT_TRACKED, decode_keyframe_image, draw_keyframe_image
from backend.pipeline.sim_engine import SimEngine, SimSettings
from backend.pipeline.snapshot import Snapshot, Tracking

H, W = 120, 188


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


class ImageEngine:
    """The Monte-Carlo engine with an image, tracking figures and a message added to each
    snapshot: keyframe k's image has a green point at u = 10 + 10 k, so snapshots differ."""

    def __init__(self) -> None:
        self.inner = SimEngine(SimSettings(window=4, max_iterations=2))

    @property
    def source(self) -> str:
        return "image test"

    @property
    def variant(self) -> str:
        return self.inner.variant

    def _decorate(self, s: Snapshot) -> Snapshot:
        k = s.keyframe
        image = draw_keyframe_image(
            np.full((H, W), 100, np.uint8),
            points_uv=np.array([[10.0 + 10.0 * k, 60.0]]),
            point_status=np.array([POINT_TRACKED], np.uint8),
            segments_uv=np.zeros((0, 2, 2)),
            segment_plane=np.zeros(0, np.int64),
            instance_labels=None,
            instance_plane=None,
        )
        tracking = Tracking(frames=20 + k, lost_frames=k, reinitializations=1, tracked_points=300 + k, tracked_lines=40)
        return dataclasses.replace(s, image=image, tracking=tracking, message=f"tracking lost at frame {k}: re-initialized")

    def step(self) -> Snapshot:
        return self._decorate(self.inner.step())

    def reoptimize(self) -> Snapshot:
        return self._decorate(self.inner.reoptimize())

    def set_variant(self, name: str) -> None:
        self.inner.set_variant(name)

    def reset(self) -> None:
        self.inner.reset()

    def compare_hessians(self, variants: tuple[str, ...]) -> dict[str, HessianStructure]:
        return self.inner.compare_hessians(variants)


def _debugger(engine: object) -> object:
    from viewer.app import Debugger, ViewerSettings

    d = Debugger(engine, port=_free_port(), settings=ViewerSettings(compare=False))  # type: ignore[arg-type]
    d.server.scene.configure_environment_map(hdri=None)
    return d


@pytest.fixture
def image_debugger() -> Iterator[object]:
    d = _debugger(ImageEngine())
    yield d
    d.stop()


@pytest.fixture
def sim_debugger() -> Iterator[object]:
    d = _debugger(SimEngine(SimSettings(window=4, max_iterations=2)))
    yield d
    d.stop()


def _green_column(rgb: np.ndarray) -> int:
    """Column of the green point's centre on row 60."""
    row = rgb[60].astype(int)
    return int(round(np.flatnonzero(row[:, 1] - row[:, 0] > 60).mean()))


def _sent_image(handle) -> np.ndarray:
    """The image a handle sends to the page (its encoded bytes, decoded to RGB)."""
    rgb = cv2.imdecode(np.frombuffer(handle._data, np.uint8), cv2.IMREAD_COLOR)
    return cv2.cvtColor(rgb, cv2.COLOR_BGR2RGB)


def test_keyframe_image_is_shown_and_follows_scrubbing(image_debugger) -> None:
    d = image_debugger
    assert not d.keyframe_tab.image.visible  # nothing shown yet
    for _ in range(3):
        d.submit("step")
    d.wait_idle()
    newest = d.history[-1]
    assert newest.keyframe == 2 and newest.image is not None
    assert d.keyframe_tab.image.visible
    assert d.keyframe_tab.image._data == newest.image.jpeg  # the snapshot's JPEG, not decoded and encoded again
    shown = _sent_image(d.keyframe_tab.image)
    assert shown.shape == (H, W, 3)
    np.testing.assert_array_equal(shown, decode_keyframe_image(newest.image))
    assert _green_column(shown) == 30
    assert "2 lost" in d.keyframe_tab.tracking_text.content and "302 points" in d.keyframe_tab.tracking_text.content
    assert "tracking lost at frame 2: re-initialized" in d.status.content
    assert "tracking lost at frame 2: re-initialized" in d.report_tab.markdown.content

    # Scrubbing back shows the older snapshot's image and message.
    d.submit("show", 0)
    d.wait_idle()
    assert d.keyframe_tab.image.visible
    np.testing.assert_array_equal(_sent_image(d.keyframe_tab.image), decode_keyframe_image(d.history[0].image))
    assert _green_column(_sent_image(d.keyframe_tab.image)) == 10
    assert "0 lost" in d.keyframe_tab.tracking_text.content
    assert "tracking lost at frame 0" in d.report_tab.markdown.content


def test_hessian_image_follows_scrubbing_and_is_encoded_once(sim_debugger) -> None:
    from viewer import images

    d = sim_debugger
    for _ in range(3):
        d.submit("step")
    d.wait_idle()
    newest_png = d.hessian_tab.image._data
    np.testing.assert_array_equal(_sent_image(d.hessian_tab.image), images.hessian_image(d.history[-1].hessian))
    d.submit("show", 0)
    d.wait_idle()
    np.testing.assert_array_equal(_sent_image(d.hessian_tab.image), images.hessian_image(d.history[0].hessian))
    d.submit("show", 2)
    d.wait_idle()
    assert d.hessian_tab.image._data is newest_png  # shown again from the kept PNG, not rendered anew


def test_keyframe_image_is_hidden_for_the_monte_carlo_engine(sim_debugger) -> None:
    d = sim_debugger
    d.submit("step")
    d.wait_idle()
    assert d.history[-1].image is None and d.history[-1].tracking is None
    assert not d.keyframe_tab.image.visible
    assert "**tracking**" not in d.report_tab.markdown.content


def test_keyframe_image_hides_again_for_a_snapshot_without_one(image_debugger) -> None:
    d = image_debugger
    d.submit("step")
    d.wait_idle()
    assert d.keyframe_tab.image.visible
    # A later snapshot without an image (e.g. from another engine) hides the panel.
    plain = dataclasses.replace(d.history[-1], image=None, tracking=None, message="")
    d._show(plain)
    assert not d.keyframe_tab.image.visible
    assert "tracking lost" not in d.report_tab.markdown.content


def test_switching_variants_keeps_each_result_and_returns_to_it(sim_debugger) -> None:
    """Cycle the six variants at the newest keyframe and return: every variant started
    from the step's state, the stepped result comes back unchanged, and scrubbing back
    to that keyframe later still shows any variant computed there."""
    from backend.optim.variant import VARIANTS

    d = sim_debugger
    for _ in range(8):
        d.submit("step")
    d.wait_idle()
    stepped = d.shown
    k = stepped.keyframe
    initial_costs = {}
    for v in VARIANTS:
        d.submit("variant", v)
        d.wait_idle()
        assert d.shown.keyframe == k and d.shown.variant == v
        initial_costs[v] = d.shown.report.initial_cost
    d.submit("variant", "PL-w")
    d.wait_idle()
    assert d.shown is stepped  # the kept snapshot, not a re-optimization of a changed state
    assert (d.shown.report.items, d.shown.report.params) == (stepped.report.items, stepped.report.params)
    assert set(d.history.variants_at(k)) == set(VARIANTS)
    # The same start for every variant of one family: the state the step left.
    assert initial_costs["P-wo"] == pytest.approx(initial_costs["P-r"], rel=0.2)
    assert "P-wo" in d.variants_tab.text.content and "◀ shown" in d.variants_tab.text.content
    # Step on with PL-r, scrub back: keyframe k shows PL-r's snapshot from before.
    d.submit("variant", "PL-r")
    d.submit("step")
    d.wait_idle()
    assert d.shown.keyframe == k + 1 and d.shown.variant == "PL-r"
    d.submit("show", k)
    d.wait_idle()
    assert d.shown.keyframe == k and d.shown.variant == "PL-r"
    assert d.shown is d.history.variants_at(k)["PL-r"]


def test_status_is_not_overwritten_by_a_late_progress_message(sim_debugger, monkeypatch) -> None:
    """The progress message (after PROGRESS_DELAY_S) must never land after the final
    status: with the delay at 1 ms and slowed re-optimizations, 20 switches end with the
    real status each time."""
    import time as _time

    import viewer.status as status_module

    d = sim_debugger
    d.submit("step")
    d.wait_idle()
    monkeypatch.setattr(status_module, "PROGRESS_DELAY_S", 0.001)
    real = d.engine.reoptimize

    def slow():
        _time.sleep(0.01)
        return real()

    monkeypatch.setattr(d.engine, "reoptimize", slow)
    for i in range(20):
        v = ("PL-r", "P-wo", "P-r", "PL-wo")[i % 4]
        d.submit("variant", v)
        d.wait_idle()
        _time.sleep(0.02)
        assert "re-optimizing" not in d.status.content, d.status.content
        assert f"keyframe 0 · {v}" in d.status.content
        assert not d.progress.visible


def test_reset_clears_what_is_shown(image_debugger) -> None:
    d = image_debugger
    for _ in range(3):
        d.submit("step")
    d.wait_idle()
    assert d.scene._handles and d.keyframe_tab.image.visible and d.report_tab.markdown.content
    d.submit("reset")
    d.wait_idle()
    assert d.shown is None and not d.history
    assert d.scene._handles == {}
    assert d.keyframe_label.value == "none"
    assert not d.keyframe_tab.image.visible and d.report_tab.markdown.content == "" and d.variants_tab.text.content == "no keyframe yet"
    assert d.slider.disabled
    assert "reset, press Step or Play" in d.status.content


def test_ab_run_steps_both_engines_and_reports_the_difference(sim_debugger) -> None:
    d = sim_debugger
    for _ in range(3):
        d.submit("step")
    d.submit("ab", "P-wo")
    for _ in range(2):
        d.submit("step")
    d.wait_idle()
    a, b = d.shown, d.history_b[d.shown.keyframe]
    assert a.variant == "PL-w" and b.variant == "P-wo" and a.keyframe == b.keyframe == 4
    assert d.session.keyframes == 5 and d.engine_b.keyframes == d.engine.keyframes  # in lockstep (while idle both are a step ahead)
    assert "/ab/trajectory" in d.scene._handles
    assert "A: PL-w" in d.variants_tab.ab_text.content and "B: P-wo" in d.variants_tab.ab_text.content and "same frame" in d.variants_tab.ab_text.content
    d.submit("ab", "off")
    d.wait_idle()
    assert d.engine_b is None and "/ab/trajectory" not in d.scene._handles


def test_plots_follow_the_shown_keyframe(sim_debugger) -> None:
    d = sim_debugger
    for _ in range(6):
        d.submit("step")
    d.wait_idle()

    def settled() -> np.ndarray:
        d.wait_plots()
        return np.asarray(d.plots_tab.image.image).copy()

    newest = settled()
    assert newest.shape[0] > 300 and d.plot_updates >= 1
    d.submit("show", 1)
    d.wait_idle()
    older = settled()
    assert older.shape == newest.shape and np.any(older != newest)  # the marker moved


def test_a_progress_message_that_fires_after_the_final_status_is_dropped(sim_debugger) -> None:
    """The race behind a stale status: the progress timer's callback runs after the work
    wrote its final status but before the worker went idle."""
    d = sim_debugger
    d._busy("re-optimizing the window with PL-r …")
    late = d.status_line.timer.function
    d.status_line.timer.cancel()
    d._set_status("**done**: keyframe 3 · PL-r")
    late()  # the timer thread wins the race
    assert d.status.content == "**done**: keyframe 3 · PL-r"
    assert not d.progress.visible
    d._idle()


def test_playing_shows_the_rate_achieved(sim_debugger) -> None:
    import time as _time

    d = sim_debugger
    d.rate.value = 30.0  # asked for more than the engine may give
    d.play.value = True
    d._playing.set()
    d.submit("wake")
    deadline = _time.monotonic() + 20
    while "keyframes/s" not in d.achieved.value and _time.monotonic() < deadline:
        _time.sleep(0.05)
    shown = d.achieved.value
    d.play.value = False
    d._playing.clear()
    d.wait_idle()
    assert shown.endswith("keyframes/s (asked 30)"), shown
    assert 0.0 < float(shown.split()[0]) < 1000.0


def test_the_segmenter_can_be_switched_in_the_debugger() -> None:
    from app.cli import build_parser
    from app.serve_command import build_engine
    from backend.frontend.segmentation_learned import LearnedSegmenter

    engine = build_engine(build_parser().parse_args(["serve", "--scene", "room", "--duration", "2"]))
    d = _debugger(engine)
    try:
        assert d.segmenter is not None and d.segmenter.value == "geometric"
        d.submit("segmenter", "learned")
        d.submit("step")
        d.wait_idle(timeout=120)
        assert isinstance(engine.segmenter, LearnedSegmenter)
        assert d.shown is not None and d.shown.image is not None
        assert d.shown.detection.instance  # the learned instances reached the co-planar detection
    finally:
        d.stop()


def test_ab_run_is_refused_for_an_engine_without_checkpoints(image_debugger) -> None:
    d = image_debugger
    d.submit("step")
    d.submit("ab", "P-w")
    d.wait_idle()
    assert d.engine_b is None and d.ab_variant.value == "off"
    assert "cannot be copied" in d.status.content


def _page_chooses(d, name: str, *, age_s: float = 0.0) -> None:
    """What viser does first when a page chooses `name` in the Variant menu: the menu's value
    set (its callback, which reads it, runs later on viser's thread pool)."""
    import time

    d.variant._impl.value = name
    d.variant._impl.update_timestamp = time.time() - age_s


def _callback_runs(d) -> None:
    """viser's thread pool runs the Variant menu's callback for a page's choice."""
    import viser

    d.controls._variant_chosen(viser.GuiEvent(client=object(), client_id=1, target=d.variant))  # type: ignore[arg-type]


def test_a_variant_chosen_while_another_tab_plays_is_not_lost(sim_debugger) -> None:
    """A keyframe shown between a page's choice and its callback (another tab playing) leaves
    the choice in the menu, and the callback asks for it, not for the variant shown."""
    d = sim_debugger
    for _ in range(3):
        d.submit("step")
    d.wait_idle()
    assert d.shown.variant == "PL-w"
    _page_chooses(d, "P-r")
    d.submit("step")  # shown before the callback has run
    d.wait_idle()
    assert d.shown.variant == "PL-w" and d.variant.value == "P-r"
    _callback_runs(d)
    d.wait_idle()
    assert (d.shown.keyframe, d.shown.variant) == (3, "P-r")
    assert d.variant.value == "P-r"
    d.submit("step")  # the run goes on with the choice; the menu follows what is shown again
    d.wait_idle()
    assert d.shown.variant == "P-r" and d.variant.value == "P-r"


def _page_scrubs(d, keyframe: int) -> None:
    """What viser does first when a page moves the Keyframe slider: its value set (the
    callback, which reads it, runs later on viser's thread pool)."""
    import time

    d.slider._impl.value = keyframe
    d.slider._impl.update_timestamp = time.time()


def _slider_callback_runs(d) -> None:
    import viser

    d.controls._slider_moved(viser.GuiEvent(client=object(), client_id=1, target=d.slider))  # type: ignore[arg-type]


def test_a_scrub_while_a_step_is_shown_is_not_lost(sim_debugger) -> None:
    """A page scrubs back while playing; a keyframe stepped before the slider's callback has
    run leaves the slider where the user put it, and the callback shows that keyframe
    (without the guard, the callback read the newest keyframe and the scrub was lost)."""
    d = sim_debugger
    for _ in range(4):
        d.submit("step")
    d.wait_idle()
    assert d.shown.keyframe == 3 and d.slider.value == 3
    _page_scrubs(d, 1)
    d.submit("step")  # Play's next keyframe, shown before the callback has run
    d.wait_idle()
    assert d.shown.keyframe == 4 and d.slider.value == 1 and d.slider.max == 4
    _slider_callback_runs(d)
    d.wait_idle()
    assert d.shown.keyframe == 1 and d.slider.value == 1
    d.submit("step")  # the next step moves the slider to the newest again
    d.wait_idle()
    assert d.shown.keyframe == 5 and d.slider.value == 5


def test_reset_moves_a_scrubbed_slider_back(sim_debugger) -> None:
    d = sim_debugger
    for _ in range(3):
        d.submit("step")
    d.wait_idle()
    _page_scrubs(d, 1)
    d.submit("reset")
    d.wait_idle()
    assert d.slider.value == 0 and d.slider.disabled
    d.submit("step")
    d.wait_idle()
    assert d.shown.keyframe == 0 and d.slider.value == 0


def test_a_choice_whose_callback_never_ran_does_not_hold_the_menu(sim_debugger) -> None:
    from viewer.page_choice import UNREAD_CHOICE_S

    d = sim_debugger
    d.submit("step")
    d.wait_idle()
    _page_chooses(d, "P-r", age_s=UNREAD_CHOICE_S + 1.0)  # its page closed before the callback
    d.submit("step")
    d.wait_idle()
    assert d.shown.variant == "PL-w" and d.variant.value == "PL-w"
