"""The debugger's 3D view as a user meets it at 1600×1000 (issue 28): the room's first map
lies between the two panels (it ran past the left edge for the first ten keyframes), the
A/B run's B stands out (its own colour, larger camera, a label) and is a run of its own,
with the panels' widths unchanged, and the displacement layer colours the map by how far
each landmark lies from itself in another variant's map."""

from __future__ import annotations

import io
import re
import time

import numpy as np
from playwright.sync_api import expect

from tests.browser.conftest import close_notifications, field, open_page, start_served, wait_shown
from viewer.framing import snapshot_bounds

# The box (x, y, width, height; CSS px) of the docked panel holding an element: its highest
# ancestor narrower than half the window.
PANEL_BOX = """(el) => { let e = el; while (e.parentElement && e.parentElement.getBoundingClientRect().width < 0.5 * window.innerWidth) e = e.parentElement;
    const r = e.getBoundingClientRect(); return [r.x, r.y, r.width, r.height]; }"""


def _choose(page, label: str, option: str) -> None:
    field(page, label).click()
    page.get_by_role("option", name=option, exact=True).click()


def _panels(page) -> tuple[list[float], list[float], list[float]]:
    """The left panel's, the right panel's and the 3D canvas's boxes (CSS px)."""
    left = page.get_by_role("tab", name="Keyframe").evaluate(PANEL_BOX)
    right = page.get_by_role("button", name="Step").evaluate(PANEL_BOX)
    canvas = page.locator("canvas").filter(visible=True).last.bounding_box()
    return left, right, [canvas["x"], canvas["y"], canvas["width"], canvas["height"]]


def _settled_camera(debugger, *, timeout: float = 20.0):
    """The tab's camera once it has stopped moving (the browser animates to a view set)."""
    client = next(iter(debugger.server.get_clients().values()))
    last, since, deadline = None, time.monotonic(), time.monotonic() + timeout
    while time.monotonic() < deadline:
        now = np.concatenate([client.camera.position, client.camera.wxyz])
        if last is None or not np.allclose(now, last, atol=1e-5):
            last, since = now, time.monotonic()
        elif time.monotonic() - since > 1.0:
            break
        time.sleep(0.1)
    return client.camera


def _on_screen(camera, p_world: np.ndarray, canvas: list[float]) -> np.ndarray:
    """Pixel coordinates (N, 2; CSS px of the page) of world points seen by the tab's camera
    (viser: `wxyz` rotates camera to world, OpenCV axes, x right, y down, z forward; `fov`
    vertical, radians; `aspect` width / height of the canvas)."""
    w, x, y, z = np.asarray(camera.wxyz, float)
    R_world_camera = np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
            [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
            [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
        ]
    )
    p_camera = (p_world - np.asarray(camera.position, float)) @ R_world_camera
    assert np.all(p_camera[:, 2] > 0), "a map point behind the camera"
    f = 0.5 / np.tan(0.5 * float(camera.fov))  # per canvas height
    u = 0.5 + f * p_camera[:, 0] / p_camera[:, 2] / float(camera.aspect)
    v = 0.5 + f * p_camera[:, 1] / p_camera[:, 2]
    return np.stack([canvas[0] + u * canvas[2], canvas[1] + v * canvas[3]], axis=1)


def _assert_map_between_panels(page, debugger) -> None:
    """The map's points and plane patches (all but the outermost 1 % of the points on each
    side) project between the left panel's right edge and the right panel's left edge."""
    camera = _settled_camera(debugger)
    left, right, canvas = _panels(page)
    snapshot = debugger.shown
    centre = _on_screen(camera, snapshot_bounds(snapshot).centre[None], canvas)[0]  # the projection holds together
    assert abs(centre[0] - (canvas[0] + 0.5 * canvas[2])) < 2 and abs(centre[1] - (canvas[1] + 0.5 * canvas[3])) < 2, centre
    p_world = snapshot.points.p_world[np.isfinite(snapshot.points.p_world).all(axis=1)]
    px = _on_screen(camera, p_world, canvas)
    lo, hi = np.percentile(px, 1, axis=0), np.percentile(px, 99, axis=0)
    hulls = np.concatenate([plane.hull_world for plane in snapshot.planes if len(plane.hull_world)])
    hull_px = _on_screen(camera, hulls, canvas)
    lo, hi = np.minimum(lo, hull_px.min(axis=0)), np.maximum(hi, hull_px.max(axis=0))
    visible_x = (left[0] + left[2], right[0])
    assert visible_x[0] <= lo[0] and hi[0] <= visible_x[1], f"keyframe {snapshot.keyframe}: map from x = {lo[0]:.0f} to {hi[0]:.0f} px, view from {visible_x[0]:.0f} to {visible_x[1]:.0f}"
    assert 0 <= lo[1] and hi[1] <= canvas[1] + canvas[3], (lo, hi)
    assert hi[0] - lo[0] > 0.3 * (visible_x[1] - visible_x[0])  # framed, not a dot


def test_the_rooms_first_map_lies_between_the_panels(browser) -> None:
    """At keyframe 0 a quarter of the room's points (the back wall left of the camera) were
    left out of the framing as outliers: the map ran past the left edge, and Frame all and
    Default view framed it the same way."""
    debugger = start_served("--scene", "room", "--duration", "6")
    try:
        page = open_page(browser, debugger, width=1600, height=1000)
        for k in range(3):
            page.get_by_role("button", name="Step").click()
            wait_shown(page, f"{k} (PL-w)")
            debugger.wait_idle(timeout=120)
            if k in (0, 2):
                _assert_map_between_panels(page, debugger)
        page.get_by_role("button", name="Frame all").click()
        _assert_map_between_panels(page, debugger)
        page.get_by_role("button", name="Default view").click()
        _assert_map_between_panels(page, debugger)
        page.close()
    finally:
        debugger.stop()


def _rgb(png: bytes) -> np.ndarray:
    from PIL import Image

    return np.asarray(Image.open(io.BytesIO(png)).convert("RGB")).astype(int)


def _b_pixels(page) -> np.ndarray:
    """The colours (N, 3) of the 3D view's pixels that B draws: those that change when the
    layer *A/B run (B)* is hidden (the view rendered with its tone mapping, so not COLOR_B
    exactly)."""
    canvas = page.locator("canvas").filter(visible=True).last
    with_b = _rgb(canvas.screenshot())
    page.get_by_label("A/B run (B)").uncheck()
    page.wait_for_timeout(1000)
    without_b = _rgb(canvas.screenshot())
    page.get_by_label("A/B run (B)").check()
    page.wait_for_timeout(500)
    return with_b[np.abs(with_b - without_b).max(axis=2) > 30]


def test_the_ab_run_stands_out_and_the_panels_keep_their_width(browser) -> None:
    """B was drawn in magenta, 1 cm from A's red newest camera beside a pink plane; on room,
    choosing B's variant changed A's too (the two engines shared the pipeline's core)."""
    debugger = start_served("--scene", "room", "--duration", "6")
    try:
        page = open_page(browser, debugger, width=1600, height=1000)
        for k in range(2):
            page.get_by_role("button", name="Step").click()
            wait_shown(page, f"{k} (PL-w)")
        debugger.wait_idle(timeout=120)
        close_notifications(page)
        off = _panels(page)
        _choose(page, "B variant", "P-wo")
        page.get_by_text(re.compile("A/B run: B = P-wo")).first.wait_for()
        debugger.wait_idle(timeout=120)
        assert _panels(page) == off
        page.get_by_role("button", name="Step").click()
        wait_shown(page, "2 (PL-w)")  # A keeps its variant
        debugger.wait_idle(timeout=120)
        assert debugger.engine.variant == "PL-w" and debugger.engine_b.variant == "P-wo"
        assert debugger.shown.variant == "PL-w" and debugger.session.other_at(2).variant == "P-wo"
        assert debugger.scene._handles["/ab/label"].text == "B: P-wo"  # B's label in the 3D view
        page.wait_for_timeout(1500)
        close_notifications(page)
        b_pixels = _b_pixels(page)
        assert len(b_pixels) > 150, len(b_pixels)  # B's camera, larger than A's, and its label
        r, g, b = np.median(b_pixels, axis=0)
        assert g > r + 40 and b > r + 30, (r, g, b)  # aquamarine (magenta before: r and b high, g low)
        assert _panels(page) == off
        page.get_by_role("tab", name="Variants").click()
        page.get_by_text(re.compile("A/B run at keyframe 2")).first.wait_for()
        assert _panels(page) == off
        _choose(page, "B variant", "off")
        debugger.wait_idle(timeout=120)
        assert "/ab/label" not in debugger.scene._handles
        assert _panels(page) == off
        page.close()
    finally:
        debugger.stop()


NOTE = re.compile(r"Displacement P-wo → PL-w.*?(\d+) of (\d+) points.*?median ([\d.]+) cm, max ([\d.]+) cm")


def test_the_displacement_layer_colours_the_map_by_how_far_landmarks_moved(browser, debugger) -> None:
    page = open_page(browser, debugger, width=1600, height=1000)
    for k in range(4):
        page.get_by_role("button", name="Step").click()
        wait_shown(page, f"{k} (PL-w)")
    _choose(page, "Variant", "P-wo")  # a second variant at keyframe 3
    wait_shown(page, "3 (P-wo)")
    debugger.wait_idle(timeout=120)
    points = debugger.scene._handles["/map/points"]
    by_plane = np.array(points.colors)
    _choose(page, "Displacement", "PL-w")
    note = page.get_by_text(NOTE).first
    note.wait_for()
    matched, total, median, largest = NOTE.search(note.inner_text()).groups()
    assert 0 < int(matched) <= int(total) == len(debugger.shown.points.id)
    assert 0.0 < float(median) <= float(largest) < 100.0  # cm: P-wo and PL-w differ, by less than a metre
    page.get_by_text(re.compile(r"colour: dark blue 0 cm → green [\d.]+ cm → yellow ≥ [\d.]+ cm")).first.wait_for()
    wait_shown(page, "3 (P-wo)")  # drawn again, the variant shown stays
    colors = np.array(points.colors)
    assert len(np.unique(colors, axis=0)) > 5 and not np.array_equal(colors, by_plane)
    assert "/map/displacement" in debugger.scene._handles  # segments to where PL-w has them
    _choose(page, "Displacement", "off")
    expect(page.get_by_text(NOTE)).to_have_count(0)
    debugger.wait_idle(timeout=120)
    np.testing.assert_array_equal(np.array(points.colors), by_plane)
    page.close()
