"""The dense check in the debugger: the layer is built in the background when switched on,
drawn as a mesh, and says how far it lies from the true planes; the README's picture."""

from __future__ import annotations

import os
import pathlib
import time

from tests.browser.conftest import close_notifications, field, open_page, start_served, wait_shown


def test_dense_layer_builds_in_the_background_and_reports_its_distance(browser, tmp_path) -> None:
    debugger = start_served("--scene", "room", "--duration", "6")
    try:
        for _ in range(8):
            debugger.submit("step")
        debugger.wait_idle(timeout=180)
        snapshot = debugger.history[-1]
        page = open_page(browser, debugger, height=1000)
        wait_shown(page, f"{snapshot.keyframe} (PL-w)")
        field(page, "Dense mesh").click()
        page.get_by_text(f"dense mesh of keyframe {snapshot.keyframe}").first.wait_for()
        assert debugger.dense.built >= 1
        text = page.get_by_text(f"dense mesh of keyframe {snapshot.keyframe}").first.inner_text()
        assert "median distance to the true planes" in text
        # Stepping does not wait for it, and the layer follows the newest keyframe.
        t0 = time.monotonic()
        page.get_by_role("button", name="Step").click()
        wait_shown(page, f"{snapshot.keyframe + 1} (PL-w)")
        assert time.monotonic() - t0 < 30.0
        page.get_by_text(f"dense mesh of keyframe {snapshot.keyframe + 1}").first.wait_for()
        close_notifications(page)
        page.wait_for_timeout(1500)
        path = pathlib.Path(os.environ.get("COPLANAR_README_SCREENSHOT_DENSE", tmp_path / "dense_debugger.png"))
        page.screenshot(path=str(path))
        field(page, "Dense mesh").click()
        page.wait_for_timeout(300)
        page.close()
    finally:
        debugger.stop()
