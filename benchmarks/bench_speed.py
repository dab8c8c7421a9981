"""Benchmark: time per frame and per stage of the pipelines on the issue's four inputs, as
`coplanar run` runs them (headless defaults: P variants detect no lines, -wo variants
segment no planes, no keyframe image, no Hessian image), beside the paper's Table III.

    .venv/bin/python benchmarks/bench_speed.py [--runs 3] [--cases mh01,room,street,vio-room] [--variant PL-w] [--no-read-ahead] [--write]

Every frame is read (or rendered) into memory first, so the times leave out reading, as
from a camera; then the engine runs the whole input. Per frame: the wall time of the
engine's steps divided by the frames (the figure the goals are about; the next frame's ORB
detection runs on a worker thread meanwhile, so it is less than the sum of the stages).
Per stage: the mean per frame (point D&M, tracking) or per keyframe (the rest), each the
elapsed time of that stage on the thread that ran it (a wall-clock interval, not CPU time:
on a busy 2-core machine it includes waiting for a core). Prints one table per case
(median over the runs) and a summary; `--write` also puts them in docs/results/speed.md
(its `bench-speed` block).

Cases: `mh01` the real EuRoC MH_01 slice (300 pairs 752×480, ../shared/data, skipped when
absent); `room` the rendered room (30 s at 20 Hz, 752×480); `street` the rendered street
(30 s at 10 Hz, 1241×376, KITTI's size); `vio-room` VIO on the rendered room (speed 1).
"""

from __future__ import annotations

import argparse
import os
import platform
import statistics
import sys
import time
from pathlib import Path

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

from backend.common.timing import PER_FRAME_STAGES, Stage
from backend.pipeline.engine import EndOfSequence
from backend.pipeline.factory import EngineConfig, Mode, make_engine

ROOT = Path(__file__).resolve().parents[1]
MH01 = ROOT.parent / "shared" / "data" / "euroc_mh01_slice"

# The paper's Table III (i7-8550U, ms): per frame point D&M 4, per keyframe line D&M 96,
# plane segmentation 29, plane fitting 10, optimization 40-46; total per frame 54-60.
PAPER = {Stage.POINT_DM: "4", Stage.LINE_DM: "96", Stage.PLANE_SEG: "29", Stage.PLANE_FIT: "10", Stage.OPTIMIZATION: "40-46", "per frame": "54-60"}
SHOWN = (Stage.POINT_DM, Stage.TRACKING, Stage.LINE_DM, Stage.PLANE_SEG, Stage.PLANE_FIT, Stage.OPTIMIZATION, Stage.MAPPING, Stage.SETUP, Stage.CULLING, Stage.UPDATE)
GOALS_MS = {"mh01": 20.0, "room": 25.0, "street": 50.0, "vio-room": 20.0}


def config_for(case: str, *, variant: str, read_ahead: bool) -> EngineConfig:
    common = {"variant": variant, "preload": True, "read_ahead": read_ahead}
    if case == "mh01":
        return EngineConfig(dataset=MH01, **common)
    if case == "room":
        return EngineConfig(scene="room", **common)
    if case == "street":
        return EngineConfig(scene="street", **common)
    if case == "vio-room":
        return EngineConfig(scene="room", mode=Mode.VIO, **common)
    raise SystemExit(f"unknown case {case!r} (mh01, room, street, vio-room)")


def run_once(config: EngineConfig) -> dict[str, float]:
    engine = make_engine(config)
    per_frame: dict[str, float] = {}
    per_keyframe: dict[str, list[float]] = {}
    frames = keyframes = 0
    wall = 0.0
    while True:
        t0 = time.perf_counter()
        try:
            snapshot = engine.step()
        except EndOfSequence:
            break
        wall += time.perf_counter() - t0
        n = snapshot.tracking.frames
        frames += n
        keyframes += 1
        for stage, ms in snapshot.report.timing_ms.items():
            if stage in PER_FRAME_STAGES:
                per_frame[stage] = per_frame.get(stage, 0.0) + ms * n
            elif stage not in (Stage.TOTAL, Stage.TOTAL_PER_FRAME):
                per_keyframe.setdefault(stage, []).append(ms)
    out = {stage: total / frames for stage, total in per_frame.items()}
    out.update({stage: statistics.fmean(values) for stage, values in per_keyframe.items()})
    out["frames"], out["keyframes"] = frames, keyframes
    out["per frame"] = 1e3 * wall / frames
    out["ate_cm"] = snapshot.metrics.ate_cm if snapshot.metrics.ate_cm is not None else float("nan")  # type: ignore[possibly-undefined]
    return out


def cpu_name() -> str:
    cpuinfo = Path("/proc/cpuinfo")
    lines = cpuinfo.read_text().splitlines() if cpuinfo.exists() else []
    return next((line.split(":", 1)[1].strip() for line in lines if line.startswith("model name")), platform.processor())


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs", type=int, default=3)
    parser.add_argument("--cases", default="mh01,room,street,vio-room")
    parser.add_argument("--variant", default="PL-w")
    parser.add_argument("--no-read-ahead", action="store_true", help="detect the next frame's keypoints after tracking, on one thread (for comparing)")
    parser.add_argument("--write", action="store_true", help="also write the tables into docs/results/speed.md")
    args = parser.parse_args()
    lines: list[str] = []

    def emit(text: str = "") -> None:
        print(text)
        lines.append(text)

    print(f"# {cpu_name()}, {os.cpu_count()} cpus, python {platform.python_version()}, OPENBLAS_NUM_THREADS={os.environ.get('OPENBLAS_NUM_THREADS')}")
    print(f"# read-ahead {'off' if args.no_read_ahead else 'on'}, median of {args.runs} run(s)")
    summary = []
    for case in args.cases.split(","):
        if case == "mh01" and not MH01.is_dir():
            print(f"{case}: skipped ({MH01} absent)")
            continue
        results = [run_once(config_for(case, variant=args.variant, read_ahead=not args.no_read_ahead)) for _ in range(args.runs)]
        med = {key: statistics.median(r[key] for r in results) for key in results[0]}
        emit(f"\n**{case}** {args.variant}: {int(med['frames'])} frames, {int(med['keyframes'])} keyframes, ATE {med['ate_cm']:.2f} cm\n")
        emit("| stage | ms (median) | per | paper (Table III) |")
        emit("|---|---|---|---|")
        for stage in SHOWN:
            if stage in med:
                emit(f"| {stage} | {med[stage]:.1f} | {'frame' if stage in PER_FRAME_STAGES else 'keyframe'} | {PAPER.get(stage, '')} |")
        runs = ", ".join(f"{r['per frame']:.1f}" for r in results)
        emit(f"| **per frame (wall)** | **{med['per frame']:.1f}** (runs {runs}) | frame | {PAPER['per frame']} |")
        summary.append(f"{case}: {med['per frame']:.1f} ms per frame (goal {GOALS_MS[case]:g})")
    print("\n" + "\n".join(summary))
    if args.write:
        sys.path.insert(0, str(ROOT / "scripts"))
        from results_doc import write_block

        command = " ".join([".venv/bin/python", "benchmarks/bench_speed.py", *sys.argv[1:]])
        head = f"`{command}` on {cpu_name()}, {os.cpu_count()} cpus, one BLAS thread, median of {args.runs} run(s), read-ahead {'off' if args.no_read_ahead else 'on'}:"
        page = write_block("bench-speed", "\n".join([head, *lines, "", *(f"- {line}" for line in summary)]))
        print(f"wrote {page}")


if __name__ == "__main__":
    main()
