"""What the learned segmenter does to the stereo pipeline, as a sweep (sweeps/segmenter_table.toml,
run as `coplanar sweep --config sweeps/segmenter_table.toml`): PL-w with the geometric and the
learned segmenter on the rendered scenes (keyframe ATE, ground-truth planes recovered, plane
segmentation time per keyframe) and on the real MH_01 slice (ATE over all frames, planes in the
map), one run each, each exactly `coplanar run --segmenter K`.

    .venv/bin/python scripts/segmenter_table.py [--variant PL-w] [--out DIR] [--workers 1 | --serial | --address ADDR]

Writes docs/pipeline/segmenter.json and replaces the segmenter-table block of
docs/results/segmenter.md. The MH_01 rows are left out where ../shared is absent.
"""

from __future__ import annotations

import argparse
import pathlib
import sys
import tempfile

from table_sweep import SHARED_DATA, SWEEPS, add_sweep_options, f, publish, sweep_runs

SWEEP = SWEEPS / "segmenter_table.toml"


def table_row(r: dict) -> str:
    """A run's row: rendered scenes with their true planes, the real slice over every frame."""
    row, t = r["row"], r["timing_ms"]
    if "plane_recovery" in r:
        planes = r["plane_recovery"]
        return f"| {row['input']} | {row['segmenter']} | {f(r['keyframe_ate_rmse_cm'])} | {planes['recovered']}/{planes['seen']} | {r['planes']} | {f(t['plane_seg'], 1)} | {r['lost_frames']} |"
    return f"| {row['input']} (real) | {row['segmenter']} | {f(r['ate_rmse_cm'])} (all frames) | – | {r['planes']} | {f(t['plane_seg'], 1)} | {r['lost_frames']} |"


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--variant", default=None, help=f"the variant (default: {SWEEP.name}'s, PL-w)")
    add_sweep_options(p, page="docs/results/segmenter.md")
    args = p.parse_args()
    with tempfile.TemporaryDirectory() as scratch:
        args.scratch = pathlib.Path(scratch)
        return _run(args)


def _run(args: argparse.Namespace) -> int:
    options = [] if args.variant is None else ["--variants", args.variant]
    config = SWEEP
    if not (SHARED_DATA / "euroc_mh01_slice").is_dir():  # the same matrix without the dataset
        print(f"{SHARED_DATA / 'euroc_mh01_slice'} is absent: the rendered scenes only", file=sys.stderr)
        config = args.scratch / SWEEP.name
        config.write_text("".join(line for line in SWEEP.read_text().splitlines(keepends=True) if not line.startswith("datasets")))
    runs = sweep_runs(config, args, options)
    rows = [table_row(r) for r in runs]
    print("\n".join(rows), flush=True)
    variant = runs[0]["variant"] if runs else args.variant
    body = "\n".join(
        [
            f"{variant}, one run each (`.venv/bin/python scripts/segmenter_table.py`): ATE after SE(3) alignment (cm; rendered scenes over keyframes, "
            "the real slice over every frame), ground-truth planes recovered (within 10°, the map plane's patch within 10 cm; planes covering ≥ 5 % of some keyframe), "
            "planes in the final map, plane segmentation per keyframe (ms), lost frames.",
            "",
            "| input | segmenter | ATE | planes recovered | map planes | plane seg. ms | lost |",
            "|---|---|---|---|---|---|---|",
            *rows,
        ]
    )
    results = [{"input": r["row"]["input"], "segmenter": r["row"]["segmenter"], **{k: v for k, v in r.items() if k != "row"}} for r in runs]
    return publish({"variant": variant, "runs": results}, body, json_name="segmenter.json", block="segmenter-table", write_doc=not args.no_doc)


if __name__ == "__main__":
    sys.exit(main())
