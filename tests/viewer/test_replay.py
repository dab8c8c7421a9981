"""Record and replay in the debugger: a session recorded with the Record box replays, in a
debugger with no engine and no dataset, keyframe for keyframe with the same snapshots and
the same panels (every tab's text and images, the status line, the plots), including the
variant the user chose at a keyframe; a variant that was not recorded says so."""

from __future__ import annotations

import pathlib

import pytest

from backend.pipeline.factory import EngineConfig, make_engine
from backend.pipeline.recording import Recording
from backend.pipeline.replay_engine import ReplayEngine
from backend.pipeline.sim_engine import SimEngine, SimSettings
from backend.pipeline.snapshot_codec import same
from tests.browser.conftest import free_port
from viewer.screen import screen_contents


def _debugger(engine):
    from viewer.app import Debugger

    d = Debugger(engine, port=free_port())
    d.server.scene.configure_environment_map(hdri=None)
    return d


def _settled(d) -> None:
    d.wait_idle(timeout=120)
    d.wait_plots()


def _record(engine, steps: int, *, variant_at: dict[int, str | tuple[str, ...]], path: pathlib.Path, record_after: int = 0):
    """Step a live debugger `steps` times (Record ticked after `record_after` steps), choosing
    `variant_at[k]` (one variant or several in turn) at keyframe k; what it showed per
    keyframe, and the recording's file."""
    d = _debugger(engine)
    shown = {}
    try:
        for k in range(steps):
            if k == record_after:
                d.submit("record", True)
            d.submit("step")
            _settled(d)
            chosen = variant_at.get(k, ())
            for variant in (chosen,) if isinstance(chosen, str) else chosen:
                d.submit("variant", variant)
                _settled(d)
            shown[k] = (d.shown, screen_contents(d, source=d.engine.source))
        assert d.controls.record_note.content.startswith(f"recording: {steps} keyframes, ")
        path.write_bytes(d.session.recorder.to_bytes())
    finally:
        d.stop()
    return shown


def _replayed_like(path: pathlib.Path, shown: dict) -> None:
    r = _debugger(ReplayEngine(Recording.open(path)))
    try:
        for k, (snapshot, contents) in shown.items():
            r.submit("step")
            _settled(r)
            assert same(r.shown, snapshot), k
            assert screen_contents(r, source=r.engine.source) == contents, k
    finally:
        r.stop()


def test_a_recorded_session_replays_with_the_same_panels(tmp_path) -> None:
    path = tmp_path / "mc-a.zip"
    shown = _record(SimEngine(SimSettings(sequence="a")), 6, variant_at={3: "P-wo", 4: ("P-r", "PL-w")}, path=path)
    assert shown[3][0].variant == "P-wo" and "P-wo" in shown[3][1]["VariantsTab.text"]
    assert shown[4][0].variant == "PL-w" and "P-r" in shown[4][1]["VariantsTab.text"]
    _replayed_like(path, shown)


def test_keyframes_kept_before_record_was_ticked_replay_without_their_comparison(tmp_path) -> None:
    """Their snapshots are recorded from the history; the plane-mode comparison is made from
    the engine's state at the newest keyframe only, so theirs says it is not recorded."""
    path = tmp_path / "mc-a.zip"
    shown = _record(SimEngine(SimSettings(sequence="a")), 4, variant_at={}, path=path, record_after=2)
    r = _debugger(ReplayEngine(Recording.open(path)))
    try:
        for k, (snapshot, contents) in shown.items():
            r.submit("step")
            _settled(r)
            assert same(r.shown, snapshot)
            replayed = screen_contents(r, source=r.engine.source)
            differ = {key for key in contents if replayed[key] != contents[key]}
            if k == 0:
                assert differ == {"HessianTab.compare_note", "HessianTab.compare_image"}
                assert replayed["HessianTab.compare_note"].startswith("*not in the recording for keyframe 0 (PL)")
            else:  # keyframe 1 was the newest when Record was ticked: its comparison was made
                assert not differ, k
    finally:
        r.stop()


def test_an_image_session_replays_with_the_same_keyframe_image_and_hessians(tmp_path) -> None:
    path = tmp_path / "room.zip"
    engine = make_engine(EngineConfig(scene="room", duration_s=4.0, interactive=True))
    shown = _record(engine, 4, variant_at={2: "PL-r"}, path=path)
    assert shown[3][1]["KeyframeTab.image"].startswith("image ") and shown[3][1]["HessianTab.compare_image"].startswith("image ")
    _replayed_like(path, shown)


def test_a_variant_not_recorded_says_so_and_keeps_the_shown_one(tmp_path) -> None:
    path = tmp_path / "mc-a.zip"
    _record(SimEngine(SimSettings(sequence="a")), 2, variant_at={}, path=path)
    r = _debugger(ReplayEngine(Recording.open(path)))
    try:
        r.submit("step")
        _settled(r)
        r.submit("variant", "P-r")
        _settled(r)
        assert "P-r was not recorded at keyframe 0 (recorded there: PL-w)" in r.status.content
        assert r.variant.value == "PL-w" and r.shown.variant == "PL-w" and r.ab_variant.disabled
        r.submit("step")
        r.submit("step")
        _settled(r)
        assert "end of the recording (2 keyframes)" in r.status.content
    finally:
        r.stop()


def test_reset_stops_recording_and_keeps_what_was_recorded() -> None:
    d = _debugger(SimEngine(SimSettings(sequence="a")))
    try:
        d.submit("record", True)
        for _ in range(3):
            d.submit("step")
        d.submit("reset")
        _settled(d)
        assert not d.session.recording and not d.controls.record.value
        assert d.controls.record_note.content.startswith("recorded (stopped): 3 keyframes")
    finally:
        d.stop()


@pytest.mark.parametrize("engine_options", ["--scene", "--duration"])
def test_replay_refuses_engine_options(tmp_path, engine_options, capsys) -> None:
    from app.cli import main

    path = tmp_path / "mc-a.zip"
    _record(SimEngine(SimSettings(sequence="a")), 1, variant_at={}, path=path)
    value = "room" if engine_options == "--scene" else "5"
    assert main(["serve", "--replay", str(path), engine_options, value]) == 2
    assert capsys.readouterr().err == f"error: --replay: {engine_options} not used (a replay shows the recorded run)\n"
