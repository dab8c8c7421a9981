"""`coplanar run` writes every tracked frame (trajectory.txt), the keyframes (keyframes.txt)
and the ground truth of the evaluated frames (groundtruth.txt), and its metrics.json
figures are what evo computes from those files: `evo_ape tum groundtruth.txt
trajectory.txt -a` (SE(3)), `-as` (Sim(3)), and `evo_rpe ... --delta 1 --delta_unit m`.

evo (GPL) is a test-time reference only: the package never imports it."""

from __future__ import annotations

import contextlib
import copy
import io
import json
import math
import pathlib

import numpy as np
import pytest

from app import cli

EUROC_SLICE = pathlib.Path("/work/shared/data/euroc_mh01_slice")
REL = 1e-6


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
    assert "keyframes" in metrics["trajectory_poses"]
    np.testing.assert_array_equal(_check_tum(out / "trajectory.txt"), _check_tum(out / "keyframes.txt"))
    _assert_matches_evo(out, metrics)


@pytest.mark.skipif(not (EUROC_SLICE / "mav0").is_dir(), reason=f"{EUROC_SLICE} not available")
def test_real_euroc_slice_metrics_match_evo(tmp_path: pathlib.Path) -> None:
    """The 300 real MH_01 stereo pairs (no imu0), all of them (about 15 s of run)."""
    out = tmp_path / "mh01"
    rc, _, err = _run(["--dataset", str(EUROC_SLICE), "--variant", "PL-w", "--out", str(out)])
    assert rc == 0, err
    metrics = _metrics(out)
    frames = _check_tum(out / "trajectory.txt")
    keyframes = _check_tum(out / "keyframes.txt")
    assert len(frames) == metrics["frames_tracked"] > len(keyframes) == metrics["keyframes"]
    assert metrics["frames_evaluated"] >= 0.9 * metrics["frames"] == 270
    ref = _assert_matches_evo(out, metrics)
    assert ref["rpe_pairs"] >= 1  # the slice travels several metres
    assert metrics["ate_rmse_cm"] < 20.0
