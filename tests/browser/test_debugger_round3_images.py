"""The debugger's images at the issue's window size (1600×1000), as a user meets them: the
Hessians opened large are large, labelled at their group boundaries, carry the colour key
and sit over the 3D view, clear of the control panel and its status line; the Plots tab
marks a plane event only where the planes changed, shows both costs on a log axis without
an offset text, with legends off the data. Each test fails on the code before this change."""

from __future__ import annotations

import re

from playwright.sync_api import expect

from tests.browser.conftest import field, open_page, start_served, wait_shown

SIZE = {"width": 1600, "height": 1000}


def _stepped_room(browser, steps: int):
    debugger = start_served("--scene", "room", "--duration", "6")
    page = open_page(browser, debugger, **SIZE)
    for k in range(steps):
        page.get_by_role("button", name="Step").click()
        wait_shown(page, f"{k} (PL-w)")
    debugger.wait_idle(timeout=120)
    return debugger, page


def _outer_panel(locator):
    """The outermost panel (mantine Paper) holding `locator`."""
    return locator.locator("xpath=ancestor::div[contains(@class,'mantine-Paper-root')][last()]")


def _overlap(a: dict, b: dict) -> bool:
    """Whether two page bounding boxes (CSS px) overlap."""
    return a["x"] < b["x"] + b["width"] and b["x"] < a["x"] + a["width"] and a["y"] < b["y"] + b["height"] and b["y"] < a["y"] + a["height"]


def _natural_width(image) -> int:
    return int(image.evaluate("e => e.naturalWidth"))


def test_the_hessians_open_large_labelled_and_beside_the_controls(browser) -> None:
    debugger, page = _stepped_room(browser, 4)
    try:
        page.get_by_role("tab", name="Hessian").click()
        in_tab = page.get_by_text("H = J^T J of the window", exact=True).locator("xpath=following-sibling::div[1]//img")
        in_tab.wait_for()
        tab_box = in_tab.bounding_box()
        page.get_by_role("button", name="Open the Hessians large").click()
        close = page.get_by_role("button", name="Close")
        close.wait_for()
        large = page.get_by_text(re.compile("^H = JᵀJ of the window")).filter(visible=True).locator("xpath=following-sibling::div[1]//img")
        large.wait_for()
        page.wait_for_timeout(500)  # the floating window takes its size
        large_box = large.bounding_box()
        assert large_box["width"] >= 1.5 * tab_box["width"], (large_box, tab_box)
        assert _natural_width(large) >= 900 > _natural_width(in_tab)  # rendered large: its expand icon enlarges it further

        floating = _outer_panel(close).bounding_box()
        controls = _outer_panel(page.get_by_role("button", name="Step")).bounding_box()
        side = _outer_panel(page.get_by_role("button", name="Open the Hessians large")).bounding_box()
        status = page.get_by_text(re.compile(r": keyframe \d+ · ")).bounding_box()
        assert not _overlap(floating, controls), (floating, controls)
        assert not _overlap(floating, side), (floating, side)
        assert not _overlap(floating, status), (floating, status)
        assert floating["width"] >= 600, floating

        # the colour key beside it, and a zoom on a pair of groups
        table = _outer_panel(close).locator("table").filter(has_text="colour")
        for colour, group in (("🟩 green", "cameras"), ("🟦 blue", "planes")):
            expect(table.locator("tr").filter(has_text=group)).to_contain_text(colour)
        whole = large.get_attribute("src")
        field(page, "Zoom on").click()
        page.get_by_role("option", name="cameras + planes", exact=True).click()
        expect(large).not_to_have_attribute("src", whole or "")
        close.click()
        expect(page.get_by_role("button", name="Close")).to_have_count(0)
        page.close()
    finally:
        debugger.stop()


def test_the_plots_tab_shows_the_plots_with_plane_changes_and_log_costs(browser, monkeypatch) -> None:
    from tests.viewer.test_plots import check_plots, drawn_figure

    debugger, page = _stepped_room(browser, 8)
    try:
        page.get_by_role("tab", name="Plots").click()
        debugger.wait_plots()
        series = debugger.history.series(debugger.shown.variant)
        figure = drawn_figure(monkeypatch, series, current=debugger.shown.keyframe)
        check_plots(figure, series)
        shown = page.get_by_text("over the kept keyframes", exact=False).filter(visible=True).locator("xpath=following-sibling::div[1]//img")
        expect(shown).to_be_visible()
        width, height = figure.canvas.get_width_height()
        assert (int(shown.evaluate("e => e.naturalWidth")), int(shown.evaluate("e => e.naturalHeight"))) == (width, height)
        page.close()
    finally:
        debugger.stop()


def test_on_a_high_density_display_the_large_view_fills_the_3d_view_and_no_more(browser) -> None:
    """A Retina laptop's window (1440×900 CSS px at pixel ratio 2): the browser reports the
    3D view in device pixels, twice its CSS size; the large view must still fit between
    the panels (it was sized from the device pixels: about twice the view's width, over
    the control panel and the status line)."""
    debugger = start_served("--scene", "room", "--duration", "6")
    try:
        page = open_page(browser, debugger, width=1440, height=900, pixel_ratio=2)
        page.get_by_role("button", name="Step").click()
        wait_shown(page, "0 (PL-w)")
        page.get_by_role("tab", name="Hessian").click()
        page.get_by_role("button", name="Open the Hessians large").click()
        close = page.get_by_role("button", name="Close")
        close.wait_for()
        page.wait_for_timeout(500)  # the floating window takes its size
        floating = _outer_panel(close).bounding_box()
        controls = _outer_panel(page.get_by_role("button", name="Step")).bounding_box()
        side = _outer_panel(page.get_by_role("button", name="Open the Hessians large")).bounding_box()
        view = page.locator("canvas").first.bounding_box()
        assert not _overlap(floating, controls), (floating, controls)
        assert not _overlap(floating, side), (floating, side)
        assert floating["width"] >= 0.9 * (view["width"] - 24), (floating, view)
        page.close()
    finally:
        debugger.stop()
