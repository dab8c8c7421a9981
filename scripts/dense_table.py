"""The dense-check table (docs/results/dense.md) as a sweep (sweeps/dense_table.toml, run as
`coplanar sweep --config sweeps/dense_table.toml`): `coplanar run --dense` for every variant on a
rendered scene (default `room`, 30 s, seed 0, one run each): the TSDF mesh's distance to the true
planes (median, 90th percentile, share within 2 cm) and the fusion time per keyframe.

    .venv/bin/python scripts/dense_table.py [--scene room] [--duration 30] [--out DIR] [--workers 1 | --serial | --address ADDR]

Writes docs/pipeline/dense.json and replaces the dense-table block of docs/results/dense.md.
"""

from __future__ import annotations

import argparse
import sys

from table_sweep import SWEEPS, add_sweep_options, axis_options, f, publish, sweep_runs

SWEEP = SWEEPS / "dense_table.toml"


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--scene", default=None, help=f"the scene (default: {SWEEP.name}'s, room)")
    p.add_argument("--duration", type=float, default=None, help=f"seconds of motion (default: {SWEEP.name}'s, 30)")
    add_sweep_options(p, page="docs/results/dense.md")
    args = p.parse_args()
    options = axis_options({"--scenes": args.scene, "--duration": None if args.duration is None else f"{args.duration:g}"})
    finished = sweep_runs(SWEEP, args, options)
    if not finished:
        raise SystemExit("dense_table: no run finished (above)")
    runs, rows = [], []
    for m in finished:
        d = m["dense"]
        dist = d["distance_to_true_planes_cm"]
        runs.append({"variant": m["variant"], "ate_rmse_cm": m["ate_rmse_cm"], "keyframe_ate_rmse_cm": m["keyframe_ate_rmse_cm"], "dense": d})
        rows.append(
            f"| {m['variant']} | {f(m['keyframe_ate_rmse_cm'])} | {f(dist['median'])} | {f(dist['p90'])} | {100 * dist['within_2cm']:.1f} | {d['triangles']} | {f(d['fusion_ms_per_keyframe'], 1)} |"
        )
        print(rows[-1], flush=True)
    scene, duration = finished[0]["row"]["input"], finished[0]["row"]["duration_s"]
    body = "\n".join(
        [
            f"`{scene}`, {duration:g} s, one run per variant (`.venv/bin/python scripts/dense_table.py`): every keyframe's rendered depth fused "
            "into a TSDF (3 cm voxels) at the keyframe's final estimated pose (`coplanar run --dense`); the distance of the mesh's vertices to the "
            "nearest true plane (cm), and the fusion time per keyframe (ms, the integration alone).",
            "",
            "| variant | keyframe ATE cm | mesh to planes: median cm | 90th pct. cm | within 2 cm % | triangles | fusion ms / keyframe |",
            "|---|---|---|---|---|---|---|",
            *rows,
        ]
    )
    return publish({"scene": scene, "duration_s": duration, "runs": runs}, body, json_name="dense.json", block="dense-table", write_doc=not args.no_doc)


if __name__ == "__main__":
    sys.exit(main())
