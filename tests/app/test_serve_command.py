"""`coplanar serve` (DESIGN §7, §8): bad input is one error line and exit code 2, and no
server starts. A valid invocation blocks forever, so none is run here; a stand-in for the
viewer fails the test instead of serving if validation lets bad input through."""

from __future__ import annotations

import pathlib
import subprocess
import sys

import pytest

import viewer.app
from app import cli, serve_command
from backend.pipeline.sim_engine import SimEngine
from backend.pipeline.stereo_engine import StereoEngine

CONSOLE_SCRIPT = pathlib.Path(sys.executable).parent / "coplanar"


class _NoServer:
    def __init__(self, *args: object, **kwargs: object) -> None:
        raise AssertionError("bad input reached the server")


@pytest.fixture(autouse=True)
def no_server(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(viewer.app, "Debugger", _NoServer)


def _assert_one_error_line(err: str, words: list[str]) -> None:
    assert "Traceback" not in err
    lines = err.strip("\n").splitlines()
    assert len(lines) == 1, err
    assert lines[0].startswith("error: ")
    for w in words:
        assert w in lines[0], (w, lines[0])


BAD_INPUT = {
    "scene": (["--scene", "nope"], ["--scene", "nope", "mc-a"]),
    "dataset": (["--dataset", "/some/path"], ["/some/path", "no such folder"]),
    "scene-and-dataset": (["--scene", "mc-a", "--dataset", "/some/path"], ["--dataset"]),
    "mislabel-high": (["--scene", "mc-a", "--mislabel", "1.5"], ["--mislabel", "1.5"]),
    "mislabel-negative": (["--scene", "mc-b", "--mislabel", "-0.1"], ["--mislabel", "-0.1"]),
    "mislabel-text": (["--scene", "mc-a", "--mislabel", "lots"], ["--mislabel", "lots"]),
    "mislabel-stereo": (["--mislabel", "0.2"], ["--mislabel 0.2", "mc-a"]),
    "scene-file-missing": (["--scene", "nowhere/scene.json"], ["--scene nowhere/scene.json", "scene file"]),
    "duration-zero": (["--duration", "0"], ["--duration 0"]),
    "duration-negative": (["--scene", "corridor", "--duration", "-5"], ["--duration -5"]),
    "duration-infinite": (["--duration", "inf"], ["--duration inf"]),
    "duration-mc": (["--scene", "mc-a", "--duration", "10"], ["--duration 10", "mc-a"]),
    "frames-not-an-option": (["--frames", "10"], ["--frames"]),
    "window": (["--window", "1"], ["--window", "1"]),
    "window-mc": (["--scene", "mc-a", "--window", "1"], ["--window", "1"]),
    "history": (["--history", "0"], ["--history", "0"]),
    "history-mb-zero": (["--history-mb", "0"], ["--history-mb 0"]),
    "history-mb-nan": (["--history-mb", "nan"], ["--history-mb nan"]),
    "port-high": (["--port", "70000"], ["--port", "70000"]),
    "port-negative": (["--port", "-1"], ["--port", "-1"]),
    "port-text": (["--port", "http"], ["--port", "http"]),
    "variant": (["--variant", "P-x"], ["--variant", "P-x"]),
    "unknown-option": (["--scenes", "mc-a"], ["--scenes"]),
    "seed-negative": (["--scene", "mc-a", "--seed", "-3"], ["--seed", "-3 is not a seed"]),
    "host-invalid": (["--scene", "mc-a", "--host", "999.1.1.1"], ["--host 999.1.1.1", "not an address of this machine"]),
    "host-unresolvable": (["--scene", "mc-a", "--host", "no-such-host.invalid"], ["--host no-such-host.invalid"]),
    "host-foreign": (["--scene", "mc-a", "--host", "192.0.2.1"], ["cannot serve on 192.0.2.1", "Cannot assign requested address"]),
    "allow-origin-path": (["--scene", "mc-a", "--allow-origin", "https://lab.example/app"], ["--allow-origin", "https://lab.example/app", "no path"]),
    "allow-origin-scheme": (["--scene", "mc-a", "--allow-origin", "ftp://lab.example"], ["--allow-origin", "ftp://lab.example", "not an origin"]),
    "allow-origin-bare": (["--scene", "mc-a", "--allow-origin", "lab.example"], ["--allow-origin", "lab.example"]),
    "allow-origin-port": (["--scene", "mc-a", "--allow-origin", "http://lab.example:99999"], ["--allow-origin", "bad port"]),
}


@pytest.mark.parametrize("case", list(BAD_INPUT))
def test_bad_input_is_one_error_line_and_exit_2(case: str, capsys: pytest.CaptureFixture[str]) -> None:
    args, words = BAD_INPUT[case]
    rc = cli.main(["serve", *args])
    out, err = capsys.readouterr()
    assert rc == 2
    _assert_one_error_line(err, words)
    assert out == ""  # no address printed: nothing serves


def test_port_is_checked_before_the_scene_is_built(monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]) -> None:
    def fail(*args: object, **kwargs: object) -> None:
        raise AssertionError("engine built for a bad port")

    monkeypatch.setattr(serve_command, "build_engine", fail)
    assert cli.main(["serve", "--port", "65536"]) == 2
    _assert_one_error_line(capsys.readouterr().err, ["--port", "65536"])


@pytest.mark.parametrize(
    ("argv", "sequence", "variant", "window", "mislabel", "seed"),
    [
        (["--scene", "mc-a"], "a", "PL-w", 10, 0.1, 0),
        (["--scene", "mc-b", "--variant", "P-r", "--window", "2", "--mislabel", "0", "--seed", "7"], "b", "P-r", 2, 0.0, 7),
        (["--scene", "mc-a", "--mislabel", "1"], "a", "PL-w", 10, 1.0, 0),
    ],
)
def test_monte_carlo_options_build_the_sim_engine(argv: list[str], sequence: str, variant: str, window: int, mislabel: float, seed: int) -> None:
    args = cli.build_parser().parse_args(["serve", *argv])
    assert args.host == "127.0.0.1" and args.port == 8080  # this machine only, by default
    engine = serve_command.build_engine(args)
    assert isinstance(engine, SimEngine)
    s = engine.settings
    assert (s.sequence, s.variant, s.window, s.mislabel, s.seed) == (sequence, variant, window, mislabel, seed)
    assert engine.variant == variant
    assert engine.keyframes == 0  # nothing runs before the viewer asks


@pytest.mark.parametrize(
    ("argv", "source", "frames", "variant", "window", "seed"),
    [
        ([], "rendered scene room (60 s, seed 0)", 1201, "PL-w", 10, 0),
        (["--scene", "corridor", "--duration", "2.5", "--variant", "P-r", "--window", "4", "--seed", "3"], "rendered scene corridor (2.5 s, seed 3)", 51, "P-r", 4, 3),
    ],
)
def test_rendered_scenes_build_the_stereo_engine(argv: list[str], source: str, frames: int, variant: str, window: int, seed: int) -> None:
    """`room` is the default; the debugger's stereo pipeline runs every stage and draws the
    keyframe image and the Hessian; nothing is rendered before the first step."""
    args = cli.build_parser().parse_args(["serve", *argv])
    engine = serve_command.build_engine(args)
    assert isinstance(engine, StereoEngine)
    assert engine.source == source and len(engine.data_source) == frames
    s = engine.settings
    assert (s.variant, s.window, s.seed) == (variant, window, seed)
    assert not s.skip_unused_stages and s.image_scale is not None and s.hessian
    assert engine.frames == 0 and engine.keyframes == 0


def test_scene_file_and_dataset_build_the_stereo_engine(tmp_path: pathlib.Path) -> None:
    from backend.data.scenes import builtin_scene, scene_to_json
    from backend.data.synthetic import SequenceSettings, render_sequence

    scene = tmp_path / "boxes.json"
    scene.write_text(scene_to_json(builtin_scene("boxes")))
    engine = serve_command.build_engine(cli.build_parser().parse_args(["serve", "--scene", str(scene), "--duration", "1"]))
    assert isinstance(engine, StereoEngine) and engine.source == f"rendered scene boxes from {scene} (1 s, seed 0)"

    root = tmp_path / "seq"
    render_sequence(builtin_scene("room"), root, settings=SequenceSettings(duration_s=0.2))
    engine = serve_command.build_engine(cli.build_parser().parse_args(["serve", "--dataset", str(root)]))
    assert isinstance(engine, StereoEngine) and engine.source == f"EuRoC folder {root}" and len(engine.data_source) == 5
    snapshot = engine.step()  # the first frame is the first keyframe, with its image
    assert snapshot.keyframe == 0 and snapshot.image is not None


def test_console_script_reports_bad_scene(tmp_path: pathlib.Path) -> None:
    assert CONSOLE_SCRIPT.exists(), CONSOLE_SCRIPT
    proc = subprocess.run([str(CONSOLE_SCRIPT), "serve", "--scene", "nope"], check=False, capture_output=True, text=True, timeout=60, cwd=tmp_path)
    assert proc.returncode == 2
    assert proc.stdout == ""
    _assert_one_error_line(proc.stderr, ["--scene", "nope"])


def test_a_port_in_use_is_one_line_at_once(capsys: pytest.CaptureFixture[str]) -> None:
    """The server binds in a thread of its own: a port in use is checked before, one line."""
    import socket

    with socket.socket() as busy:
        busy.bind(("127.0.0.1", 0))
        busy.listen()
        port = busy.getsockname()[1]
        rc = cli.main(["serve", "--scene", "mc-a", "--port", str(port)])
    out, err = capsys.readouterr()
    assert rc == 2 and out == ""
    _assert_one_error_line(err, [f"cannot serve on 127.0.0.1:{port}", "Address already in use"])
    with pytest.raises(SystemExit):  # and the help says so (it used to promise the next free port)
        cli.main(["serve", "--help"])
    help_text = " ".join(capsys.readouterr().out.split())
    assert "a port in use is an error" in help_text and "next free" not in help_text


class _Started(Exception):
    pass


def _serve_until_the_server_starts(monkeypatch: pytest.MonkeyPatch, argv: list[str]) -> dict[str, object]:
    """Run `serve ARGV` up to the Debugger's construction; what it was given."""
    given: dict[str, object] = {}

    def record(engine: object, **kwargs: object) -> None:
        given.update(kwargs)
        raise _Started

    monkeypatch.setattr(viewer.app, "Debugger", record)
    with pytest.raises(_Started):
        cli.main(["serve", "--scene", "mc-a", "--port", "0", *argv])
    return given


@pytest.mark.parametrize("host", ["0.0.0.0", "::"])
def test_serving_on_every_interface_warns_before_it_starts(monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str], host: str) -> None:
    given = _serve_until_the_server_starts(monkeypatch, ["--host", host])
    assert given["host"] == host
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith(f"warning: --host {host} serves the debugger on every network interface")


def test_the_default_host_serves_quietly_and_admits_no_other_origin(monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]) -> None:
    from viewer.access import AccessSettings

    given = _serve_until_the_server_starts(monkeypatch, [])
    assert given["host"] == "127.0.0.1" and given["access"] == AccessSettings()
    assert capsys.readouterr().err == ""


def test_allow_origin_and_share_reach_the_server(monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]) -> None:
    given = _serve_until_the_server_starts(monkeypatch, ["--allow-origin", "HTTPS://Lab.Example:443/", "--allow-origin", "http://10.0.0.5:9000", "--share"])
    access = given["access"]
    assert access.allowed_origins == ("https://lab.example", "http://10.0.0.5:9000") and access.share  # type: ignore[attr-defined]
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("warning: --share:")


def test_sweep_folder_reaches_the_debugger(monkeypatch: pytest.MonkeyPatch, tmp_path: pathlib.Path) -> None:
    (tmp_path / "results.json").write_text('{"runs": []}')
    given = _serve_until_the_server_starts(monkeypatch, ["--sweep", str(tmp_path)])
    assert given["settings"].sweep == tmp_path  # type: ignore[attr-defined]


def test_a_sweep_folder_without_results_is_one_error_line(tmp_path: pathlib.Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert cli.main(["serve", "--scene", "mc-a", "--port", "0", "--sweep", str(tmp_path)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith(f"error: --sweep {tmp_path}: no results.json there"), err
