"""The figures `coplanar run` writes to metrics.json: trajectory accuracy against ground
truth, the stereo pipeline's timing means, and the VIO initialization's report. Pure
functions of the engine's trajectories and reports (no files)."""

from __future__ import annotations

from typing import Any

import numpy as np

from backend.common.timing import PER_FRAME_STAGES, Stage
from backend.eval.trajectory import ate_rmse, relative_pose_error, translational_rmse, umeyama_alignment

RPE_DELTA_M = 1.0  # path length per relative-pose-error pair, metres


def trajectory_metrics(estimate, ground_truth) -> tuple[dict, tuple[np.ndarray, np.ndarray, np.ndarray]]:
    """Accuracy of the poses `estimate` (a Trajectory) against `ground_truth` (a Trajectory
    of the same instants, NaN rows: none); also the evaluated ground truth as
    `(timestamp_ns, R_world_camera, t_world_camera)` arrays.

    Evaluated: the poses with ground truth (`frames_evaluated`). Positions are taken as
    written to the TUM file (9 decimals), so evo on the files gives the same figures:

    - `ate_rmse_cm`: absolute trajectory error, RMSE of the position errors after the
      least-squares rigid alignment of the estimate to the ground truth (Umeyama, SE(3));
      `evo_ape tum groundtruth.txt trajectory.txt -a`. Null below 2 evaluated poses.
    - `ate_sim3_rmse_cm`: the same after a similarity alignment (Sim(3), `-as`); null below 3.
    - `rmse_cm`: RMSE of the position errors without alignment (the engine starts at the
      ground-truth pose where there is one).
    - `rpe_cm_per_m`: relative pose error, RMSE over consecutive pose pairs about
      `rpe_delta_m` = 1 m of travelled path apart (path measured on the estimate) of the
      translation of `(Q_i⁻¹ Q_j)⁻¹ (P_i⁻¹ P_j)`, in cm, i.e. cm per metre travelled;
      `evo_rpe tum groundtruth.txt trajectory.txt --delta 1 --delta_unit m`. Null when the
      path is shorter than 1 m (`rpe_pairs` 0).
    """
    valid = np.isfinite(ground_truth.t_world_camera).all(axis=1) if len(ground_truth) else np.zeros(0, bool)
    if len(ground_truth) != len(estimate):
        valid = np.zeros(len(estimate), bool)
    stamp = np.asarray(estimate.timestamp_ns)[valid]
    p_est = np.round(np.asarray(estimate.t_world_camera)[valid], 9)
    p_gt = np.round(np.asarray(ground_truth.t_world_camera)[valid], 9)
    R_est = np.asarray(estimate.R_world_camera)[valid]
    R_gt = np.asarray(ground_truth.R_world_camera)[valid]
    n = int(valid.sum())
    nan = float("nan")
    rpe = relative_pose_error(R_est, p_est, R_gt, p_gt, delta_m=RPE_DELTA_M) if n else None
    metrics = {
        "frames_evaluated": n,
        "ate_rmse_cm": 100.0 * ate_rmse(p_est, p_gt, align="se3") if n >= 2 else nan,
        "ate_sim3_rmse_cm": 100.0 * ate_rmse(p_est, p_gt, align="sim3") if n >= 3 else nan,
        "rmse_cm": 100.0 * translational_rmse(p_est, p_gt) if n else nan,
        "rpe_cm_per_m": rpe.rmse_cm_per_m if rpe is not None else nan,
        "rpe_delta_m": RPE_DELTA_M,
        "rpe_pairs": rpe.pairs if rpe is not None else 0,
    }
    return metrics, (stamp, R_gt, p_gt)


def stereo_timing(steps: list[tuple[int, dict[str, float]]]) -> dict:
    """DESIGN §7's timing means from the steps' `(frames, timing_ms)`, milliseconds.

    The stereo engine reports `point_dm`, `tracking` and `load` as means per frame within a
    step: they are averaged per frame (each step weighted by its frames). `total` is the
    step's wall time without loading images: `total_per_frame` is Σ total / Σ frames. Every
    other stage runs once per keyframe and is averaged over the keyframes where it ran (a
    stage that did not run reports 0: the first keyframe's optimization, line D&M of P
    variants, segmentation of -wo variants); None where it never ran."""
    frames = sum(f for f, _ in steps)
    stages: list[str] = []
    for _, step_timing in steps:
        stages += [k for k in step_timing if k not in stages]
    mean: dict[str, float | None] = {}
    for stage in stages:
        if stage == Stage.TOTAL_PER_FRAME:
            continue
        if stage in PER_FRAME_STAGES:
            mean[stage] = sum(f * t.get(stage, 0.0) for f, t in steps) / frames if frames else None
        else:
            ran = [t[stage] for _, t in steps if t.get(stage, 0.0) != 0.0]
            mean[stage] = sum(ran) / len(ran) if ran else None
    mean[Stage.TOTAL_PER_FRAME] = sum(t.get(Stage.TOTAL, 0.0) for _, t in steps) / frames if frames else None
    contract = (Stage.POINT_DM, Stage.TRACKING, Stage.LINE_DM, Stage.PLANE_SEG, Stage.PLANE_FIT, Stage.OPTIMIZATION, Stage.TOTAL_PER_FRAME)  # DESIGN §7
    timing: dict[str, Any] = {k: mean.get(k) for k in contract}
    timing["all_stages"] = mean
    return timing


def vio_metrics(snapshot, frames, *, excitation_onset_s: float | None = None) -> dict:
    """The VIO part of metrics.json: the first initialization (keyframe, time, what the
    alignment estimated and, on rendered scenes, its errors; the latest one's too, after a
    loss VIO starts again; the gravity direction and gyroscope bias errors after the
    refinement by the windows with IMU factors), the last keyframe's velocity and biases,
    and the scale error of the whole trajectory (the Sim(3) alignment's scale minus one, in
    percent, over the tracked frames with ground truth after the initialization).
    `excitation_onset_s`: when the input first moved enough for a start to see its scale
    (`backend.eval.excitation`, seconds from the first frame; None: never, or no ground
    truth); the start's time after it is `init_after_excitation_s`."""
    imu = snapshot.imu
    first = imu.first_init_keyframe

    def time_s(k: int) -> float | None:
        return float((snapshot.estimate.timestamp_ns[k] - snapshot.estimate.timestamp_ns[0]) * 1e-9) if k >= 0 else None

    out = {
        "initialized": imu.initialized,
        "status": imu.status,
        "init_keyframe": first,
        "init_time_s": time_s(first),
        "alignment": imu.first_report,
        "last_init_keyframe": imu.init_keyframe,
        "last_init_time_s": time_s(imu.init_keyframe),
        "last_alignment": imu.report,
        "velocity_world": imu.velocity_world[-1].tolist(),
        "bias_accel": imu.bias[-1][:3].tolist(),
        "bias_gyro": imu.bias[-1][3:].tolist(),
        "scale_error_pct": None,
        "excitation_onset_s": excitation_onset_s,
        "init_after_excitation_s": None,
    }
    init_s = time_s(first)
    if init_s is not None and excitation_onset_s is not None:
        out["init_after_excitation_s"] = init_s - excitation_onset_s
    if first >= 0 and snapshot.ground_truth is not None:
        # Gravity after the refinement: the angle between the world's vertical seen from the
        # estimated and from the true keyframe orientation (roll and pitch error), at the
        # initialization keyframe as the windows with IMU factors left it, and over all
        # keyframes since.
        z = np.array([0.0, 0.0, 1.0])
        R_est = np.asarray(snapshot.estimate.R_world_camera)[first:]
        R_gt = np.asarray(snapshot.ground_truth.R_world_camera)[first:]
        ok = np.all(np.isfinite(R_gt.reshape(len(R_gt), -1)), axis=1)
        a, b = R_est[ok].transpose(0, 2, 1) @ z, R_gt[ok].transpose(0, 2, 1) @ z
        tilt = np.degrees(np.arccos(np.clip(np.sum(a * b, axis=1), -1.0, 1.0)))
        if len(tilt):
            out["gravity_error_refined_deg"] = float(tilt[0])
            out["tilt_error_median_deg"] = float(np.median(tilt))
    if first >= 0 and imu.bias_true is not None:
        # The gyroscope bias after the refinement likewise: the initialization keyframe's, as
        # the windows with IMU factors left it, and the median over the keyframes since.
        b_est, b_true = np.asarray(imu.bias)[first:, 3:], np.asarray(imu.bias_true)[first:, 3:]
        pct = 100.0 * np.linalg.norm(b_est - b_true, axis=1) / np.maximum(np.linalg.norm(b_true, axis=1), 1e-12)
        out["bias_gyro_error_refined_pct"] = float(pct[0])
        out["bias_gyro_error_median_pct"] = float(np.median(pct))
    if first >= 0:
        t0 = snapshot.estimate.timestamp_ns[first]
        p_est, p_gt = np.asarray(frames.estimate.t_world_camera), np.asarray(frames.ground_truth.t_world_camera)
        sel = (np.asarray(frames.estimate.timestamp_ns) >= t0) & np.all(np.isfinite(p_gt), axis=1)
        if sel.sum() >= 3:
            _, _, scale = umeyama_alignment(p_est[sel], p_gt[sel], with_scale=True)
            out["scale_error_pct"] = float(100.0 * (scale - 1.0))
            # The frames before the first initialization have no metric scale (a failed start
            # keeps its arbitrary unit): VIO's accuracy is that of the frames from it on.
            out["frames_after_init"] = int(sel.sum())
            out["ate_after_init_cm"] = float(100.0 * ate_rmse(p_est[sel], p_gt[sel], align="se3"))
            out["ate_sim3_after_init_cm"] = float(100.0 * ate_rmse(p_est[sel], p_gt[sel], align="sim3"))
    return out
