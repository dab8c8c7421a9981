"""The debugger's server with its door checked: viser's server, started so that every HTTP
request and websocket handshake passes the Host and Origin rules (viewer/access.py) and every
client frame passes the message rules (viewer/inbound.py) before viser handles it.

viser (pinned, 1.1.1) offers no hook for either: its websocket server calls
`websockets.asyncio.server.serve(ws_handler, host, port, process_request=...)` on its own
thread while `ViserServer.__init__` waits for it, and reads frames in a private loop. So the
narrowest point is that one call: while this module constructs the server (under a lock),
`websockets.asyncio.server.serve` is replaced by a function that hands the real one

- a `process_request` that answers 403 before viser's own (which serves the page) when the
  rules refuse the request, so a refused page never completes a handshake;
- a handler that gives viser's handler the connection behind a proxy whose `recv()` returns
  only admitted frames, so a refused frame is never decoded, dispatched or applied;
- a smaller frame limit and a logger that writes one line where websockets would log a
  traceback.

If a later viser starts its server another way, construction fails loudly instead of
serving unguarded (`GuardNotInstalledError`).
"""

from __future__ import annotations

import asyncio
import collections
import http
import logging
import threading
import time
from collections.abc import Awaitable, Callable
from typing import Any

import viser
import websockets.asyncio.server
from viser import _messages

from viewer.access import AccessSettings, OriginPolicy
from viewer.inbound import BUTTONS, InboundFilter, Verdict, control_label

log = logging.getLogger(__name__)
MAX_FRAME_BYTES = 2 * 2**20  # the largest client frame: viser's client sends uploads in 512 KiB parts
LOGGED_PER_CLIENT = 5  # refusals logged per client one by one; then one line per 100
NOTICE_INTERVAL_S = 0.5  # at most one "ignored" notification per tab this often

_construction_lock = threading.Lock()


class GuardNotInstalledError(RuntimeError):
    """viser no longer starts its server through websockets.asyncio.server.serve."""


class _OneLine(logging.Filter):
    """Turn a record with a traceback into one line naming the exception."""

    def filter(self, record: logging.LogRecord) -> bool:
        if record.exc_info and record.exc_info[1] is not None:
            e = record.exc_info[1]
            record.msg = f"{record.getMessage()}: {type(e).__name__}: {e}"
            record.args = ()
            record.exc_info = None
            record.exc_text = None
        return True


def _websockets_logger() -> logging.Logger:
    logger = logging.getLogger("coplanar.viewer.websocket")
    if not any(isinstance(f, _OneLine) for f in logger.filters):
        logger.addFilter(_OneLine())
    return logger


class _CheckedConnection:
    """A websockets ServerConnection whose recv() returns admitted frames only; everything
    else (send, close, subprotocol, request) is the connection's own."""

    def __init__(self, connection: websockets.asyncio.server.ServerConnection, guard: Guard) -> None:
        self._connection = connection
        self._guard = guard
        self.client_id: int | None = None

    def __getattr__(self, name: str) -> Any:
        return getattr(self._connection, name)

    async def recv(self, *args: Any, **kwargs: Any) -> Any:
        while True:
            frame = await self._connection.recv(*args, **kwargs)
            if self._guard.admit(self, frame):
                return frame


class Guard:
    """The checks of one server (module docstring) and their counts."""

    def __init__(self, *, host: str, access: AccessSettings) -> None:
        self.access = access
        self.server: viser.ViserServer | None = None
        self.installed = False
        self.policy = OriginPolicy(bind_host=host, allowed_origins=access.allowed_origins, share_origin=self._share_url)
        self.inbound = InboundFilter(find_control=self._find_control, is_command=self._is_command, share=access.share, max_upload_bytes=access.max_upload_bytes)
        self._lock = threading.Lock()
        self._accepted = 0
        self._refused: collections.Counter[str] = collections.Counter()
        self._refused_per_client: collections.Counter[int] = collections.Counter()
        self._handshakes_refused = 0
        self._noticed_at: dict[int, float] = {}

    # ---------------------------------------------------------------- viser's state

    def _share_url(self) -> str | None:
        tunnel = getattr(self.server, "_share_tunnel", None)
        return tunnel.get_url() if tunnel is not None else None

    def _find_control(self, client_id: int, uuid: str) -> Any:
        server = self.server
        if server is None:
            return None
        handle = server.gui._gui_input_handle_from_uuid.get(uuid)
        if handle is None:
            client = server.get_clients().get(client_id)
            handle = client.gui._gui_input_handle_from_uuid.get(uuid) if client is not None else None
        return handle

    def _is_command(self, uuid: str) -> bool:
        return self.server is not None and uuid in self.server.gui._command_handle_from_uuid

    def _client_id(self, connection: _CheckedConnection) -> int | None:
        if connection.client_id is None and self.server is not None:
            for client_id, live in tuple(self.server._websock_server._live_connections.items()):
                if live is connection:
                    connection.client_id = int(client_id)
        return connection.client_id

    # ---------------------------------------------------------------- hooks

    def serve(self, original: Callable[..., Any]) -> Callable[..., Any]:
        """`websockets.asyncio.server.serve` with the checks added (module docstring)."""

        def serve(handler: Callable[[Any], Awaitable[None]], *args: Any, **kwargs: Any) -> Any:
            self.installed = True
            kwargs["process_request"] = self._process_request(kwargs.get("process_request"))
            kwargs["max_size"] = MAX_FRAME_BYTES
            kwargs["logger"] = _websockets_logger()

            async def checked_handler(connection: websockets.asyncio.server.ServerConnection) -> None:
                await handler(_CheckedConnection(connection, self))

            return original(checked_handler, *args, **kwargs)

        return serve

    def _process_request(self, inner: Callable[..., Any] | None) -> Callable[..., Any]:
        def process_request(connection: websockets.asyncio.server.ServerConnection, request: Any) -> Any:
            headers = request.headers
            upgrade = [v.lower() for v in headers.get_all("Upgrade")]
            why = self.policy.refusal(headers, get_all=headers.get_all, websocket="websocket" in upgrade)
            if why is not None:
                with self._lock:
                    self._handshakes_refused += 1
                    count = self._handshakes_refused
                if count <= 20 or count % 100 == 0:
                    log.warning("refused %s (%d refused so far): %s", "a websocket" if upgrade else f"GET {request.path[:80]!r}", count, why)
                return connection.respond(http.HTTPStatus.FORBIDDEN, f"coplanar debugger: {why}\n")
            return inner(connection, request) if inner is not None else None

        return process_request

    def admit(self, connection: _CheckedConnection, frame: bytes | str) -> bool:
        """Whether viser may handle `frame` from `connection`'s client; a refusal is counted,
        logged (rate-limited) and, for a control's value, told to that tab."""
        client_id = self._client_id(connection)
        if client_id is None:  # the server is still being built: nothing to drive yet
            verdict = Verdict(False, "early", "the server is not ready")
        else:
            try:
                verdict = self.inbound.check(client_id, frame)
            except Exception as e:
                log.error("checking a frame from client %s failed (refused): %s: %s", client_id, type(e).__name__, e)
                verdict = Verdict(False, "check failed", f"{type(e).__name__}: {e}")
        with self._lock:
            if verdict.accepted:
                self._accepted += 1
                return True
            self._refused[verdict.kind] += 1
            cid = -1 if client_id is None else client_id
            self._refused_per_client[cid] += 1
            count = self._refused_per_client[cid]
        if count <= LOGGED_PER_CLIENT or count % 100 == 0:
            log.warning("ignored a %s from client %s (%d ignored from it): %s", verdict.kind, cid, count, verdict.reason)
        if verdict.control is not None and client_id is not None:
            self._tell(client_id, verdict)
        return False

    def _tell(self, client_id: int, verdict: Verdict, *, tries: int = 20) -> None:
        """Say in the tab why its value was ignored, and set its widget back. A tab counts
        as connected once viser has handled its first camera message, which may still be on
        its way: then try again shortly (on the server's event loop, where this runs)."""
        server = self.server
        client = server.get_clients().get(client_id) if server is not None else None
        if client is None:
            if tries > 0:
                asyncio.get_running_loop().call_later(0.05, lambda: self._tell(client_id, verdict, tries=tries - 1))
            return
        handle = verdict.control
        assert handle is not None
        if not isinstance(handle, BUTTONS):
            client._websock_connection.queue_message(_messages.GuiUpdateMessage(handle._impl.uuid, {"value": handle.value}))
        now = time.monotonic()
        if now - self._noticed_at.get(client_id, -1e9) < NOTICE_INTERVAL_S:
            return
        self._noticed_at[client_id] = now
        client.add_notification(f"Ignored: {control_label(handle)}", verdict.reason, auto_close_seconds=6.0, color="yellow")

    def forget(self, client_id: int) -> None:
        self.inbound.forget(client_id)
        with self._lock:
            self._noticed_at.pop(client_id, None)

    def figures(self) -> dict[str, Any]:
        """Counts so far: frames accepted and refused (by kind), handshakes refused."""
        with self._lock:
            return {
                "accepted": self._accepted,
                "refused": sum(self._refused.values()),
                "refused_by_kind": dict(self._refused.most_common()),
                "handshakes_refused": self._handshakes_refused,
            }


def start_server(*, host: str, port: int, access: AccessSettings = AccessSettings(), label: str | None = None) -> tuple[viser.ViserServer, Guard]:
    """viser's server on `host:port` behind a Guard (module docstring)."""
    guard = Guard(host=host, access=access)
    with _construction_lock:
        original = websockets.asyncio.server.serve
        websockets.asyncio.server.serve = guard.serve(original)  # type: ignore[assignment,misc]
        try:
            server = viser.ViserServer(host=host, port=port, label=label)
        finally:
            websockets.asyncio.server.serve = original  # type: ignore[misc]
    if not guard.installed:
        server.stop()
        raise GuardNotInstalledError(
            f"viser {viser.__version__} did not start its server through websockets.asyncio.server.serve: viewer/guard.py was written against viser 1.1.1 and will not serve unchecked"
        )
    missing = [
        name
        for owner, name in (
            (server._websock_server, "_live_connections"),
            (server.gui, "_gui_input_handle_from_uuid"),
            (server.gui, "_command_handle_from_uuid"),
        )
        if not hasattr(owner, name)
    ]
    if missing:
        server.stop()
        raise GuardNotInstalledError(f"viser {viser.__version__} lacks {', '.join(missing)}: viewer/guard.py was written against viser 1.1.1")
    guard.server = server
    server.on_client_disconnect(lambda client: guard.forget(client.client_id))
    return server, guard
