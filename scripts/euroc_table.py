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
import json
import os
import pathlib
import subprocess
import sys
import tempfile
import time

from results_doc import write_block

ROOT = pathlib.Path(__file__).resolve().parents[1]
VARIANTS = ("P-wo", "P-r", "P-w", "PL-wo", "PL-r", "PL-w")
DEFAULT_DATASET = ROOT.parent / "shared" / "data" / "euroc_mh01_slice"
SWEEP = ROOT / "sweeps" / "euroc_table.toml"  # its datasets: DEFAULT_DATASET


def run_one(source: list[str], variant: str, *, keep: tuple[str, ...] = ()) -> dict:
    """`coplanar run SOURCE --variant V` into a temporary folder, as a user runs it; its
    metrics.json plus the wall time (s) and the text of the written files named in `keep`."""
    with tempfile.TemporaryDirectory() as out:
        t0 = time.perf_counter()
        subprocess.run(
            [str(ROOT / ".venv" / "bin" / "coplanar"), "run", *source, "--variant", variant, "--out", out],
            check=True,
            env={**os.environ, "OPENBLAS_NUM_THREADS": "1"},
            stdout=subprocess.DEVNULL,
            stderr=subprocess.DEVNULL,
        )
        metrics = json.loads((pathlib.Path(out) / "metrics.json").read_text())
        metrics["files"] = {name: (pathlib.Path(out) / name).read_text() for name in keep}
    metrics["wall_s"] = time.perf_counter() - t0
    return metrics


def sweep_runs(config: pathlib.Path, out: pathlib.Path, options: list[str]) -> list[dict] | None:
    """`coplanar sweep --config CONFIG --out OUT OPTIONS`, as a user runs it; every finished
    run's metrics.json plus its wall time (s), in the matrix's order (None: the sweep refused
    its options, having said why on stderr)."""
    process = subprocess.run(
        [sys.executable, "-m", "app.cli", "sweep", "--config", str(config), "--out", str(out), *options], cwd=ROOT, env={**os.environ, "OPENBLAS_NUM_THREADS": "1"}, stdout=subprocess.DEVNULL
    )
    if process.returncode == 2:
        return None
    rows = json.loads((out / "results.json").read_text())
    for row in rows:
        if row["status"] != "ok":
            print(f"failed: {row['run_id']}: {row['error']}", file=sys.stderr)
    return [{**json.loads((out / row["run_id"] / "metrics.json").read_text()), "wall_s": row["wall_s"]} for row in rows if row["status"] == "ok"]


def publish(results: dict | None, body: str, *, json_name: str, block: str, write_doc: bool) -> int:
    """Write `results` to docs/pipeline/JSON_NAME (unless None), put the table `body`
    between `<!-- BLOCK:start -->` and `<!-- BLOCK:end -->` of the docs/results/ page that
    holds them (if `write_doc`; `results_doc.write_block`) and print it; returns 0."""
    if results is not None:
        out = ROOT / "docs" / "pipeline" / json_name
        out.parent.mkdir(parents=True, exist_ok=True)
        out.write_text(json.dumps(results, indent=2) + "\n")
    if write_doc:
        write_block(block, body)
    print(body)
    return 0


def add_no_doc_option(parser: argparse.ArgumentParser, leaves: str) -> None:
    """`--no-doc` (and its old name `--no-readme`): print the table, leave `leaves` alone."""
    parser.add_argument(
        "--no-doc", "--no-readme", dest="no_doc", action="store_true", help=f"print the table, leave {leaves} alone (--no-readme: the old name, from when the tables were in README.md)"
    )


def _f(value: float | None, digits: int = 2) -> str:
    return "–" if value is None else f"{value:.{digits}f}"


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
            f"| {r['variant']} | {_f(r['ate_rmse_cm'])} | {_f(r['ate_sim3_rmse_cm'])} | {_f(r['rpe_cm_per_m'])} | {r['frames_evaluated']} / {r['frames']} "
            f"| {r['keyframes']} | {r['lost_frames']} | {r['reinitializations']} | {_f(t['point_dm'], 1)} | {_f(t['line_dm'], 1)} | {_f(t['plane_seg'], 1)} "
            f"| {_f(t['plane_fit'], 1)} | {_f(t['optimization'], 1)} | {_f(t['total_per_frame'], 1)} |"
        )
    return "\n".join(lines)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--dataset", type=pathlib.Path, default=None, help=f"another EuRoC folder (default: {SWEEP.name}'s, {DEFAULT_DATASET.name})")
    parser.add_argument("--out", type=pathlib.Path, default=None, help="keep the sweep's folder here (default: a temporary folder)")
    run = parser.add_mutually_exclusive_group()
    run.add_argument("--workers", type=int, default=1, help="runs at a time (default 1: the stage times comparable)")
    run.add_argument("--serial", action="store_true", help="in one process, without Ray")
    parser.add_argument("--address", default=None, help="an existing Ray cluster")
    add_no_doc_option(parser, "docs/results/euroc.md")
    args = parser.parse_args()
    options = ["--serial"] if args.serial else ["--workers", str(args.workers)] + (["--address", args.address] if args.address else [])
    if args.dataset is not None:
        options += ["--datasets", str(args.dataset)]
    with tempfile.TemporaryDirectory() as scratch:
        results = sweep_runs(SWEEP, args.out or pathlib.Path(scratch), options)
    if results is None:
        return 2
    for r in results:
        print(
            f"{r['variant']:6s} ATE {_f(r['ate_rmse_cm'])} cm over {r['frames_evaluated']} frames, lost {r['lost_frames']}, "
            f"kf {r['keyframes']}, total/frame {_f(r['timing_ms']['total_per_frame'], 1)} ms ({r['wall_s']:.0f} s)",
            flush=True,
        )
    name = (args.dataset or DEFAULT_DATASET).name
    return publish({"dataset": name, "runs": results}, table(results, name), json_name="euroc.json", block="euroc-table", write_doc=not args.no_doc)


if __name__ == "__main__":
    sys.exit(main())
