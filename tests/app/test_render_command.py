"""`coplanar render` (DESIGN §7): writes an EuRoC folder that `--dataset` reads back; bad
input is one error line and exit code 2, and an existing sequence is never overwritten."""

from __future__ import annotations

import pathlib

import pytest

from app import cli


def _one_error(capsys: pytest.CaptureFixture[str], *words: str) -> None:
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("error: ") and all(w in err[0] for w in words), err


def test_render_and_read_back(tmp_path: pathlib.Path, capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "boxes"
    assert cli.main(["render", "--scene", "boxes", "--out", str(out), "--duration", "0.2", "--image-noise", "2", "--exposure", "0.1"]) == 0
    assert "rendered 5 stereo pairs of boxes" in capsys.readouterr().out
    assert len(list((out / "mav0" / "cam0" / "data").iterdir())) == 5
    # --dataset reads it through the same reader and runs the stereo pipeline on it.
    assert cli.main(["run", "--dataset", str(out), "--variant", "P-wo", "--out", str(tmp_path / "run")]) == 0
    assert "5 frames" in capsys.readouterr().out
    # Rendering again into the same folder is refused and keeps the sequence.
    before = sorted(p.name for p in (out / "mav0" / "cam0" / "data").iterdir())
    assert cli.main(["render", "--scene", "room", "--out", str(out), "--duration", "0.1"]) == 2
    _one_error(capsys, "already holds mav0; choose a new folder")
    assert sorted(p.name for p in (out / "mav0" / "cam0" / "data").iterdir()) == before


@pytest.mark.parametrize(
    ("argv", "words"),
    [
        (["--scene", "castle"], ["--scene castle", "room"]),
        (["--duration", "-1"], ["duration"]),
        (["--exposure", "1.5"], ["exposure"]),
    ],
)
def test_bad_options(tmp_path: pathlib.Path, capsys: pytest.CaptureFixture[str], argv: list[str], words: list[str]) -> None:
    out = tmp_path / "never"
    assert cli.main(["render", "--out", str(out), *argv]) == 2
    _one_error(capsys, *words)
    assert not out.exists()


def test_malformed_scene_file_names_the_file(tmp_path: pathlib.Path, capsys: pytest.CaptureFixture[str]) -> None:
    scene = tmp_path / "my_scene.json"
    scene.write_text('{"name": "x", "rectangles": [ {"p0": [0, 0]')
    assert cli.main(["render", "--scene", str(scene), "--out", str(tmp_path / "out")]) == 2
    _one_error(capsys, "my_scene.json")
