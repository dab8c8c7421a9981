"""The debugger on the stereo pipeline (the default of `coplanar serve`), as a user sees it:
the keyframe image panel with its features, the map and the report; the README's picture."""

from __future__ import annotations

import os
import pathlib

import numpy as np

from tests.browser.conftest import close_notifications, open_page, start_served, wait_shown


def test_stereo_debugger_shows_keyframe_image_and_map(browser, tmp_path) -> None:
    """Twelve keyframes of the rendered room; written to $COPLANAR_README_SCREENSHOT_STEREO
    when set (docs/stereo_debugger.png), else to a temporary file."""
    from PIL import Image

    debugger = start_served("--scene", "room", "--duration", "6")  # as `coplanar serve` builds it
    try:
        for _ in range(12):
            debugger.submit("step")
        debugger.wait_idle(timeout=180)
        snapshot = debugger.history[-1]
        page = open_page(browser, debugger, height=1250)
        wait_shown(page, f"{snapshot.keyframe} (PL-w)")
        page.get_by_role("tab", name="Keyframe").click()
        page.get_by_text(f"keyframe {snapshot.keyframe}: left image").first.wait_for()
        # The keyframe image is on the page (an <img> with a data URL, larger than the panel's blanks).
        sizes = page.locator("img").evaluate_all("els => els.map(e => e.naturalWidth * e.naturalHeight)")
        assert max(sizes) >= 752 * 480, sizes  # sent at full size (it was 376×240)
        page.get_by_role("tab", name="Report").click()
        page.get_by_text(f"{len(snapshot.planes)} planes").first.wait_for()
        page.get_by_role("tab", name="Keyframe").click()
        close_notifications(page)
        page.wait_for_timeout(1500)
        path = pathlib.Path(os.environ.get("COPLANAR_README_SCREENSHOT_STEREO", tmp_path / "stereo_debugger.png"))
        page.screenshot(path=str(path))
        rgb = np.asarray(Image.open(path).convert("RGB")).astype(int)
        assert rgb.shape[:2] == (1250, 1400)
        assert int(np.sum(rgb.max(axis=2) - rgb.min(axis=2) > 80)) > 5000  # coloured map and image, not a blank page
        page.close()
    finally:
        debugger.stop()
