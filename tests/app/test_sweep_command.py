"""`coplanar sweep` (DESIGN §7): a matrix of `run`s, each in its own folder complete or not at
all, the results as CSV, JSON, a Markdown table and plots; a failed run is a row, not the
sweep's end (exit 1); a second sweep of the same folder runs only what is not finished; bad
options are one line and exit 2; Ray gives the same results as --serial."""

from __future__ import annotations

import contextlib
import importlib.util
import io
import json
import pathlib
import shutil
import signal
import subprocess
import sys
import time

import pytest

from app import cli
from backend.sweep.results import without_times

TINY = ["--scenes", "room", "--duration", "1", "--variants", "P-wo,PL-w"]
IDS = ["room_P-wo_stereo_geometric_seed0_1s", "room_PL-w_stereo_geometric_seed0_1s"]
OUTPUTS = ["ate_by_variant.png", "results.csv", "results.json", "table.md", "time_by_stage.png"]


def _sweep(argv: list[str]) -> tuple[int, str, str]:
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        rc = cli.main(["sweep", *argv])
    return rc, out.getvalue(), err.getvalue()


def _rows(out: pathlib.Path) -> list[dict]:
    return json.loads((out / "results.json").read_text())


@pytest.fixture(scope="module")
def serial(tmp_path_factory: pytest.TempPathFactory) -> pathlib.Path:
    """A 2-run sweep in this process: room, 1 s, P-wo and PL-w."""
    out = tmp_path_factory.mktemp("sweep") / "serial"
    rc, stdout, stderr = _sweep([*TINY, "--serial", "--out", str(out)])
    assert rc == 0, stderr
    assert "2 runs: 2 ran, 0 already finished, 0 failed" in stdout
    return out


def test_serial_sweep_writes_each_run_and_the_results(serial: pathlib.Path) -> None:
    assert sorted(p.name for p in serial.iterdir()) == sorted(IDS + OUTPUTS)  # no staging folder left
    for run_id in IDS:
        record = json.loads((serial / run_id / "run.json").read_text())
        metrics = json.loads((serial / run_id / "metrics.json").read_text())
        assert record["run_id"] == run_id and record["wall_s"] > 0 and metrics["variant"] == run_id.split("_")[1]
        assert (serial / run_id / "trajectory.txt").stat().st_size > 0 and (serial / run_id / "map.ply").exists()
    rows = _rows(serial)
    assert [r["run_id"] for r in rows] == IDS and all(r["status"] == "ok" for r in rows)
    for row in rows:
        metrics = json.loads((serial / row["run_id"] / "metrics.json").read_text())
        assert row["ate_rmse_cm"] == metrics["ate_rmse_cm"] and 0 < row["ate_rmse_cm"] < 10
        assert row["keyframes"] == metrics["keyframes"] and row["lost_frames"] == metrics["lost_frames"] == 0
        assert row["time_total_per_frame_ms"] == metrics["timing_ms"]["total_per_frame"]
    table = (serial / "table.md").read_text()
    assert "| sequence | P-wo | PL-w |" in table and "| **mean** |" in table and "Lost frames" in table
    assert (serial / "results.csv").read_text().count("\n") == 3


def test_a_resumed_sweep_runs_only_what_is_not_finished(serial: pathlib.Path, tmp_path: pathlib.Path) -> None:
    out = tmp_path / "resumed"
    shutil.copytree(serial, out)
    shutil.rmtree(out / IDS[1])  # as if the sweep was killed before that run ended ...
    stale = out / ".coplanar-partial-999999999" / IDS[1]  # ... in the middle of writing it
    stale.mkdir(parents=True)
    (stale / "metrics.json").write_text("{")
    kept = (out / IDS[0] / "metrics.json").stat().st_mtime_ns
    rc, stdout, stderr = _sweep([*TINY, "--serial", "--out", str(out)])
    assert rc == 0, stderr
    assert "2 runs: 1 ran, 1 already finished, 0 failed" in stdout
    assert stdout.count("ok     ") == 1 and IDS[1] in stdout and IDS[0] not in stdout.split("2 runs:")[0]
    assert (out / IDS[0] / "metrics.json").stat().st_mtime_ns == kept
    assert sorted(p.name for p in out.iterdir()) == sorted(IDS + OUTPUTS)  # the stale staging folder is gone
    assert [without_times(r) for r in _rows(out)] == [without_times(r) for r in _rows(serial)]
    rc, stdout, _ = _sweep([*TINY, "--serial", "--out", str(out)])
    assert rc == 0 and "2 runs: 0 ran, 2 already finished, 0 failed" in stdout


def test_each_run_says_where_it_was_made_and_a_resume_notes_runs_from_elsewhere(serial: pathlib.Path, tmp_path: pathlib.Path) -> None:
    """A table built from a sweep folder can tell which code and machine made each run (the
    VIO's outcomes shift with rounding: 8.09 against 5.20 cm on `exposure` seed 2 across
    BLAS kernels), and resuming into a folder of runs made elsewhere says so instead of
    mixing them in silently."""
    from backend.sweep.provenance import Provenance, current

    here = current()
    for run_id in IDS:
        recorded = Provenance.from_dict(json.loads((serial / run_id / "run.json").read_text())["provenance"])
        assert recorded == here and recorded.cpu and recorded.blas
    rc, _, stderr = _sweep([*TINY, "--serial", "--out", str(serial)])
    assert rc == 0 and "note:" not in stderr  # all made here by this code
    out = tmp_path / "elsewhere"
    shutil.copytree(serial, out)
    record_path = out / IDS[1] / "run.json"
    record = json.loads(record_path.read_text())
    record["provenance"] = {**record["provenance"], "commit": "0000000"}
    record_path.write_text(json.dumps(record))
    rc, stdout, stderr = _sweep([*TINY, "--serial", "--out", str(out)])
    assert rc == 0 and "2 runs: 0 ran, 2 already finished, 0 failed" in stdout
    assert f"note: 1 finished runs in {out} were made by other code or on another machine" in stderr and IDS[1] in stderr


def test_a_failing_run_is_a_row_not_the_end(tmp_path: pathlib.Path, monkeypatch: pytest.MonkeyPatch) -> None:
    from backend.headless import run as headless

    (tmp_path / "notadataset").mkdir()
    real = headless.run_headless

    def flaky(config, out, **kwargs):
        if config.seed == 1:
            raise RuntimeError("the solver blew up\nwith a second line")
        return real(config, out, **kwargs)

    monkeypatch.setattr(headless, "run_headless", flaky)
    out = tmp_path / "out"
    argv = ["--scenes", "room", "--datasets", str(tmp_path / "notadataset"), "--duration", "0.5", "--variants", "P-wo", "--seeds", "0,1", "--serial", "--out", str(out)]
    rc, stdout, stderr = _sweep(argv)
    assert rc == 1, stderr
    rows = {r["run_id"]: r for r in _rows(out)}
    assert rows["room_P-wo_stereo_geometric_seed0_0.5s"]["status"] == "ok"
    assert rows["room_P-wo_stereo_geometric_seed1_0.5s"]["error"] == "RuntimeError: the solver blew up"
    bad = rows["notadataset_P-wo_stereo_geometric_seed0"]
    assert bad["status"] == "failed" and bad["error"].startswith("DatasetError: ") and "notadataset" in bad["error"]
    assert sorted(p.name for p in out.iterdir()) == sorted(["room_P-wo_stereo_geometric_seed0_0.5s", *OUTPUTS])  # no folder for a failed run
    assert "4 runs: 4 ran, 0 already finished, 3 failed" in stdout and stdout.count("failed ") == 3
    assert "## Failed runs" in (out / "table.md").read_text()


def test_sigterm_between_runs_keeps_the_finished_ones_and_the_sweep_resumes(tmp_path: pathlib.Path) -> None:
    out = tmp_path / "out"
    argv = ["--scenes", "room", "--duration", "2", "--variants", "P-wo,P-w,PL-w", "--serial", "--out", str(out)]
    root = pathlib.Path(__file__).resolve().parents[2]
    process = subprocess.Popen([sys.executable, "-m", "app.cli", "sweep", *argv], cwd=root, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    deadline = time.monotonic() + 120
    while not (out / "room_P-wo_stereo_geometric_seed0_2s").is_dir() and process.poll() is None and time.monotonic() < deadline:
        time.sleep(0.1)
    assert process.poll() is None, "the sweep ended before the signal"
    process.send_signal(signal.SIGTERM)
    _, err = process.communicate(timeout=120)
    assert process.returncode == 130 and err.strip().splitlines()[-1] == f"interrupted: the finished runs are in {out}; the same command resumes there", err
    finished = sorted(p.name for p in out.iterdir())
    assert finished and all((out / name / "run.json").is_file() for name in finished)  # finished runs only: no staging folder, no half run
    rc, stdout, stderr = _sweep(argv)
    assert rc == 0 and f"3 runs: {3 - len(finished)} ran, {len(finished)} already finished, 0 failed" in stdout, stderr


@pytest.mark.parametrize(
    ("argv", "words"),
    [
        (["--seeds", "0-x"], ["--seeds", "not an integer"]),
        (["--variants", "P-wo,XL-w"], ["--variants", "XL-w"]),
        (["--scenes", "mc-b"], ["--scenes", "coplanar sim"]),
        (["--datasets", "/no/such/dataset"], ["--datasets", "no such file"]),
        (["--modes", "stereo,mono"], ["--modes", "mono"]),
        (["--duration", "0"], ["--duration", "more than 0"]),
        (["--serial", "--address", "auto"], ["--serial", "--address"]),
        (["--serial", "--workers", "2"], ["--serial", "--workers"]),
        (["--workers", "0"], ["--workers 0", "at least 1"]),
        (["--workers", "two"], ["--workers", "invalid int"]),
        (["--address", "127.0.0.1:1"], ["cannot reach the Ray cluster at 127.0.0.1:1", "--serial"]),
        (["--config", "{tmp}/missing.toml"], ["missing.toml", "cannot read"]),
        (["--config", "{tmp}/bad.toml"], ["bad.toml", "colour", "not a sweep axis"]),
    ],
)
def test_bad_options_are_one_line_and_exit_2(argv: list[str], words: list[str], tmp_path: pathlib.Path) -> None:
    (tmp_path / "bad.toml").write_text('colour = "red"\n')
    out = tmp_path / "out"
    rc, stdout, stderr = _sweep([*(a.replace("{tmp}", str(tmp_path)) for a in argv), "--out", str(out)])
    lines = stderr.strip().splitlines()
    assert rc == 2 and stdout == "" and len(lines) == 1 and lines[0].startswith("error: ") and all(w in lines[0] for w in words), stderr
    assert not out.exists()


def test_toml_matrix_and_dry_run(serial: pathlib.Path, tmp_path: pathlib.Path) -> None:
    config = tmp_path / "sweep.toml"
    config.write_text('scenes = ["room"]\nvariants = ["P-wo", "PL-w", "P-r"]\nduration = 1\n')
    rc, stdout, stderr = _sweep(["--matrix", str(config), "--seeds", "0", "--dry-run", "--out", str(serial)])
    assert rc == 0, stderr
    assert stdout.splitlines() == [f"finished {IDS[0]}", f"finished {IDS[1]}", "to run   room_P-r_stereo_geometric_seed0_1s"]


@pytest.mark.skipif(importlib.util.find_spec("ray") is None, reason="Ray is not installed (pyproject.toml pins it)")
def test_ray_sweep_gives_the_serial_results(serial: pathlib.Path, tmp_path: pathlib.Path) -> None:
    """The same 2-run matrix as Ray tasks (2 local workers): the same numbers, timings aside."""
    out = tmp_path / "ray"
    rc, stdout, stderr = _sweep([*TINY, "--workers", "2", "--out", str(out)])
    if rc == 2 and "cannot start Ray" in stderr:
        pytest.skip(f"Ray cannot start on this machine: {stderr.strip()}")
    assert rc == 0, stderr
    assert "2 runs: 2 ran, 0 already finished, 0 failed" in stdout and "Ray on this machine (2 CPUs)" in stderr
    assert sorted(p.name for p in out.iterdir()) == sorted(IDS + OUTPUTS)
    assert [without_times(r) for r in _rows(out)] == [without_times(r) for r in _rows(serial)]
    for run_id in IDS:
        assert (out / run_id / "trajectory.txt").read_bytes() == (serial / run_id / "trajectory.txt").read_bytes()


def test_a_bag_sweeps_with_its_calibration_as_run_reads_it(tmp_path: pathlib.Path) -> None:
    """A ROS bag holds no calibration: `--calib` gives it to every dataset run of the sweep,
    and the run is the one `coplanar run --dataset BAG --calib DIR` makes."""
    with contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(io.StringIO()):
        assert cli.main(["render", "--scene", "boxes", "--duration", "1", "--format", "rosbag1", "--out", str(tmp_path / "bag")]) == 0
    bag, calib = tmp_path / "bag" / "data.bag", tmp_path / "bag" / "calib"
    rc, _, err = _sweep(["--datasets", str(bag), "--variants", "P-wo", "--serial", "--out", str(tmp_path / "sweep")])
    assert rc == 1 and "a bag holds no camera calibration" in _rows(tmp_path / "sweep")[0]["error"], err
    rc, _, err = _sweep(["--datasets", str(bag), "--calib", str(calib), "--variants", "P-wo", "--serial", "--out", str(tmp_path / "sweep")])
    assert rc == 0, err
    (row,) = _rows(tmp_path / "sweep")
    assert row["status"] == "ok" and row["calib"] == str(calib)
    with contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(io.StringIO()):
        assert cli.main(["run", "--dataset", str(bag), "--calib", str(calib), "--variant", "P-wo", "--out", str(tmp_path / "run")]) == 0
    run_metrics = json.loads((tmp_path / "run" / "metrics.json").read_text())
    assert row["ate_rmse_cm"] == pytest.approx(run_metrics["ate_rmse_cm"], rel=1e-12)


def test_run_options_reach_each_run_as_run_takes_them(tmp_path: pathlib.Path) -> None:
    """`--windows`, `--keyframes` and `--trajectory-frame` make the run `coplanar run` makes with
    `--window`, `--keyframes` and `--trajectory-frame`: the same trajectory file."""
    options = ["--windows", "3", "--keyframes", "3", "--trajectory-frame", "camera"]
    rc, _, err = _sweep(["--scenes", "room", "--duration", "1", "--variants", "P-wo", *options, "--serial", "--out", str(tmp_path / "sweep")])
    assert rc == 0, err
    (row,) = _rows(tmp_path / "sweep")
    assert row["run_id"] == "room_P-wo_stereo_geometric_seed0_1s_window3_keyframes3_camera" and row["keyframes"] == 3
    assert (row["window"], row["keyframes_limit"], row["trajectory_frame"], row["dense"]) == (3, 3, "camera", False)
    with contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(io.StringIO()):
        argv = ["run", "--scene", "room", "--duration", "1", "--variant", "P-wo", "--window", "3", "--keyframes", "3", "--trajectory-frame", "camera"]
        assert cli.main([*argv, "--out", str(tmp_path / "run")]) == 0
    swept = tmp_path / "sweep" / row["run_id"]
    assert (swept / "trajectory.txt").read_bytes() == (tmp_path / "run" / "trajectory.txt").read_bytes()
    assert json.loads((swept / "metrics.json").read_text())["trajectory_frame"] == json.loads((tmp_path / "run" / "metrics.json").read_text())["trajectory_frame"]


def test_bag_topics_reach_the_reader_and_a_folder_of_other_topics_is_kept(tmp_path: pathlib.Path) -> None:
    """`--topics` is run's `--topic` for every bag of the sweep; a finished run's folder whose
    run.json names other topics (not in the folder name) is a failed row, not resumed as if
    it were this run, and is left as it was."""
    with contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(io.StringIO()):
        assert cli.main(["render", "--scene", "boxes", "--duration", "1", "--format", "rosbag2", "--out", str(tmp_path / "bag")]) == 0
    bag, calib = tmp_path / "bag" / "data", tmp_path / "bag" / "calib"
    common = ["--datasets", str(bag), "--calib", str(calib), "--variants", "P-wo", "--serial"]
    rc, _, err = _sweep([*common, "--topics", "cam1=/no/such/topic", "--out", str(tmp_path / "wrong")])
    assert rc == 1 and "/no/such/topic" in _rows(tmp_path / "wrong")[0]["error"], err
    rc, _, err = _sweep([*common, "--out", str(tmp_path / "sweep")])
    assert rc == 0, err
    (folder,) = [p for p in (tmp_path / "sweep").iterdir() if p.is_dir()]
    before = (folder / "trajectory.txt").read_bytes()
    rc, _, err = _sweep([*common, "--topics", "cam0=/cam0/image_raw", "--out", str(tmp_path / "sweep")])
    (row,) = _rows(tmp_path / "sweep")
    assert rc == 1 and row["status"] == "failed" and "holds a finished run with other topics" in row["error"], err
    assert (folder / "trajectory.txt").read_bytes() == before
