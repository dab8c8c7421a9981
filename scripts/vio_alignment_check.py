"""Check the VIO initialization's visual-inertial alignment (backend/vio/alignment.py) on
the built-in scenes' trajectories, without rendering images.

    .venv/bin/python scripts/vio_alignment_check.py [--seeds 10] [--speeds 1,2] [--durations 1,2,3]

For each scene (room, corridor, boxes), trajectory speed (1: the rendered sequences' pace,
~0.2 m/s; 2: the same paths twice as fast), duration (the first 1, 2, 3 s) and seed: the
sequence's trajectory and IMU noise (seed), keyframes at 10 Hz from the true camera poses
in the first camera's frame, scaled by 0.37 and perturbed by 0.2° (per keyframe) and 0.5 %
of the mean keyframe-to-keyframe distance (per keyframe); the IMU with the sequence's noise
densities and bias random walk, started at a EuRoC-like gyro bias of 0.027 rad/s in a random
direction per seed (the sequences' own bias starts at zero and stays ~3e-5 rad/s over 3 s,
too small for a relative error to mean anything), accelerometer bias starting at zero.

Writes docs/vio/alignment_check.json (settings, every run, the per-case summary) and prints
a markdown table per case: success rate; over the accepted runs, the gravity direction
error (deg), the gyro bias error (% of the true bias and rad/s) and the scale error (%),
median and largest; over all runs that reached a scale, the median |scale error|
(rejected runs included: what the rejection protects from); the most frequent rejection.
"""

from __future__ import annotations

import argparse
import collections
import json
import os
import pathlib
import sys
import time

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")  # small dense solves, as the tests run them

import numpy as np

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parents[1]))

from backend.data.motion import GRAVITY_WORLD, add_imu_noise
from backend.data.scenes import STANDARD_SCENES, builtin_scene
from backend.data.synthetic import SequenceSettings, SyntheticSequence
from backend.eval.vio import visual_keyframes
from backend.vio.alignment import AlignmentSettings, align_visual_inertial

VISUAL_SCALE = 0.37
KEYFRAME_RATE_HZ = 10.0
ROTATION_NOISE_DEG = 0.2
POSITION_NOISE_FRACTION = 0.005
BIAS_GYRO_NORM = 0.027  # rad/s, |(0.01, -0.02, 0.015)|, EuRoC-like
OUT = pathlib.Path(__file__).resolve().parents[1] / "docs" / "vio" / "alignment_check.json"


def run_one(scene: str, speed: float, duration_s: float, seed: int, settings: AlignmentSettings) -> dict:
    seq = SyntheticSequence(builtin_scene(scene), settings=SequenceSettings(duration_s=duration_s + 0.2, seed=seed, speed=speed))
    rng = np.random.default_rng([seed, 0xA119])
    direction = rng.normal(size=3)
    bias0 = BIAS_GYRO_NORM * direction / np.linalg.norm(direction)
    imu, bias_gyro, _ = add_imu_noise(seq.imu_true, rng, noise=seq.settings.imu_noise, bias_gyro=bias0)

    kf = visual_keyframes(seq, duration_s, rate_hz=KEYFRAME_RATE_HZ, rotation_deg=ROTATION_NOISE_DEG, position_fraction=POSITION_NOISE_FRACTION, rng=rng)
    R, p, t_ns, index, R_world_c0 = kf.R_c0_cam, kf.p_c0_cam, kf.timestamps_ns, kf.index, kf.R_world_c0

    start = time.perf_counter()
    alignment = align_visual_inertial(t_ns, R, VISUAL_SCALE * p, imu, T_body_cam0=seq.T_body_cam0, settings=settings)
    elapsed_ms = 1e3 * (time.perf_counter() - start)

    inside = (imu.timestamp_ns >= t_ns[0]) & (imu.timestamp_ns < t_ns[-1])
    b_true = bias_gyro[inside].mean(axis=0)
    g_true = R_world_c0.T @ GRAVITY_WORLD
    g = alignment.gravity_c0
    cos = float(g @ g_true / (np.linalg.norm(g) * np.linalg.norm(g_true))) if np.all(np.isfinite(g)) else float("nan")
    v_true = seq.trajectory.velocity(t_ns * 1e-9) @ R_world_c0
    accel = seq.trajectory.acceleration(np.linspace(0.0, duration_s, 101))
    return {
        "scene": scene,
        "speed": speed,
        "duration_s": duration_s,
        "seed": seed,
        "keyframes": int(len(index)),
        "success": alignment.success,
        "reason": alignment.reason,
        "gravity_error_deg": float(np.degrees(np.arccos(np.clip(cos, -1.0, 1.0)))),
        "bias_gyro_error_radps": float(np.linalg.norm(alignment.bias_gyro - b_true)),
        "bias_gyro_error_pct": float(100.0 * np.linalg.norm(alignment.bias_gyro - b_true) / np.linalg.norm(b_true)),
        "scale_error_pct": float(100.0 * (alignment.scale * VISUAL_SCALE - 1.0)),
        "velocity_error_max_mps": float(np.max(np.abs(alignment.velocity_c0 - v_true))),
        "true_accel_rms_mps2": float(np.sqrt(np.mean(np.sum(accel**2, axis=1)))),
        "time_ms": elapsed_ms,
        "quality": alignment.to_dict()["quality"],
    }


def _stat(values: list[float], how: str) -> float:
    values = [v for v in values if np.isfinite(v)]
    if not values:
        return float("nan")
    return float(np.median(values) if how == "median" else np.max(values))


def summarize(runs: list[dict]) -> dict:
    ok = [r for r in runs if r["success"]]
    reasons = collections.Counter(r["reason"].split(":")[0] for r in runs if not r["success"])
    return {
        "runs": len(runs),
        "success_rate": len(ok) / len(runs),
        "gravity_error_deg_median": _stat([r["gravity_error_deg"] for r in ok], "median"),
        "gravity_error_deg_max": _stat([r["gravity_error_deg"] for r in ok], "max"),
        "bias_gyro_error_pct_median": _stat([r["bias_gyro_error_pct"] for r in ok], "median"),
        "bias_gyro_error_pct_max": _stat([r["bias_gyro_error_pct"] for r in ok], "max"),
        "bias_gyro_error_radps_median": _stat([r["bias_gyro_error_radps"] for r in ok], "median"),
        "scale_error_pct_abs_median": _stat([abs(r["scale_error_pct"]) for r in ok], "median"),
        "scale_error_pct_abs_max": _stat([abs(r["scale_error_pct"]) for r in ok], "max"),
        "velocity_error_mps_max": _stat([r["velocity_error_max_mps"] for r in ok], "max"),
        "scale_error_pct_abs_median_all": _stat([abs(r["scale_error_pct"]) for r in runs], "median"),
        "true_accel_rms_mps2_median": _stat([r["true_accel_rms_mps2"] for r in runs], "median"),
        "rejections": dict(reasons),
    }


def _finite(obj: object) -> object:
    """NaN and infinities as null, for strict JSON readers."""
    if isinstance(obj, float):
        return obj if np.isfinite(obj) else None
    if isinstance(obj, dict):
        return {k: _finite(v) for k, v in obj.items()}
    if isinstance(obj, list):
        return [_finite(v) for v in obj]
    return obj


def _f(x: float, digits: int) -> str:
    return "–" if not np.isfinite(x) else f"{x:.{digits}f}"


def table(summary: dict) -> str:
    lines = [
        "| scene | speed | s | accel rms m/s² | success | gravity err ° med / max | gyro bias err % med / max | "
        "gyro bias err rad/s med | scale err % med / max | scale err % med, all runs | most frequent rejection |",
        "|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for key, s in summary.items():
        scene, speed, duration = key.split("|")
        top = max(s["rejections"].items(), key=lambda kv: kv[1], default=None)
        rejection = f"{top[0]} ({top[1]})" if top else "–"
        lines.append(
            f"| {scene} | {speed} | {duration} | {_f(s['true_accel_rms_mps2_median'], 2)} "
            f"| {round(100 * s['success_rate'])} % ({round(s['success_rate'] * s['runs'])}/{s['runs']}) "
            f"| {_f(s['gravity_error_deg_median'], 2)} / {_f(s['gravity_error_deg_max'], 2)} "
            f"| {_f(s['bias_gyro_error_pct_median'], 1)} / {_f(s['bias_gyro_error_pct_max'], 1)} "
            f"| {_f(s['bias_gyro_error_radps_median'], 4)} "
            f"| {_f(s['scale_error_pct_abs_median'], 2)} / {_f(s['scale_error_pct_abs_max'], 2)} "
            f"| {_f(s['scale_error_pct_abs_median_all'], 1)} | {rejection} |"
        )
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=10)
    parser.add_argument("--speeds", default="1,2")
    parser.add_argument("--durations", default="1,2,3")
    parser.add_argument("--out", type=pathlib.Path, default=OUT)
    args = parser.parse_args(argv)
    speeds = [float(s) for s in args.speeds.split(",")]
    durations = [float(d) for d in args.durations.split(",")]
    settings = AlignmentSettings()
    start = time.perf_counter()
    runs, summary = [], {}
    for scene in STANDARD_SCENES:
        for speed in speeds:
            for duration in durations:
                case = [run_one(scene, speed, duration, seed, settings) for seed in range(args.seeds)]
                runs.extend(case)
                summary[f"{scene}|{speed:g}|{duration:g}"] = summarize(case)
    elapsed = time.perf_counter() - start
    args.out.parent.mkdir(parents=True, exist_ok=True)
    document = {
        "command": " ".join([".venv/bin/python scripts/vio_alignment_check.py", *(argv if argv is not None else sys.argv[1:])]),
        "keyframe_rate_hz": KEYFRAME_RATE_HZ,
        "visual_scale": VISUAL_SCALE,
        "rotation_noise_deg": ROTATION_NOISE_DEG,
        "position_noise_fraction_of_keyframe_distance": POSITION_NOISE_FRACTION,
        "bias_gyro_initial_norm_radps": BIAS_GYRO_NORM,
        "settings": {k: (list(v) if isinstance(v, tuple) else v) for k, v in vars(settings).items()},
        "elapsed_s": elapsed,
        "summary": summary,
        "runs": runs,
    }
    args.out.write_text(json.dumps(_finite(document), indent=1, allow_nan=False) + "\n")
    print(table(summary))
    print(f"\n{len(runs)} alignments in {elapsed:.1f} s; wrote {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
