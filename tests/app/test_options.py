"""Numbers checked at the command line's edge (issue 16's first rows): a negative seed, an
infinite duration or blur is one `error:` line naming the option, exit code 2, nothing written."""

from __future__ import annotations

import pathlib

import pytest

from app import cli

@pytest.mark.parametrize(
    ("argv", "words"),
    [
        (["run", "--scene", "room", "--seed", "-2", "--variant", "PL-w"], ["--seed", "-2 is not a seed"]),
        (["run", "--scene", "mc-a", "--seed", "-2", "--variant", "PL-w"], ["--seed", "-2 is not a seed"]),
        (["run", "--scene", "room", "--seed", "x", "--variant", "PL-w"], ["--seed", "is not an integer"]),
        (["sim", "--sequence", "a", "--seed", "-1"], ["--seed", "-1 is not a seed"]),
        (["render", "--scene", "room", "--seed", "-1"], ["--seed", "-1 is not a seed"]),
        (["render", "--scene", "room", "--duration", "inf"], ["--duration", "inf is outside (0, 3600] seconds"]),
        (["render", "--scene", "room", "--duration", "nan"], ["--duration", "nan is outside"]),
        (["render", "--scene", "room", "--blur", "inf"], ["--blur", "inf is outside [0, 50] pixels"]),
        (["render", "--scene", "room", "--image-noise", "-1"], ["--image-noise", "outside [0, 255]"]),
    ],
    ids=lambda v: " ".join(v) if isinstance(v, list) else None,
)
def test_bad_numbers_are_one_line(argv: list[str], words: list[str], tmp_path: pathlib.Path, capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "out"
    extra = ["--json", str(out / "sim.json")] if argv[0] == "sim" else ["--out", str(out)]
    assert cli.main([*argv, *extra]) == 2
    err = capsys.readouterr().err
    lines = err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("error: ") and all(w in lines[0] for w in words), err
    assert not out.exists()


LONG = "a" * 300  # a path component longer than the file system's 255 bytes


@pytest.mark.parametrize(
    ("argv", "words"),
    [
        (["run", "--scene", "mc-a", "--variant", "PL-w", "--keyframes", "2", "--out", "{tmp}/" + LONG + "/x"], ["--out", "File name too long"]),
        (["render", "--scene", "room", "--duration", "0.1", "--out", "{tmp}/" + LONG], ["--out", "File name too long"]),
        (["sim", "--sequence", "a", "--runs", "1", "--json", "{tmp}/" + LONG + ".json"], ["--json", "File name too long"]),
        (["sim", "--sequence", "a", "--runs", "1", "--json", "{tmp}/s.json", "--plot", "{tmp}/out.xyz"], ["--plot", "unknown image format 'xyz'"]),
    ],
    ids=["run long --out", "render long --out", "sim long --json", "sim --plot xyz"],
)
def test_bad_paths_are_one_line(argv: list[str], words: list[str], tmp_path: pathlib.Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert cli.main([a.replace("{tmp}", str(tmp_path)) for a in argv]) == 2
    lines = capsys.readouterr().err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("error: ") and all(w in lines[0] for w in words), lines
    assert list(tmp_path.iterdir()) == []  # nothing half-written
