"""The debugger as a user drives it in the browser: step, switch the variant, scrub,
export PLY, two tabs, an error inside a step, and a screenshot of the scene."""

from __future__ import annotations

import io
import os
import pathlib
import re

import numpy as np

from tests.browser.conftest import close_notifications, field, open_page, start_debugger, wait_shown


def _saturated_pixels(png: bytes) -> int:
    """Pixels of clearly coloured map elements (grid and background are grey/white)."""
    from PIL import Image

    rgb = np.asarray(Image.open(io.BytesIO(png)).convert("RGB")).astype(int)
    return int(np.sum(rgb.max(axis=2) - rgb.min(axis=2) > 80))


def _legend(page) -> tuple[str, int, int]:
    """Variant, items and params of the Hessian legend (its tab in the left panel)."""
    page.get_by_role("tab", name="Hessian").click()
    text = page.get_by_text(re.compile(r"^P[L]?-(wo|r|w): H = JᵀJ of the window, \d+ items, \d+ params")).first.inner_text()
    m = re.match(r"(P[L]?-(?:wo|r|w)): H = JᵀJ of the window, (\d+) items, (\d+) params", text)
    assert m, text
    return m.group(1), int(m.group(2)), int(m.group(3))


def _image_sources(page) -> list[str]:
    return page.locator("img").evaluate_all("els => els.map(e => e.src)")


def test_step_switch_scrub_export(browser, debugger) -> None:
    from plyfile import PlyData

    page = open_page(browser, debugger)
    canvas = page.locator("canvas").first
    before = _saturated_pixels(canvas.screenshot())

    for k in range(12):
        page.get_by_role("button", name="Step").click()
        wait_shown(page, f"{k} (PL-w)")
    assert debugger.session.keyframes == 12

    # Switching the variant re-optimizes the current window at once: the legend's counts
    # drop from -wo to -w as the first issue's table says (planar features lose their
    # variables, one 3-dof plane each is added) and the Hessian image changes.
    field(page, "Variant").click()
    page.get_by_role("option", name="PL-wo", exact=True).click()
    wait_shown(page, "11 (PL-wo)")
    variant, items_wo, params_wo = _legend(page)
    assert variant == "PL-wo"
    assert (items_wo, params_wo) == (debugger.history[-1].report.items, debugger.history[-1].report.params)
    images_wo = _image_sources(page)
    field(page, "Variant").click()
    page.get_by_role("option", name="PL-w", exact=True).click()
    wait_shown(page, "11 (PL-w)")
    page.wait_for_function("old => [...document.querySelectorAll('img')].map(e => e.src).join() !== old", arg=",".join(images_wo))
    variant, items_w, params_w = _legend(page)
    snap = debugger.history[-1]
    assert variant == "PL-w" and (items_w, params_w) == (snap.report.items, snap.report.params)
    planes = snap.hessian.groups[3].items
    assert planes >= 1
    assert items_w < items_wo and params_w < params_wo
    assert snap.hessian.groups[0].items == 10  # the same window of cameras

    # Stepping continues with the new variant.
    page.get_by_role("button", name="Step").click()
    wait_shown(page, "12 (PL-w)")

    # Scrub back without re-running the engine.
    slider_input = field(page, "Keyframe")
    slider_input.fill("3")
    slider_input.press("Enter")
    wait_shown(page, "3 (PL-w)")
    assert debugger.session.keyframes == 13

    # Export the shown map: counts match the snapshot on screen (keyframe 3).
    shown = debugger.history[3]
    with page.expect_download() as download:
        page.get_by_role("button", name="Download map (PLY)").click()
    data = pathlib.Path(download.value.path()).read_bytes()
    assert data.startswith(b"ply\nformat binary_little_endian 1.0\n")
    ply = PlyData.read(io.BytesIO(data))
    hulls = [p for p in shown.planes if len(p.hull_world) >= 3]
    assert ply["vertex"].count == len(shown.points) + 2 * len(shown.lines) + sum(len(p.hull_world) for p in hulls)
    assert ply["edge"].count == len(shown.lines)
    assert ply["face"].count == len(hulls)
    assert "kf00003" in download.value.suggested_filename

    # The scene is drawn: coloured points, segments, planes and frustums appear.
    after = _saturated_pixels(canvas.screenshot())
    assert after > before + 2000, (before, after)
    page.close()


def test_two_tabs_stay_in_sync(browser, debugger) -> None:
    first = open_page(browser, debugger)
    second = open_page(browser, debugger)
    first.get_by_role("button", name="Step").click()
    wait_shown(first, "0 (PL-w)")
    wait_shown(second, "0 (PL-w)")
    second.get_by_role("button", name="Step").click()
    wait_shown(first, "1 (PL-w)")
    wait_shown(second, "1 (PL-w)")
    first.close()
    second.get_by_role("button", name="Step").click()
    wait_shown(second, "2 (PL-w)")
    assert len(debugger.server.get_clients()) == 1
    second.close()


def test_error_in_a_step_pauses_and_keeps_serving(browser, debugger, monkeypatch) -> None:
    page = open_page(browser, debugger)
    real_step = debugger.engine.step
    calls = {"n": 0}

    def failing_step():
        calls["n"] += 1
        if calls["n"] == 1:
            raise FloatingPointError("singular window")
        return real_step()

    monkeypatch.setattr(debugger.engine, "step", failing_step)
    page.get_by_role("button", name="Step").click()
    page.get_by_text(re.compile("error.*singular window")).wait_for()
    page.get_by_role("button", name="Step").click()
    wait_shown(page, "0 (PL-w)")
    page.close()


def test_readme_screenshot(browser, tmp_path) -> None:
    """The README's picture: 45 keyframes of sequence a with every layer on. Written to
    $COPLANAR_README_SCREENSHOT when set (docs/debugger.png), else to a temporary file."""
    from PIL import Image

    debugger = start_debugger()
    try:
        for _ in range(45):
            debugger.submit("step")
        debugger.wait_idle(timeout=120)
        page = open_page(browser, debugger, height=1250)
        wait_shown(page, "44 (PL-w)")
        page.get_by_role("tab", name="Hessian").click()
        close_notifications(page)
        page.wait_for_timeout(1500)
        path = pathlib.Path(os.environ.get("COPLANAR_README_SCREENSHOT", tmp_path / "debugger.png"))
        page.screenshot(path=str(path))
        image = np.asarray(Image.open(path).convert("RGB")).astype(int)
        assert image.shape[:2] == (1250, 1400)
        assert _saturated_pixels(path.read_bytes()) > 5000
        page.close()
    finally:
        debugger.stop()


def test_play_pause_layers_and_reset(browser, debugger) -> None:
    page = open_page(browser, debugger)
    play = field(page, "Play")
    play.check()
    shown = field(page, "Shown")
    shown.element_handle().wait_for_element_state("visible")
    page.wait_for_function("el => parseInt(el.value) >= 3", arg=shown.element_handle())  # playing steps on its own
    play.uncheck()
    page.wait_for_timeout(300)
    debugger.wait_idle()
    stopped_at = debugger.session.keyframes
    page.wait_for_timeout(1000)
    assert debugger.session.keyframes == stopped_at and debugger.engine.keyframes <= stopped_at + 1  # paused (one step computed ahead at most)

    # Layer toggles hide and show scene nodes for every client.
    field(page, "Points").uncheck()
    page.wait_for_timeout(300)
    assert debugger.scene.layers.points is False
    assert debugger.scene._handles["/map/points"].visible is False
    field(page, "Points").check()
    page.wait_for_timeout(200)
    assert debugger.scene._handles["/map/points"].visible is True

    page.get_by_role("button", name="Reset").click()
    page.get_by_text(re.compile("reset, press Step or Play")).wait_for()
    assert debugger.session.keyframes == 0 and len(debugger.history) == 0
    page.get_by_role("button", name="Step").click()
    wait_shown(page, "0 (PL-w)")
    page.close()
