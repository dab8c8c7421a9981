"""Time per frame of the VIO pipeline, as `coplanar run --mode vio` runs it: `--runs`
invocations on a rendered scene (default `room`, PL-w, 30 s at 2× speed, learned segmenter);
prints each run's mean total per frame (images rendered or read are not counted, as in the
stereo tables), the median, and the stages per keyframe with their share of the time.

    .venv/bin/python benchmarks/bench_vio.py [--runs 3] [--scene room] [--variant PL-w] [--duration 30] [--speed 2]
"""

from __future__ import annotations

import argparse
import os
import pathlib
import platform
import statistics
import sys

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
ROOT = pathlib.Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "scripts"))

from vio_table import run_one

#: Stages that run once per keyframe (the others are means per frame), keys of timing_ms.all_stages.
KEYFRAME_STAGES = ("line_dm", "mapping", "plane_seg", "plane_fit", "setup", "optimization", "update", "culling")


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--runs", type=int, default=3)
    p.add_argument("--scene", default="room")
    p.add_argument("--variant", default="PL-w")
    p.add_argument("--duration", type=float, default=30.0)
    p.add_argument("--speed", type=float, default=2.0)
    args = p.parse_args()
    print(f"{platform.processor() or platform.machine()}, {os.cpu_count()} CPUs, Python {platform.python_version()}")
    totals = []
    for run in range(args.runs):
        m = run_one(args.scene, args.variant, "vio", duration=args.duration, speed=args.speed)
        t = m["timing_ms"]
        totals.append(t["total_per_frame"])
        stages = t["all_stages"]
        share = {k: (stages.get(k) or 0.0) * m["keyframes"] / m["frames"] for k in KEYFRAME_STAGES}
        share.update({k: stages.get(k) or 0.0 for k in ("point_dm", "tracking")})
        slowest = max(share, key=share.get)
        print(
            f"run {run + 1}: {t['total_per_frame']:.1f} ms per frame ({m['frames']} frames, {m['keyframes']} keyframes); per frame: "
            + ", ".join(f"{k} {v:.1f}" for k, v in sorted(share.items(), key=lambda kv: -kv[1]))
            + f"; slowest stage: {slowest}",
            flush=True,
        )
    print(f"median of {args.runs}: {statistics.median(totals):.1f} ms per frame (range {min(totals):.1f}-{max(totals):.1f})")
    return 0


if __name__ == "__main__":
    sys.exit(main())
