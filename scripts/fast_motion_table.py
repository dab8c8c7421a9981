"""Regenerate the fast-motion table (docs/results/pipeline.md) as a sweep (sweeps/fast_motion_table.toml,
run as `coplanar sweep --config sweeps/fast_motion_table.toml`): every variant on a rendered
scene with fewer frames (stride 4: 5 frames per second) and faster motion along the same path
(speeds 1, 2, 3), each run exactly `coplanar run --scene room --stride 4 --speed F`, one run
each.

    .venv/bin/python scripts/fast_motion_table.py [--scene room] [--strides 4] [--speeds 1,2,3] [--out DIR] [--workers 1 | --serial | --address ADDR]

`--workers 2` runs two at a time (half the wall time; the accuracy columns are the same, the
times are not comparable then and are left out). Writes docs/pipeline/fast_motion.json and
replaces the text between the fast-motion-table markers in docs/results/pipeline.md. Per run
(from `metrics.json` and the written ground truth): the motion between frames (median and
largest translation and rotation), per-frame ATE after SE(3) alignment (cm), lost frames,
re-initializations, frames relocalized by PnP, keyframes (and how many the fast-motion rule
made), total time per frame (ms).
"""

from __future__ import annotations

import argparse
import io
import sys

import numpy as np
from scipy.spatial.transform import Rotation
from table_sweep import SWEEPS, add_sweep_options, axis_options, f, publish, sweep_runs

SWEEP = SWEEPS / "fast_motion_table.toml"


def motion_between_frames(groundtruth_tum: str) -> dict[str, float]:
    """Median and largest translation (cm) and rotation (degrees) between consecutive poses."""
    g = np.loadtxt(io.StringIO(groundtruth_tum), ndmin=2)
    step_cm = 100.0 * np.linalg.norm(np.diff(g[:, 1:4], axis=0), axis=1)
    R = Rotation.from_quat(g[:, 4:8])
    step_deg = np.degrees((R[:-1].inv() * R[1:]).magnitude())
    return {"cm_median": float(np.median(step_cm)), "cm_max": float(step_cm.max()), "deg_median": float(np.median(step_deg)), "deg_max": float(step_deg.max())}


def case(r: dict) -> dict:
    """A run's entry of docs/pipeline/fast_motion.json, from its metrics.json and groundtruth.txt."""
    row = r.pop("row")
    r["motion"] = motion_between_frames(r.pop("files")["groundtruth.txt"])
    r["relocalized_frames"] = sum(part.count("relocalized by PnP") for part in r["messages"])
    r.update(scene=row["input"], stride=row["stride"], speed=row["speed"])
    return r


def table(results: list[dict], *, timed: bool) -> str:
    lines = [
        "`.venv/bin/python scripts/fast_motion_table.py`, one run each, 30 s of the path (ATE of `trajectory.txt`, poses of the body frame): motion between frames (median / "
        "largest), per-frame ATE after SE(3) alignment (cm), lost frames, re-initializations, frames relocalized by PnP, "
        "keyframes (of them by the fast-motion rule)" + (", total ms per frame." if timed else "."),
        "",
        "| stride × speed | motion per frame | variant | ATE | lost | re-init. | relocalized | keyframes (fast) |" + (" ms / frame |" if timed else ""),
        "|---|---|---|---|---|---|---|---|" + ("---|" if timed else ""),
    ]
    for r in results:
        m = r["motion"]
        row = (
            f"| {r['stride']} × {r['speed']:g} | {m['cm_median']:.0f} / {m['cm_max']:.0f} cm, {m['deg_median']:.0f} / {m['deg_max']:.0f}° "
            f"| {r['variant']} | {f(r['ate_rmse_cm'])} | {r['lost_frames']} | {r['reinitializations']} | {r['relocalized_frames']} / {r['frames']} "
            f"| {r['keyframes']} ({r['keyframe_reasons'].get('fast motion', 0)}) |"
        )
        lines.append(row + (f" {f(r['timing_ms']['total_per_frame'], 1)} |" if timed else ""))
    return "\n".join(lines)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scene", default=None, help=f"the scene (default: {SWEEP.name}'s, room)")
    parser.add_argument("--strides", default=None, help=f"strides (default: {SWEEP.name}'s, 4)")
    parser.add_argument("--speeds", default=None, help=f"speeds (default: {SWEEP.name}'s, 1,2,3)")
    parser.add_argument("--variants", default=None, help=f"variants (default: {SWEEP.name}'s, all)")
    add_sweep_options(parser, page="docs/results/pipeline.md")
    args = parser.parse_args()
    options = axis_options({"--scenes": args.scene, "--strides": args.strides, "--speeds": args.speeds, "--variants": args.variants})
    results = []
    for r in sweep_runs(SWEEP, args, options, keep=("groundtruth.txt",)):
        results.append(case(r))
        print(
            f"{r['stride']}x{r['speed']:g} {r['variant']:6s} ATE {f(r['ate_rmse_cm'])} cm, lost {r['lost_frames']}, "
            f"re-init {r['reinitializations']}, relocalized {r['relocalized_frames']}, ({r['wall_s']:.0f} s)",
            flush=True,
        )
    timed = args.serial or args.workers <= 1
    scene = results[0]["scene"] if results else args.scene
    body = table(results, timed=timed)
    return publish({"scene": scene, "workers": 1 if args.serial else args.workers, "runs": results}, body, json_name="fast_motion.json", block="fast-motion-table", write_doc=not args.no_doc)


if __name__ == "__main__":
    sys.exit(main())
