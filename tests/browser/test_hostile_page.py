"""A hostile web page open in the same browser as the debugger: it can neither connect to
the debugger's websocket from its own origin nor load the debugger under its own name (DNS
rebinding, simulated with Chromium's host resolver rules)."""

from __future__ import annotations

import http.server
import threading
from collections.abc import Iterator

import pytest
import viser

from tests.browser.conftest import CHROMIUM, FLAGS, TIMEOUT_MS, free_port

pytestmark = pytest.mark.hostile_page  # refused handshakes are these tests' point (conftest.nothing_refused)

PROBE = """async ([url, protocol]) => await new Promise((done) => {
  const ws = new WebSocket(url, protocol);
  ws.onopen = () => { ws.close(); done("open"); };
  ws.onerror = () => done("refused");
  setTimeout(() => done("timeout"), 10000);
})"""


@pytest.fixture
def hostile_site() -> Iterator[int]:
    """An unrelated site on another port: a page with nothing on it."""

    class Page(http.server.BaseHTTPRequestHandler):
        def do_GET(self) -> None:
            body = b"<html><body>cute cats</body></html>"
            self.send_response(200)
            self.send_header("Content-Type", "text/html")
            self.send_header("Content-Length", str(len(body)))
            self.end_headers()
            self.wfile.write(body)

        def log_message(self, *args: object) -> None:
            pass

    server = http.server.ThreadingHTTPServer(("127.0.0.1", free_port()), Page)
    threading.Thread(target=server.serve_forever, daemon=True).start()
    yield server.server_address[1]
    server.shutdown()


def test_a_page_from_another_site_cannot_open_the_debuggers_websocket(browser, debugger, hostile_site) -> None:
    page = browser.new_page()
    page.set_default_timeout(TIMEOUT_MS)
    protocol = f"viser-v{viser.__version__}"
    page.goto(f"http://127.0.0.1:{hostile_site}/")
    assert page.evaluate(PROBE, [f"ws://127.0.0.1:{debugger.port}", protocol]) == "refused"
    page.goto(f"http://127.0.0.1:{debugger.port}/")  # the debugger's own page: the same call connects
    assert page.evaluate(PROBE, [f"ws://127.0.0.1:{debugger.port}", protocol]) == "open"
    page.close()
    assert debugger.steps_done == 0
    assert debugger.guard.figures()["handshakes_refused"] == 1


def test_a_hostile_name_that_resolves_to_this_machine_gets_no_page(browser, debugger) -> None:
    """DNS rebinding: evil.example resolves to 127.0.0.1; its page would be same-origin with
    a websocket to evil.example:PORT. The Host header names it, and the debugger refuses."""
    rebound = browser.browser_type.launch(executable_path=str(CHROMIUM), args=[*FLAGS, "--host-resolver-rules=MAP evil.example 127.0.0.1"])
    try:
        page = rebound.new_page()
        page.set_default_timeout(TIMEOUT_MS)
        response = page.goto(f"http://evil.example:{debugger.port}/")
        assert response is not None and response.status == 403
        assert "not this machine" in page.content()
        protocol = f"viser-v{viser.__version__}"
        assert page.evaluate(PROBE, [f"ws://evil.example:{debugger.port}", protocol]) == "refused"
        assert page.goto(f"http://localhost:{debugger.port}/").status == 200  # the same browser, the right name
    finally:
        rebound.close()
    assert debugger.steps_done == 0
    assert debugger.guard.figures()["handshakes_refused"] >= 2  # the page, its websocket (and the favicon)
