"""The debugger's third round, as a user meets it in the browser: everything on screen is
true for the keyframe shown. Scrubbed back, the status line and the variant choice stay at
that keyframe; the plane-mode comparison is the shown keyframe's and does not change with
the variant chosen; P variants say that the lines drawn are not used; Reset returns the
keyframe slider to its start. Each test fails on the code before this round."""

from __future__ import annotations

import re

from playwright.sync_api import expect

from tests.browser.conftest import field, open_page, start_served, wait_shown


def _choose(page, label: str, option: str) -> None:
    field(page, label).click()
    page.get_by_role("option", name=option, exact=True).click()


def _status(page):
    """The status line's first paragraph (the input's name, then what is shown), or its
    note on a variant that cannot be shown (not the notification that repeats the note)."""
    return page.get_by_text(re.compile(r": keyframe \d+ · |was not computed at keyframe")).and_(page.locator(":not(.mantine-Notification-title)"))


def _scrub(page, keyframe: int) -> None:
    slider = field(page, "Keyframe")
    slider.fill(str(keyframe))
    slider.press("Enter")


def _stepped(browser, debugger, steps: int, **page_options: int):
    page = open_page(browser, debugger, **page_options)
    for k in range(steps):
        page.get_by_role("button", name="Step").click()
        wait_shown(page, f"{k} (PL-w)")
    debugger.wait_idle(timeout=120)
    return page


def test_scrubbed_back_the_status_line_says_the_keyframe_shown(browser, debugger) -> None:
    page = _stepped(browser, debugger, 6)
    _status(page).filter(has_text=re.compile(r"keyframe 5 · PL-w$")).wait_for()
    _scrub(page, 2)
    wait_shown(page, "2 (PL-w)")
    _status(page).filter(has_text=re.compile(r"keyframe 2 · PL-w · scrubbed back \(newest 5\)")).wait_for()
    _scrub(page, 3)
    wait_shown(page, "3 (PL-w)")
    _status(page).filter(has_text=re.compile(r"keyframe 3 · PL-w · scrubbed back \(newest 5\)")).wait_for()
    page.close()


def test_a_refused_variant_stays_readable_after_the_next_step(browser, debugger) -> None:
    """Scrubbed back, a variant that was not computed there is refused in the status line;
    the next step (here a Step click, as another tab's Play does at every step) replaces the
    status line, so the tab that chose also gets the refusal as a notification that stays."""
    page = _stepped(browser, debugger, 4)
    _scrub(page, 1)
    wait_shown(page, "1 (PL-w)")
    _choose(page, "Variant", "P-wo")  # not computed at keyframe 1
    notice = page.locator(".mantine-Notification-root").filter(has_text="P-wo was not computed at keyframe 1")
    notice.wait_for()
    expect(notice).to_contain_text("Still showing PL-w")
    page.get_by_role("button", name="Step").click()
    wait_shown(page, "4 (PL-w)")
    _status(page).filter(has_text=re.compile(r"keyframe 4 · PL-w$")).wait_for()  # the status line has moved on
    expect(notice).to_be_visible()  # the refusal has not
    page.close()


def test_a_variant_chosen_scrubbed_back_stays_at_the_keyframe_shown(browser, debugger) -> None:
    page = _stepped(browser, debugger, 6)
    _choose(page, "Variant", "P-r")  # kept at keyframe 5
    wait_shown(page, "5 (P-r)")
    _choose(page, "Variant", "PL-w")
    wait_shown(page, "5 (PL-w)")
    _scrub(page, 2)
    wait_shown(page, "2 (PL-w)")
    _choose(page, "Variant", "PL-r")  # not computed at keyframe 2
    _status(page).filter(has_text="PL-r was not computed at keyframe 2").wait_for()
    debugger.wait_idle(timeout=120)
    wait_shown(page, "2 (PL-w)")
    expect(field(page, "Variant")).to_have_value("PL-w")
    assert debugger.history.newest_keyframe == 5 and debugger.shown.keyframe == 2
    page.get_by_role("tab", name="Variants").click()
    page.get_by_text(re.compile(r"variants can be added at the newest keyframe \(5\) only")).filter(visible=True).wait_for()
    _scrub(page, 5)
    wait_shown(page, "5 (PL-w)")
    _choose(page, "Variant", "P-r")  # kept there: shown again, not re-optimized
    wait_shown(page, "5 (P-r)")
    page.get_by_text(re.compile("choose another in .?Variant.? to add it")).filter(visible=True).wait_for()
    page.close()


def test_reset_returns_the_keyframe_slider_to_its_start(browser, debugger) -> None:
    page = _stepped(browser, debugger, 5)
    page.get_by_role("button", name="Reset", exact=True).click()
    wait_shown(page, "none")
    expect(field(page, "Keyframe")).to_have_value("0")
    assert debugger.slider.max == 1 and debugger.slider.disabled
    page.get_by_role("button", name="Step").click()
    wait_shown(page, "0 (PL-w)")
    expect(field(page, "Keyframe")).to_have_value("0")
    page.close()


def test_the_plane_mode_comparison_is_the_shown_keyframes_step(browser) -> None:
    """On room, re-optimizing with PL-r drops some of the window's lines, so a comparison
    taken from the engine's state after it counted fewer items (PL-w 48 / 137 with PL-w
    chosen, 44 / 127 with PL-r); scrubbed back, it showed the newest window."""
    debugger = start_served("--scene", "room", "--duration", "6")  # as `coplanar serve` builds it
    try:
        page = open_page(browser, debugger, width=1600, height=1000)
        page.get_by_role("tab", name="Hessian").click()
        page.get_by_label(re.compile("^Compare")).check()
        for k in range(6):
            page.get_by_role("button", name="Step").click()
            wait_shown(page, f"{k} (PL-w)")
        debugger.wait_idle(timeout=120)
        compare = debugger.hessian_tab.compare_image
        stepped = compare._data  # the PNG sent to the page
        _choose(page, "Variant", "PL-r")
        wait_shown(page, "5 (PL-r)")
        debugger.wait_idle(timeout=120)
        assert compare._data == stepped
        _scrub(page, 2)
        wait_shown(page, "2 (PL-w)")  # PL-r was not computed there
        debugger.wait_idle(timeout=120)
        assert compare._data != stepped
        page.get_by_text("keyframe 2's window as its step left it").wait_for()
        page.close()
    finally:
        debugger.stop()


def test_p_variants_draw_the_lines_faint_and_say_so(browser) -> None:
    debugger = start_served("--scene", "room", "--duration", "6")
    try:
        page = _stepped(browser, debugger, 3, width=1600, height=1000)
        lines = debugger.scene._handles["/map/lines"]
        assert lines.thickness == 3.0
        _choose(page, "Variant", "P-wo")
        wait_shown(page, "2 (P-wo)")
        page.get_by_text(re.compile("P-wo: planes and lines are detected and drawn faint")).wait_for()
        debugger.wait_idle(timeout=120)
        assert lines.thickness == 1.0
        _choose(page, "Variant", "PL-w")
        wait_shown(page, "2 (PL-w)")
        debugger.wait_idle(timeout=120)
        assert lines.thickness == 3.0
        expect(page.get_by_text(re.compile("drawn faint for reference"))).to_have_count(0)
        page.close()
    finally:
        debugger.stop()


LABEL_FIT = """() => [...document.querySelectorAll('.mantine-Button-label, label')]
    .filter(e => e.offsetParent !== null && e.textContent.trim())
    .map(e => {
        const range = document.createRange();
        range.selectNodeContents(e);  // the text's line boxes: one distinct top per line
        const lines = new Set([...range.getClientRects()].filter(r => r.width > 0).map(r => Math.round(r.top))).size;
        return {text: e.textContent.trim(), cut: e.scrollWidth > e.clientWidth + 1, lines: lines};
    })
    .filter(x => x.cut || x.lines > 1)"""


def _labels_not_fitting(page) -> list:
    """The labels cut short or wrapped, in the control panel and in every tab."""
    bad = page.evaluate(LABEL_FIT)
    for tab in ("Hessian", "Variants", "Plots", "Report"):
        page.get_by_role("tab", name=tab).click()
        page.wait_for_timeout(300)
        bad += page.evaluate(LABEL_FIT)
    return bad


def test_every_label_fits_on_one_line(browser, debugger) -> None:
    """No button or control label is cut short or wrapped, in the control panel and in
    every tab (1600×1000, the size the issue's screenshots were taken at)."""
    page = _stepped(browser, debugger, 2, width=1600, height=1000)
    assert not (bad := _labels_not_fitting(page)), bad
    page.close()


def test_every_label_fits_on_one_line_on_the_image_pipeline(browser) -> None:
    """The same on the rendered room, whose panel has the image pipeline's controls too
    (Segmenter, Dense mesh, the keyframe image's tab)."""
    debugger = start_served("--scene", "room", "--duration", "6")
    page = _stepped(browser, debugger, 2, width=1600, height=1000)
    assert not (bad := _labels_not_fitting(page)), bad
    page.close()


def test_the_hessian_tab_has_a_colour_key(browser, debugger) -> None:
    page = _stepped(browser, debugger, 2)
    page.get_by_role("tab", name="Hessian").click()
    table = page.locator("table").filter(has_text="colour").filter(visible=True).first
    for row in ("🟩 green cameras", "🟧 orange points", "🟧 orange lines", "🟦 blue planes"):
        colour, hue, group = row.split()
        expect(table.locator("tr").filter(has_text=group)).to_contain_text(f"{colour} {hue}")
    page.get_by_text(re.compile("points and lines share orange")).filter(visible=True).wait_for()
    page.close()


def test_a_session_recorded_in_the_page_replays_without_the_engine(browser, debugger, tmp_path) -> None:
    """The user ticks Record, steps, tries another variant, downloads the recording and opens
    it with `coplanar serve --replay FILE`: the replay steps through the same keyframes with
    the variant chosen, the same map and the same panels, and says it is a replay."""
    import pathlib

    from backend.pipeline.snapshot_codec import same
    from tests.browser.conftest import start_served

    page = open_page(browser, debugger)
    page.get_by_role("checkbox", name="Record").check()
    for k in range(3):
        page.get_by_role("button", name="Step").click()
        wait_shown(page, f"{k} (PL-w)")
    _choose(page, "Variant", "P-r")
    wait_shown(page, "2 (P-r)")
    page.get_by_text(re.compile(r"^recording: 3 keyframes, \d+\.\d MB$")).wait_for()
    live = {k: debugger.history.get(k) for k in range(3)}
    with page.expect_download() as download:
        page.get_by_role("button", name="Download recording (zip)").click()
    path = tmp_path / download.value.suggested_filename
    download.value.save_as(path)
    assert path.name.endswith("3kf.recording.zip")
    page.close()

    replay = start_served("--replay", str(path))
    page = open_page(browser, replay)
    for k in range(3):
        page.get_by_role("button", name="Step").click()
        wait_shown(page, f"{k} (PL-w)" if k < 2 else "2 (P-r)")
        assert same(replay.shown, live[k])
    _status(page).filter(has_text=re.compile(rf"\(replay of {re.escape(path.name)}\): keyframe 2 · P-r$")).wait_for()
    expect(field(page, "B variant")).to_be_disabled()
    _choose(page, "Variant", "PL-w")  # the stepped variant, recorded beside the one chosen
    wait_shown(page, "2 (PL-w)")
    assert pathlib.Path(path).stat().st_size > 10_000
    page.close()
    replay.stop()
