"""The guard itself (viewer/guard.py): it fails closed when viser changes under it, keeps a
connection open when a check fails, and admits real uploads to real upload controls."""

from __future__ import annotations

import logging
import time

import pytest
import viser

from tests.viewer.raw_client import RawClient, free_port
from viewer import guard as guard_module
from viewer.access import AccessSettings
from viewer.guard import GuardNotInstalledError, start_server


def _wait(predicate, timeout: float = 10.0) -> bool:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline and not predicate():
        time.sleep(0.02)
    return predicate()


def test_a_viser_that_starts_its_server_another_way_is_not_served(monkeypatch: pytest.MonkeyPatch) -> None:
    stopped = []

    class OtherViser:
        def __init__(self, **kwargs: object) -> None:
            pass  # never calls websockets.asyncio.server.serve

        def stop(self) -> None:
            stopped.append(True)

    monkeypatch.setattr(viser, "ViserServer", OtherViser)
    with pytest.raises(GuardNotInstalledError, match="1.1.1"):
        start_server(host="127.0.0.1", port=free_port())
    assert stopped == [True]


def test_a_failing_check_refuses_the_frame_and_keeps_the_connection(monkeypatch: pytest.MonkeyPatch, caplog: pytest.LogCaptureFixture) -> None:
    server, guard = start_server(host="127.0.0.1", port=free_port())
    try:
        clicks: list[int] = []
        button = server.gui.add_button("Go")
        button.on_click(lambda _: clicks.append(1))
        with RawClient(server.get_port()) as client:
            assert _wait(lambda: len(server.get_clients()) == 1)  # its camera message handled
            check = guard.inbound.check
            calls = []

            def broken_once(client_id: int, frame: bytes | str):
                calls.append(1)
                if len(calls) == 1:
                    raise KeyError("a bug in a check")
                return check(client_id, frame)

            monkeypatch.setattr(guard.inbound, "check", broken_once)
            client.click(client.uuid("Go"))  # refused by the failing check
            client.click(client.uuid("Go"))  # the same connection still works
            assert _wait(lambda: clicks == [1])
        errors = [r.getMessage() for r in caplog.records if r.levelno >= logging.ERROR]
        assert len(errors) == 1 and "KeyError" in errors[0] and not any(r.exc_info for r in caplog.records)
    finally:
        server.stop()


def test_an_upload_control_takes_a_file_within_the_limit() -> None:
    server, guard = start_server(host="127.0.0.1", port=free_port(), access=AccessSettings(max_upload_bytes=10))
    try:
        files: list[bytes] = []
        upload = server.gui.add_upload_button("Scene file")
        upload.on_upload(lambda _: files.append(upload.value.content))
        with RawClient(server.get_port()) as client:
            target = client.uuid("Scene file")
            assert _wait(lambda: len(server.get_clients()) == 1)
            client.send("FileTransferStartUpload", source_component_uuid=target, transfer_uuid="ok", filename="a.json", mime_type="application/json", part_count=2, size_bytes=6)
            client.send("FileTransferPart", source_component_uuid=target, transfer_uuid="ok", part_index=0, content=b"abc")
            client.send("FileTransferPart", source_component_uuid=target, transfer_uuid="ok", part_index=1, content=b"def")
            assert _wait(lambda: files == [b"abcdef"])
            client.send("FileTransferStartUpload", source_component_uuid=target, transfer_uuid="big", filename="b.json", mime_type="application/json", part_count=1, size_bytes=11)
            client.send("FileTransferPart", source_component_uuid=target, transfer_uuid="big", part_index=0, content=b"x" * 11)
            client.send("FileTransferStartUpload", source_component_uuid=target, transfer_uuid="lie", filename="c.json", mime_type="application/json", part_count=1, size_bytes=2)
            client.send("FileTransferPart", source_component_uuid=target, transfer_uuid="lie", part_index=0, content=b"longer")
            assert _wait(lambda: guard.figures()["refused"] == 3)
            assert any("up to" in n["props"]["body"] for n in client.read(timeout=0.5) if n["type"] == "NotificationShowMessage")
        assert files == [b"abcdef"]
        assert guard.figures()["refused_by_kind"] == {"FileTransferStartUpload": 1, "FileTransferPart": 2}
    finally:
        server.stop()


def test_the_websockets_serve_function_is_restored() -> None:
    import websockets.asyncio.server

    original = websockets.asyncio.server.serve
    server, _ = start_server(host="127.0.0.1", port=free_port())
    server.stop()
    assert websockets.asyncio.server.serve is original
    assert guard_module.MAX_FRAME_BYTES >= 512 * 1024 + 1024  # an upload part of viser's client fits a frame
