"""The debugger's second round, as a user meets it in the browser: variants kept per
keyframe, a status line that tells the truth, Reset and Export, a first view that frames
the map, the A/B run, plots over time and keyboard shortcuts."""

from __future__ import annotations

import io
import os
import pathlib
import re

import numpy as np

from tests.browser.conftest import close_notifications, field, open_page, start_debugger, wait_shown
from viewer.framing import snapshot_bounds


def _choose(page, label: str, option: str) -> None:
    field(page, label).click()
    page.get_by_role("option", name=option, exact=True).click()


def _coloured(png: bytes, *, magenta: bool = False) -> int:
    from PIL import Image

    rgb = np.asarray(Image.open(io.BytesIO(png)).convert("RGB")).astype(int)
    if magenta:
        return int(np.sum((rgb[..., 0] > 150) & (rgb[..., 2] > 150) & (rgb[..., 1] < 90)))
    return int(np.sum(rgb.max(axis=2) - rgb.min(axis=2) > 80))


def test_variants_are_kept_per_keyframe_and_the_status_stays_true(browser, debugger) -> None:
    page = open_page(browser, debugger)
    for k in range(12):
        page.get_by_role("button", name="Step").click()
        wait_shown(page, f"{k} (PL-w)")
    stepped = debugger.shown
    sequence = ["PL-wo", "P-w", "PL-r", "P-wo", "P-r"] * 4  # 20 switches
    for variant in sequence:
        _choose(page, "Variant", variant)
        wait_shown(page, f"11 ({variant})")
        page.get_by_text(re.compile(rf"keyframe 11 · {re.escape(variant)}$")).first.wait_for()
    page.wait_for_timeout(700)  # longer than the progress delay: nothing may overwrite the status
    assert "re-optimizing" not in page.content()
    page.get_by_text(re.compile(r"keyframe 11 · P-r$")).first.wait_for()
    _choose(page, "Variant", "PL-w")
    wait_shown(page, "11 (PL-w)")
    assert debugger.shown is stepped  # PL-w's own result, not a re-optimization of a changed state
    page.get_by_role("tab", name="Variants").click()
    table = page.locator("table").filter(has_text="items / params").first
    rows = table.locator("tbody tr")
    assert rows.count() == 6
    assert f"{stepped.report.items} / {stepped.report.params}" in rows.nth(0).inner_text()
    assert "shown" in rows.nth(0).inner_text()
    page.close()


def test_reset_clears_the_screen_and_export_says_why_it_has_nothing(browser, debugger) -> None:
    page = open_page(browser, debugger)
    for k in range(5):
        page.get_by_role("button", name="Step").click()
        wait_shown(page, f"{k} (PL-w)")
    close_notifications(page)
    page.wait_for_timeout(800)
    canvas = page.locator("canvas").first
    drawn = _coloured(canvas.screenshot())
    page.get_by_role("button", name="Reset", exact=True).click()
    wait_shown(page, "none")
    page.get_by_text(re.compile("reset, press Step or Play")).wait_for()
    page.wait_for_timeout(800)
    assert _coloured(canvas.screenshot()) < drawn / 4  # the map is gone (grid and axes stay)
    page.get_by_role("tab", name="Variants").click()
    page.get_by_text("no keyframe yet").filter(visible=True).first.wait_for()
    page.get_by_role("button", name="Download map (PLY)").click()
    page.get_by_text("Nothing to export").wait_for()
    page.close()


def test_first_view_frames_the_map_beside_the_panels(browser) -> None:
    """The map's bounding box projects inside the 3D canvas, and the canvas lies between
    the docked panels instead of under them."""
    debugger = start_debugger()
    try:
        page = open_page(browser, debugger)
        for _ in range(30):
            debugger.submit("step")
        debugger.wait_idle(timeout=120)
        wait_shown(page, "29 (PL-w)")
        late = open_page(browser, debugger, width=1200, height=1000)  # a tab opened after the steps
        wait_shown(late, "29 (PL-w)")
        page.wait_for_timeout(2000)
        for tab, client in zip((page, late), debugger.server.get_clients().values()):
            _assert_framed(tab, client, debugger.shown)
        page.close()
        late.close()
    finally:
        debugger.stop()


def _assert_framed(page, client, snapshot) -> None:
    canvas = page.locator("canvas").filter(visible=True).last.bounding_box()
    panel = page.get_by_role("button", name="Step").bounding_box()
    assert canvas["x"] + canvas["width"] <= panel["x"] + 1  # the control panel is beside the view
    assert canvas["x"] >= 300  # so is the left panel
    cam = client.camera
    b = snapshot_bounds(snapshot)
    corners = b.centre + np.array([[sx, sy, sz] for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)]) * (b.radius / np.sqrt(3))
    f = cam.look_at - cam.position
    f /= np.linalg.norm(f)
    r = np.cross(f, [0.0, 0.0, 1.0])
    r /= np.linalg.norm(r)
    u = np.cross(r, f)
    d = corners - cam.position
    z = d @ f
    assert np.all(z > 0)
    ty = np.tan(cam.fov / 2)
    ndc = np.stack([(d @ r) / z / (ty * cam.aspect), (d @ u) / z / ty], axis=1)
    assert np.all(np.abs(ndc) <= 1.0), ndc
    assert np.abs(ndc).max() > 0.3  # framed, not a dot
    assert abs(cam.aspect - canvas["width"] / canvas["height"]) < 0.05


def test_ab_run_draws_both_trajectories_and_fills_the_difference(browser, tmp_path) -> None:
    """B = P-wo beside A = PL-w on sequence a; written to $COPLANAR_README_SCREENSHOT_AB when
    set (docs/debugger_ab.png)."""
    debugger = start_debugger()
    try:
        for _ in range(20):
            debugger.submit("step")
        debugger.wait_idle(timeout=120)
        page = open_page(browser, debugger, height=1000)
        wait_shown(page, "19 (PL-w)")
        _choose(page, "B variant", "P-wo")
        page.get_by_text(re.compile("A/B run: B = P-wo")).first.wait_for()
        for k in (20, 21, 22):
            page.get_by_role("button", name="Step").click()
            wait_shown(page, f"{k} (PL-w)")
        debugger.wait_idle(timeout=120)  # the step ahead moves A's engine, then B's: compare them once it is done
        assert debugger.session.keyframes == 23 and debugger.engine_b.keyframes == debugger.engine.keyframes
        assert "/ab/trajectory" in debugger.scene._handles
        page.get_by_role("tab", name="Variants").click()
        page.get_by_text(re.compile("A/B run at keyframe 22")).first.wait_for()
        page.get_by_text("B: P-wo").first.wait_for()
        close_notifications(page)
        page.wait_for_timeout(1500)
        assert "/ab/camera" in debugger.scene._handles and debugger.scene._handles["/ab/label"].text == "B: P-wo"  # B's camera and label (aquamarine: test_debugger_round3_scene.py)
        path = pathlib.Path(os.environ.get("COPLANAR_README_SCREENSHOT_AB", tmp_path / "debugger_ab.png"))
        page.screenshot(path=str(path))
        page.close()
    finally:
        debugger.stop()


def test_plots_change_with_the_slider_and_keys_step_and_scrub(browser, debugger) -> None:
    page = open_page(browser, debugger)
    for k in range(6):
        page.get_by_role("button", name="Step").click()
        wait_shown(page, f"{k} (PL-w)")
    # The Hessians open large in a floating window, and close again.
    page.get_by_role("tab", name="Hessian").click()
    page.get_by_role("button", name="Open the Hessians large").click()
    page.get_by_role("tab", name="Large view").wait_for()
    # The window's H drawn large (>= 900 px) and the comparison twice, in its tab and in the
    # large view (whose images load after the view opens: wait for them).
    page.wait_for_function(
        "() => { const w = [...document.querySelectorAll('img')].map(i => i.naturalWidth).filter(x => x > 300); return w.some(x => x >= 900) && w.some((x, i) => w.indexOf(x) !== i); }",
        timeout=10_000,
    )
    page.get_by_role("button", name="Close").click()
    page.get_by_role("tab", name="Large view").wait_for(state="detached")

    page.get_by_role("tab", name="Plots").click()
    page.wait_for_function("() => [...document.querySelectorAll('img')].some(i => i.naturalHeight >= 700)")
    src = lambda: page.evaluate("() => [...document.querySelectorAll('img')].filter(i => i.naturalHeight >= 700).map(i => i.src)[0]")  # noqa: E731
    page.wait_for_timeout(1500)
    before = src()
    slider_input = field(page, "Keyframe")
    slider_input.fill("2")
    slider_input.press("Enter")
    wait_shown(page, "2 (PL-w)")
    page.wait_for_function("old => [...document.querySelectorAll('img')].filter(i => i.naturalHeight >= 700).map(i => i.src)[0] !== old", arg=before)

    # Keys: → steps (on the 3D view, not in a text field), shift+← scrubs back, space plays.
    close_notifications(page)
    box = page.locator("canvas").filter(visible=True).last.bounding_box()
    page.mouse.click(box["x"] + 40, box["y"] + box["height"] - 40)
    page.keyboard.press("ArrowRight")
    wait_shown(page, "6 (PL-w)")
    page.keyboard.press("Shift+ArrowLeft")
    wait_shown(page, "5 (PL-w)")
    page.keyboard.press("Space")
    page.wait_for_function(
        "() => { const l = [...document.querySelectorAll('label')].find(l => l.textContent === 'Shown'); return parseInt(l.closest('.mantine-Flex-root').querySelector('input').value) >= 8; }"
    )
    page.keyboard.press("Space")
    page.wait_for_timeout(500)
    debugger.wait_idle()
    assert not debugger.play.value
    page.close()
