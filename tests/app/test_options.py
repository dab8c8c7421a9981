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


def _scene_text(change) -> str:
    import json

    from backend.data.scenes import builtin_scene, scene_to_dict

    data = scene_to_dict(builtin_scene("room"))
    change(data)
    return json.dumps(data)


def _set(path: tuple, value: object):
    def change(data: dict) -> None:
        target = data
        for key in path[:-1]:
            target = target[key]
        target[path[-1]] = value

    return change


@pytest.mark.parametrize(
    ("text", "words"),
    [
        (_scene_text(_set(("camera_region", "centre"), [float("inf"), 0.0, 1.0])), ["camera_region.centre", "finite"]),
        (_scene_text(_set(("camera_region", "half_extent"), [float("nan"), 1.0, 1.0])), ["camera_region.half_extent"]),
        (_scene_text(_set(("cylinders", 0, "radius"), 1e300)), ["cylinders[0]", "radius in (0, 10000] m"]),
        (_scene_text(_set(("spheres", 0, "radius"), float("inf"))), ["spheres[0]", "radius"]),
        ("[" * 100_000 + "]" * 100_000, ["nested too deeply"]),
    ],
    ids=["region-inf", "region-nan", "cylinder-huge", "sphere-inf", "deeply-nested"],
)
def test_bad_scene_files_are_one_line(text: str, words: list[str], tmp_path: pathlib.Path, capsys: pytest.CaptureFixture[str]) -> None:
    scene = tmp_path / "scene.json"
    scene.write_text(text)
    out = tmp_path / "out"
    assert cli.main(["run", "--scene", str(scene), "--variant", "PL-w", "--duration", "0.5", "--out", str(out)]) == 2
    lines = capsys.readouterr().err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("error: "), lines
    assert all(w in lines[0] for w in [str(scene), *words]), lines
    assert not out.exists()
