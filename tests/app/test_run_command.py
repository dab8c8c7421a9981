"""`coplanar run` (DESIGN §7): a headless run writes a TUM trajectory, metrics.json with the
contract's keys and the map as PLY, for the stereo pipeline (rendered scenes, scene files,
EuRoC folders) and the Monte-Carlo worlds; bad input is one error line, exit 2, nothing
written (DESIGN §8), also when the dataset turns out bad in the middle of the run."""

from __future__ import annotations

import contextlib
import io
import json
import math
import os
import pathlib
import pty
import shutil
import struct
import subprocess
import sys

import numpy as np
import pytest
from plyfile import PlyData

from app import cli

CONSOLE_SCRIPT = pathlib.Path(sys.executable).parent / "coplanar"
CONTRACT_TIMING = ("point_dm", "tracking", "line_dm", "plane_seg", "plane_fit", "optimization", "total_per_frame", "all_stages")
METRICS_KEYS = (
    "source",
    "variant",
    "frames",
    "keyframes",
    "ate_rmse_cm",
    "rmse_cm",
    "planes",
    "points",
    "lines",
    "lost_frames",
    "reinitializations",
    "timing_ms",
    "messages",
    "warnings",
    "trajectory_poses",
    "frames_tracked",
    "frames_evaluated",
    "ate_sim3_rmse_cm",
    "rpe_cm_per_m",
    "rpe_delta_m",
    "rpe_pairs",
    "keyframe_ate_rmse_cm",
    "keyframe_rmse_cm",
)


def _strict_json(text: str) -> dict:
    """json.loads that refuses NaN / Infinity (not JSON)."""

    def refuse(name: str) -> None:
        raise ValueError(f"{name} is not JSON")

    return json.loads(text, parse_constant=refuse)


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
def room_run(tmp_path_factory: pytest.TempPathFactory) -> dict:
    """One `run --scene room --duration 2 --variant PL-w` (41 frames)."""
    out = tmp_path_factory.mktemp("room") / "new" / "run"
    rc, stdout, stderr = _run(["--scene", "room", "--duration", "2", "--variant", "PL-w", "--out", str(out)])
    return {"rc": rc, "out": out, "stdout": stdout, "stderr": stderr}


@pytest.fixture(scope="module")
def euroc_room(tmp_path_factory: pytest.TempPathFactory) -> pathlib.Path:
    """The `room` scene rendered for 1.5 s (31 frames) into an EuRoC folder."""
    from backend.data.scenes import builtin_scene
    from backend.data.synthetic import SequenceSettings, render_sequence

    root = tmp_path_factory.mktemp("euroc") / "room"
    render_sequence(builtin_scene("room"), root, settings=SequenceSettings(duration_s=1.5, seed=0))
    return root


def test_stereo_run_writes_trajectory_metrics_and_map(room_run: dict) -> None:
    assert room_run["rc"] == 0, room_run["stderr"]
    out = room_run["out"]
    metrics = _strict_json((out / "metrics.json").read_text())
    for key in METRICS_KEYS:
        assert key in metrics, key
    assert metrics["source"] == "rendered scene room (2 s, seed 0)"
    assert metrics["variant"] == "PL-w" and metrics["frames"] == 41
    assert 2 <= metrics["keyframes"] <= metrics["frames"]
    assert f"{metrics['frames']} frames, {metrics['keyframes']} keyframes" in room_run["stdout"]
    assert np.isfinite(metrics["ate_rmse_cm"]) and 0.0 <= metrics["ate_rmse_cm"] < 10.0
    assert metrics["points"] > 0 and metrics["planes"] >= 1
    assert isinstance(metrics["messages"], list)
    assert metrics["lost_frames"] >= 0 and metrics["reinitializations"] >= 0
    recovery = metrics["plane_recovery"]  # the room's floor and walls fill the first keyframes
    assert recovery["seen"] >= 2 and 1 <= recovery["recovered"] <= recovery["seen"]
    assert sorted(recovery["recovered_ids"] + recovery["missed_ids"]) == sorted(set(recovery["recovered_ids"] + recovery["missed_ids"]))
    assert len(recovery["recovered_ids"]) == recovery["recovered"] and len(recovery["missed_ids"]) == recovery["seen"] - recovery["recovered"]

    timing = metrics["timing_ms"]
    for key in CONTRACT_TIMING:
        assert key in timing, key
    for key in ("point_dm", "tracking", "line_dm", "plane_seg", "plane_fit", "optimization", "total_per_frame"):
        assert isinstance(timing[key], float) and timing[key] > 0, key  # PL-w runs every stage
    assert timing["all_stages"]["total"] > timing["total_per_frame"]  # several frames per keyframe

    rows = np.loadtxt(out / "trajectory.txt", ndmin=2)
    assert rows.shape == (metrics["frames_tracked"], 8)  # one pose per tracked frame
    assert metrics["frames_tracked"] == metrics["frames"] - metrics["lost_frames"]  # no re-initialization here
    assert rows[0, 0] == 0.0 and np.all(np.diff(rows[:, 0]) > 0)  # seconds, increasing
    np.testing.assert_allclose(np.linalg.norm(rows[:, 4:], axis=1), 1.0, atol=1e-6)
    kf_rows = np.loadtxt(out / "keyframes.txt", ndmin=2)
    assert kf_rows.shape == (metrics["keyframes"], 8)  # one pose per keyframe

    ply = PlyData.read(io.BytesIO((out / "map.ply").read_bytes()))
    assert ply["vertex"].count == metrics["points"] + 2 * metrics["lines"] + sum(len(f) for f in ply["face"]["vertex_indices"])
    assert ply["edge"].count == metrics["lines"]


def test_scene_file_and_skipped_stages(tmp_path: pathlib.Path, capsys: pytest.CaptureFixture[str]) -> None:
    """A scene JSON file runs; P variants detect no lines, -wo variants segment no planes
    (the paper's Table III), so those stages are null; --frames stops early."""
    from backend.data.scenes import builtin_scene, scene_to_json

    scene = tmp_path / "my boxes.json"
    scene.write_text(scene_to_json(builtin_scene("boxes")))
    out = tmp_path / "out"
    assert cli.main(["run", "--scene", str(scene), "--duration", "5", "--frames", "25", "--variant", "P-wo", "--out", str(out)]) == 0
    assert "25 frames" in capsys.readouterr().out
    metrics = _strict_json((out / "metrics.json").read_text())
    assert str(scene) in metrics["source"] and metrics["frames"] == 25 and metrics["lines"] == 0
    timing = metrics["timing_ms"]
    assert timing["line_dm"] is None and timing["plane_seg"] is None and timing["plane_fit"] is None
    assert timing["point_dm"] > 0 and timing["optimization"] > 0


def test_point_variant_skips_line_detection(tmp_path: pathlib.Path) -> None:
    out = tmp_path / "out"
    rc, _, err = _run(["--scene", "room", "--duration", "1.2", "--variant", "P-w", "--keyframes", "3", "--out", str(out)])
    assert rc == 0, err
    metrics = _strict_json((out / "metrics.json").read_text())
    assert metrics["keyframes"] == 3 and len(np.loadtxt(out / "keyframes.txt", ndmin=2)) == 3
    assert len(np.loadtxt(out / "trajectory.txt", ndmin=2)) == metrics["frames_tracked"] > 3
    assert metrics["timing_ms"]["line_dm"] is None and metrics["lines"] == 0
    assert metrics["timing_ms"]["plane_seg"] > 0 and metrics["timing_ms"]["plane_fit"] > 0


def test_dataset_runs_the_stereo_pipeline(euroc_room: pathlib.Path, tmp_path: pathlib.Path) -> None:
    out = tmp_path / "out"
    rc, stdout, err = _run(["--dataset", str(euroc_room), "--variant", "PL-w", "--out", str(out)])
    assert rc == 0, err
    metrics = _strict_json((out / "metrics.json").read_text())
    assert metrics["source"] == f"EuRoC folder {euroc_room}" and metrics["frames"] == 31
    assert np.isfinite(metrics["ate_rmse_cm"]) and metrics["ate_rmse_cm"] < 10.0
    assert "31 frames" in stdout


def test_dataset_with_a_deleted_image(euroc_room: pathlib.Path, tmp_path: pathlib.Path) -> None:
    root = tmp_path / "seq"
    shutil.copytree(euroc_room, root)
    victim = sorted((root / "mav0" / "cam0" / "data").iterdir())[10]
    victim.unlink()
    out = tmp_path / "out"
    rc, _, err = _run(["--dataset", str(root), "--variant", "PL-w", "--out", str(out)])
    assert rc == 2
    _one_error_line(err, [victim.name])
    assert not out.exists()


def _break_image(euroc_room: pathlib.Path, root: pathlib.Path) -> pathlib.Path:
    """A copy of the folder whose 13th right image is not an image: found only when read."""
    shutil.copytree(euroc_room, root)
    victim = sorted((root / "mav0" / "cam1" / "data").iterdir())[12]
    victim.write_bytes(b"not a png")
    return victim


def test_dataset_error_in_the_middle_of_the_run(euroc_room: pathlib.Path, tmp_path: pathlib.Path) -> None:
    victim = _break_image(euroc_room, tmp_path / "seq")
    out = tmp_path / "out"
    rc, stdout, err = _run(["--dataset", str(tmp_path / "seq"), "--variant", "PL-w", "--out", str(out)])
    assert rc == 2 and stdout == ""
    _one_error_line(err, [victim.name, "not a readable image"])
    assert not (out / "metrics.json").exists()


@pytest.mark.skipif(not CONSOLE_SCRIPT.exists(), reason="console script not installed")
def test_progress_bar_on_a_terminal_leaves_the_error_line_clean(euroc_room: pathlib.Path, tmp_path: pathlib.Path) -> None:
    """On a terminal the bar is drawn, and cleared before the error line."""
    import fcntl
    import termios

    victim = _break_image(euroc_room, tmp_path / "seq")
    primary, secondary = pty.openpty()
    fcntl.ioctl(secondary, termios.TIOCSWINSZ, struct.pack("HHHH", 40, 120, 0, 0))
    proc = subprocess.Popen(
        [str(CONSOLE_SCRIPT), "run", "--dataset", str(tmp_path / "seq"), "--variant", "P-wo", "--out", str(tmp_path / "out")],
        stdin=subprocess.DEVNULL,
        stdout=subprocess.PIPE,
        stderr=secondary,
        cwd=tmp_path,
    )
    os.close(secondary)
    chunks = []
    while True:
        try:
            chunk = os.read(primary, 4096)
        except OSError:  # the child closed the terminal
            break
        if not chunk:
            break
        chunks.append(chunk)
    os.close(primary)
    assert proc.wait(timeout=120) == 2
    assert proc.stdout is not None and proc.stdout.read() == b""
    screen = b"".join(chunks).decode()
    assert "frame" in screen and "%|" in screen  # the bar was drawn
    last_line = screen.replace("\r\n", "\n").rstrip("\n").split("\n")[-1]
    visible = last_line.split("\r")[-1]  # what stays on screen after carriage returns
    assert visible.startswith("error: ") and victim.name in visible and "Traceback" not in screen, repr(screen[-500:])


class _SceneCuts:
    """A rendered sequence whose frames 20-39 come from another scene: tracking is lost at
    frames 20 and 40 with features in view, so the map is re-initialized twice."""

    def __init__(self, first, second) -> None:
        self._first, self._second = first, second

    def __len__(self) -> int:
        return len(self._first)

    def __getattr__(self, name: str):
        return getattr(self._first, name)

    def rectified_pair(self, index: int):
        return (self._second if 20 <= index < 40 else self._first).rectified_pair(index)


def test_tracking_loss_is_counted_and_reported(tmp_path: pathlib.Path, monkeypatch: pytest.MonkeyPatch) -> None:
    from backend.data import synthetic
    from backend.data.scenes import builtin_scene

    real = synthetic.SyntheticSequence

    def cut(scene, *, settings):
        other = real(builtin_scene("boxes"), settings=synthetic.SequenceSettings(duration_s=settings.duration_s, seed=5))
        return _SceneCuts(real(scene, settings=settings), other)

    monkeypatch.setattr(synthetic, "SyntheticSequence", cut)
    out = tmp_path / "out"
    rc, _, err = _run(["--scene", "room", "--duration", "2.1", "--variant", "P-wo", "--out", str(out)])
    assert rc == 0, err
    metrics = _strict_json((out / "metrics.json").read_text())
    reinitialized = [m for m in metrics["messages"] if "re-initialized" in m]
    assert len(reinitialized) == 2 and all(m.startswith("keyframe ") for m in reinitialized)
    assert metrics["lost_frames"] >= 2
    assert metrics["reinitializations"] == len(reinitialized)


def test_monte_carlo_run_writes_trajectory_metrics_and_map(tmp_path: pathlib.Path, capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "new" / "run"
    assert cli.main(["run", "--scene", "mc-b", "--variant", "PL-w", "--keyframes", "15", "--out", str(out)]) == 0
    assert "15 keyframes" in capsys.readouterr().out

    rows = np.loadtxt(out / "trajectory.txt")
    assert rows.shape == (15, 8)
    np.testing.assert_allclose(rows[:, 0], 0.1 * np.arange(15), atol=1e-9)  # seconds
    np.testing.assert_allclose(np.linalg.norm(rows[:, 4:], axis=1), 1.0, atol=1e-9)
    np.testing.assert_allclose(rows[0, 1:4], [0.0, -1.0, 0.0], atol=1e-9)  # keyframe 0 is the gauge
    # No frames between keyframes: trajectory.txt is keyframes.txt, and says so.
    np.testing.assert_array_equal(np.loadtxt(out / "keyframes.txt"), rows)
    assert np.loadtxt(out / "groundtruth.txt").shape == (15, 8)

    metrics = _strict_json((out / "metrics.json").read_text())
    assert metrics["variant"] == "PL-w" and metrics["frames"] == 15 and metrics["keyframes"] == 15
    assert metrics["frames_tracked"] == metrics["frames_evaluated"] == 15 and "keyframes" in metrics["trajectory_poses"]
    assert math.isclose(metrics["ate_rmse_cm"], metrics["keyframe_ate_rmse_cm"], rel_tol=1e-6, abs_tol=1e-9)
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
        (["--scene", "mc-a", "--keyframes", "0"], ["--keyframes", "at least 1"]),
        (["--scene", "room", "--keyframes", "0"], ["--keyframes", "at least 1"]),
        (["--frames", "0"], ["--frames 0", "at least 1"]),
        (["--scene", "mc-b", "--frames", "5"], ["--frames 5", "mc-b"]),
        (["--dataset", "/data/euroc"], ["/data/euroc", "no such folder"]),
        (["--scene", "castle"], ["--scene castle", "room", "mc-a"]),
        (["--scene", "missing/scene.json"], ["--scene missing/scene.json", "scene file"]),
        (["--duration", "0"], ["--duration 0", "more than 0"]),
        (["--duration", "-2"], ["--duration -2"]),
        (["--duration", "nan"], ["--duration nan"]),
        (["--duration", "soon"], ["--duration", "soon"]),
        (["--scene", "mc-a", "--duration", "5"], ["--duration 5", "mc-a"]),
        (["--dataset", "/data/euroc", "--duration", "5"], ["--duration 5", "--dataset"]),
        (["--mislabel", "0.2"], ["--mislabel 0.2", "mc-a"]),
        (["--scene", "mc-a", "--mislabel", "2"], ["--mislabel 2", "[0, 1]"]),
        (["--window", "1"], ["--window 1", "at least 2"]),
        (["--scene", "room", "--dataset", "/data/euroc"], ["--dataset"]),
        (["--scene", "room", "--calib", "camchain.yaml"], ["--calib", "only with --dataset"]),
        (["--scene", "mc-a", "--topic", "cam0=/left"], ["--topic", "only with --dataset"]),
        (["--dataset", "/data/x.bag", "--topic", "cam0"], ["--topic", "NAME=TOPIC"]),
    ],
)
def test_bad_input_is_one_line_and_exit_2(tmp_path: pathlib.Path, capsys: pytest.CaptureFixture[str], argv: list[str], words: list[str]) -> None:
    out = tmp_path / "out"
    assert cli.main(["run", "--variant", "PL-w", "--out", str(out), *argv]) == 2
    _one_error_line(capsys.readouterr().err, words)
    assert not out.exists()


def test_malformed_scene_file_names_the_file(tmp_path: pathlib.Path, capsys: pytest.CaptureFixture[str]) -> None:
    scene = tmp_path / "my_scene.json"
    scene.write_text('{"name": "x", "rectangles": [')
    out = tmp_path / "out"
    assert cli.main(["run", "--scene", str(scene), "--variant", "PL-w", "--out", str(out)]) == 2
    _one_error_line(capsys.readouterr().err, ["my_scene.json", "invalid JSON"])
    assert not out.exists()


@pytest.mark.parametrize("scene", ["mc-b", "room"])
def test_out_that_is_a_file_is_refused_and_kept(tmp_path: pathlib.Path, capsys: pytest.CaptureFixture[str], scene: str) -> None:
    target = tmp_path / "results"
    target.write_text("keep me")
    assert cli.main(["run", "--scene", scene, "--variant", "P-w", "--out", str(target)]) == 2
    _one_error_line(capsys.readouterr().err, ["--out", "not a folder"])
    assert target.read_text() == "keep me"


def test_stride_keeps_every_nth_frame_and_tracking_survives(tmp_path: pathlib.Path) -> None:
    """`--stride 4`: 5 frames per second with four times the motion between frames (room:
    up to about 10 cm and 4° per frame); every frame is tracked, without a re-initialization."""
    out = tmp_path / "run"
    assert cli.main(["run", "--scene", "room", "--duration", "8", "--stride", "4", "--variant", "PL-w", "--out", str(out)]) == 0
    metrics = _strict_json((out / "metrics.json").read_text())
    assert metrics["frames"] == 41  # t = 0, 0.2, …, 8 s
    assert metrics["lost_frames"] == 0 and metrics["reinitializations"] == 0
    assert metrics["frames_tracked"] == 41
    assert metrics["ate_rmse_cm"] < 3.0
    stamps = np.loadtxt(out / "trajectory.txt")[:, 0]
    np.testing.assert_allclose(np.diff(stamps), 0.2, atol=1e-6)


def test_fast_and_suddenly_changing_motion_is_tracked_without_reinitializing(tmp_path: pathlib.Path) -> None:
    """`--stride 4 --speed 2`: 5 Hz along room's path at twice the speed (median 12 cm and 8°
    per frame, up to 30 cm and 26°): the constant-velocity model fails on many frames and
    the pose comes from a wider search or PnP against the last keyframe or the local map;
    no frame is lost and the map is never re-initialized (before the fallback candidates
    were compared: one re-initialization and 41 cm ATE on this run)."""
    out = tmp_path / "run"
    assert cli.main(["run", "--scene", "room", "--duration", "12", "--stride", "4", "--speed", "2", "--variant", "PL-w", "--out", str(out)]) == 0
    metrics = _strict_json((out / "metrics.json").read_text())
    assert metrics["frames"] == 61
    assert metrics["lost_frames"] == 0 and metrics["reinitializations"] == 0
    assert metrics["frames_tracked"] == 61
    assert metrics["ate_rmse_cm"] < 5.0
    assert any("relocalized by PnP" in m for m in metrics["messages"])  # the fallback was needed


@pytest.mark.parametrize(
    "argv, words",
    [
        (["--scene", "room", "--stride", "0"], ["--stride", "0", "at least 1"]),
        (["--scene", "mc-a", "--stride", "2"], ["--stride", "2", "mc-a"]),
    ],
)
def test_bad_stride_is_one_error_line(argv: list[str], words: list[str], tmp_path: pathlib.Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert cli.main(["run", *argv, "--variant", "PL-w", "--out", str(tmp_path / "run")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("error:")
    assert all(w in err[0] for w in words)
    assert not (tmp_path / "run").exists()


def test_learned_segmenter_runs_the_stereo_pipeline(tmp_path: pathlib.Path) -> None:
    out = tmp_path / "run"
    assert cli.main(["run", "--scene", "room", "--duration", "3", "--segmenter", "learned", "--variant", "PL-w", "--out", str(out)]) == 0
    metrics = _strict_json((out / "metrics.json").read_text())
    assert "learned segmenter" in metrics["source"]
    assert metrics["planes"] >= 2 and metrics["timing_ms"]["plane_seg"] > 0


@pytest.mark.parametrize(
    "argv, words",
    [
        (["--scene", "room", "--segmenter-model", "x.onnx"], ["--segmenter-model", "only with --segmenter learned"]),
        (["--scene", "mc-a", "--segmenter", "learned"], ["--segmenter", "mc-a"]),
        (["--scene", "room", "--segmenter", "learned", "--segmenter-model", "MISSING"], ["MISSING", "model file missing"]),
    ],
)
def test_bad_segmenter_options_are_one_error_line(argv: list[str], words: list[str], tmp_path: pathlib.Path, capsys: pytest.CaptureFixture[str]) -> None:
    argv = [str(tmp_path / "none.onnx") if a == "MISSING" else a for a in argv]
    words = [str(tmp_path / "none.onnx") if w == "MISSING" else w for w in words]
    assert cli.main(["run", *argv, "--variant", "PL-w", "--out", str(tmp_path / "run")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("error:"), err
    assert all(w in err[0] for w in words), err[0]
    assert not (tmp_path / "run").exists()


def test_corrupt_segmenter_model_is_one_error_line(tmp_path: pathlib.Path, capsys: pytest.CaptureFixture[str]) -> None:
    import shutil

    from backend.frontend.segmentation_learned import DEFAULT_MODEL

    model = tmp_path / "bad.onnx"
    model.write_bytes(b"garbage" * 100)
    shutil.copy(DEFAULT_MODEL.with_suffix(".json"), model.with_suffix(".json"))
    assert cli.main(["run", "--scene", "room", "--segmenter", "learned", "--segmenter-model", str(model), "--variant", "PL-w", "--out", str(tmp_path / "run")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "bad.onnx: not a loadable ONNX model" in err[0]
    assert not (tmp_path / "run").exists()


def test_run_record_writes_a_recording_serve_replays(tmp_path: pathlib.Path, capsys: pytest.CaptureFixture[str]) -> None:
    """`run --record FILE`: the outputs and one recording of every keyframe, with the image,
    the Hessian and the plane-mode comparison; `serve --replay FILE` builds its replay, whose
    last keyframe is the map the run wrote."""
    from app.serve_command import build_engine
    from backend.pipeline.recording import Recording

    record = tmp_path / "room.recording.zip"
    assert cli.main(["run", "--scene", "room", "--duration", "3", "--variant", "PL-w", "--out", str(tmp_path / "out"), "--record", str(record)]) == 0
    summary = capsys.readouterr().out
    metrics = json.loads((tmp_path / "out" / "metrics.json").read_text())
    assert f"recorded {metrics['keyframes']} keyframes to {record}" in summary
    recording = Recording.open(record)
    assert len(recording) == metrics["keyframes"]
    last = recording.keyframes[-1]
    snapshot = recording.snapshot(last.keyframe, last.stepped)
    assert snapshot.image is not None and snapshot.hessian is not None and len(snapshot.points) == metrics["points"]
    assert set(recording.comparison(last.keyframe, with_lines=True)) == {"PL-wo", "PL-r", "PL-w"}
    engine = build_engine(cli.build_parser().parse_args(["serve", "--replay", str(record)]))
    assert engine.keyframes == metrics["keyframes"] and engine.source.endswith(f"(replay of {record.name})")


def test_run_record_to_a_missing_folder_is_one_line_before_the_run(tmp_path: pathlib.Path, capsys: pytest.CaptureFixture[str]) -> None:
    missing = tmp_path / "no" / "rec.zip"
    assert cli.main(["run", "--scene", "mc-a", "--keyframes", "2", "--variant", "P-wo", "--out", str(tmp_path / "out"), "--record", str(missing)]) == 2
    assert capsys.readouterr().err == f"error: --record {missing}: the folder {missing.parent} does not exist\n"
    assert not (tmp_path / "out").exists()


def test_serve_replay_of_a_file_that_is_not_a_recording_is_one_line(tmp_path: pathlib.Path, capsys: pytest.CaptureFixture[str]) -> None:
    bad = tmp_path / "map.ply"
    bad.write_bytes(b"ply\nformat ascii 1.0\n")
    assert cli.main(["serve", "--replay", str(bad)]) == 2
    assert capsys.readouterr().err == f"error: --replay {bad}: not a coplanar recording (not a zip archive, or a truncated one)\n"
