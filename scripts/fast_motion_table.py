"""Regenerate the fast-motion table (docs/results/pipeline.md): every variant on a rendered scene with fewer
frames (`--stride N`: 20/N frames per second) and faster motion along the same path
(`--speed F`), each run exactly as `coplanar run --scene S --stride N --speed F` runs it,
one run each.

    .venv/bin/python scripts/fast_motion_table.py [--scene room] [--cases 4x1,4x2,4x3] [--jobs 1]

`--cases` lists STRIDExSPEED pairs. `--jobs 2` runs two at a time (half the wall time; the
accuracy columns are the same, the times are not comparable then and are left out).
Writes docs/pipeline/fast_motion.json and replaces the text between the fast-motion-table
markers in docs/results/pipeline.md. Per run (from `metrics.json` and the written ground truth): the
motion between frames (median and largest translation and rotation), per-frame ATE after
SE(3) alignment (cm), lost frames, re-initializations, frames relocalized by PnP,
keyframes (and how many the fast-motion rule made), total time per frame (ms).
"""

from __future__ import annotations

import argparse
import concurrent.futures
import io
import sys

import numpy as np
from euroc_table import VARIANTS, _f, add_no_doc_option, publish, run_one
from scipy.spatial.transform import Rotation


def motion_between_frames(groundtruth_tum: str) -> dict[str, float]:
    """Median and largest translation (cm) and rotation (degrees) between consecutive poses."""
    g = np.loadtxt(io.StringIO(groundtruth_tum), ndmin=2)
    step_cm = 100.0 * np.linalg.norm(np.diff(g[:, 1:4], axis=0), axis=1)
    R = Rotation.from_quat(g[:, 4:8])
    step_deg = np.degrees((R[:-1].inv() * R[1:]).magnitude())
    return {"cm_median": float(np.median(step_cm)), "cm_max": float(step_cm.max()), "deg_median": float(np.median(step_deg)), "deg_max": float(step_deg.max())}


def run_case(scene: str, stride: int, speed: float, variant: str) -> dict:
    r = run_one(["--scene", scene, "--stride", str(stride), "--speed", f"{speed:g}"], variant, keep=("groundtruth.txt",))
    r["motion"] = motion_between_frames(r.pop("files")["groundtruth.txt"])
    r["relocalized_frames"] = sum(part.count("relocalized by PnP") for part in r["messages"])
    r.update(scene=scene, stride=stride, speed=speed, variant=variant)
    return r


def table(results: list[dict], *, timed: bool) -> str:
    lines = [
        "`.venv/bin/python scripts/fast_motion_table.py`, one run each, 30 s of the path: motion between frames (median / "
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
            f"| {r['variant']} | {_f(r['ate_rmse_cm'])} | {r['lost_frames']} | {r['reinitializations']} | {r['relocalized_frames']} / {r['frames']} "
            f"| {r['keyframes']} ({r['keyframe_reasons'].get('fast motion', 0)}) |"
        )
        lines.append(row + (f" {_f(r['timing_ms']['total_per_frame'], 1)} |" if timed else ""))
    return "\n".join(lines)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scene", default="room")
    parser.add_argument("--cases", default="4x1,4x2,4x3", help="STRIDExSPEED pairs, comma-separated")
    parser.add_argument("--variants", default=",".join(VARIANTS))
    parser.add_argument("--jobs", type=int, default=1, help="runs at a time (more than 1: no time column)")
    add_no_doc_option(parser, "docs/results/pipeline.md")
    args = parser.parse_args()
    try:
        cases = [(int(a), float(b)) for a, b in (c.split("x") for c in args.cases.split(","))]
    except ValueError:
        print(f"error: --cases {args.cases}: expected STRIDExSPEED pairs such as 4x1,4x2", file=sys.stderr)
        return 2
    todo = [(args.scene, stride, speed, v) for stride, speed in cases for v in args.variants.split(",")]
    with concurrent.futures.ThreadPoolExecutor(max_workers=max(args.jobs, 1)) as pool:
        results = []
        for r in pool.map(lambda job: run_case(*job), todo):
            results.append(r)
            print(
                f"{r['stride']}x{r['speed']:g} {r['variant']:6s} ATE {_f(r['ate_rmse_cm'])} cm, lost {r['lost_frames']}, "
                f"re-init {r['reinitializations']}, relocalized {r['relocalized_frames']}, ({r['wall_s']:.0f} s)",
                flush=True,
            )
    body = table(results, timed=args.jobs <= 1)
    return publish({"scene": args.scene, "jobs": args.jobs, "runs": results}, body, json_name="fast_motion.json", block="fast-motion-table", write_doc=not args.no_doc)


if __name__ == "__main__":
    sys.exit(main())
