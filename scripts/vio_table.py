"""The VIO table (docs/results/vio.md; the paper's Table II, VIO columns) with the stereo
figures of the same input beside them: every variant on every rendered scene, as a sweep
(sweeps/vio_table.toml, run as `coplanar sweep --config sweeps/vio_table.toml`: each run
exactly `coplanar run --mode vio|stereo --scene S --variant V --duration 30`, at the scenes'
own speed, the default; seed
0, one run each).

    .venv/bin/python scripts/vio_table.py [--duration 30] [--speed 1] [--scenes room,corridor,boxes] [--out DIR] [--workers 1 | --serial | --address ADDR]

`--workers 1` (the default) runs one at a time, so that the times per frame are comparable;
`--out DIR` keeps the sweep's folder (a second call runs only what is not finished there).

Writes docs/vio/results.json and replaces the vio-table block of docs/results/vio.md. Per run:
ATE over all tracked frames with ground truth after SE(3) and Sim(3) alignment (cm), the Sim(3)
scale error (%), the initialization (time, gravity error, scale error at the alignment), lost
frames, re-initializations and the mean total time per frame (ms).
"""

from __future__ import annotations

import argparse
import json
import sys

from table_sweep import ROOT, SWEEPS, add_sweep_options, f, publish, sweep_runs

from backend.optim.variant import VARIANTS

SWEEP = SWEEPS / "vio_table.toml"


def row(scene: str, variant: str, vio: dict, stereo: dict) -> str:
    """One table row from the two runs' metrics.json."""
    v = vio["vio"]
    al = v.get("alignment") or {}
    return (
        f"| {scene} | {variant} | {f(v.get('ate_after_init_cm'))} | {f(v.get('ate_sim3_after_init_cm'))} | {f(vio['ate_rmse_cm'])} | {f(v['scale_error_pct'], 1)} | "
        f"{f(v['init_time_s'], 1)} | {f(al.get('gravity_error_deg'), 2)} / {f(v.get('gravity_error_refined_deg'), 2)} | {f(al.get('scale_error_pct'), 1)} / {f(al.get('joint_scale_error_pct'), 1)} | "
        f"{f(al.get('bias_gyro_error_pct'), 1)} / {f(v.get('bias_gyro_error_refined_pct'), 1)} | {vio['lost_frames']} / {vio['reinitializations']} | {f(vio['timing_ms']['total_per_frame'], 1)} | "
        f"{f(stereo['ate_rmse_cm'])} | {f(stereo['timing_ms']['total_per_frame'], 1)} |"
    )


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--duration", type=float, default=30.0)
    p.add_argument("--speed", type=float, default=1.0)
    p.add_argument("--scenes", default="room,corridor,boxes")
    p.add_argument("--variants", default=",".join(VARIANTS))
    add_sweep_options(p, page="docs/results/vio.md")
    p.add_argument("--from-json", action="store_true", help="rewrite the table from docs/vio/results.json without running")
    p.add_argument("--stereo-from-json", action="store_true", help="run VIO only; the stereo columns from docs/vio/results.json (for a change that leaves the stereo pipeline as it was)")
    args = p.parse_args()
    out = ROOT / "docs" / "vio" / "results.json"
    results = []
    rows = []
    saved_stereo = {}
    if args.stereo_from_json:
        saved_stereo = {(r["scene"], r["variant"]): r["stereo"] for r in json.loads(out.read_text())["runs"]}
    if args.from_json:
        saved = json.loads(out.read_text())
        args.duration, args.speed, results = saved["duration_s"], saved["speed"], saved["runs"]
        rows = [row(r["scene"], r["variant"], r["vio"], r["stereo"]) for r in results]
    if not args.from_json:
        options = ["--scenes", args.scenes, "--variants", args.variants, "--duration", f"{args.duration:g}", "--speeds", f"{args.speed:g}"]
        options += ["--modes", "vio" if args.stereo_from_json else "vio,stereo"]
        found = {(r["row"]["input"], r["row"]["mode"], r["variant"]): r for r in sweep_runs(SWEEP, args, options)}
        for r in found.values():
            r.pop("row")
        for scene in args.scenes.split(","):
            for variant in args.variants.split(","):
                vio = found.get((scene, "vio", variant))
                stereo = saved_stereo.get((scene, variant)) or found.get((scene, "stereo", variant))
                if vio is None or stereo is None:
                    raise SystemExit(f"vio_table: {scene} {variant}: a run failed (above)")
                results.append({"scene": scene, "variant": variant, "vio": vio, "stereo": stereo})
                rows.append(row(scene, variant, vio, stereo))
                print(rows[-1], flush=True)
    if not args.from_json:
        out.parent.mkdir(parents=True, exist_ok=True)
        out.write_text(json.dumps({"duration_s": args.duration, "speed": args.speed, "runs": results}, indent=2) + "\n")
    body = "\n".join(
        [
            f"Rendered scenes at {args.speed:g}× speed, {args.duration:g} s, seed 0, one run each (`.venv/bin/python scripts/vio_table.py`; "
            "VIO with the learned segmenter, stereo with the geometric one, each its default). ATE over every tracked frame with ground truth "
            "(cm; VIO: the frames from its first initialization on, after SE(3) and Sim(3) alignment, and all frames after SE(3) alignment, "
            "which includes the frames of a failed start that never got a metric scale), the Sim(3) scale error of VIO from the initialization on (%), the initialization "
            "(the first one: time from the first frame, s; gravity direction error of the alignment / after the refinement by the windows with IMU factors, °; "
            "scale error of the alignment / after the start's joint visual-inertial solve, %; gyroscope bias error of the alignment / after the refinement, % of the true bias; "
            "both refined figures at the initialization keyframe as the windows left it), VIO's lost frames / re-initializations, "
            "mean total time per frame (ms, this 2-core VM), and the stereo pipeline on the same frames.",
            "",
            "| scene | variant | VIO ATE SE(3) | VIO ATE Sim(3) | VIO ATE all frames | scale err. % | init. s | gravity err. "
            "° | init. scale err. % (align. / joint) | gyro bias err. % | lost / re-init. | VIO ms/frame | stereo ATE SE(3) | stereo ms/frame |",
            "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|",
            *rows,
        ]
    )
    return publish(None, body, json_name="", block="vio-table", write_doc=not args.no_doc)


if __name__ == "__main__":
    sys.exit(main())
