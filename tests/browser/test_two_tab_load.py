"""Two tabs on one debugger under load, for a bounded time (issue 29): one plays at the
highest rate (and resumes Play whenever the other paused it) while the other scrubs,
switches variants, toggles layers, opens every tab and changes the point size as fast as
the page answers. The server keeps answering every action, stepping on, within its history
caps, and both tabs end showing the same keyframe; nothing either page sends is refused
(the conftest's check) and no step fails."""

from __future__ import annotations

import random
import re
import time

from playwright.sync_api import expect

from tests.browser.conftest import field, open_page, start_debugger, wait_shown

LOAD_S = 20.0  # how long the second tab works while the first plays, at least
MIN_ACTIONS = 20  # and how many actions it takes, at least
ANSWER_MS = 30_000  # the longest any single action may wait for the page to show its effect


def _rss_mb() -> float:
    with open("/proc/self/status") as f:  # the server runs in this process; the browser does not
        return next(int(line.split()[1]) / 1024.0 for line in f if line.startswith("VmRSS:"))


def _debugger():
    from viewer.settings import ViewerSettings

    # Caps small enough to be reached within the load: 12 keyframes, 2 MiB of snapshots.
    return start_debugger(settings=ViewerSettings(history=12, history_mb=2.0))


def _shown_keyframe(page) -> int:
    return int(re.match(r"\d+", field(page, "Shown").input_value()).group())  # type: ignore[union-attr]


def _answered(done, action: str, *, state=lambda: "") -> None:
    """Wait until `done()` holds, at most ANSWER_MS; `state()` describes the pages and the
    server for the failure message."""
    deadline = time.monotonic() + ANSWER_MS / 1000
    while not done():
        if time.monotonic() >= deadline:
            raise AssertionError(f"{action} was not answered in {ANSWER_MS} ms; {state()}")
        time.sleep(0.05)


def test_two_tabs_under_load_stay_answered_bounded_and_in_sync(browser) -> None:
    debugger = _debugger()
    try:
        player = open_page(browser, debugger)
        worker = open_page(browser, debugger)
        player.get_by_role("button", name="Step").click()
        wait_shown(worker, "0 (PL-w)")
        rss_start = _rss_mb()
        statuses: list[str] = []
        set_status = debugger._set_status
        debugger._set_status = lambda text: (statuses.append(text), set_status(text))[1]  # a failed step says "**error** in ..."

        rate = field(player, "Rate (Hz)")
        rate.fill("30")
        rate.press("Enter")
        field(player, "Play").check()
        rng = random.Random(0)
        actions: dict[str, int] = {}
        began = time.monotonic()
        end = began + LOAD_S
        while time.monotonic() < end or sum(actions.values()) < MIN_ACTIONS:
            action = rng.choice(["scrub", "variant", "layer", "tab", "point size"])
            actions[action] = actions.get(action, 0) + 1
            if action == "scrub":
                # As a user scrubs while the other tab plays: pause, then type the keyframe (typed
                # while Play moves the slider, the box's text and Play's update mix: "139131").
                # The user types once the view has settled: a step still on its way when the
                # box is filled lands in the middle of the typed text ("104100", refused).
                field(worker, "Play").uncheck()
                debugger.wait_idle(timeout=ANSWER_MS / 1000)
                slider = field(worker, "Keyframe")
                expect(slider).to_have_value(str(int(debugger.controls.slider.value)), timeout=ANSWER_MS)
                target = max(debugger.history.first_keyframe, debugger.history.newest_keyframe - rng.randint(1, 3))
                slider.fill(str(target))
                slider.press("Enter")
                _answered(lambda target=target: _shown_keyframe(worker) == target, f"scrubbing to {target}")
            elif action == "variant":
                # At the newest keyframe the variant is computed and shown; scrubbed back, where
                # it was not computed, the status line says so and the shown one stays.
                # The refusal is looked for in the statuses the server set rather than on the
                # page: with the other tab playing at 30 Hz the next step's status replaces it
                # at once.
                name = rng.choice(["P-wo", "P-w", "PL-r", "PL-w"])
                said_before = len(statuses)
                variant_before = field(worker, "Variant").input_value()
                field(worker, "Variant").click()
                worker.get_by_role("option", name=name, exact=True).click()
                shown = field(worker, "Shown")

                def answered(shown=shown, name=name, said_before=said_before) -> bool:
                    refused = any(f"{name} was not computed at keyframe" in text for text in statuses[said_before:])
                    return refused or shown.input_value().endswith(f"({name})")

                def state(shown=shown, said_before=said_before, before=variant_before) -> str:
                    return (
                        f"worker's Variant {before!r} before the choice, {field(worker, 'Variant').input_value()!r} now, Shown {shown.input_value()!r}; "
                        f"engine variant {debugger.engine.variant}, shown snapshot {debugger._shown.keyframe if debugger._shown else None}; "
                        f"statuses since the choice {statuses[said_before:][-3:]}"
                    )

                _answered(answered, f"choosing {name}", state=state)
            elif action == "layer":
                box = field(worker, rng.choice(["Points", "Lines", "Planes", "Cameras"]))
                box.set_checked(not box.is_checked())
            elif action == "tab":
                worker.get_by_role("tab", name=rng.choice(["Keyframe", "Hessian", "Variants", "Plots", "Report"])).click()
            else:
                size = field(worker, "Point size")
                size.fill(f"{rng.uniform(0.5, 3.0):.1f}")
                size.press("Enter")
            play = field(player, "Play")
            if not play.is_checked():  # the first tab's user plays on
                play.check()

        field(player, "Play").uncheck()
        debugger.wait_idle(timeout=120)
        stepped = debugger.session.keyframes
        assert stepped >= 5, f"Play was starved under the load: {stepped} keyframes in {LOAD_S:.0f} s"  # mc-a steps ~10 per second alone
        assert len(debugger.history) <= 12 and debugger.history.bytes <= 2 * 2**20, (len(debugger.history), debugger.history.bytes)

        # After the load: the next step reaches both tabs, the same keyframe in each.
        worker.get_by_role("button", name="Step").click()
        expect(field(worker, "Shown")).to_have_value(re.compile(rf"^{stepped} \("), timeout=ANSWER_MS)
        expect(field(player, "Shown")).to_have_value(field(worker, "Shown").input_value(), timeout=ANSWER_MS)
        assert not [text for text in statuses if "error" in text], statuses
        grown = _rss_mb() - rss_start
        print(f"\ntwo tabs: {sum(actions.values())} actions in {time.monotonic() - began:.0f} s ({actions}); {stepped} keyframes played; server memory +{grown:.0f} MB")
        assert grown < 400, f"the server grew by {grown:.0f} MB under a capped history"
        player.close()
        worker.close()
    finally:
        debugger.stop()
