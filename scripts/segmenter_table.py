"""What the learned segmenter does to the stereo pipeline: PL-w with `--segmenter geometric`
and `--segmenter learned` on the rendered scenes (keyframe ATE, ground-truth planes
recovered, plane segmentation time per keyframe) and on the real MH_01 slice (ATE over all
frames, planes in the map), one run each, as `coplanar run` runs them.

    .venv/bin/python scripts/segmenter_table.py [--duration 30] [--variant PL-w]

Writes docs/pipeline/segmenter.json and replaces the segmenter-table block of
docs/results/segmenter.md.
"""

from __future__ import annotations

import argparse
import sys

from euroc_table import DEFAULT_DATASET, _f, add_no_doc_option, publish
from euroc_table import run_one as run_dataset
from pipeline_table import run_one as run_scene


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--duration", type=float, default=30.0)
    p.add_argument("--variant", default="PL-w")
    p.add_argument("--scenes", default="room,corridor,boxes")
    add_no_doc_option(p, "docs/results/segmenter.md")
    args = p.parse_args()
    rows, runs = [], []
    for scene in args.scenes.split(","):
        for kind in ("geometric", "learned"):
            r = run_scene(scene, args.variant, args.duration, segmenter=kind)
            runs.append({"input": scene, "segmenter": kind, **r})
            t = r["timing_ms"]
            rows.append(f"| {scene} | {kind} | {_f(r['ate_cm'])} | {r['planes_recovered']}/{r['planes_seen']} | {r['map_planes']} | {_f(t['plane_seg'], 1)} | {r['lost_frames']} |")
            print(rows[-1], flush=True)
    if DEFAULT_DATASET.is_dir():
        for kind in ("geometric", "learned"):
            r = run_dataset(["--dataset", str(DEFAULT_DATASET), "--segmenter", kind], args.variant)
            r.pop("files")
            runs.append({"input": DEFAULT_DATASET.name, "segmenter": kind, **r})
            rows.append(f"| {DEFAULT_DATASET.name} (real) | {kind} | {_f(r['ate_rmse_cm'])} (all frames) | – | {r['planes']} | {_f(r['timing_ms']['plane_seg'], 1)} | {r['lost_frames']} |")
            print(rows[-1], flush=True)
    body = "\n".join(
        [
            f"{args.variant}, one run each (`.venv/bin/python scripts/segmenter_table.py`): ATE after SE(3) alignment (cm; rendered scenes over keyframes, "
            "the real slice over every frame), ground-truth planes recovered (within 10°, the map plane's patch within 10 cm; planes covering ≥ 5 % of some keyframe), "
            "planes in the final map, plane segmentation per keyframe (ms), lost frames.",
            "",
            "| input | segmenter | ATE | planes recovered | map planes | plane seg. ms | lost |",
            "|---|---|---|---|---|---|---|",
            *rows,
        ]
    )
    return publish({"variant": args.variant, "runs": runs}, body, json_name="segmenter.json", block="segmenter-table", write_doc=not args.no_doc)


if __name__ == "__main__":
    sys.exit(main())
