"""The debugger's websocket against hostile clients (a raw viser client, as a web page or a
local script can open one): who may connect, which messages reach the debugger, which values
reach the engine, and how a burst of commands is queued. Each case failed on the code before
the guard (viewer/guard.py): the note in the changelog gives the before and after."""

from __future__ import annotations

import logging
import math
import os
import random
import threading
import time
from collections.abc import Callable, Iterator
from typing import Any

import msgspec
import pytest
from websockets.exceptions import InvalidStatus

from backend.pipeline.sim_engine import SimEngine, SimSettings
from backend.pipeline.snapshot import Snapshot
from tests.viewer.raw_client import CAMERA, RawClient, free_port, http_status
from viewer.access import AccessSettings
from viewer.app import Debugger, ViewerSettings

EVIL = "http://evil.example.com"


def _start(engine: object | None = None, *, access: AccessSettings = AccessSettings()) -> Debugger:
    engine = engine if engine is not None else SimEngine(SimSettings(window=4, max_iterations=2))
    d = Debugger(engine, port=free_port(), settings=ViewerSettings(compare=False, plots=False), access=access)  # type: ignore[arg-type]
    d.server.scene.configure_environment_map(hdri=None)
    return d


@pytest.fixture
def debugger() -> Iterator[Debugger]:
    d = _start()
    yield d
    d.stop()


def _wait(predicate: Callable[[], bool], timeout: float = 10.0) -> bool:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if predicate():
            return True
        time.sleep(0.02)
    return predicate()


def _steps_after_click(d: Debugger, client: RawClient) -> int:
    before = d.steps_done
    client.click(client.uuid("Step"))
    _wait(lambda: d.steps_done > before)
    d.wait_idle()
    return d.steps_done - before


def _settle(client: RawClient) -> None:
    """Wait until the server has handled everything `client` sent: its messages are handled
    in order, so a camera message sent last and echoed in a later GUI broadcast is not
    needed; a short read that drains the socket suffices for the event loop to catch up."""
    client.send("ViewerCameraMessage", **CAMERA)
    client.read(timeout=0.5)


# ---------------------------------------------------------------- who may connect


def test_a_page_from_another_origin_is_refused_at_the_handshake(debugger: Debugger) -> None:
    d = debugger
    assert http_status(d.port, host=f"127.0.0.1:{d.port}", origin=EVIL, websocket=True) == 403
    with pytest.raises(InvalidStatus) as refused:
        RawClient(d.port, origin=EVIL)
    assert refused.value.response.status_code == 403
    assert http_status(d.port, host=f"127.0.0.1:{d.port}", origin="null", websocket=True) == 403  # a sandboxed frame or a file
    assert d.steps_done == 0


@pytest.mark.parametrize("origin", ["own", "localhost", None])
def test_the_debuggers_own_pages_and_local_scripts_connect(debugger: Debugger, origin: str | None) -> None:
    d = debugger
    header = {"own": f"http://127.0.0.1:{d.port}", "localhost": f"http://localhost:{d.port}", None: None}[origin]
    with RawClient(d.port, origin=header, address="localhost" if origin == "localhost" else "127.0.0.1") as client:
        assert _steps_after_click(d, client) == 1


def test_a_host_name_that_is_not_this_machine_is_refused(debugger: Debugger) -> None:
    """DNS rebinding: a hostile name that resolves to 127.0.0.1 loads the page from its own
    origin; the Host header still names it."""
    d = debugger
    port = d.port
    assert http_status(port, host=f"evil.example.com:{port}") == 403
    assert http_status(port, host=f"evil.example.com:{port}", origin=f"http://evil.example.com:{port}", websocket=True) == 403
    assert http_status(port, host=f"127.0.0.1:{port}") == 200
    assert http_status(port, host=f"localhost:{port}") == 200
    assert http_status(port, host=f"[::1]:{port}") == 200
    assert http_status(port, host=f"127.0.0.1:{port}", origin=f"http://127.0.0.1:{port}", websocket=True) == 101


def test_allow_origin_admits_a_named_origin_and_its_host() -> None:
    d = _start(access=AccessSettings(allowed_origins=("https://slam.lab.example",)))
    try:
        with RawClient(d.port, origin="https://slam.lab.example") as client:
            assert _steps_after_click(d, client) == 1
        assert http_status(d.port, host="slam.lab.example") == 200  # behind a proxy that keeps the Host
        assert http_status(d.port, host=f"127.0.0.1:{d.port}", origin=EVIL, websocket=True) == 403
    finally:
        d.stop()


# ---------------------------------------------------------------- which messages


def _share_recorder(d: Debugger) -> list[str]:
    calls: list[str] = []
    d.server.request_share_url = lambda *a, **k: calls.append("request")  # type: ignore[method-assign]
    d.server.disconnect_share_url = lambda *a, **k: calls.append("disconnect")  # type: ignore[method-assign]
    return calls


def test_share_requests_are_ignored_unless_share_was_given(debugger: Debugger) -> None:
    calls = _share_recorder(debugger)
    with RawClient(debugger.port) as client:
        client.send("ShareUrlRequest")
        client.send("ShareUrlDisconnect")
        _settle(client)
        assert _steps_after_click(debugger, client) == 1
    time.sleep(0.3)
    assert calls == []


def test_share_requests_are_served_with_share() -> None:
    d = _start(access=AccessSettings(share=True))
    try:
        calls = _share_recorder(d)
        with RawClient(d.port) as client:
            client.send("ShareUrlRequest")
            assert _wait(lambda: calls == ["request"])
    finally:
        d.stop()


def test_an_upload_aimed_at_a_slider_is_refused_and_play_still_steps(debugger: Debugger) -> None:
    d = debugger
    with RawClient(d.port) as client:
        rate = client.uuid("Rate (Hz)")
        client.send("FileTransferStartUpload", source_component_uuid=rate, transfer_uuid="t1", filename="x.bin", mime_type="application/octet-stream", part_count=1, size_bytes=4)
        client.send("FileTransferPart", source_component_uuid=rate, transfer_uuid="t1", part_index=0, content=b"abcd")
        _settle(client)
        assert d.rate.value == 5.0
        client.set_value(client.uuid("Play"), True)
        assert _wait(lambda: d.steps_done >= 3), d.status.content
        client.set_value(client.uuid("Play"), False)
    assert "error" not in d.status.content


def _rss_mb() -> float:
    with open(f"/proc/{os.getpid()}/statm") as f:
        return int(f.read().split()[1]) * os.sysconf("SC_PAGE_SIZE") / 2**20


def test_parts_of_an_unfinished_upload_are_not_kept(debugger: Debugger) -> None:
    d = debugger
    part = b"\x00" * 2**20
    with RawClient(d.port) as client:
        before = _rss_mb()
        client.send(
            "FileTransferStartUpload",
            source_component_uuid=client.uuid("Step"),
            transfer_uuid="big",
            filename="x.bin",
            mime_type="application/octet-stream",
            part_count=300,
            size_bytes=300 * len(part),
        )
        for i in range(100):
            client.send("FileTransferPart", source_component_uuid=client.uuid("Step"), transfer_uuid="big", part_index=i, content=part)
        _settle(client)
        grown = _rss_mb() - before
        assert grown < 50, f"{grown:.0f} MB kept for 100 MB of parts"
        assert _steps_after_click(d, client) == 1


def test_clients_cannot_overwrite_a_controls_internals(debugger: Debugger) -> None:
    d = debugger
    with RawClient(d.port) as hostile:
        step, play = hostile.uuid("Step"), hostile.uuid("Play")
        hostile.send("GuiUpdateMessage", uuid=step, updates={"update_cb": [], "removed": True, "is_button": False})
        hostile.send("GuiUpdateMessage", uuid=step, updates={"value": True, "disabled": True})
        hostile.send("GuiUpdateMessage", uuid=play, updates={"sync_cb": None})
        hostile.send("GuiUpdateMessage", uuid=play, updates={"no_such_property": 1})
        _settle(hostile)
    assert d.steps_done == 0  # the message that also wrote `disabled` was refused whole
    with RawClient(d.port) as first, RawClient(d.port) as second:
        assert _steps_after_click(d, first) == 1  # Step still works, in a tab opened later too
        second.set_value(second.uuid("Play"), True)  # Play still reaches the other tabs
        assert _wait(lambda: any(m["type"] == "GuiUpdateMessage" and m["uuid"] == play and m["updates"] == {"value": True} for m in first.read(timeout=0.5)))
        second.set_value(second.uuid("Play"), False)


BAD_VALUES = {
    "rate-nan": ("Rate (Hz)", math.nan),
    "rate-inf": ("Rate (Hz)", math.inf),
    "rate-zero": ("Rate (Hz)", 0.0),
    "rate-negative": ("Rate (Hz)", -2.0),
    "rate-huge": ("Rate (Hz)", 1e9),
    "rate-text": ("Rate (Hz)", "fast"),
    "rate-bool": ("Rate (Hz)", True),
    "rate-list": ("Rate (Hz)", [1.0]),
    "play-text": ("Play", "yes"),
    "play-number": ("Play", 1),
    "variant-unknown": ("Variant", "P-x"),
    "variant-number": ("Variant", 3),
    "ab-unknown": ("B variant", "nope"),
    "keyframe-disabled": ("Keyframe", 1),
    "point-size-inf": ("Point size", math.inf),
    "shown-is-read-only": ("Shown", "99 (PL-w)"),
    "button-false": ("Reset", False),
}


@pytest.mark.parametrize("case", list(BAD_VALUES))
def test_a_bad_value_is_refused_with_a_message_and_the_engine_keeps_stepping(debugger: Debugger, case: str) -> None:
    d = debugger
    label, value = BAD_VALUES[case]
    handles = {
        "Rate (Hz)": d.rate,
        "Play": d.play,
        "Variant": d.variant,
        "B variant": d.ab_variant,
        "Keyframe": d.slider,
        "Point size": d.point_scale,
        "Shown": d.keyframe_label,
        "Reset": d.reset_button,
    }
    before = handles[label].value
    with RawClient(d.port) as client:
        client.set_value(client.uuid(label), value)
        _settle(client)
        assert handles[label].value == before or (isinstance(before, float) and math.isnan(before))
        said = [n for n in client.notifications() if label in n["props"]["title"] + n["props"]["body"]]
        assert said, f"no message about {label}"
        if label != "Reset":  # and the tab's widget is set back to the value in force
            uuid = client.uuid(label)
            assert any(m["type"] == "GuiUpdateMessage" and m["uuid"] == uuid and m["updates"] == {"value": before} for m in client.messages)
        assert _steps_after_click(d, client) == 1
        client.set_value(client.uuid("Play"), True)  # and the worker still times Play with a sane rate
        assert _wait(lambda: d.steps_done >= 3)
        client.set_value(client.uuid("Play"), False)
    assert "error" not in d.status.content
    assert d.rate.value == 5.0


def test_a_non_finite_camera_in_one_tab_does_not_stop_the_others(debugger: Debugger) -> None:
    d = debugger
    d.follow.value = True
    with RawClient(d.port) as broken, RawClient(d.port) as healthy:
        broken.send("ViewerCameraMessage", **{**CAMERA, "position": [math.nan, 0.0, 5.0]})
        broken.send("ViewerCameraMessage", **{**CAMERA, "look_at": [0.0, math.inf, 0.0], "fov": -1.0})
        _settle(healthy)
        for _ in range(3):
            d.submit("step")
        d.wait_idle()
        assert d.shown is not None and d.shown.keyframe == 2
        assert "error" not in d.status.content, d.status.content
        moved = [m for m in healthy.read(timeout=1.0) if m["type"] == "SetCameraPositionMessage"]
        assert moved, "the healthy tab is no longer followed"


class SlowEngine(SimEngine):
    """The Monte-Carlo engine with 0.2 s per step: a burst of Steps takes long to run."""

    STATE = (*SimEngine.STATE, "steps")

    def __init__(self) -> None:
        super().__init__(SimSettings(window=4, max_iterations=2))
        self.steps = 0

    def step(self) -> Snapshot:
        time.sleep(0.2)
        self.steps += 1
        return super().step()


def test_a_burst_of_steps_is_one_pending_step_and_reset_acts_at_once() -> None:
    engine = SlowEngine()
    d = _start(engine)
    try:
        with RawClient(d.port) as client:
            step, step_key, reset = client.uuid("Step"), client.command("Step"), client.uuid("Reset")
            for _ in range(100):
                client.click(step)
                client.send("CommandTriggerMessage", uuid=step_key)  # the → key
            client.click(reset)
            t0 = time.monotonic()
            assert _wait(lambda: "reset" in d.status.content, timeout=5.0), f"Reset not done after 5 s ({engine.steps} steps run)"
            took = time.monotonic() - t0
        d.wait_idle()
        assert engine.steps <= 3 and took < 2.0, (engine.steps, took)
        assert d.shown is None
    finally:
        d.stop()


# ---------------------------------------------------------------- random messages


def _random_value(rng: random.Random, depth: int = 0) -> Any:
    kind = rng.randrange(11 if depth < 2 else 8)
    return [
        lambda: None,
        lambda: rng.random() < 0.5,
        lambda: rng.randint(-(2**40), 2**40),
        lambda: rng.uniform(-1e6, 1e6),
        lambda: rng.choice([math.nan, math.inf, -math.inf, 0.0, -0.0, 1e308]),
        lambda: "".join(chr(rng.randrange(0x20, 0x2FFF)) for _ in range(rng.randrange(12))),
        lambda: rng.randbytes(rng.randrange(40)),
        lambda: rng.choice(["value", "PL-w", "off", "", "\x00"]),
        lambda: [_random_value(rng, depth + 1) for _ in range(rng.randrange(5))],
        lambda: {rng.choice(["value", "uuid", "updates", "removed", "sync_cb", "x"]): _random_value(rng, depth + 1) for _ in range(rng.randrange(4))},
        lambda: [rng.uniform(-5, 5) for _ in range(rng.choice([2, 3, 4]))],
    ][kind]()


CLIENT_TYPES = [
    "GuiUpdateMessage",
    "ViewerCameraMessage",
    "CommandTriggerMessage",
    "ShareUrlRequest",
    "ShareUrlDisconnect",
    "FileTransferStartUpload",
    "FileTransferPart",
    "GuiButtonHoldMessage",
    "GuiFormSubmitMessage",
    "GuiFormDirtyMessage",
    "SceneNodeClickMessage",
    "ScenePointerMessage",
    "TransformControlsUpdateMessage",
    "GetRenderResponseMessage",
    "LocalStorageGetItemResponseMessage",
    "ThemeConfigurationMessage",
    "ResetSceneMessage",
    "RemoveSceneNodeMessage",
]


def random_messages(rng: random.Random, uuids: list[str], count: int) -> Iterator[tuple[str, bytes | str]]:
    """`count` (kind, frame) pairs: undecodable bytes and text frames, msgpack that is not a
    message, client and server message types with random fields, and well-formed GUI and
    camera messages with random values aimed at the debugger's real controls."""
    for _ in range(count):
        roll = rng.random()
        if roll < 0.08:
            yield "bytes", rng.randbytes(rng.randrange(1, 64))
        elif roll < 0.12:
            yield "text", "".join(chr(rng.randrange(0x20, 0x7F)) for _ in range(rng.randrange(1, 40)))
        elif roll < 0.2:
            yield "msgpack", msgspec.msgpack.encode(_random_value(rng))
        elif roll < 0.45:
            name = rng.choice(CLIENT_TYPES + ["NoSuchMessage", "Message", ""])
            fields = {rng.choice(["uuid", "updates", "wxyz", "position", "fov", "transfer_uuid", "content", "owner", "name", "value"]): _random_value(rng) for _ in range(rng.randrange(5))}
            yield name or "empty", msgspec.msgpack.encode({"type": name, **fields})
        elif roll < 0.8:
            plausible = rng.choice([True, False, 0, 1, 2, 0.5, 5.0, 30.0, 2.0, "PL-r", "P-w", "off", "geometric", "learned"])
            updates = rng.choice(
                [
                    {"value": plausible},
                    {"value": plausible},
                    {"value": _random_value(rng)},
                    {"value": plausible, "visible": False},
                    {rng.choice(["update_cb", "removed", "is_button", "sync_cb", "disabled"]): _random_value(rng)},
                ]
            )
            yield "GuiUpdateMessage", msgspec.msgpack.encode({"type": "GuiUpdateMessage", "uuid": rng.choice(uuids + ["nope"]), "updates": updates})
        else:
            camera = {k: (rng.choice([_random_value(rng), v]) if rng.random() < 0.3 else v) for k, v in CAMERA.items()}
            yield "ViewerCameraMessage", msgspec.msgpack.encode({"type": "ViewerCameraMessage", **camera})


def test_a_thousand_random_messages_leave_the_server_healthy(capfd: pytest.CaptureFixture[str], caplog: pytest.LogCaptureFixture) -> None:
    engine = SlowEngine()
    d = _start(engine)
    caplog.set_level(logging.WARNING)
    try:
        with RawClient(d.port) as hostile:
            uuids = sorted({str(m["uuid"]) for m in hostile.messages if m["type"].startswith("Gui") and "uuid" in m})
            kinds: dict[str, int] = {}
            t0 = time.monotonic()
            for kind, frame in random_messages(random.Random(30), uuids, 1000):
                kinds[kind] = kinds.get(kind, 0) + 1
                hostile.send_raw(frame)  # the connection stays open: garbage is dropped, not fatal
                hostile.drain()  # and take what the server sends, as a browser does
            _settle(hostile)
            sent_s = time.monotonic() - t0
            seen = d.guard.figures()
            assert seen["accepted"] + seen["refused"] == 1000 + 2  # every frame was checked (and two cameras)
        d.submit("reset")  # whatever the messages started (Play, steps): back to a known state
        d.play.value = False
        d.wait_idle(timeout=60)
        threads = {t.name for t in threading.enumerate()}
        assert "coplanar-engine" in threads
        with RawClient(d.port) as user:  # a user's tab still steps and switches variants
            assert _steps_after_click(d, user) == 1
            user.set_value(user.uuid("Variant"), "P-r")
            assert _wait(lambda: d.shown is not None and d.shown.variant == "P-r")
        assert "error" not in d.status.content, d.status.content
        figures = d.guard.figures()
        assert figures["refused"] > 0 and figures["accepted"] > 0
    finally:
        d.stop()
    out, err = capfd.readouterr()
    assert "Traceback" not in out + err
    assert not [r for r in caplog.records if r.exc_info], "a traceback was logged"
    assert not [r.getMessage() for r in caplog.records if r.levelno >= logging.ERROR]
    with capfd.disabled():  # the figures, for `pytest -s` (the changelog quotes them)
        top = ", ".join(f"{k or 'no type'} {n}" for k, n in list(figures["refused_by_kind"].items())[:6])
        print(f"\nrandom messages: {sum(kinds.values())} frames in {sent_s:.1f} s; guard accepted {figures['accepted']}, refused {figures['refused']} ({top}, ...)")
