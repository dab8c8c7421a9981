"""How the VIO start does beyond the table's paths, as a sweep (sweeps/vio_start_check.toml, run as
`coplanar sweep --config sweeps/vio_start_check.toml`): every rendered scene with its table path
(seed 0) and other random paths (seeds 1, 2), each run exactly
`coplanar run --mode vio --scene S --seed N --variant V --speed 2 --duration 30 [--frames F]`.

    .venv/bin/python scripts/vio_start_check.py [--seeds 0-2] [--variants P-wo,PL-w] [--seconds 30] [--out DIR] [--workers 1 | --serial | --address ADDR]

Writes docs/vio/start_check.json and replaces the vio-start block of docs/results/vio.md. Per
run: the first initialization (s from the first frame; none by the end), lost frames, restarts
of the start, re-initializations, the gravity and gyroscope bias errors after the refinement,
and the ATE (SE(3) alignment) from the initialization on and over all frames.
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys

from table_sweep import ROOT, SWEEPS, add_sweep_options, axis_options, f, publish, sweep_runs

SWEEP = SWEEPS / "vio_start_check.toml"
SPEED = 2.0
FPS = 20.0  # the rendered scenes' camera rate


def row(r: dict, *, seconds: float) -> str:
    """One table row from a run's record."""
    init = r["init_time_s"]
    return (
        f"| {r['seed']} | {r['scene']} | {r['variant']} | {f(init, 2) if init is not None else 'not by ' + format(seconds, 'g') + ' s'} | {r['lost_frames']} | "
        f"{r['restarts']} | {r['reinitializations']} | {f(r['gravity_error_refined_deg'])} | {f(r['bias_gyro_error_refined_pct'], 1)} | "
        f"{f(r['ate_after_init_cm'])} | {f(r['ate_rmse_cm'])} |"
    )


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--seeds", default=None, help=f"seeds (default: {SWEEP.name}'s, 0-2)")
    p.add_argument("--scenes", default=None, help=f"scenes (default: {SWEEP.name}'s, room,corridor,boxes)")
    p.add_argument("--variants", default=None, help=f"variants (default: {SWEEP.name}'s, P-wo,PL-w)")
    p.add_argument("--seconds", type=float, default=30.0, help="frames from the start that are run (s; at most the 30 s path)")
    add_sweep_options(p, page="docs/results/vio.md")
    p.add_argument("--from-json", action="store_true", help="rewrite the vio-start block of docs/results/vio.md from docs/vio/start_check.json without running")
    args = p.parse_args()
    out = ROOT / "docs" / "vio" / "start_check.json"
    runs: list[dict] = []
    if args.from_json:
        saved = json.loads(out.read_text())
        args.seconds, runs = saved["seconds"], saved["runs"]
    else:
        options = axis_options({"--seeds": args.seeds, "--scenes": args.scenes, "--variants": args.variants})
        options += ["--frames", str(int(round(args.seconds * FPS)))] if args.seconds < 30.0 else []
        for m in sweep_runs(SWEEP, args, options):
            v = m["vio"]
            runs.append(
                {
                    "seed": m["row"]["seed"],
                    "scene": m["row"]["input"],
                    "variant": m["variant"],
                    "initialized": v["initialized"],
                    "init_time_s": v["init_time_s"] if v["initialized"] else None,
                    "lost_frames": m["lost_frames"],
                    "reinitializations": m["reinitializations"],
                    "restarts": sum("starting again" in msg for msg in m["messages"]),
                    "ate_after_init_cm": v.get("ate_after_init_cm"),
                    "ate_rmse_cm": m["ate_rmse_cm"],
                    "gravity_error_refined_deg": v.get("gravity_error_refined_deg"),
                    "bias_gyro_error_refined_pct": v.get("bias_gyro_error_refined_pct"),
                }
            )
        runs.sort(key=lambda r: r["seed"])  # the table by seed (the sweep: scenes outermost), otherwise in the sweep's order
        for r in runs:
            print(row(r, seconds=args.seconds), flush=True)
    rows = [row(r, seconds=args.seconds) for r in runs]
    ok = sum(r["initialized"] and r["init_time_s"] <= 3.0 for r in runs)
    ates = [r["ate_after_init_cm"] for r in runs if r["ate_after_init_cm"] is not None]
    mean_ate, median_ate = (statistics.mean(ates), statistics.median(ates)) if ates else (float("nan"), float("nan"))
    if not args.from_json:
        out.write_text(json.dumps({"speed": SPEED, "seconds": args.seconds, "runs": runs}, indent=2) + "\n")
    body = "\n".join(
        [
            f"The table's paths (seed 0) and other random paths through the rendered scenes (`--seed`), the first {args.seconds:g} s at {SPEED:g}× speed, one run each "
            f"(`.venv/bin/python scripts/vio_start_check.py`): the first initialization (s), lost frames, restarts of the start "
            f"(too few features followed from its first keyframe), re-initializations, gravity / gyroscope bias errors after the refinement (°, % of the true bias), "
            f"and the ATE after SE(3) alignment from the initialization on and over all frames (cm). "
            f"**{ok} of {len(runs)} initialize within 3 s**; ATE from the initialization: mean {mean_ate:.2f}, median {median_ate:.2f} cm.",
            "",
            "| seed | scene | variant | init. s | lost | restarts | re-init. | gravity err. ° | gyro bias err. % | ATE from init. | ATE all frames |",
            "|---|---|---|---|---|---|---|---|---|---|---|",
            *rows,
        ]
    )
    return publish(None, body, json_name="", block="vio-start", write_doc=not args.no_doc)


if __name__ == "__main__":
    sys.exit(main())
