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


@pytest.mark.parametrize(("fmt", "folder"), [("kitti", "sequences/00"), ("euroc", "")])
def test_street_renders_a_kitti_like_dataset_that_reads_back(tmp_path: pathlib.Path, capsys: pytest.CaptureFixture[str], fmt: str, folder: str) -> None:
    """The stress scene `street` written as KITTI or EuRoC: 10 Hz pairs with its KITTI-like
    camera, which `--dataset` reads back as it was rendered."""
    from backend.data.rigs import KITTI_RIG
    from backend.data.source import open_dataset

    out = tmp_path / fmt
    assert cli.main(["render", "--scene", "street", "--format", fmt, "--out", str(out), "--duration", "0.3"]) == 0
    assert "rendered 4 stereo pairs of street" in capsys.readouterr().out
    dataset = open_dataset(out / folder)
    assert dataset.camera == KITTI_RIG.camera and len(dataset) == 4
    assert list(dataset.timestamps_ns) == [0, 100_000_000, 200_000_000, 300_000_000]
    assert cli.main(["run", "--dataset", str(out / folder), "--variant", "P-wo", "--out", str(tmp_path / "run")]) == 0
    assert "4 frames" in capsys.readouterr().out
