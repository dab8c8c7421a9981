"""`coplanar run` writes every tracked frame (trajectory.txt), the keyframes (keyframes.txt)
and the ground truth of the evaluated frames (groundtruth.txt), and its metrics.json
figures are what evo computes from those files: `evo_ape tum groundtruth.txt
trajectory.txt -a` (SE(3)), `-as` (Sim(3)), and `evo_rpe ... --delta 1 --delta_unit m`.
By default the poses are of the frame the dataset's own ground truth is of (EuRoC, rendered
scenes: the IMU body), so `evo_ape euroc DATASET/mav0/state_groundtruth_estimate0/data.csv
trajectory.txt -a` gives `ate_rmse_cm` too; `--trajectory-frame camera` writes the
rectified left camera (and its groundtruth.txt in the same frame).

evo (GPL) is a test-time reference only: the package never imports it."""

from __future__ import annotations

import contextlib
import copy
import io
import json
import math
import pathlib
import subprocess
import sys
import zipfile

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from app import cli

SHARED = pathlib.Path(__file__).resolve().parents[2] / ".." / "shared" / "data"
EUROC_SLICE = SHARED / "euroc_mh01_slice"
SLICE_FRAMES = 150  # of the slice's 300: about 7 s of run, 1.5 m of path
REL = 1e-6
needs_slice = pytest.mark.skipif(not (EUROC_SLICE / "mav0").is_dir(), reason=f"{EUROC_SLICE} not available")


def _run(argv: list[str]) -> tuple[int, str, str]:
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        rc = cli.main(["run", *argv])
    return rc, out.getvalue(), err.getvalue()


def _metrics(out: pathlib.Path) -> dict:
    def refuse(name: str) -> None:
        raise ValueError(f"{name} is not JSON")

    return json.loads((out / "metrics.json").read_text(), parse_constant=refuse)


def _evo(out: pathlib.Path) -> dict:
    """evo's APE (SE(3), Sim(3) aligned) and RPE (1 m) RMSE in cm from the run's files."""
    file_interface = pytest.importorskip("evo.tools.file_interface")
    from evo.core import metrics, sync
    from evo.core.filters import FilterException

    ref = file_interface.read_tum_trajectory_file(str(out / "groundtruth.txt"))
    est = file_interface.read_tum_trajectory_file(str(out / "trajectory.txt"))
    ref, est = sync.associate_trajectories(ref, est)
    result = {"frames_evaluated": ref.num_poses}
    for key, correct_scale in (("ate_rmse_cm", False), ("ate_sim3_rmse_cm", True)):
        aligned = copy.deepcopy(est)
        aligned.align(ref, correct_scale=correct_scale)
        ape = metrics.APE(metrics.PoseRelation.translation_part)
        ape.process_data((ref, aligned))
        result[key] = 100.0 * ape.get_statistic(metrics.StatisticsType.rmse)
    rpe = metrics.RPE(metrics.PoseRelation.translation_part, delta=1.0, delta_unit=metrics.Unit.meters, all_pairs=False)
    try:
        rpe.process_data((ref, est))
        result["rpe_pairs"] = len(rpe.error)
        result["rpe_cm_per_m"] = 100.0 * rpe.get_statistic(metrics.StatisticsType.rmse) if len(rpe.error) else None
    except FilterException:  # no pair: the path is shorter than 1 m
        result["rpe_pairs"], result["rpe_cm_per_m"] = 0, None
    return result


def _assert_matches_evo(out: pathlib.Path, metrics: dict) -> dict:
    ref = _evo(out)
    assert metrics["frames_evaluated"] == ref["frames_evaluated"]
    for key in ("ate_rmse_cm", "ate_sim3_rmse_cm"):
        assert math.isclose(metrics[key], ref[key], rel_tol=REL), (key, metrics[key], ref[key])
    assert metrics["rpe_pairs"] == ref["rpe_pairs"]
    if ref["rpe_cm_per_m"] is None:
        assert metrics["rpe_cm_per_m"] is None
    else:
        assert math.isclose(metrics["rpe_cm_per_m"], ref["rpe_cm_per_m"], rel_tol=REL), (metrics["rpe_cm_per_m"], ref["rpe_cm_per_m"])
    return ref


def _check_tum(path: pathlib.Path) -> np.ndarray:
    rows = np.loadtxt(path, ndmin=2)
    assert rows.shape[1] == 8
    assert np.all(np.diff(rows[:, 0]) > 0)  # strictly increasing seconds
    np.testing.assert_allclose(np.linalg.norm(rows[:, 4:], axis=1), 1.0, atol=1e-6)
    return rows


@pytest.fixture(scope="module")
def room3(tmp_path_factory: pytest.TempPathFactory) -> tuple[pathlib.Path, dict]:
    """`run --scene room --duration 3 --variant P-w` (61 frames)."""
    out = tmp_path_factory.mktemp("room3") / "run"
    rc, _, err = _run(["--scene", "room", "--duration", "3", "--variant", "P-w", "--out", str(out)])
    assert rc == 0, err
    return out, _metrics(out)


def test_trajectory_has_every_tracked_frame(room3: tuple[pathlib.Path, dict]) -> None:
    out, metrics = room3
    frames = _check_tum(out / "trajectory.txt")
    keyframes = _check_tum(out / "keyframes.txt")
    gt = _check_tum(out / "groundtruth.txt")
    assert metrics["trajectory_poses"] == "tracked frames"
    assert metrics["trajectory_frame"] == "body"  # a rendered scene's ground truth is the IMU body's
    assert metrics["frames"] == 61 and metrics["lost_frames"] == 0
    assert len(frames) == metrics["frames_tracked"] == 61 > len(keyframes) == metrics["keyframes"] >= 2
    np.testing.assert_allclose(frames[:, 0], 0.05 * np.arange(61), atol=1e-9)  # 20 frames per second
    # Keyframes are frames, at the same pose in both files.
    at = np.searchsorted(frames[:, 0], keyframes[:, 0])
    np.testing.assert_allclose(frames[at], keyframes, atol=1e-9)
    # The rendered room has ground truth everywhere: every tracked frame is evaluated.
    assert metrics["frames_evaluated"] == len(gt) == len(frames)
    np.testing.assert_array_equal(gt[:, 0], frames[:, 0])
    for key in ("ate_rmse_cm", "ate_sim3_rmse_cm", "rmse_cm", "keyframe_ate_rmse_cm"):
        assert isinstance(metrics[key], float) and 0.0 <= metrics[key] < 10.0, key
    assert metrics["ate_sim3_rmse_cm"] <= metrics["ate_rmse_cm"] + 1e-9 and metrics["ate_rmse_cm"] <= metrics["rmse_cm"] + 1e-9
    assert metrics["rpe_delta_m"] == 1.0


def test_rendered_run_metrics_match_evo(room3: tuple[pathlib.Path, dict]) -> None:
    out, metrics = room3
    _assert_matches_evo(out, metrics)


def test_monte_carlo_run_metrics_match_evo(tmp_path: pathlib.Path) -> None:
    """mc-a has keyframes only: trajectory.txt holds them, and the figures are evo's."""
    out = tmp_path / "mc"
    rc, _, err = _run(["--scene", "mc-a", "--variant", "PL-w", "--keyframes", "12", "--out", str(out)])
    assert rc == 0, err
    metrics = _metrics(out)
    assert metrics["frames"] == metrics["keyframes"] == metrics["frames_tracked"] == metrics["frames_evaluated"] == 12
    assert "keyframes" in metrics["trajectory_poses"] and metrics["trajectory_frame"] == "camera"
    np.testing.assert_array_equal(_check_tum(out / "trajectory.txt"), _check_tum(out / "keyframes.txt"))
    _assert_matches_evo(out, metrics)


def _data_csv(dataset: pathlib.Path) -> pathlib.Path:
    return dataset / "mav0" / "state_groundtruth_estimate0" / "data.csv"


def _evo_ape_euroc(data_csv: pathlib.Path, out: pathlib.Path) -> tuple[int, float]:
    """`evo_ape euroc DATA_CSV DIR/trajectory.txt -a` through evo's API, as its command
    line does it: the pairs it evaluates and the RMSE (cm)."""
    file_interface = pytest.importorskip("evo.tools.file_interface")
    from evo.core import metrics, sync

    ref = file_interface.read_euroc_csv_trajectory(str(data_csv))
    est = file_interface.read_tum_trajectory_file(str(out / "trajectory.txt"))
    ref, est = sync.associate_trajectories(ref, est)
    aligned = copy.deepcopy(est)
    aligned.align(ref)
    ape = metrics.APE(metrics.PoseRelation.translation_part)
    ape.process_data((ref, aligned))
    return ref.num_poses, 100.0 * ape.get_statistic(metrics.StatisticsType.rmse)


def _run_on(dataset: pathlib.Path, out: pathlib.Path, *extra: str) -> dict:
    rc, _, err = _run(["--dataset", str(dataset), "--variant", "PL-w", "--out", str(out), *extra])
    assert rc == 0, err
    return _metrics(out)


def _poses(rows: np.ndarray) -> np.ndarray:
    """TUM rows (N, 8) as poses (N, 4, 4)."""
    T = np.tile(np.eye(4), (len(rows), 1, 1))
    T[:, :3, :3] = Rotation.from_quat(rows[:, 4:8]).as_matrix()
    T[:, :3, 3] = rows[:, 1:4]
    return T


@pytest.fixture(scope="module")
def mh01(tmp_path_factory: pytest.TempPathFactory) -> tuple[pathlib.Path, dict]:
    """The first SLICE_FRAMES real MH_01 stereo pairs (no imu0), default frame (the body)."""
    if not (EUROC_SLICE / "mav0").is_dir():
        pytest.skip(f"{EUROC_SLICE} not available")
    out = tmp_path_factory.mktemp("mh01") / "run"
    return out, _run_on(EUROC_SLICE, out, "--frames", str(SLICE_FRAMES))


@pytest.fixture(scope="module")
def rendered(tmp_path_factory: pytest.TempPathFactory) -> tuple[pathlib.Path, pathlib.Path, dict]:
    """`coplanar render --scene room --duration 3` read back with `run --dataset`."""
    folder = tmp_path_factory.mktemp("rendered") / "room"
    assert cli.main(["render", "--scene", "room", "--duration", "3", "--out", str(folder)]) == 0
    out = folder.parent / "run"
    return folder, out, _run_on(folder, out)


@needs_slice
def test_real_euroc_slice_metrics_match_evo(mh01: tuple[pathlib.Path, dict]) -> None:
    out, metrics = mh01
    frames = _check_tum(out / "trajectory.txt")
    keyframes = _check_tum(out / "keyframes.txt")
    assert len(frames) == metrics["frames_tracked"] > len(keyframes) == metrics["keyframes"]
    assert metrics["frames_evaluated"] >= 0.9 * metrics["frames"] == 0.9 * SLICE_FRAMES
    ref = _assert_matches_evo(out, metrics)
    assert ref["rpe_pairs"] >= 1  # the slice travels more than a metre
    assert metrics["ate_rmse_cm"] < 20.0


@needs_slice
def test_real_euroc_trajectory_against_the_datasets_own_ground_truth_file(mh01: tuple[pathlib.Path, dict], tmp_path: pathlib.Path) -> None:
    """What a user runs: `evo_ape euroc .../data.csv trajectory.txt -a` gives metrics.json's
    ATE (the poses are of the body, as data.csv's; a frame is paired with the sample evo
    pairs it with). Once through evo's command line too, reading the figure it saves."""
    out, metrics = mh01
    assert metrics["trajectory_frame"] == "body" and "IMU body" in metrics["trajectory_frame_note"]
    for name in ("trajectory.txt", "keyframes.txt", "groundtruth.txt"):
        assert "T_world_body" in (out / name).read_text().split("\n# t x y z")[0], name
    pairs, ate_cm = _evo_ape_euroc(_data_csv(EUROC_SLICE), out)
    assert pairs == metrics["frames_evaluated"]
    assert math.isclose(ate_cm, metrics["ate_rmse_cm"], rel_tol=REL), (ate_cm, metrics["ate_rmse_cm"])
    evo_ape = pathlib.Path(sys.executable).with_name("evo_ape")
    if not evo_ape.exists():
        pytest.skip("the evo_ape command is not installed beside this Python")
    saved = tmp_path / "ape.zip"
    cmd = [str(evo_ape), "euroc", str(_data_csv(EUROC_SLICE)), str(out / "trajectory.txt"), "-a", "--save_results", str(saved), "--no_warnings"]
    subprocess.run(cmd, check=True, capture_output=True, timeout=120)
    with zipfile.ZipFile(saved) as z:
        stats = json.loads(z.read("stats.json"))
    assert math.isclose(100.0 * stats["rmse"], metrics["ate_rmse_cm"], rel_tol=REL), (stats["rmse"], metrics["ate_rmse_cm"])


@needs_slice
def test_real_euroc_camera_frame_matches_its_own_ground_truth(mh01: tuple[pathlib.Path, dict], tmp_path: pathlib.Path) -> None:
    """`--trajectory-frame camera`: the rectified left camera, as before; evo against
    groundtruth.txt (same frame) still gives every figure. Against the dataset's body poses
    it does not (the mistake the default prevents), and the two runs' poses are the same
    estimate in two frames: T_world_rect0 = T_world_body · T_frame_rect0."""
    body_out, body = mh01
    out = tmp_path / "camera"
    metrics = _run_on(EUROC_SLICE, out, "--frames", str(SLICE_FRAMES), "--trajectory-frame", "camera")
    assert metrics["trajectory_frame"] == "rect0" and "rectified left camera" in metrics["trajectory_frame_note"]
    np.testing.assert_array_equal(metrics["T_frame_rect0"], np.eye(4))
    assert "T_world_rect0" in (out / "trajectory.txt").read_text().split("\n# t x y z")[0]
    _assert_matches_evo(out, metrics)
    _, against_body = _evo_ape_euroc(_data_csv(EUROC_SLICE), out)
    assert not math.isclose(against_body, metrics["ate_rmse_cm"], rel_tol=0.01)
    camera_rows, body_rows = _check_tum(out / "trajectory.txt"), _check_tum(body_out / "trajectory.txt")
    np.testing.assert_array_equal(camera_rows[:, 0], body_rows[:, 0])
    T_body_rect0 = np.asarray(body["T_frame_rect0"])
    np.testing.assert_allclose(_poses(body_rows) @ T_body_rect0, _poses(camera_rows), atol=1e-6)


def test_rendered_euroc_folder_against_its_ground_truth_file(rendered: tuple[pathlib.Path, pathlib.Path, dict]) -> None:
    """`coplanar render` then `run --dataset`: the trajectory is the body's, as the folder's
    data.csv, and evo against that file gives metrics.json's ATE; every frame is evaluated
    (the rendered ground truth has a row at every frame's time)."""
    folder, out, metrics = rendered
    assert metrics["trajectory_frame"] == "body" and metrics["frames_evaluated"] == metrics["frames_tracked"] == metrics["frames"] == 61
    pairs, ate_cm = _evo_ape_euroc(_data_csv(folder), out)
    assert pairs == metrics["frames_evaluated"]
    assert math.isclose(ate_cm, metrics["ate_rmse_cm"], rel_tol=REL), (ate_cm, metrics["ate_rmse_cm"])
    _assert_matches_evo(out, metrics)
    assert metrics["ate_rmse_cm"] < 5.0
