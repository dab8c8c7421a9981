"""What the debugger shows when the user switches the variant on one window: every variant
re-optimizes the same window from the same state, as the debugger's variant control does
(`engine.set_variant`, `engine.reoptimize`), and the report and running trajectory error
are printed side by side.

    .venv/bin/python scripts/variant_switch.py --scene mc-a --keyframes 60
    .venv/bin/python scripts/variant_switch.py --scene room --keyframes 20
    .venv/bin/python scripts/variant_switch.py --scene mc-a --keyframes 60 --from-start

The engine runs `--keyframes` steps with `--variant` (PL-w by default, the debugger's
default); then each variant starts from that engine's state, so that none sees another's
result: the engine is rebuilt and replayed for each variant (the engines are deterministic
for a seed; the script checks that every replay reaches the same state). With
`--from-start` each variant instead runs the whole sequence itself (the study's setting:
every keyframe's window optimized with that variant). Costs are ½ Σ whitened residual² of the window's own factors (a variant's
factor set differs: -r adds plane residuals, -w has fewer unknowns), so compare them within
a variant (initial → final); the trajectory errors compare across variants: `win cm` is
the RMSE of the window's keyframe positions against the ground truth (no alignment: older
keyframes hold the gauge), RMSE and ATE (SE(3) alignment) are over all keyframes so far.
"""

from __future__ import annotations

import argparse
import math
import os
import pathlib
import sys

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import numpy as np

ROOT = pathlib.Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from app.serve_command import DEFAULT_DURATION_S
from backend.optim.variant import VARIANTS
from backend.pipeline.factory import EngineConfig, make_engine
from backend.pipeline.snapshot import Snapshot


def window_rmse_cm(snapshot: Snapshot) -> float:
    """RMSE (cm) of the window keyframes' positions against the ground truth."""
    if snapshot.ground_truth is None:
        return math.nan
    w = snapshot.window
    err = snapshot.estimate.t_world_camera[w] - snapshot.ground_truth.t_world_camera[w]
    return 100.0 * float(np.sqrt(np.mean(np.sum(err**2, axis=1))))


def row(variant: str, s: Snapshot) -> str:
    r = s.report
    return (
        f"{variant:7s} {r.items:5d} {r.params:6d} {r.iterations:5d} {r.initial_cost:13.6g} {r.final_cost:13.6g} {window_rmse_cm(s):7.2f} {s.metrics.rmse_cm:8.2f} {s.metrics.ate_cm:7.2f}"
        f" {r.timing_ms.get('optimization', float('nan')):7.1f}  {r.termination}"
    )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--scene", default="mc-a")
    parser.add_argument("--keyframes", type=int, default=60)
    parser.add_argument("--variant", default="PL-w")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--from-start", action="store_true", help="run every variant from keyframe 0 instead of switching on the last window")
    args = parser.parse_args()

    def replay(variant: str = args.variant):
        engine = make_engine(EngineConfig(scene=args.scene, variant=variant, seed=args.seed, duration_s=DEFAULT_DURATION_S, interactive=True))  # as `coplanar serve`
        for _ in range(args.keyframes):
            snapshot = engine.step()
        return engine, snapshot

    _, snapshot = replay()
    print(f"# {args.scene}: {args.keyframes} keyframes with {args.variant}; keyframe {snapshot.keyframe}, window {snapshot.report.window} + {snapshot.report.fixed_poses} fixed")
    print(f"# after the step ({args.variant}): window {window_rmse_cm(snapshot):.2f} cm, RMSE {snapshot.metrics.rmse_cm:.2f} cm, ATE {snapshot.metrics.ate_cm:.2f} cm")
    print(f"{'variant':7s} {'items':>5s} {'params':>6s} {'iters':>5s} {'initial cost':>13s} {'final cost':>13s} {'win cm':>7s} {'RMSE cm':>8s} {'ATE cm':>7s} {'opt ms':>7s}  termination")
    for variant in VARIANTS:
        if args.from_start:
            print(row(variant, replay(variant)[1]))
            continue
        engine, before = replay()
        if not np.array_equal(before.estimate.t_world_camera, snapshot.estimate.t_world_camera):
            raise SystemExit("the engine is not deterministic: replays differ")
        engine.set_variant(variant)
        print(row(variant, engine.reoptimize()))


if __name__ == "__main__":
    main()
