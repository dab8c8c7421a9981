"""The Hessian tab's -wo | -r | -w comparison: kept per keyframe as the PNG the page is
sent, shown again when the user scrubs back, decoded only to be shown large."""

from __future__ import annotations

from collections.abc import Iterator

import numpy as np
import pytest

from backend.pipeline.sim_engine import SimEngine, SimSettings
from tests.viewer.raw_client import free_port
from viewer import images


@pytest.fixture
def compare_debugger() -> Iterator[object]:
    from viewer.app import Debugger, ViewerSettings

    d = Debugger(SimEngine(SimSettings(window=4, max_iterations=2)), port=free_port(), settings=ViewerSettings(compare=True))  # type: ignore[arg-type]
    d.server.scene.configure_environment_map(hdri=None)
    yield d
    d.stop()


def test_comparisons_are_kept_encoded_and_shown_again_when_scrubbing_back(compare_debugger) -> None:
    d = compare_debugger
    tab = d.hessian_tab
    d.submit("step")
    d.wait_idle()
    first = tab.compare_image._data
    structures = d.session.compare_hessians(d.shown.variant.family())  # kept: the same window's structures
    pixels = images.compare_image(structures)
    np.testing.assert_array_equal(images.decode_png(first), pixels)  # the page gets the same picture as before
    for _ in range(3):
        d.submit("step")
    d.wait_idle()
    assert tab.compare_image._data != first
    assert all(isinstance(png, bytes) for png in tab._compares.values()) and len(tab._compares) == 4
    assert max(len(png) for png in tab._compares.values()) < pixels.nbytes / 5
    d.submit("show", 0)  # scrubbed back: its comparison, as its step left it
    d.wait_idle()
    assert tab.compare_image._data == first
    assert "keyframe 0's window as its step left it" in tab.compare_note.content
