"""Benchmark: the stereo pipeline's time per frame on a rendered scene, as `coplanar run`
measures it (no keyframe image, no Hessian image; P variants skip line D&M and -wo variants
plane segmentation, as in the paper's Table III). Rendering the images is not counted.

    .venv/bin/python benchmarks/bench_pipeline.py [--scene room] [--variant PL-w] [--duration 30] [--runs 1]

Prints per run: frames, keyframes, ATE, the per-frame stages (point D&M, tracking), the
per-keyframe stages (line D&M, plane segmentation, plane fitting, optimization, ...) and
the mean total per frame; then the median total per frame over the runs and the slowest
stage per frame (a keyframe stage's mean times keyframes / frames).
"""

from __future__ import annotations

import argparse
import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import numpy as np

from backend.data.scenes import builtin_scene
from backend.data.synthetic import SequenceSettings, SyntheticSequence
from backend.pipeline.engine import EndOfSequence
from backend.pipeline.stereo_engine import StereoEngine, StereoSettings

PER_FRAME = ("point_dm", "tracking")


def run_once(scene: str, variant: str, duration: float, seed: int) -> dict[str, float]:
    seq = SyntheticSequence(builtin_scene(scene), settings=SequenceSettings(duration_s=duration, seed=seed))
    engine = StereoEngine(seq, settings=StereoSettings(variant=variant, seed=seed, skip_unused_stages=True, image_scale=None, hessian=False))
    per_frame: dict[str, float] = {}
    per_kf: dict[str, list[float]] = {}
    frames = 0
    total = 0.0
    snapshot = None
    while True:
        try:
            snapshot = engine.step()
        except EndOfSequence:
            break
        n = snapshot.tracking.frames
        frames += n
        for stage, ms in snapshot.report.timing_ms.items():
            if stage in PER_FRAME:
                per_frame[stage] = per_frame.get(stage, 0.0) + ms * n
            elif stage not in ("load", "total", "total_per_frame"):
                per_kf.setdefault(stage, []).append(ms)
        total += snapshot.report.timing_ms["total"]
    keyframes = engine.keyframes
    out = {f"{k} (per frame)": v / frames for k, v in per_frame.items()}
    out.update({f"{k} (per keyframe)": float(np.mean(v)) for k, v in per_kf.items()})
    out["frames"], out["keyframes"] = frames, keyframes
    out["ate_cm"] = snapshot.metrics.ate_cm
    out["total_per_frame"] = total / frames
    share = {k: v / frames for k, v in per_frame.items()}
    share.update({k: float(np.sum(v)) / frames for k, v in per_kf.items() if k not in ("linearize", "solve")})
    out["slowest"] = max(share, key=share.get)
    out["slowest_ms_per_frame"] = share[out["slowest"]]
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scene", default="room")
    parser.add_argument("--variant", default="PL-w")
    parser.add_argument("--duration", type=float, default=30.0)
    parser.add_argument("--runs", type=int, default=1)
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()
    totals = []
    for r in range(args.runs):
        out = run_once(args.scene, args.variant, args.duration, args.seed)
        totals.append(out["total_per_frame"])
        print(f"run {r + 1}/{args.runs}: {args.scene} {args.variant}, {out['frames']} frames, {out['keyframes']} keyframes, ATE {out['ate_cm']:.2f} cm")
        for k, v in out.items():
            if k not in ("frames", "keyframes", "ate_cm", "slowest"):
                print(f"  {k:32s} {v:8.2f} ms")
        print(f"  slowest stage per frame: {out['slowest']} ({out['slowest_ms_per_frame']:.1f} ms per frame)")
    print(f"total per frame: median {np.median(totals):.1f} ms over {args.runs} run(s) (range {min(totals):.1f}-{max(totals):.1f})")


if __name__ == "__main__":
    main()
