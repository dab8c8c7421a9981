"""`coplanar run` (DESIGN §7): a headless run writes a TUM trajectory, metrics.json with the
contract's keys and the map as PLY; bad input is one error line, exit 2, nothing written."""

from __future__ import annotations

import io
import json
import pathlib

import numpy as np
import pytest
from plyfile import PlyData

from app import cli


def test_run_writes_trajectory_metrics_and_map(tmp_path: pathlib.Path, capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "new" / "run"
    assert cli.main(["run", "--scene", "mc-b", "--variant", "PL-w", "--keyframes", "15", "--out", str(out)]) == 0
    assert "15 keyframes" in capsys.readouterr().out

    rows = np.loadtxt(out / "trajectory.txt")
    assert rows.shape == (15, 8)
    np.testing.assert_allclose(rows[:, 0], 0.1 * np.arange(15), atol=1e-9)  # seconds
    np.testing.assert_allclose(np.linalg.norm(rows[:, 4:], axis=1), 1.0, atol=1e-9)
    np.testing.assert_allclose(rows[0, 1:4], [0.0, -1.0, 0.0], atol=1e-9)  # keyframe 0 is the gauge

    metrics = json.loads((out / "metrics.json").read_text())
    assert metrics["variant"] == "PL-w" and metrics["frames"] == 15 and metrics["keyframes"] == 15
    assert np.isfinite(metrics["ate_rmse_cm"]) and 0.0 <= metrics["ate_rmse_cm"] < 50.0
    timing = metrics["timing_ms"]
    for key in ("point_dm", "line_dm", "plane_seg", "plane_fit", "optimization", "total_per_frame"):
        assert key in timing
    assert timing["optimization"] > 0 and timing["total_per_frame"] >= timing["optimization"]

    ply = PlyData.read(io.BytesIO((out / "map.ply").read_bytes()))
    assert ply["vertex"].count == metrics["points"] + 2 * metrics["lines"] + sum(len(f) for f in ply["face"]["vertex_indices"])
    assert ply["edge"].count == metrics["lines"]


@pytest.mark.parametrize(
    ("argv", "words"),
    [
        (["--keyframes", "0"], ["--keyframes", "at least 1"]),
        (["--dataset", "/data/euroc"], ["/data/euroc", "no such folder"]),
        (["--scene", "room"], ["--scene", "room"]),
    ],
)
def test_bad_input_is_one_line_and_exit_2(tmp_path: pathlib.Path, capsys: pytest.CaptureFixture[str], argv: list[str], words: list[str]) -> None:
    out = tmp_path / "out"
    assert cli.main(["run", "--variant", "PL-w", "--out", str(out), *argv]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("error: ") and all(w in err[0] for w in words), err
    assert not out.exists()


def test_out_that_is_a_file_is_refused_and_kept(tmp_path: pathlib.Path, capsys: pytest.CaptureFixture[str]) -> None:
    target = tmp_path / "results"
    target.write_text("keep me")
    assert cli.main(["run", "--scene", "mc-b", "--variant", "P-w", "--out", str(target)]) == 2
    assert "not a folder" in capsys.readouterr().err
    assert target.read_text() == "keep me"


def test_dataset_is_read_and_checked(tmp_path: pathlib.Path, capsys: pytest.CaptureFixture[str]) -> None:
    """A good EuRoC folder is read (the pipeline that runs on it comes later); a broken one
    is one line naming the bad file."""
    import shutil

    from tests.backend.data.test_euroc import write_euroc

    root = write_euroc(tmp_path / "seq")
    assert cli.main(["run", "--dataset", str(root), "--variant", "PL-w", "--out", str(tmp_path / "out")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "stereo frames" in err[0] and "not implemented" in err[0]
    shutil.rmtree(root / "mav0" / "cam1")
    assert cli.main(["run", "--dataset", str(root), "--variant", "PL-w", "--out", str(tmp_path / "out")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("error: ") and "cam1" in err[0] and "Traceback" not in err[0]
