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
    "mislabel-high": (["--mislabel", "1.5"], ["--mislabel", "1.5"]),
    "mislabel-negative": (["--mislabel", "-0.1"], ["--mislabel", "-0.1"]),
    "mislabel-text": (["--mislabel", "lots"], ["--mislabel", "lots"]),
    "window": (["--window", "1"], ["--window", "1"]),
    "history": (["--history", "0"], ["--history", "0"]),
    "port-high": (["--port", "70000"], ["--port", "70000"]),
    "port-negative": (["--port", "-1"], ["--port", "-1"]),
    "port-text": (["--port", "http"], ["--port", "http"]),
    "variant": (["--variant", "P-x"], ["--variant", "P-x"]),
    "unknown-option": (["--scenes", "mc-a"], ["--scenes"]),
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
        ([], "a", "PL-w", 10, 0.1, 0),
        (["--scene", "mc-b", "--variant", "P-r", "--window", "2", "--mislabel", "0", "--seed", "7"], "b", "P-r", 2, 0.0, 7),
        (["--scene", "mc-a", "--mislabel", "1"], "a", "PL-w", 10, 1.0, 0),
    ],
)
def test_valid_options_build_the_engine(argv: list[str], sequence: str, variant: str, window: int, mislabel: float, seed: int) -> None:
    args = cli.build_parser().parse_args(["serve", *argv])
    assert args.host == "127.0.0.1" and args.port == 8080  # this machine only, by default
    engine = serve_command.build_engine(args)
    assert isinstance(engine, SimEngine)
    s = engine.settings
    assert (s.sequence, s.variant, s.window, s.mislabel, s.seed) == (sequence, variant, window, mislabel, seed)
    assert engine.variant == variant
    assert engine.keyframes == 0  # nothing runs before the viewer asks


def test_console_script_reports_bad_scene(tmp_path: pathlib.Path) -> None:
    assert CONSOLE_SCRIPT.exists(), CONSOLE_SCRIPT
    proc = subprocess.run([str(CONSOLE_SCRIPT), "serve", "--scene", "nope"], check=False, capture_output=True, text=True, timeout=60, cwd=tmp_path)
    assert proc.returncode == 2
    assert proc.stdout == ""
    _assert_one_error_line(proc.stderr, ["--scene", "nope"])
