"""`coplanar run --dataset` on EuRoC folders as users have them (DESIGN §8): no imu0 and
camera lists with rows outside the stereo set run; a truly broken folder is one `error:`
line naming the file, exit 2, nothing written."""

from __future__ import annotations

import contextlib
import io
import json
import pathlib
import shutil

import pytest

from app import cli


def _run(argv: list[str]) -> tuple[int, str, str]:
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        rc = cli.main(["run", *argv])
    return rc, out.getvalue(), err.getvalue()


def _one_error_line(err: str, words: list[str]) -> None:
    assert "Traceback" not in err
    lines = err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("error: ") and all(w in lines[0] for w in words), err


@pytest.fixture(scope="module")
def rendered(tmp_path_factory: pytest.TempPathFactory) -> pathlib.Path:
    """The `room` scene rendered for 0.5 s (11 frames) into an EuRoC folder."""
    from backend.data.scenes import builtin_scene
    from backend.data.synthetic import SequenceSettings, render_sequence

    root = tmp_path_factory.mktemp("euroc") / "room"
    render_sequence(builtin_scene("room"), root, settings=SequenceSettings(duration_s=0.5, seed=0))
    return root


def test_run_without_imu0_and_with_a_longer_cam1_list(rendered: pathlib.Path, tmp_path: pathlib.Path) -> None:
    root = tmp_path / "seq"
    shutil.copytree(rendered, root)
    shutil.rmtree(root / "mav0" / "imu0")
    cam1 = root / "mav0" / "cam1" / "data.csv"
    last = int(cam1.read_text().strip().splitlines()[-1].split(",")[0])
    cam1.write_text(cam1.read_text() + "".join(f"{last + k * 50_000_000},{last + k * 50_000_000}.png\n" for k in (1, 2)))  # images absent
    out = tmp_path / "out"
    rc, stdout, err = _run(["--dataset", str(root), "--variant", "P-wo", "--out", str(out)])
    assert rc == 0, err
    assert json.loads((out / "metrics.json").read_text())["frames"] == 11
    assert "11 frames" in stdout


@pytest.mark.parametrize(
    ("remove", "words"),
    [
        ("mav0/cam0", ["mav0/cam0", "missing folder"]),
        ("mav0/cam1/sensor.yaml", ["mav0/cam1/sensor.yaml", "missing file"]),
        ("mav0/imu0/data.csv", ["mav0/imu0/data.csv", "missing file"]),  # imu0 present but broken
    ],
)
def test_broken_folder_is_one_error_line_and_exit_2(rendered: pathlib.Path, tmp_path: pathlib.Path, remove: str, words: list[str]) -> None:
    root = tmp_path / "seq"
    shutil.copytree(rendered, root)
    victim = root / remove
    shutil.rmtree(victim) if victim.is_dir() else victim.unlink()
    out = tmp_path / "out"
    rc, stdout, err = _run(["--dataset", str(root), "--variant", "PL-w", "--out", str(out)])
    assert rc == 2 and stdout == ""
    _one_error_line(err, [str(root / remove), *words[1:]])
    assert not out.exists()


def test_missing_stereo_image_names_the_list_and_line(rendered: pathlib.Path, tmp_path: pathlib.Path) -> None:
    root = tmp_path / "seq"
    shutil.copytree(rendered, root)
    shutil.rmtree(root / "mav0" / "imu0")
    listed = (root / "mav0" / "cam1" / "data.csv").read_text().splitlines()
    assert listed[0].startswith("#")
    victim = root / "mav0" / "cam1" / "data" / listed[5].split(",")[1]  # line 6 of the list: the fifth frame
    victim.unlink()
    out = tmp_path / "out"
    rc, _, err = _run(["--dataset", str(root), "--variant", "PL-w", "--out", str(out)])
    assert rc == 2
    _one_error_line(err, [f"{root / 'mav0' / 'cam1' / 'data.csv'} line 6:", victim.name, "listed but absent"])
    assert not out.exists()


def test_a_huge_resolution_is_one_line(rendered: pathlib.Path, tmp_path: pathlib.Path) -> None:
    """A sensor.yaml with a huge `resolution` no longer runs out of memory building the
    rectification maps: one line naming the file."""
    root = tmp_path / "seq"
    shutil.copytree(rendered, root)
    for cam in ("cam0", "cam1"):
        yaml = root / "mav0" / cam / "sensor.yaml"
        yaml.write_text("\n".join("resolution: [752000000, 480000000]" if line.startswith("resolution:") else line for line in yaml.read_text().splitlines()) + "\n")
    out = tmp_path / "out"
    rc, _, err = _run(["--dataset", str(root), "--variant", "PL-w", "--out", str(out)])
    assert rc == 2
    _one_error_line(err, [str(root / "mav0" / "cam0" / "sensor.yaml"), "larger than 16384 pixels per side"])
    assert not out.exists()


def test_a_16_bit_image_is_one_line_and_a_colour_one_is_read_as_grey(rendered: pathlib.Path, tmp_path: pathlib.Path, capfd: pytest.CaptureFixture[str]) -> None:
    """Images are decoded as stored and their depth checked: EuRoC's are 8-bit grey. A
    truncated PNG is one line too, without OpenCV's own warning on stderr."""
    import cv2
    import numpy as np

    root = tmp_path / "seq"
    shutil.copytree(rendered, root)
    shutil.rmtree(root / "mav0" / "imu0")
    images = sorted((root / "mav0" / "cam0" / "data").glob("*.png"))
    grey = cv2.imread(str(images[0]), cv2.IMREAD_UNCHANGED)
    cv2.imwrite(str(images[0]), np.dstack([grey] * 3))
    rc, _, err = _run(["--dataset", str(root), "--variant", "P-wo", "--frames", "3", "--out", str(tmp_path / "colour")])
    assert rc == 0, err

    cv2.imwrite(str(images[1]), grey.astype(np.uint16) * 257)
    rc, _, err = _run(["--dataset", str(root), "--variant", "P-wo", "--out", str(tmp_path / "deep")])
    assert rc == 2
    _one_error_line(err, [str(images[1]), "16-bit pixels; expected 8-bit grey"])

    images[1].write_bytes(images[2].read_bytes()[:2000])
    capfd.readouterr()
    rc, _, err = _run(["--dataset", str(root), "--variant", "P-wo", "--out", str(tmp_path / "cut")])
    assert rc == 2
    _one_error_line(err + capfd.readouterr().err, [str(images[1]), "not a readable image"])


def _edit_row(root: pathlib.Path, row: int, name: str) -> None:
    """cam0's data.csv with the image name of data row `row` (1-based) replaced."""
    csv = root / "mav0" / "cam0" / "data.csv"
    lines = csv.read_text().splitlines()
    data = [i for i, line in enumerate(lines) if line and not line.startswith("#")]
    stamp = lines[data[row - 1]].split(",")[0]
    lines[data[row - 1]] = f"{stamp},{name}"
    csv.write_text("\n".join(lines) + "\n")


@pytest.mark.parametrize("kind", ["absolute", "climbing", "fifo", "folder"])
def test_an_image_outside_the_dataset_or_not_a_file_is_refused_with_its_line(rendered: pathlib.Path, tmp_path: pathlib.Path, kind: str) -> None:
    """data.csv may not name a file anywhere on disk (an absolute path, `..`), and an image
    that is a FIFO or a folder is refused without opening it: a FIFO blocked the run
    forever, an absolute path was read."""
    import os
    import signal

    root = tmp_path / "seq"
    shutil.copytree(rendered, root)
    images = root / "mav0" / "cam0" / "data"
    rows = [line for line in (root / "mav0" / "cam0" / "data.csv").read_text().splitlines() if line and not line.startswith("#")]
    third = images / rows[2].split(",")[1]
    if kind == "absolute":
        _edit_row(root, 3, str(third))
    elif kind == "climbing":
        _edit_row(root, 3, f"../data/{third.name}")
    elif kind == "fifo":
        third.unlink()
        os.mkfifo(third)
    else:
        third.unlink()
        third.mkdir()

    def blocked(_signum: int, _frame: object) -> None:
        raise TimeoutError("the run blocked")

    previous = signal.signal(signal.SIGALRM, blocked)
    signal.alarm(120)
    try:
        rc, _, err = _run(["--dataset", str(root), "--variant", "P-wo", "--out", str(tmp_path / "out")])
    finally:
        signal.alarm(0)
        signal.signal(signal.SIGALRM, previous)
    assert rc == 2 and not (tmp_path / "out").exists()
    words = {"absolute": ["outside", "refused"], "climbing": ["outside", "'..'"], "fifo": ["is a FIFO", "refused"], "folder": ["is a folder", "refused"]}[kind]
    _one_error_line(err, ["mav0/cam0/data.csv line 4", *words])  # line 1 is the header
