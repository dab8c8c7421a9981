"""`coplanar run --dataset` on TUM-VI exports (DESIGN §7, §8): a rendered sequence converted
to a TUM-VI-style folder (equidistant fisheye, 16-bit images, Kalibr calibration) runs to an
ATE comparable to its EuRoC folder's; `render --format tumvi` writes one; a bad camchain is
one `error:` line naming it and exit code 2."""

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
        rc = cli.main(argv)
    return rc, out.getvalue(), err.getvalue()


@pytest.fixture(scope="module")
def folders(tmp_path_factory: pytest.TempPathFactory) -> tuple[pathlib.Path, pathlib.Path]:
    """The `room` scene rendered for 1 s (21 frames) as EuRoC, and its TUM-VI conversion."""
    from backend.data.scenes import builtin_scene
    from backend.data.synthetic import SequenceSettings, render_sequence
    from backend.data.tumvi_writer import convert

    base = tmp_path_factory.mktemp("tumvi")
    render_sequence(builtin_scene("room"), base / "euroc", settings=SequenceSettings(duration_s=1.0, seed=0))
    convert(base / "euroc", base / "tumvi")
    return base / "euroc", base / "tumvi"


def test_the_export_runs_to_an_ate_comparable_to_the_euroc_folders(folders: tuple[pathlib.Path, pathlib.Path], tmp_path: pathlib.Path) -> None:
    ate = {}
    for name, folder in zip(("euroc", "tumvi"), folders):
        rc, stdout, err = _run(["run", "--dataset", str(folder), "--variant", "PL-w", "--out", str(tmp_path / name)])
        assert rc == 0, err
        metrics = json.loads((tmp_path / name / "metrics.json").read_text())
        assert metrics["frames"] == 21
        ate[name] = metrics["ate_rmse_cm"]
    print(f"ATE: EuRoC folder {ate['euroc']:.2f} cm, TUM-VI export {ate['tumvi']:.2f} cm")
    assert ate["tumvi"] <= 2.0 * ate["euroc"] + 1.0


def test_render_format_tumvi_reads_back(tmp_path: pathlib.Path) -> None:
    out = tmp_path / "seq"
    rc, stdout, err = _run(["render", "--scene", "boxes", "--duration", "0.2", "--format", "tumvi", "--out", str(out)])
    assert rc == 0, err
    assert "rendered 5 stereo pairs of boxes" in stdout and f"--dataset {out}" in stdout
    assert sorted(p.name for p in out.iterdir()) == ["dso", "mav0"]  # no staging or render leftovers
    assert sorted(p.name for p in (out / "mav0").iterdir()) == ["cam0", "cam1", "imu0", "mocap0"]
    from backend.data.source import dataset_format

    assert dataset_format(out).label == "TUM-VI folder"
    rc, _, err = _run(["render", "--scene", "boxes", "--duration", "0.1", "--format", "tumvi", "--out", str(out)])
    assert rc == 2 and "already holds mav0" in err


@pytest.mark.parametrize(
    ("old", "new", "words"),
    [
        ("distortion_model: equidistant", "distortion_model: fov", "cam0.distortion_model 'fov' is not supported"),
        ("camera_model: pinhole", "camera_model: omni", "cam0.camera_model 'omni' is not supported"),
        ("  T_cn_cnm1:", "  T_cn_cnm2:", "missing key 'cam1.T_cn_cnm1'"),
        ("  intrinsics:", "  focal_lengths:", "missing key 'cam0.intrinsics'"),
    ],
)
def test_a_bad_camchain_is_one_error_line_and_exit_2(folders: tuple[pathlib.Path, pathlib.Path], tmp_path: pathlib.Path, old: str, new: str, words: str) -> None:
    root = tmp_path / "export"
    shutil.copytree(folders[1], root)
    camchain = root / "dso" / "camchain.yaml"
    text = camchain.read_text()
    assert old in text
    camchain.write_text(text.replace(old, new, 1))
    if "T_cn_cnm2" in new:  # without T_cn_cnm1 cam1's own T_cam_imu places it: take that away too
        camchain.write_text(camchain.read_text().replace("cam1:\n  T_cam_imu:", "cam1:\n  T_imu_cam:"))
    out = tmp_path / "out"
    rc, stdout, err = _run(["run", "--dataset", str(root), "--variant", "PL-w", "--out", str(out)])
    assert rc == 2 and stdout == "" and "Traceback" not in err
    lines = err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith(f"error: {camchain}: ") and words in lines[0], err
    assert not out.exists()
