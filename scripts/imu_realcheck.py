"""Preintegration on real IMU data: EuRoC V1_01's whole IMU stream against its ground truth
(`../shared/data/euroc_v101_imu`, PROVENANCE.txt there: no images; body = IMU frame).

    .venv/bin/python scripts/imu_realcheck.py [--data ../shared/data/euroc_v101_imu] [--out docs/vio/imu_realcheck.json]
    .venv/bin/python scripts/imu_realcheck.py --control room     # the same check on a rendered scene's IMU (exact truth)

1. Ground truth: body poses at 200 Hz (timestamps rounded to 10 µs, no velocities). World
   velocities are the first derivative of a local cubic least-squares fit over ±50 ms
   (Savitzky-Golay, 21 samples) of the positions.
2. Windows: consecutive, disjoint 0.5 s spans between ground-truth samples (100 samples).
   Biases (accel, gyro) are estimated by Gauss-Newton on the IMU factor residuals of the
   windows in the first 20 s, states held at the ground truth (`J_bias_i` of
   `imu_factor_error`; two re-integrations at the estimate, three steps each); and, for
   each window, the same on the windows of the preceding 10 s (the bias random walk of
   EuRoC's accelerometer moves its bias by ~0.05 m/s² over the sequence).
3. On every following window: preintegrate with the estimated bias and predict the state at
   the window's end from the ground-truth state at its start; rotation (deg), position (cm)
   and velocity (cm/s) errors (median, 95th percentile), the 1-σ the sensor.yaml densities
   imply (square root of the trace of each 3×3 block of the preintegrated covariance: the
   RMS of the error's norm; median over windows), and NEES per block (the IMU factor's
   residual at the ground-truth states, each 3-block normalized by its marginal covariance,
   divided by 3: about 1 when the model is consistent). The same with zero biases, for
   contrast. The ImuFactor's covariance has no bias random walk, and the ground truth's
   own errors (derived velocities above all) enter every figure.
4. The median errors against the window length (50 ms to 2 s), estimated bias: whether they
   grow like white noise (√T), like a rate error (T), or stay flat (ground-truth noise).
5. The rate error itself, per axis (`rate_discrepancy`).
Writes the JSON (default docs/vio/imu_realcheck.json) and prints a markdown table. Exits 2
with a one-line message when the data folder is absent.
"""

from __future__ import annotations

import argparse
import json
import pathlib
import sys
import time

ROOT = pathlib.Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

import numpy as np
from scipy.signal import savgol_filter

from backend.data.calibration import read_imu_yaml
from backend.data.euroc import _read_ground_truth, _read_imu
from backend.data.motion import GRAVITY_WORLD, ImuData
from backend.geometry import so3
from backend.imu.preintegration import imu_factor, imu_factor_error, predict_state, preintegrate, preintegration_params

DEFAULT_DATA = ROOT.parent / "shared" / "data" / "euroc_v101_imu"
DEFAULT_OUT = ROOT / "docs" / "vio" / "imu_realcheck.json"
DEFAULT_CONTROL_OUT = ROOT / "docs" / "vio" / "imu_realcheck_control.json"
CONTROL_DURATION_S = 145.0  # as long as V1_01
WINDOW_SAMPLES = 100  # ground-truth samples per window: 0.5 s at 200 Hz
VELOCITY_HALF_WINDOW = 10  # ±50 ms of ground truth for the velocity fit
BIAS_SEGMENT_S = 20.0  # biases from the windows starting in the first 20 s
ROLLING_S = 10.0  # or from the windows of the preceding 10 s
SCAN_WINDOW_SAMPLES = (10, 20, 50, 100, 200, 400)  # 50 ms ... 2 s
BLOCKS = {"rotation": slice(0, 3), "position": slice(3, 6), "velocity": slice(6, 9)}


def load(data: pathlib.Path) -> tuple[ImuData, object, dict]:
    """IMU samples, ground truth with fitted velocities, and the IMU calibration, read by
    the EuRoC reader's own CSV / YAML functions (the dataset class needs images)."""
    mav0 = data / "mav0"
    calibration, imu, missing = _read_imu(mav0 / "imu0", lambda imu_dir: read_imu_yaml(imu_dir / "sensor.yaml"))
    if imu is None:
        raise SystemExit(f"imu_realcheck: {missing[0]}: {missing[1]}")
    if not np.allclose(calibration.T_body_imu, np.eye(4)):
        raise SystemExit(f"imu_realcheck: {calibration.source}: T_BS is not the identity; this check assumes IMU = body frame")
    truth = _read_ground_truth(mav0 / "state_groundtruth_estimate0")
    period_ns = np.diff(truth.timestamp_ns)
    if np.any(np.abs(period_ns - 5_000_000) > 20_000):
        raise SystemExit("imu_realcheck: ground truth is not at a steady 200 Hz; the velocity fit assumes it")
    v_world = savgol_filter(truth.p_world_body, 2 * VELOCITY_HALF_WINDOW + 1, 3, deriv=1, delta=float(np.mean(period_ns)) * 1e-9, axis=0)
    return imu, truth, {"calibration": calibration, "v_world": v_world}


def load_control(scene: str, *, duration_s: float, seed: int) -> tuple[ImuData, object, dict]:
    """The control: a rendered scene's trajectory (twice the speed, as the VIO table) and its
    IMU (the sensor.yaml densities and bias random walk of EuRoC, EuRoC-like biases), with the
    true body poses at 200 Hz as the ground truth, through the same check. Only the
    trajectory is used (no image is rendered). What the real data gives beyond this is the
    data's, not the preintegration's."""
    from types import SimpleNamespace

    from backend.data.euroc import GroundTruth
    from backend.data.scenes import builtin_scene
    from backend.data.synthetic import SequenceSettings, SyntheticSequence

    seq = SyntheticSequence(builtin_scene(scene), settings=SequenceSettings(duration_s=duration_s, seed=seed, speed=2.0))
    stamps = np.arange(0, int(seq.timestamps_ns[-1]) + 1, 5_000_000, dtype=np.int64)
    t = stamps * 1e-9
    nan = np.full((len(t), 3), np.nan)
    truth = GroundTruth(stamps, seq.trajectory.position(t), seq.trajectory.rotation(t), nan, nan, nan)
    v_world = savgol_filter(truth.p_world_body, 2 * VELOCITY_HALF_WINDOW + 1, 3, deriv=1, delta=0.005, axis=0)
    calibration = SimpleNamespace(noise=seq.settings.imu_noise, T_body_imu=np.eye(4), source=f"rendered scene {scene}")
    return seq.imu, truth, {"calibration": calibration, "v_world": v_world, "bias_true": {"gyro_rad_s": seq.bias_gyro[0].tolist(), "accel_m_s2": seq.bias_accel[0].tolist()}}


def windows(truth, *, segment_s: float) -> tuple[np.ndarray, np.ndarray]:
    """Start indices of the bias-estimation windows and of the evaluation windows."""
    starts = np.arange(VELOCITY_HALF_WINDOW, len(truth) - VELOCITY_HALF_WINDOW - WINDOW_SAMPLES, WINDOW_SAMPLES)
    t_start_s = (truth.timestamp_ns[starts] - truth.timestamp_ns[0]) * 1e-9
    fit = t_start_s + WINDOW_SAMPLES * 0.005 <= segment_s
    return starts[fit], starts[~fit]


def _states(truth, v_world: np.ndarray, i: int) -> tuple[np.ndarray, ...]:
    j = i + WINDOW_SAMPLES
    return truth.R_world_body[i], truth.p_world_body[i], v_world[i], truth.R_world_body[j], truth.p_world_body[j], v_world[j]


def estimate_bias(imu: ImuData, truth, v_world: np.ndarray, starts: np.ndarray, params) -> np.ndarray:
    """Gauss-Newton on the 6 bias parameters, states fixed at the ground truth."""
    bias = np.zeros(6)
    for _ in range(2):  # re-integrate at the current estimate, then first-order steps
        terms = [imu_factor(preintegrate(imu, int(truth.timestamp_ns[i]), int(truth.timestamp_ns[i + WINDOW_SAMPLES]), bias_accel=bias[:3], bias_gyro=bias[3:], params=params)) for i in starts]
        for _ in range(3):
            H = np.zeros((6, 6))
            g = np.zeros(6)
            for term, i in zip(terms, starts):
                r = imu_factor_error(term, *_states(truth, v_world, i), bias)
                H += r.J_bias_i.T @ r.J_bias_i
                g += r.J_bias_i.T @ r.residual
            bias = bias - np.linalg.solve(H, g)
    return bias


def rolling_biases(imu: ImuData, truth, v_world: np.ndarray, starts: np.ndarray, params, *, before: np.ndarray, seconds: float) -> np.ndarray:
    """Per window in `starts`, the biases fitted (`estimate_bias`) on the windows of
    `before` ∪ `starts` that end within the preceding `seconds`: (N, 6)."""
    every = np.union1d(before, starts)
    span = int(round(seconds / 0.005))
    return np.array([estimate_bias(imu, truth, v_world, every[(every + WINDOW_SAMPLES <= i) & (every >= i - span)], params) for i in starts])


def evaluate(imu: ImuData, truth, v_world: np.ndarray, starts: np.ndarray, params, bias: np.ndarray) -> dict:
    """Prediction errors, implied 1-σ and NEES over the windows (module docstring); `bias`
    (6,) for every window or (N, 6) per window."""
    per_window = np.broadcast_to(bias, (len(starts), 6))
    errors = {name: [] for name in BLOCKS}
    sigmas = {name: [] for name in BLOCKS}
    nees = {name: [] for name in (*BLOCKS, "all")}
    scale = {"rotation": np.degrees(1.0), "position": 100.0, "velocity": 100.0}
    for i, bias in zip(starts, per_window):
        R_i, p_i, v_i, R_j, p_j, v_j = _states(truth, v_world, i)
        pim = preintegrate(imu, int(truth.timestamp_ns[i]), int(truth.timestamp_ns[i + WINDOW_SAMPLES]), bias_accel=bias[:3], bias_gyro=bias[3:], params=params)
        R_pred, p_pred, v_pred = predict_state(pim, R_i, p_i, v_i, bias=bias)
        errors["rotation"].append(np.linalg.norm(so3.log(R_j.T @ R_pred)) * scale["rotation"])
        errors["position"].append(np.linalg.norm(p_pred - p_j) * scale["position"])
        errors["velocity"].append(np.linalg.norm(v_pred - v_j) * scale["velocity"])
        covariance = pim.preintMeasCov()
        term = imu_factor(pim)
        e = np.linalg.solve(term.sqrt_information, imu_factor_error(term, R_i, p_i, v_i, R_j, p_j, v_j, bias).residual)
        residual_covariance = np.linalg.inv(term.sqrt_information.T @ term.sqrt_information)
        for name, block in BLOCKS.items():
            sigmas[name].append(np.sqrt(np.trace(covariance[block, block])) * scale[name])
            nees[name].append(e[block] @ np.linalg.solve(residual_covariance[block, block], e[block]) / 3.0)
        nees["all"].append(e @ np.linalg.solve(residual_covariance, e) / 9.0)
    out: dict = {"windows": int(len(starts))}
    units = {"rotation": "deg", "position": "cm", "velocity": "cm_s"}
    for name in BLOCKS:
        values = np.array(errors[name])
        out[f"{name}_error_{units[name]}"] = {"median": float(np.median(values)), "p95": float(np.percentile(values, 95)), "max": float(values.max())}
        out[f"{name}_sigma_{units[name]}_median"] = float(np.median(sigmas[name]))
    out["nees"] = {name: float(np.mean(values)) for name, values in nees.items()}
    out["nees_median"] = {name: float(np.median(values)) for name, values in nees.items()}
    return out


def window_length_scan(imu: ImuData, truth, v_world: np.ndarray, first: int, params, bias: np.ndarray) -> list[dict]:
    """Median prediction errors and implied 1-σ against the window length, on disjoint windows
    from ground-truth index `first` on (after the bias segment): how the errors grow."""
    rows = []
    for n in SCAN_WINDOW_SAMPLES:
        starts = np.arange(first, len(truth) - n - VELOCITY_HALF_WINDOW, max(n, 20))
        rot, pos, vel, sigma_rot = [], [], [], []
        for i in starts:
            j = i + n
            pim = preintegrate(imu, int(truth.timestamp_ns[i]), int(truth.timestamp_ns[j]), bias_accel=bias[:3], bias_gyro=bias[3:], params=params)
            R_pred, p_pred, v_pred = predict_state(pim, truth.R_world_body[i], truth.p_world_body[i], v_world[i], bias=bias)
            rot.append(np.degrees(np.linalg.norm(so3.log(truth.R_world_body[j].T @ R_pred))))
            pos.append(100.0 * np.linalg.norm(p_pred - truth.p_world_body[j]))
            vel.append(100.0 * np.linalg.norm(v_pred - v_world[j]))
            sigma_rot.append(np.degrees(np.sqrt(np.trace(pim.preintMeasCov()[:3, :3]))))
        rows.append(
            {
                "window_s": n * 0.005,
                "windows": int(len(starts)),
                "rotation_error_deg_median": float(np.median(rot)),
                "rotation_sigma_deg_median": float(np.median(sigma_rot)),
                "position_error_cm_median": float(np.median(pos)),
                "velocity_error_cm_s_median": float(np.median(vel)),
            }
        )
    return rows


def rate_discrepancy(imu: ImuData, truth, bias_gyro: np.ndarray, first: int) -> dict:
    """Where the rotation errors come from: the gyroscope minus the estimated bias against the
    ground truth's angular rate (body frame, from the orientation ±25 ms apart), each
    averaged over the same 50 ms, from ground-truth index `first` on; per axis, the RMS of
    its 1 s moving average (rad/s), the range of that average on the worst axis, and the RMS
    left after a least-squares fit of a 3×3 matrix on the rate plus a constant (a scale and
    misalignment calibration the sensor.yaml does not have; a rotation between the frames
    would make the matrix antisymmetric)."""
    half = 5
    t_gt = truth.timestamp_ns * 1e-9
    idx = np.arange(max(first, half), len(truth) - half)
    R = truth.R_world_body
    w_gt = np.array([so3.log(R[i - half].T @ R[i + half]) / (t_gt[i + half] - t_gt[i - half]) for i in idx])
    t_imu = imu.timestamp_ns * 1e-9
    lo = np.searchsorted(t_imu, t_gt[idx - half])
    hi = np.searchsorted(t_imu, t_gt[idx + half])
    csum = np.concatenate([np.zeros((1, 3)), np.cumsum(imu.gyro, axis=0)])
    w_imu = (csum[hi] - csum[lo]) / np.maximum(hi - lo, 1)[:, None]
    d = w_imu - bias_gyro - w_gt
    second = 200  # ground-truth samples per second

    def smoothed(x: np.ndarray) -> np.ndarray:
        return np.stack([np.convolve(x[:, c], np.ones(second) / second, mode="valid") for c in range(3)], axis=1)

    ds = smoothed(d)
    A = np.hstack([w_gt, np.ones((len(w_gt), 1))])
    coef, *_ = np.linalg.lstsq(A, d, rcond=None)
    rs = smoothed(d - A @ coef)
    worst = int(np.argmax(np.sqrt(np.mean(ds**2, axis=0))))
    return {
        "samples": int(len(idx)),
        "rms_1s_rad_s": np.sqrt(np.mean(ds**2, axis=0)).tolist(),
        "worst_axis": "xyz"[worst],
        "worst_axis_range_1s_rad_s": [float(ds[:, worst].min()), float(ds[:, worst].max())],
        "linear_fit_matrix": coef[:3].T.tolist(),  # row: error axis, column: rate axis
        "rms_1s_after_linear_fit_rad_s": np.sqrt(np.mean(rs**2, axis=0)).tolist(),
    }


def table(result: dict) -> str:
    lines = [
        f"`.venv/bin/python scripts/imu_realcheck.py{' --control ' + result['control'] if result.get('control') else ''}`: "
        f"{'EuRoC V1_01' if not result.get('control') else result['data']}, {result['evaluation']['estimated_bias']['windows']} windows of 0.5 s after the first "
        f"{BIAS_SEGMENT_S:.0f} s, state predicted from the ground truth at each window's start; median / 95th percentile of the error, "
        "the 1-σ implied by sensor.yaml (median), NEES per block (mean; ~1 if consistent).",
        "",
        "| bias | rotation (deg) | position (cm) | velocity (cm/s) | NEES rot. / pos. / vel. |",
        "|---|---|---|---|---|",
    ]
    for name, label in (("estimated_bias", "estimated (first 20 s)"), ("rolling_bias", f"estimated (the preceding {ROLLING_S:.0f} s)"), ("zero_bias", "zero")):
        r = result["evaluation"][name]
        cells = [f"{r[f'{k}_error_{u}']['median']:.3g} / {r[f'{k}_error_{u}']['p95']:.3g}" for k, u in (("rotation", "deg"), ("position", "cm"), ("velocity", "cm_s"))]
        n = r["nees"]
        lines.append(f"| {label} | {cells[0]} | {cells[1]} | {cells[2]} | {n['rotation']:.3g} / {n['position']:.3g} / {n['velocity']:.3g} |")
    r = result["evaluation"]["estimated_bias"]
    lines.append(f"| 1-σ from sensor.yaml | {r['rotation_sigma_deg_median']:.3g} | {r['position_sigma_cm_median']:.3g} | {r['velocity_sigma_cm_s_median']:.3g} | |")
    lines += [
        "",
        "Against the window length (estimated bias; median error, rotation 1-σ from sensor.yaml):",
        "",
        "| window | rotation (deg) | rotation 1-σ (deg) | position (cm) | velocity (cm/s) |",
        "|---|---|---|---|---|",
    ]
    for r in result["by_window_length"]:
        lines.append(
            f"| {r['window_s'] * 1e3:.0f} ms | {r['rotation_error_deg_median']:.3g} | {r['rotation_sigma_deg_median']:.3g} "
            f"| {r['position_error_cm_median']:.3g} | {r['velocity_error_cm_s_median']:.3g} |"
        )
    r = result["rate_discrepancy"]
    lines += [
        "",
        "Gyroscope minus bias against the ground truth's rate (1 s averages, rad/s RMS x / y / z): "
        + " / ".join(f"{x:.4f}" for x in r["rms_1s_rad_s"])
        + f"; {r['worst_axis']} ranges over [{r['worst_axis_range_1s_rad_s'][0]:+.4f}, {r['worst_axis_range_1s_rad_s'][1]:+.4f}]; after a fitted 3x3 matrix on the rate: "
        + " / ".join(f"{x:.4f}" for x in r["rms_1s_after_linear_fit_rad_s"])
        + ".",
    ]
    b = result["bias_estimate"]
    lines += ["", f"Estimated bias: accel ({', '.join(f'{x:+.4f}' for x in b['accel_m_s2'])}) m/s², gyro ({', '.join(f'{x:+.5f}' for x in b['gyro_rad_s'])}) rad/s."]
    return "\n".join(lines)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--data", type=pathlib.Path, default=DEFAULT_DATA)
    parser.add_argument("--out", type=pathlib.Path, default=None, help=f"default {DEFAULT_OUT.relative_to(ROOT)} ({DEFAULT_CONTROL_OUT.relative_to(ROOT)} with --control)")
    parser.add_argument("--control", metavar="SCENE", help="instead of the real data: a rendered scene's trajectory and IMU (exact ground truth; see load_control)")
    args = parser.parse_args()
    if args.out is None:
        args.out = DEFAULT_OUT if args.control is None else DEFAULT_CONTROL_OUT
    if args.control is None and not (args.data / "mav0").is_dir():
        print(f"imu_realcheck: {args.data}/mav0 is absent (EuRoC V1_01 IMU + ground truth, see ../shared/data)", file=sys.stderr)
        return 2
    started = time.perf_counter()
    if args.control is None:
        imu, truth, extra = load(args.data)
    else:
        imu, truth, extra = load_control(args.control, duration_s=CONTROL_DURATION_S, seed=0)
    calibration, v_world = extra["calibration"], extra["v_world"]
    params = preintegration_params(calibration.noise, gravity_m_s2=float(-GRAVITY_WORLD[2]))
    fit_starts, eval_starts = windows(truth, segment_s=BIAS_SEGMENT_S)
    bias = estimate_bias(imu, truth, v_world, fit_starts, params)
    result = {
        "data": str(args.data) if args.control is None else f"control: rendered scene {args.control}, {CONTROL_DURATION_S:g} s at 2x speed, seed 0",
        "control": args.control,
        "command": "scripts/imu_realcheck.py",
        "method": {
            "window_s": WINDOW_SAMPLES * 0.005,
            "velocity": "derivative of a cubic least-squares fit over ±50 ms (Savitzky-Golay, 21 ground-truth samples)",
            "bias_fit": f"Gauss-Newton on the IMU factor residuals of the {len(fit_starts)} windows in the first {BIAS_SEGMENT_S:.0f} s, states at the ground truth",
            "sigma": "sqrt(trace) of each 3x3 block of pim.preintMeasCov(), median over windows",
            "nees": "IMU factor residual at the ground-truth states, per 3-block with its marginal residual covariance, / 3; 'all' is the 9-vector / 9",
            "gravity_m_s2": float(-GRAVITY_WORLD[2]),
            "noise": {k: float(v) for k, v in vars(calibration.noise).items()},
        },
        "bias_estimate": {"accel_m_s2": bias[:3].tolist(), "gyro_rad_s": bias[3:].tolist(), "windows": int(len(fit_starts))},
        **({"bias_true_at_start": extra["bias_true"]} if "bias_true" in extra else {}),
        "evaluation": {
            "estimated_bias": evaluate(imu, truth, v_world, eval_starts, params, bias),
            "zero_bias": evaluate(imu, truth, v_world, eval_starts, params, np.zeros(6)),
            "rolling_bias": evaluate(imu, truth, v_world, eval_starts, params, rolling_biases(imu, truth, v_world, eval_starts, params, before=fit_starts, seconds=ROLLING_S)),
        },
    }
    result["by_window_length"] = window_length_scan(imu, truth, v_world, int(eval_starts[0]), params, bias)
    result["rate_discrepancy"] = rate_discrepancy(imu, truth, bias[3:], int(eval_starts[0]))
    result["seconds"] = round(time.perf_counter() - started, 2)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(result, indent=2) + "\n")
    print(table(result))
    print(f"\nwrote {args.out} ({result['seconds']:.1f} s)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
