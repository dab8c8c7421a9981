"""Regenerate the stereo-pipeline tables (docs/results/pipeline.md; the paper's Tables II and
III on the rendered scenes): every variant on every built-in scene, run exactly as
`coplanar run` runs it (`--duration 30`, seed 0), one run each.

    .venv/bin/python scripts/pipeline_table.py [--duration 30] [--scenes room,corridor,boxes]

Writes docs/pipeline/results.json and replaces the text between the pipeline-table markers in
docs/results/pipeline.md. Per run: keyframe ATE after SE(3) alignment (cm), frames, keyframes,
lost frames, the Table III stages (point D&M per frame; line D&M, plane segmentation, plane
fitting and optimization per keyframe where the variant runs them; total per frame), and the
planes recovered: ground-truth planes that cover at least 5 % of some keyframe's left image,
matched by a map plane within 10° whose patch (the hull of its landmarks) lies within 10 cm of
the true plane (`backend.eval.planes.recovered_planes`; the JSON also keeps the older count by
the offset at the world origin).
"""

from __future__ import annotations

import argparse
import json
import os
import pathlib
import sys
import time

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import numpy as np

ROOT = pathlib.Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "scripts"))

from results_doc import write_block

from backend.eval.planes import recovered_planes
from backend.eval.run_metrics import stereo_timing
from backend.optim.variant import VARIANTS
from backend.pipeline.engine import EndOfSequence
from backend.pipeline.factory import EngineConfig, make_engine

MIN_SHARE = 0.05


def run_one(scene: str, variant: str, duration: float, *, segmenter: str | None = None) -> dict:
    """The headless engine `coplanar run --scene SCENE --variant V --duration D` runs, stepped
    to the end: its figures and the ground-truth planes it recovered."""
    engine = make_engine(EngineConfig(scene=scene, variant=variant, duration_s=duration, segmenter=segmenter))
    steps, lost, snapshot = [], 0, None
    t0 = time.perf_counter()
    while True:
        try:
            snapshot = engine.step()
        except EndOfSequence:
            break
        steps.append((snapshot.tracking.frames, dict(snapshot.report.timing_ms)))
        lost += snapshot.tracking.lost_frames
    wall = time.perf_counter() - t0
    source = engine.data_source
    # Ground-truth planes seen in the keyframes, and those the map recovered.
    frames = np.searchsorted(source.timestamps_ns, snapshot.estimate.timestamp_ns)
    seen: set[int] = set()
    for i in frames:
        ids, counts = np.unique(source.views(int(i))[0].plane_id, return_counts=True)
        seen |= {int(p) for p, c in zip(ids, counts) if p >= 0 and c >= MIN_SHARE * source.camera.width * source.camera.height}
    ids = sorted(seen)
    table = source.plane_table
    est = (np.array([p.n for p in snapshot.planes]).reshape(-1, 3), np.array([p.d for p in snapshot.planes]))
    true = (np.array([table[i][:3] for i in ids]).reshape(-1, 3), np.array([table[i][3] for i in ids]))
    found = recovered_planes(*est, *true, hulls_est_world=[p.hull_world for p in snapshot.planes])
    found_at_origin = recovered_planes(*est, *true)
    return {
        "scene": scene,
        "variant": variant,
        "duration_s": duration,
        "frames": engine.frames,
        "keyframes": engine.keyframes,
        "ate_cm": snapshot.metrics.ate_cm,
        "lost_frames": lost,
        "map_planes": len(snapshot.planes),
        "planes_seen": len(ids),
        "planes_recovered": int(found.sum()),
        "planes_recovered_by_origin_offset": int(found_at_origin.sum()),
        "timing_ms": stereo_timing(steps),
        "wall_s": wall,
    }


def _ms(value: float | None) -> str:
    return "–" if value is None else f"{value:.1f}"


def tables(results: list[dict], scenes: list[str]) -> str:
    by = {(r["scene"], r["variant"]): r for r in results}
    lines = [
        "**Accuracy** (Table II): keyframe ATE after SE(3) alignment (cm), and the ground-truth planes recovered (a map plane within "
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
    parser.add_argument("--duration", type=float, default=30.0)
    parser.add_argument("--scenes", default="room,corridor,boxes")
    parser.add_argument(
        "--no-doc", "--no-readme", dest="no_doc", action="store_true", help="print the tables, leave docs/results/pipeline.md alone (--no-readme: the old name, from when the tables were in README.md)"
    )
    parser.add_argument("--from-json", action="store_true", help="rewrite the tables in docs/results/pipeline.md from docs/pipeline/results.json without running")
    args = parser.parse_args()
    scenes = args.scenes.split(",")
    out = ROOT / "docs" / "pipeline" / "results.json"
    results = json.loads(out.read_text()) if args.from_json else []
    for scene in [] if args.from_json else scenes:
        for variant in VARIANTS:
            r = run_one(scene, variant, args.duration)
            results.append(r)
            print(
                f"{scene:9s} {variant:6s} ATE {r['ate_cm']:6.2f} cm  planes {r['planes_recovered']}/{r['planes_seen']}  "
                f"kf {r['keyframes']:3d}/{r['frames']}  lost {r['lost_frames']}  total/frame {_ms(r['timing_ms']['total_per_frame'])} ms  ({r['wall_s']:.0f} s)",
                flush=True,
            )
    if not args.from_json:
        out.parent.mkdir(parents=True, exist_ok=True)
        out.write_text(json.dumps(results, indent=2) + "\n")
    body = tables(results, scenes)
    if not args.no_doc:
        write_block("pipeline-table", body)
    print(body)
    return 0


if __name__ == "__main__":
    sys.exit(main())
