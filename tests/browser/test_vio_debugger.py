"""The debugger on the VIO pipeline (`coplanar serve --mode vio`), as a user drives it: it
steps, switches the variant and shows the IMU state (status, velocity, biases, gravity) in
the report; the status line says what the start waits for and, once initialized, how well
it knows the scale (issue 28's item 12: it gave no hint before); the README's picture of
the VIO mode."""

from __future__ import annotations

import os
import pathlib
import re

from tests.browser.conftest import close_notifications, field, open_page, start_served, wait_shown


def test_vio_debugger_steps_switches_variant_and_shows_the_imu_state(browser, tmp_path) -> None:
    debugger = start_served("--scene", "room", "--mode", "vio", "--speed", "2", "--duration", "4", "--segmenter", "oracle")
    try:
        page = open_page(browser, debugger, height=1250)
        for k in range(10):  # through the initialization (keyframe 7 at 1.3 s)
            page.get_by_role("button", name="Step").click()
            wait_shown(page, f"{k} (PL-w)")
            if k == 0:  # before the start: what it waits for
                page.get_by_text(re.compile(r"^VIO not initialized yet: ")).first.wait_for()
        # after it: when, how well the alignment knew the scale (1σ), and the error against the truth
        note = page.get_by_text(re.compile(r"initialized at keyframe \d+ \([\d.]+ s of motion\), the alignment's scale known to ±\d+ % \(1σ\)"))
        note.filter(has_text=re.compile(r"after the joint solve -?[\d.]+ % against the truth")).first.wait_for()
        snapshot = debugger.history[-1]
        assert snapshot.imu is not None and snapshot.imu.initialized
        page.get_by_role("tab", name="Report").click()
        page.get_by_text(re.compile(r"IMU \(initialized\)")).first.wait_for()
        page.get_by_text("gyroscope bias (rad/s)").first.wait_for()
        page.get_by_text("velocity (m/s, world)").first.wait_for()
        field(page, "Variant").click()
        page.get_by_role("option", name="P-w", exact=True).click()
        wait_shown(page, f"{snapshot.keyframe} (P-w)")
        page.get_by_text(re.compile(rf"keyframe {snapshot.keyframe} · P-w$")).first.wait_for()
        page.get_by_text(re.compile(r"IMU \(initialized\)")).first.wait_for()  # the re-optimized window keeps its IMU state
        page.get_by_role("button", name="Step").click()
        wait_shown(page, f"{snapshot.keyframe + 1} (P-w)")
        close_notifications(page)
        page.wait_for_timeout(1500)
        path = pathlib.Path(os.environ.get("COPLANAR_README_SCREENSHOT_VIO", tmp_path / "vio_debugger.png"))
        page.screenshot(path=str(path))
        page.close()
    finally:
        debugger.stop()
