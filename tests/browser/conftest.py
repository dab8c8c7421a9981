"""Browser tests: Playwright drives Debian's Chromium (headless, software WebGL) against a
debugger served in-process on a free port. `scripts/test.sh` installs Chromium where
missing; without it these tests skip with the reason."""

from __future__ import annotations

import os
import pathlib
import re
import socket
from collections.abc import Iterator

import pytest

CHROMIUM = pathlib.Path(os.environ.get("COPLANAR_CHROMIUM", "/usr/bin/chromium"))
FLAGS = [
    "--headless",
    "--no-sandbox",
    "--disable-gpu",
    "--disable-quic",
    "--no-first-run",
    "--disable-background-networking",
    "--disable-component-update",
    "--disable-sync",
]
TIMEOUT_MS = 60_000


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


@pytest.fixture(scope="session")
def browser() -> Iterator[object]:
    if not CHROMIUM.exists():
        pytest.skip(f"{CHROMIUM} is missing: run `bash scripts/test.sh` as root to install Debian's chromium")
    playwright_api = pytest.importorskip("playwright.sync_api", reason="playwright is not installed (pip install -e .[test])")
    with playwright_api.sync_playwright() as p:
        b = p.chromium.launch(executable_path=str(CHROMIUM), args=FLAGS)
        yield b
        b.close()


_started: list[object] = []  # the debuggers a test started, checked after it (nothing_refused)


@pytest.fixture(autouse=True)
def nothing_refused(request: pytest.FixtureRequest) -> Iterator[None]:
    """A browser is the debugger's own page: every message it sends in a user's whole
    session must pass the guard (viewer/inbound.py), or the guard is refusing a real use.
    Tests marked `hostile_page` open other pages too, whose refused handshakes they check."""
    _started.clear()
    yield
    hostile = request.node.get_closest_marker("hostile_page") is not None
    for d in _started:
        figures = d.guard.figures()  # type: ignore[attr-defined]
        assert figures["refused"] == 0 and (hostile or figures["handshakes_refused"] == 0), figures
    _started.clear()


def start_debugger(*, sequence: str = "a", settings: object = None, **engine_options: object):
    """A debugger on a free port over the Monte-Carlo engine (with viewer `settings`, a
    ViewerSettings, where given), with the HDRI off (it stalls software rendering)."""
    from backend.pipeline.sim_engine import SimEngine, SimSettings
    from viewer.app import Debugger
    from viewer.settings import ViewerSettings

    debugger = Debugger(SimEngine(SimSettings(sequence=sequence, **engine_options)), port=free_port(), settings=settings or ViewerSettings())
    debugger.server.scene.configure_environment_map(hdri=None)
    _started.append(debugger)
    return debugger


def start_served(*argv: str):
    """A debugger on a free port over the engine `coplanar serve ARGV` builds, HDRI off."""
    from app.cli import build_parser
    from app.serve_command import build_engine
    from viewer.app import Debugger

    debugger = Debugger(build_engine(build_parser().parse_args(["serve", *argv])), port=free_port())
    debugger.server.scene.configure_environment_map(hdri=None)
    _started.append(debugger)
    return debugger


@pytest.fixture
def debugger() -> Iterator[object]:
    d = start_debugger()
    yield d
    d.stop()


def open_page(browser, debugger, *, width: int = 1400, height: int = 900, pixel_ratio: float = 1.0):
    """The debugger's page in a `width`×`height` CSS px window on a display of
    `pixel_ratio`, rendered at that ratio throughout: viser's `fixedDpr` turns off its
    adaptive resolution, which lowers the 3D view's device pixels by up to a quarter
    whenever software rendering is slow (a busy CI machine), and the debugger sizes
    windows from them."""
    page = browser.new_page(viewport={"width": width, "height": height}, device_scale_factor=pixel_ratio, accept_downloads=True)
    page.set_default_timeout(TIMEOUT_MS)
    page.goto(f"http://127.0.0.1:{debugger.port}/?fixedDpr={pixel_ratio:g}")
    page.get_by_role("button", name="Step").wait_for()
    return page


def field(page, label: str):
    """The input of the GUI row labelled `label` (viser rows: a label and an input)."""
    lab = page.locator("label").filter(has_text=re.compile(f"^{re.escape(label)}$"))
    return lab.locator("xpath=ancestor::div[contains(@class,'mantine-Flex-root')][1]").locator("input:not([type=hidden])").first


def wait_shown(page, text: str) -> None:
    """Wait until the 'Shown' field (updated last in every scene update) reads `text`."""
    from playwright.sync_api import expect

    expect(field(page, "Shown")).to_have_value(text, timeout=TIMEOUT_MS)


def close_notifications(page) -> None:
    """Close notifications such as Chromium's "software WebGL" before a screenshot."""
    close = page.locator(".mantine-Notification-closeButton")
    for i in range(close.count()):
        close.nth(i).click()
