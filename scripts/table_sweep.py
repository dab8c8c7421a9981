"""What the table scripts share: each runs its matrix as a sweep (a file in `sweeps/`, run as a
user runs it: `coplanar sweep --config sweeps/NAME.toml --out DIR`), reads every finished run's
`metrics.json`, and writes its table into a docs/results/ page (`results_doc.write_block`)
and its figures into docs/pipeline/ (or docs/vio/).

The options every table script takes: `--out DIR` keeps the sweep's folder (a second call with
it runs only what is not finished there; default a temporary folder), `--workers N` (default
1: one run at a time, so that the stage times are comparable), `--serial` (in one process,
without Ray), `--address ADDR` (an existing Ray cluster), `--no-doc` (print the table only:
the docs/results/ page and the docs/pipeline/ JSON stay as they are).
"""

from __future__ import annotations

import argparse
import json
import os
import pathlib
import subprocess
import sys
import tempfile
from collections.abc import Sequence

from results_doc import write_block

ROOT = pathlib.Path(__file__).resolve().parents[1]
SWEEPS = ROOT / "sweeps"
SHARED_DATA = ROOT.parent / "shared" / "data"


def add_sweep_options(parser: argparse.ArgumentParser, *, page: str) -> None:
    """`--out`, `--workers` | `--serial`, `--address` and `--no-doc` (leaving `page` alone)."""
    parser.add_argument("--out", type=pathlib.Path, default=None, help="keep the sweep's folder here (default: a temporary folder)")
    run = parser.add_mutually_exclusive_group()
    run.add_argument("--workers", type=int, default=1, help="runs at a time (default 1: the stage times comparable)")
    run.add_argument("--serial", action="store_true", help="in one process, without Ray")
    parser.add_argument("--address", default=None, help="an existing Ray cluster")
    add_no_doc_option(parser, page)


def add_no_doc_option(parser: argparse.ArgumentParser, leaves: str) -> None:
    """`--no-doc` (and its old name `--no-readme`): print the table, leave `leaves` alone."""
    parser.add_argument(
        "--no-doc", "--no-readme", dest="no_doc", action="store_true", help=f"print the table, leave {leaves} alone (--no-readme: the old name, from when the tables were in README.md)"
    )


def execution(args: argparse.Namespace) -> list[str]:
    """The sweep options of `--workers` / `--serial` / `--address`."""
    if args.serial:
        return ["--serial"]
    return ["--workers", str(args.workers)] + (["--address", args.address] if args.address else [])


def axis_options(given: dict[str, str | None]) -> list[str]:
    """The sweep options `{"--seeds": "2-4", "--scenes": None, ...}` as arguments, those given
    (not None) only."""
    return [item for option, value in given.items() if value is not None for item in (option, value)]


def sweep_runs(config: pathlib.Path, args: argparse.Namespace, options: Sequence[str] = (), *, keep: tuple[str, ...] = (), failed: list[dict] | None = None) -> list[dict]:
    """`coplanar sweep --config CONFIG --out OUT OPTIONS` (OUT: `args.out` or a temporary
    folder), as a user runs it; every finished run's metrics.json with its results row
    (`row`: the run's parameters), its wall time (`wall_s`), where it was made
    (`provenance`: commit, CPU and BLAS kernels from its run.json, None for runs from before
    they were kept) and, where `keep` names files, their text (`files`), in the matrix's
    order. Failed runs are printed to stderr and left out; exits 2 where the sweep refused
    its options (it said why)."""
    with tempfile.TemporaryDirectory() as scratch:
        out = args.out or pathlib.Path(scratch)
        command = [sys.executable, "-m", "app.cli", "sweep", "--config", str(config), "--out", str(out), *execution(args), *options]
        process = subprocess.run(command, cwd=ROOT, env={**os.environ, "OPENBLAS_NUM_THREADS": "1"}, stdout=subprocess.DEVNULL)
        if process.returncode == 2:
            raise SystemExit(2)
        runs = []
        for row in json.loads((out / "results.json").read_text()):
            if row["status"] != "ok":
                print(f"failed: {row['run_id']}: {row['error']}", file=sys.stderr)
                if failed is not None:
                    failed.append(row)
                continue
            folder = out / row["run_id"]
            metrics = json.loads((folder / "metrics.json").read_text())
            record = json.loads((folder / "run.json").read_text())
            run = {**metrics, "row": row, "wall_s": row["wall_s"], "provenance": record.get("provenance")}
            if keep:
                run["files"] = {name: (folder / name).read_text() for name in keep}
            runs.append(run)
    return runs


def publish(results: dict | None, body: str, *, json_name: str, block: str, write_doc: bool) -> int:
    """Print the table `body`; if `write_doc`, write `results` to docs/pipeline/JSON_NAME
    (unless None) and put `body` between `<!-- BLOCK:start -->` and `<!-- BLOCK:end -->` of
    the docs/results/ page that holds it (`results_doc.write_block`). Returns 0. An
    experiment (`--no-doc`, often a subset of the matrix) leaves both published files as
    they are (its runs stay in its `--out` folder)."""
    if write_doc and results is not None:
        out = ROOT / "docs" / "pipeline" / json_name
        out.parent.mkdir(parents=True, exist_ok=True)
        out.write_text(json.dumps(results, indent=2) + "\n")
    if write_doc:
        write_block(block, body)
    print(body)
    return 0


def f(value: float | None, digits: int = 2) -> str:
    """A figure with `digits` decimals; – for none."""
    return "–" if value is None else f"{value:.{digits}f}"
