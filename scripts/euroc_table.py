"""Regenerate the table of the six variants on a real EuRoC folder (docs/results/euroc.md; by
default the 300-pair MH_01 slice in the project's shared data) as a sweep: the matrix is
sweeps/euroc_table.toml, run as a user runs it (`coplanar sweep --config
sweeps/euroc_table.toml --out DIR`: each run exactly `coplanar run --dataset DIR --variant V`).

    .venv/bin/python scripts/euroc_table.py [--dataset ../shared/data/euroc_mh01_slice] [--out DIR] [--workers 1 | --serial | --address ADDR]

`--workers 1` (the default) runs one at a time, so that the stage times are comparable; more
give the same accuracy columns sooner. `--out DIR` keeps the sweep's folder (a second call
with it runs only what is not finished there; default: a temporary folder).

Writes docs/pipeline/euroc.json and replaces the text between the euroc-table markers in
docs/results/euroc.md. Per run (from `metrics.json`): ATE over every frame with ground truth after SE(3)
and Sim(3) alignment (cm), RPE (cm per metre of path), frames evaluated, keyframes, lost
frames, re-initializations, and the Table III stages in milliseconds.
"""

from __future__ import annotations

import argparse
import pathlib
import sys

from table_sweep import SHARED_DATA, SWEEPS, add_sweep_options, f, publish, sweep_runs

DEFAULT_DATASET = SHARED_DATA / "euroc_mh01_slice"
SWEEP = SWEEPS / "euroc_table.toml"  # its datasets: DEFAULT_DATASET


def table(results: list[dict], name: str) -> str:
    lines = [
        f"`{name}`, one run per variant (`.venv/bin/python scripts/euroc_table.py`). ATE over every tracked frame with ground "
        "truth after SE(3) / Sim(3) alignment (cm; `evo_ape` gives the same from the written files), RPE in cm per metre of "
        "path, and the Table III stages in ms (point D&M per frame; line D&M, plane segmentation, plane fitting and "
        "optimization per keyframe; total per frame).",
        "",
        "| variant | ATE SE(3) | ATE Sim(3) | RPE cm/m | frames evaluated | keyframes | lost | re-init. | point D&M | line D&M | plane seg. | plane fit. | optimization | total per frame |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for r in results:
        t = r["timing_ms"]
        lines.append(
            f"| {r['variant']} | {f(r['ate_rmse_cm'])} | {f(r['ate_sim3_rmse_cm'])} | {f(r['rpe_cm_per_m'])} | {r['frames_evaluated']} / {r['frames']} "
            f"| {r['keyframes']} | {r['lost_frames']} | {r['reinitializations']} | {f(t['point_dm'], 1)} | {f(t['line_dm'], 1)} | {f(t['plane_seg'], 1)} "
            f"| {f(t['plane_fit'], 1)} | {f(t['optimization'], 1)} | {f(t['total_per_frame'], 1)} |"
        )
    return "\n".join(lines)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--dataset", type=pathlib.Path, default=None, help=f"another EuRoC folder (default: {SWEEP.name}'s, {DEFAULT_DATASET.name})")
    add_sweep_options(parser, page="docs/results/euroc.md")
    args = parser.parse_args()
    results = sweep_runs(SWEEP, args, [] if args.dataset is None else ["--datasets", str(args.dataset)])
    for r in results:
        r.pop("row")
        print(
            f"{r['variant']:6s} ATE {f(r['ate_rmse_cm'])} cm over {r['frames_evaluated']} frames, lost {r['lost_frames']}, "
            f"kf {r['keyframes']}, total/frame {f(r['timing_ms']['total_per_frame'], 1)} ms ({r['wall_s']:.0f} s)",
            flush=True,
        )
    name = (args.dataset or DEFAULT_DATASET).name
    return publish({"dataset": name, "runs": results}, table(results, name), json_name="euroc.json", block="euroc-table", write_doc=not args.no_doc)


if __name__ == "__main__":
    sys.exit(main())
