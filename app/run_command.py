"""`coplanar run`: the engine headless, writing the trajectory, metrics and map (DESIGN §7)."""

from __future__ import annotations

import argparse
import json
import math
import pathlib
import sys

DEFAULT_DURATION_S = 30.0
# Stages the stereo engine reports as means per frame within a step (the rest: per keyframe).
PER_FRAME_STAGES = ("point_dm", "tracking", "load")


def add_parser(sub: argparse._SubParsersAction) -> None:
    from app.sources import add_source_arguments
    from backend.optim.problem import VARIANTS

    p = sub.add_parser("run", help="run the engine headless; write trajectory.txt, metrics.json and map.ply")
    add_source_arguments(p, duration_default=DEFAULT_DURATION_S)
    p.add_argument("--variant", required=True, choices=VARIANTS, help="parametrization")
    p.add_argument("--out", required=True, type=pathlib.Path, help="output folder (created if missing)")
    p.add_argument("--frames", type=int, default=None, metavar="N", help="stereo inputs: stop after the first N frames (default all)")
    p.add_argument("--keyframes", type=int, default=None, metavar="N",
                   help="stop after N keyframes (default: mc-a / mc-b one pass of the trajectory, stereo inputs all)")
    p.set_defaults(run=run, history=1)


def _prepare_out(out: pathlib.Path) -> None:
    from app.cli import UsageError

    if out.exists() and not out.is_dir():
        raise UsageError(f"--out {out}: exists and is not a folder")
    try:
        out.mkdir(parents=True, exist_ok=True)
        probe = out / ".coplanar-write-test"
        probe.write_bytes(b"")
        probe.unlink()
    except OSError as e:
        raise UsageError(f"--out {out}: cannot write there: {e.strerror or e}") from None


def _json_safe(value):  # noqa: ANN001, ANN202
    """`value` with every non-finite float replaced by None (JSON has no NaN)."""
    if isinstance(value, dict):
        return {k: _json_safe(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_json_safe(v) for v in value]
    if isinstance(value, float) and not math.isfinite(value):
        return None
    return value


def _write_outputs(out: pathlib.Path, snapshot, metrics: dict) -> None:  # noqa: ANN001
    from backend.export.ply import write_ply
    from backend.export.tum import write_tum

    write_tum(out / "trajectory.txt", snapshot.estimate)
    (out / "metrics.json").write_text(json.dumps(_json_safe(metrics), indent=2, allow_nan=False) + "\n")
    write_ply(out / "map.ply", snapshot)


def _cm(value: float) -> str:
    return f"{value:.2f} cm" if math.isfinite(value) else "n/a (no ground truth)"


def run(args: argparse.Namespace) -> int:
    from app.sources import build_engine
    from backend.pipeline.sim_engine import SimEngine

    engine = build_engine(args, headless=True)
    if isinstance(engine, SimEngine):
        return _run_simulation(args, engine)
    return _run_stereo(args, engine)


def _run_simulation(args: argparse.Namespace, engine) -> int:  # noqa: ANN001
    import numpy as np
    from tqdm import tqdm

    from app.cli import UsageError
    from backend.eval import sequences

    n = args.keyframes if args.keyframes is not None else len(sequences.make_world(engine.settings.sequence, seed=args.seed).t_world_camera)
    if n < 1:
        raise UsageError(f"--keyframes {n}: must be at least 1")
    _prepare_out(args.out)
    timings: dict[str, list[float]] = {}
    snapshot = None
    with tqdm(total=n, desc=f"run {engine.source}", unit="kf", file=sys.stderr, disable=None) as bar:
        for _ in range(n):
            snapshot = engine.step()
            for stage, ms in snapshot.report.timing_ms.items():
                timings.setdefault(stage, []).append(ms)
            bar.update(1)
    assert snapshot is not None
    mean = {k: float(np.mean(v)) for k, v in timings.items()}
    metrics = {
        "source": engine.source,
        "variant": args.variant,
        "frames": n,
        "keyframes": n,
        "ate_rmse_cm": snapshot.metrics.ate_cm,
        "rmse_cm": snapshot.metrics.rmse_cm,
        "planes": len(snapshot.planes),
        "points": len(snapshot.points),
        "lines": len(snapshot.lines),
        # DESIGN §7's stages; the simulation has no images, so no feature detection and
        # matching or segmentation: those are null. Means over keyframes, milliseconds.
        "timing_ms": {
            "point_dm": None,
            "line_dm": None,
            "plane_seg": None,
            "plane_fit": mean["detection"],
            "optimization": mean["optimization"],
            "total_per_frame": mean["total"],
            "all_stages": mean,
        },
    }
    _write_outputs(args.out, snapshot, metrics)
    print(f"{n} keyframes, {args.variant}: ATE {_cm(snapshot.metrics.ate_cm)} (SE3-aligned), RMSE {_cm(snapshot.metrics.rmse_cm)}, "
          f"{len(snapshot.planes)} planes; {mean['total']:.1f} ms per keyframe; wrote {args.out}/trajectory.txt, metrics.json, map.ply")
    return 0


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
    for _, timing in steps:
        stages += [k for k in timing if k not in stages]
    mean: dict[str, float | None] = {}
    for stage in stages:
        if stage == "total_per_frame":
            continue
        if stage in PER_FRAME_STAGES:
            mean[stage] = sum(f * t.get(stage, 0.0) for f, t in steps) / frames if frames else None
        else:
            ran = [t[stage] for _, t in steps if t.get(stage, 0.0) != 0.0]
            mean[stage] = sum(ran) / len(ran) if ran else None
    mean["total_per_frame"] = sum(t.get("total", 0.0) for _, t in steps) / frames if frames else None
    timing = {k: mean.get(k) for k in ("point_dm", "tracking", "line_dm", "plane_seg", "plane_fit", "optimization", "total_per_frame")}
    timing["all_stages"] = mean
    return timing


def _run_stereo(args: argparse.Namespace, engine) -> int:  # noqa: ANN001
    from tqdm import tqdm

    from app.cli import UsageError
    from backend.pipeline.engine import EndOfSequence

    if args.keyframes is not None and args.keyframes < 1:
        raise UsageError(f"--keyframes {args.keyframes}: must be at least 1")
    _prepare_out(args.out)
    total_frames = len(engine.data_source)
    steps: list[tuple[int, dict[str, float]]] = []
    messages: list[str] = []
    lost = reinitializations = 0
    snapshot = None
    bar = tqdm(total=total_frames, desc=f"run {args.variant}", unit="frame", file=sys.stderr, disable=None, dynamic_ncols=True)
    engine.on_frame = lambda _index: bar.update(1)
    try:
        while args.keyframes is None or len(steps) < args.keyframes:
            try:
                snapshot = engine.step()
            except EndOfSequence:
                break
            tracking = snapshot.tracking
            steps.append((tracking.frames, dict(snapshot.report.timing_ms)))
            lost += tracking.lost_frames
            reinitializations += tracking.reinitializations
            if snapshot.message:
                messages.append(f"keyframe {snapshot.keyframe}: {snapshot.message}")
                bar.write(f"keyframe {snapshot.keyframe}: {snapshot.message}", file=sys.stderr)
    except BaseException:
        bar.leave = False  # an error line (or the interruption) follows: no half-drawn bar above it
        raise
    finally:
        bar.close()
        engine.on_frame = None
    if snapshot is None:
        raise UsageError(f"{engine.source}: no keyframe in {engine.frames} frames")
    metrics = {
        "source": engine.source,
        "variant": args.variant,
        "frames": engine.frames,
        "keyframes": len(snapshot.estimate),
        "ate_rmse_cm": snapshot.metrics.ate_cm,
        "rmse_cm": snapshot.metrics.rmse_cm,
        "planes": len(snapshot.planes),
        "points": len(snapshot.points),
        "lines": len(snapshot.lines),
        "lost_frames": lost,
        "reinitializations": reinitializations,
        "timing_ms": stereo_timing(steps),
        "messages": messages,
    }
    _write_outputs(args.out, snapshot, metrics)
    per_frame = metrics["timing_ms"]["total_per_frame"]
    print(f"{engine.frames} frames, {metrics['keyframes']} keyframes, {args.variant}: ATE {_cm(snapshot.metrics.ate_cm)} (SE3-aligned), "
          f"RMSE {_cm(snapshot.metrics.rmse_cm)}, {len(snapshot.planes)} planes, {lost} lost frames, {reinitializations} re-initializations; "
          f"{per_frame:.1f} ms per frame; wrote {args.out}/trajectory.txt, metrics.json, map.ply")
    return 0
