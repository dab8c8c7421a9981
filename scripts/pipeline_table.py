"""Regenerate the stereo-pipeline tables (docs/results/pipeline.md; the paper's Tables II and
III on the rendered scenes) as a sweep: every variant on every built-in scene, 30 s, seed 0,
one run each (sweeps/pipeline_table.toml, run as `coplanar sweep --config
sweeps/pipeline_table.toml --out DIR`: each run exactly `coplanar run --scene S --variant V`).

    .venv/bin/python scripts/pipeline_table.py [--duration 30] [--scenes room,corridor,boxes] [--out DIR] [--workers 1 | --serial | --address ADDR]

Writes docs/pipeline/results.json and replaces the text between the pipeline-table markers in
docs/results/pipeline.md. Per run (from `metrics.json`): keyframe ATE after SE(3) alignment
(cm), frames, keyframes, lost frames, the Table III stages (point D&M per frame; line D&M,
plane segmentation, plane fitting and optimization per keyframe where the variant runs them;
total per frame), and the ground-truth planes recovered (`plane_recovery`: planes that cover
at least 5 % of some keyframe's left image, matched by a map plane within 10° whose patch lies
within 10 cm of the true plane).
"""

from __future__ import annotations

import argparse
import json
import sys

from table_sweep import ROOT, SWEEPS, add_sweep_options, axis_options, publish, sweep_runs

from backend.optim.variant import VARIANTS

SWEEP = SWEEPS / "pipeline_table.toml"


def result(metrics: dict) -> dict:
    """A run's entry of docs/pipeline/results.json, from its metrics.json."""
    row, planes = metrics["row"], metrics["plane_recovery"]
    return {
        "scene": row["input"],
        "variant": metrics["variant"],
        "duration_s": row["duration_s"],
        "frames": metrics["frames"],
        "keyframes": metrics["keyframes"],
        "ate_cm": metrics["keyframe_ate_rmse_cm"],
        "ate_all_frames_cm": metrics["ate_rmse_cm"],
        "lost_frames": metrics["lost_frames"],
        "map_planes": metrics["planes"],
        "planes_seen": planes["seen"],
        "planes_recovered": planes["recovered"],
        "planes_recovered_by_origin_offset": planes["recovered_by_origin_offset"],
        "timing_ms": metrics["timing_ms"],
        "wall_s": metrics["wall_s"],
    }


def _ms(value: float | None) -> str:
    return "–" if value is None else f"{value:.1f}"


def tables(results: list[dict], scenes: list[str]) -> str:
    by = {(r["scene"], r["variant"]): r for r in results}
    lines = [
        "**Accuracy** (Table II): keyframe ATE after SE(3) alignment (cm; `keyframes.txt` against the ground truth of the body frame, "
        "as `evo_ape` gives it), and the ground-truth planes recovered (a map plane within "
        "10° of a plane covering ≥ 5 % of some keyframe, its patch within 10 cm of it; -wo variants detect no planes).",
        "",
        "| variant | " + " | ".join(f"{s} ATE | {s} planes" for s in scenes) + " |",
        "|---|" + "---|---|" * len(scenes),
    ]
    for v in VARIANTS:
        cells = []
        for s in scenes:
            r = by[(s, v)]
            planes = "–" if v.endswith("-wo") else f"{r['planes_recovered']}/{r['planes_seen']}"
            cells += [f"{r['ate_cm']:.2f}", planes]
        lines.append(f"| {v} | " + " | ".join(cells) + " |")
    lines += [
        "",
        "**Time** (Table III), ms, scene `room`: point D&M per frame; line D&M, plane segmentation, plane fitting and "
        "optimization per keyframe (– : the variant does not run it); total: all work per frame (keyframe work spread over the frames).",
        "",
        "| variant | point D&M* | line D&M | plane seg. | plane fitting | optimization | total per frame | keyframes / frames |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for v in VARIANTS:
        r = by[(scenes[0], v)]
        t = r["timing_ms"]
        lines.append(
            f"| {v} | {_ms(t['point_dm'])} | {_ms(t['line_dm'])} | {_ms(t['plane_seg'])} | {_ms(t['plane_fit'])} | "
            f"{_ms(t['optimization'])} | {_ms(t['total_per_frame'])} | {r['keyframes']} / {r['frames']} |"
        )
    return "\n".join(lines)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--duration", type=float, default=None, help=f"seconds of motion (default: {SWEEP.name}'s, 30)")
    parser.add_argument("--scenes", default=None, help=f"scenes (default: {SWEEP.name}'s, room,corridor,boxes)")
    add_sweep_options(parser, page="docs/results/pipeline.md")
    parser.add_argument("--from-json", action="store_true", help="rewrite the tables in docs/results/pipeline.md from docs/pipeline/results.json without running")
    args = parser.parse_args()
    out = ROOT / "docs" / "pipeline" / "results.json"
    if args.from_json:
        results = json.loads(out.read_text())
    else:
        options = axis_options({"--duration": None if args.duration is None else f"{args.duration:g}", "--scenes": args.scenes})
        results = [result(m) for m in sweep_runs(SWEEP, args, options)]
        for r in results:
            print(
                f"{r['scene']:9s} {r['variant']:6s} ATE {r['ate_cm']:6.2f} cm  planes {r['planes_recovered']}/{r['planes_seen']}  "
                f"kf {r['keyframes']:3d}/{r['frames']}  lost {r['lost_frames']}  total/frame {_ms(r['timing_ms']['total_per_frame'])} ms  ({r['wall_s']:.0f} s)",
                flush=True,
            )
        out.parent.mkdir(parents=True, exist_ok=True)
        out.write_text(json.dumps(results, indent=2) + "\n")
    scenes = list(dict.fromkeys(r["scene"] for r in results))
    return publish(None, tables(results, scenes), json_name="", block="pipeline-table", write_doc=not args.no_doc)


if __name__ == "__main__":
    sys.exit(main())
