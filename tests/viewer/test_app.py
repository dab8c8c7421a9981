"""The debugger's keyframe-image panel, without a browser: the GUI handles' state after
steps and scrubbing, over the Monte-Carlo engine and over an engine whose snapshots carry
an image (as the stereo pipeline's do)."""

from __future__ import annotations

import dataclasses
import socket
from collections.abc import Iterator

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
            points_uv=np.array([[10.0 + 10.0 * k, 60.0]]), point_status=np.array([POINT_TRACKED], np.uint8),
            segments_uv=np.zeros((0, 2, 2)), segment_plane=np.zeros(0, np.int64),
            instance_labels=None, instance_plane=None,
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


def test_keyframe_image_is_shown_and_follows_scrubbing(image_debugger) -> None:  # noqa: ANN001
    d = image_debugger
    assert not d.image_folder.visible  # nothing shown yet
    for _ in range(3):
        d.submit("step")
    d.wait_idle()
    newest = d.history[-1]
    assert newest.keyframe == 2 and newest.image is not None
    assert d.image_folder.visible
    shown = d.keyframe_image.image
    assert shown.shape == (H, W, 3)
    np.testing.assert_array_equal(shown, decode_keyframe_image(newest.image))
    assert _green_column(shown) == 30
    assert "2 lost" in d.tracking_text.content and "302 points" in d.tracking_text.content
    assert "tracking lost at frame 2: re-initialized" in d.status.content
    assert "tracking lost at frame 2: re-initialized" in d.report.content

    # Scrubbing back shows the older snapshot's image and message.
    d.submit("show", 0)
    d.wait_idle()
    assert d.image_folder.visible
    np.testing.assert_array_equal(d.keyframe_image.image, decode_keyframe_image(d.history[0].image))
    assert _green_column(d.keyframe_image.image) == 10
    assert "0 lost" in d.tracking_text.content
    assert "tracking lost at frame 0" in d.report.content


def test_keyframe_image_is_hidden_for_the_monte_carlo_engine(sim_debugger) -> None:  # noqa: ANN001
    d = sim_debugger
    d.submit("step")
    d.wait_idle()
    assert d.history[-1].image is None and d.history[-1].tracking is None
    assert not d.image_folder.visible
    assert "**tracking**" not in d.report.content


def test_keyframe_image_hides_again_for_a_snapshot_without_one(image_debugger) -> None:  # noqa: ANN001
    d = image_debugger
    d.submit("step")
    d.wait_idle()
    assert d.image_folder.visible
    # A later snapshot without an image (e.g. from another engine) hides the panel.
    plain = dataclasses.replace(d.history[-1], image=None, tracking=None, message="")
    d._show(plain)
    assert not d.image_folder.visible
    assert "tracking lost" not in d.report.content
