"""`coplanar render --format kitti` and `coplanar run --dataset` on KITTI odometry sequences:
a render written as KITTI runs to the same trajectory as the same render read as EuRoC; a
broken sequence is one `error:` line naming the file, exit 2, nothing written; VIO asks for
an IMU KITTI does not have, in one line."""

from __future__ import annotations

import contextlib
import io
import json
import pathlib
import shutil

import numpy as np
import pytest

from app import cli


def _cli(argv: list[str]) -> tuple[int, str, str]:
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        rc = cli.main(argv)
    return rc, out.getvalue(), err.getvalue()


def _one_error_line(err: str, words: list[str]) -> None:
    assert "Traceback" not in err
    lines = err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("error: ") and all(w in lines[0] for w in words), err


@pytest.fixture(scope="module")
def rendered(tmp_path_factory: pytest.TempPathFactory) -> tuple[pathlib.Path, pathlib.Path]:
    """`boxes` rendered for 1 s (21 frames) by `coplanar render`, as EuRoC and as KITTI."""
    root = tmp_path_factory.mktemp("render")
    for fmt in ("euroc", "kitti"):
        rc, stdout, err = _cli(["render", "--scene", "boxes", "--duration", "1", "--format", fmt, "--out", str(root / fmt)])
        assert rc == 0, err
    assert f"read it back with --dataset {root / 'kitti' / 'sequences' / '00'}" in stdout
    return root / "euroc", root / "kitti"


def test_kitti_runs_to_the_trajectory_of_the_same_render_as_euroc(rendered: tuple[pathlib.Path, pathlib.Path], tmp_path: pathlib.Path) -> None:
    euroc, kitti = rendered
    assert sorted(p.name for p in kitti.iterdir()) == ["poses", "sequences"]
    trajectories = []
    for name, dataset in (("euroc", euroc), ("kitti", kitti / "sequences" / "00")):
        # In the rectified camera's frame: EuRoC's ground truth is the body's, KITTI's the camera's.
        rc, stdout, err = _cli(["run", "--dataset", str(dataset), "--variant", "PL-w", "--trajectory-frame", "camera", "--out", str(tmp_path / name)])
        assert rc == 0, err
        assert "21 frames" in stdout
        trajectories.append(np.loadtxt(tmp_path / name / "trajectory.txt"))
    a, b = trajectories
    assert a.shape == b.shape and a.shape[0] >= 15
    assert np.abs(a - b).max() <= 1e-9  # same images, camera and first pose: the same run
    metrics = json.loads((tmp_path / "kitti" / "metrics.json").read_text())
    assert metrics["source"].startswith("KITTI sequence ") and metrics["frames_evaluated"] == 21  # render gives every frame ground truth, the last one too


def test_render_never_overwrites_a_kitti_sequence(rendered: tuple[pathlib.Path, pathlib.Path]) -> None:
    _, kitti = rendered
    before = sorted((kitti / "sequences" / "00" / "image_0").iterdir())
    rc, _, err = _cli(["render", "--scene", "room", "--duration", "0.1", "--format", "kitti", "--out", str(kitti)])
    assert rc == 2
    _one_error_line(err, [f"--out {kitti}", "already holds sequences"])
    assert sorted((kitti / "sequences" / "00" / "image_0").iterdir()) == before


def test_vio_on_kitti_is_one_line(rendered: tuple[pathlib.Path, pathlib.Path], tmp_path: pathlib.Path) -> None:
    sequence = rendered[1] / "sequences" / "00"
    rc, _, err = _cli(["run", "--mode", "vio", "--dataset", str(sequence), "--variant", "PL-w", "--out", str(tmp_path / "out")])
    assert rc == 2
    _one_error_line(err, [str(sequence), "KITTI odometry has no IMU data", "IMU data is needed for VIO"])
    assert not (tmp_path / "out").exists()


def _drop_line(path: pathlib.Path, index: int) -> None:
    lines = path.read_text().splitlines()
    del lines[index]
    path.write_text("\n".join(lines) + "\n")


def _short_pose_row(path: pathlib.Path) -> None:
    lines = path.read_text().splitlines()
    lines[4] = " ".join(lines[4].split()[:11])
    path.write_text("\n".join(lines) + "\n")


@pytest.mark.parametrize(
    ("case", "words"),
    [
        ("calib.txt without P1", ["sequences/00/calib.txt: no P1 line"]),
        ("times.txt one short", ["sequences/00/times.txt: 20 times, but", "image_0 holds 21 PNG images"]),
        ("poses row of 11", ["poses/00.txt line 5: 11 numbers, expected 12"]),
        ("missing image", ["sequences/00/image_1/000007.png: missing image of frame 7"]),
    ],
)
def test_a_broken_sequence_is_one_error_line_and_exit_2(rendered: tuple[pathlib.Path, pathlib.Path], tmp_path: pathlib.Path, case: str, words: list[str]) -> None:
    root = tmp_path / "kitti"
    shutil.copytree(rendered[1], root)
    sequence = root / "sequences" / "00"
    if case == "calib.txt without P1":
        _drop_line(sequence / "calib.txt", 1)
    elif case == "times.txt one short":
        _drop_line(sequence / "times.txt", -1)
    elif case == "poses row of 11":
        _short_pose_row(root / "poses" / "00.txt")
    else:
        (sequence / "image_1" / "000007.png").unlink()
    out = tmp_path / "out"
    rc, stdout, err = _cli(["run", "--dataset", str(sequence), "--variant", "PL-w", "--out", str(out)])
    assert rc == 2 and stdout == ""
    _one_error_line(err, [f"error: {root}", *words])
    assert not out.exists()
