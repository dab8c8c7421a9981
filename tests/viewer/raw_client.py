"""A websocket client that speaks viser's wire format without a browser: what a hostile web
page or a local script can send to the debugger. Client messages are plain msgpack maps with
a "type"; server frames are [8 bytes raw size][8 bytes compressed size][zstd msgpack]
followed by binary buffers (viser.infra._infra._message_producer)."""

from __future__ import annotations

import socket
import time
from collections.abc import Iterator
from typing import Any

import msgspec
import viser
import zstandard
from websockets.sync.client import ClientConnection, connect

SUBPROTOCOL = f"viser-v{viser.__version__}"

# A camera as a browser reports it: viser counts a client as connected (and runs GUI
# callbacks for it) only after its first camera message.
CAMERA: dict[str, Any] = {
    "wxyz": [1.0, 0.0, 0.0, 0.0],
    "position": [0.0, 0.0, 5.0],
    "fov": 1.0,
    "near": 0.01,
    "far": 100.0,
    "image_height": 600,
    "image_width": 800,
    "look_at": [0.0, 0.0, 0.0],
    "up_direction": [0.0, 0.0, 1.0],
}


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def decode_frame(frame: bytes) -> list[dict[str, Any]]:
    """The messages of one server frame."""
    raw_size = int.from_bytes(frame[:8], "little")
    compressed_size = int.from_bytes(frame[8:16], "little")
    inner = zstandard.ZstdDecompressor().decompress(frame[16 : 16 + compressed_size], max_output_size=raw_size)
    return list(msgspec.msgpack.decode(inner)["messages"])


class RawClient:
    """One websocket connection to the debugger on `address`:`port`, with `origin` as the
    Origin header (None: none, as a non-browser client sends)."""

    def __init__(self, port: int, *, origin: str | None = None, address: str = "127.0.0.1", camera: bool = True) -> None:
        self.ws: ClientConnection = connect(
            f"ws://{address}:{port}",
            origin=origin,
            subprotocols=[SUBPROTOCOL],
            open_timeout=10,
            max_size=None,  # type: ignore[list-item]
        )
        self.messages: list[dict[str, Any]] = []
        self.read(until="ReplayDoneMessage")
        if camera:
            self.send("ViewerCameraMessage", **CAMERA)

    def send(self, type_name: str, **fields: Any) -> None:
        self.ws.send(msgspec.msgpack.encode({"type": type_name, **fields}))

    def send_raw(self, data: bytes | str) -> None:
        self.ws.send(data)

    def click(self, uuid: str) -> None:
        self.send("GuiUpdateMessage", uuid=uuid, updates={"value": True})

    def set_value(self, uuid: str, value: Any) -> None:
        self.send("GuiUpdateMessage", uuid=uuid, updates={"value": value})

    def read(self, *, until: str | None = None, timeout: float = 10.0) -> list[dict[str, Any]]:
        """Messages received until one of type `until` arrives (None: until `timeout`
        passes quietly, 0.3 s)."""
        got: list[dict[str, Any]] = []
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            try:
                frame = self.ws.recv(timeout=0.3 if until is None else max(deadline - time.monotonic(), 0.01))
            except TimeoutError:
                if until is None:
                    break
                continue
            assert isinstance(frame, bytes)
            batch = decode_frame(frame)
            got += batch
            if until is not None and any(m["type"] == until for m in batch):
                break
        self.messages += got
        return got

    def drain(self) -> None:
        """Take the frames already received, without waiting (so the server is never held
        up by a client that does not read)."""
        while True:
            try:
                frame = self.ws.recv(timeout=0)
            except TimeoutError:
                return
            assert isinstance(frame, bytes)
            self.messages += decode_frame(frame)

    def uuid(self, label: str) -> str:
        """The uuid of the control labelled `label`, from the messages that built the GUI."""
        for m in self.messages:
            if m["type"].startswith("Gui") and isinstance(m.get("props"), dict) and m["props"].get("label") == label:
                return str(m["uuid"])
        raise KeyError(label)

    def command(self, label: str) -> str:
        """The uuid of the keyboard command labelled `label`."""
        for m in self.messages:
            if m["type"] == "RegisterCommandMessage" and m["props"].get("label") == label:
                return str(m["uuid"])
        raise KeyError(label)

    def notifications(self) -> Iterator[dict[str, Any]]:
        return (m for m in self.messages if m["type"] == "NotificationShowMessage")

    def close(self) -> None:
        self.ws.close()

    def __enter__(self) -> RawClient:
        return self

    def __exit__(self, *_: object) -> None:
        self.close()


def http_status(port: int, *, host: str, origin: str | None = None, websocket: bool = False, path: str = "/") -> int:
    """The status code the debugger answers a request for `path` with the given Host (and
    Origin) header; `websocket`: an upgrade request as a browser's WebSocket sends."""
    lines = [f"GET {path} HTTP/1.1", f"Host: {host}"]
    if origin is not None:
        lines.append(f"Origin: {origin}")
    if websocket:
        lines += [
            "Upgrade: websocket",
            "Connection: Upgrade",
            "Sec-WebSocket-Key: dGhlIHNhbXBsZSBub25jZQ==",
            "Sec-WebSocket-Version: 13",
            f"Sec-WebSocket-Protocol: {SUBPROTOCOL}",
        ]
    with socket.create_connection(("127.0.0.1", port), timeout=10) as s:
        s.sendall(("\r\n".join(lines) + "\r\n\r\n").encode())
        head = b""
        while b"\r\n" not in head:
            chunk = s.recv(4096)
            if not chunk:
                break
            head += chunk
    return int(head.split(b" ", 2)[1])
