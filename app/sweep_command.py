"""`coplanar sweep`: a matrix of headless runs as one command (DESIGN §7), on this machine's
cores or a Ray cluster.

The matrix comes from options (`--scenes room,corridor --variants all --modes stereo,vio
--seeds 0-4`) or a TOML file with the same names as keys (`--config sweep.toml`; options given
besides take the file's place for their axis); `backend.sweep.matrix` checks and spans it.
Each run is `coplanar run`'s (`backend.headless.run_headless`) in its own folder
`--out DIR/<run-id>/`, complete or not at all; one Ray task per run (`ray.init()` on this
machine, `--workers N` CPUs at most; `--address` an existing cluster, whose nodes must all see
DIR), or all in this process with `--serial`. Folders of finished runs are kept and not run
again: the same command resumes a killed sweep. Then DIR gets `results.csv`, `results.json`
(one row per run: parameters, figures, times, status), `table.md` (the paper's Table II
shape) and the plots `ate_by_variant.png` and `time_by_stage.png`.

Exit code 0 when every run finished, 1 when some failed (each a row with its reason), 2 for
bad options (one line, nothing run).
"""

from __future__ import annotations

import argparse
import contextlib
import functools
import pathlib
import sys
from typing import Any

AXIS_OPTIONS = {
    "scenes": (
        "NAME,...",
        "rendered scenes: room, corridor, boxes, the stress scenes street, shake, slow-start, low-texture, exposure, or scene files "
        "(default: the three standard scenes room, corridor, boxes unless --datasets)",
    ),
    "datasets": ("PATH,...", "recorded datasets (any format `coplanar run --dataset` reads)"),
    "variants": ("all|V,...", "parametrizations (default all)"),
    "modes": ("stereo,vio", "pipelines (default stereo)"),
    "segmenters": ("KIND,...", "geometric, learned, oracle (default: each mode's own)"),
    "seeds": ("0-4|N,...", "seeds: numbers and ranges (default 0)"),
    "speeds": ("F,...", "rendered scenes: motion speeds (default 1)"),
    "strides": ("N,...", "rendered scenes: keep every N-th frame (default 1)"),
    "windows": ("N,...", "keyframes optimized per step, as run's --window (default 10 in stereo, 20 in VIO)"),
    "duration": ("SECONDS", "rendered scenes: seconds of motion (default 30)"),
    "frames": ("N", "only the first N frames of every input (default all)"),
    "keyframes": ("N", "stop every run after N keyframes, as run's --keyframes (default: at the end)"),
    "trajectory_frame": ("truth|camera", "what the written trajectories are poses of, as run's --trajectory-frame (default truth)"),
    "calib": ("PATH", "datasets that hold no calibration (ROS bags): read with this one, as run's --calib"),
    "topics": ("NAME=TOPIC,...", "ROS bags: read cam0, cam1, imu0, groundtruth from these topics, as run's --topic"),
    "segmenter_model": ("FILE.onnx", "the learned segmenter's model, as run's --segmenter-model (default the shipped one)"),
}
OUTPUTS = ("results.csv", "results.json", "table.md", "ate_by_variant.png", "time_by_stage.png")
#: Seconds an interrupted sweep waits for Ray's workers to end before it removes what they half wrote.
STAGING_WAIT_S = 5.0


def add_parser(sub: argparse._SubParsersAction) -> None:
    from app.options import name_or_path, path

    p = sub.add_parser("sweep", help="run a matrix of runs (inputs × variants × modes × seeds ...) on Ray or --serial; write every run's folder, results.csv, results.json, table.md and plots")
    p.add_argument(
        "--config", "--matrix", dest="config", type=path, default=None, metavar="FILE.toml", help="the matrix as TOML (keys: the axis options' names); axis options given besides replace its axes"
    )
    for name, (metavar, text) in AXIS_OPTIONS.items():
        p.add_argument(f"--{name.replace('_', '-')}", dest=name, type=name_or_path, default=None, metavar=metavar, help=text)
    p.add_argument("--dense", action="store_const", const=True, default=None, help="image inputs: also fuse each run's keyframes into mesh.ply, as run's --dense")
    p.add_argument("--out", required=True, type=path, help="the sweep's folder: one folder per run and the results (created if missing; a finished run there is not run again)")
    p.add_argument("--address", default=None, metavar="RAY_ADDRESS", help="run on this existing Ray cluster (e.g. ray://head:10001 or auto); every node must see --out")
    p.add_argument("--workers", type=int, default=None, metavar="N", help="at most N runs at once (on this machine: Ray's CPUs; default all cores)")
    p.add_argument("--serial", action="store_true", help="run in this process one after the other, without Ray (same runs, same results)")
    p.add_argument("--dry-run", action="store_true", help="list the runs (and which are finished) without running them")
    p.set_defaults(run=run)


def matrix_runs(args: argparse.Namespace) -> list[Any]:
    """The runs of `--config` and the axis options; UsageError (one line) for a bad value."""
    from app.errors import UsageError
    from backend.sweep.matrix import MatrixError, matrix_from, read_toml

    given = {name: getattr(args, name) for name in (*AXIS_OPTIONS, "dense") if getattr(args, name, None) is not None}
    try:
        file_values = read_toml(args.config) if args.config is not None else None
        return matrix_from(file_values, given, file=args.config).runs()
    except MatrixError as e:
        raise UsageError(str(e)) from None


def _check_execution(args: argparse.Namespace) -> None:
    from app.errors import UsageError

    if args.serial and (args.address is not None or args.workers is not None):
        raise UsageError(f"--serial: runs in this process, not with {'--address' if args.address is not None else '--workers'}")
    if args.workers is not None and args.workers < 1:
        raise UsageError(f"--workers {args.workers}: must be at least 1")
    if args.address is not None and not args.address.strip():
        raise UsageError("--address: empty")


def _print_row(row: dict[str, Any]) -> None:
    from tqdm import tqdm

    if row["status"] != "ok":
        tqdm.write(f"failed {row['run_id']}: {row['error']}", file=sys.stdout)
    else:
        ate = "n/a" if row["ate_rmse_cm"] is None else f"{row['ate_rmse_cm']:.2f} cm"
        tqdm.write(f"ok     {row['run_id']}: ATE {ate}, {row['lost_frames']} lost frames, {row['keyframes']} keyframes, {row['wall_s']:.1f} s", file=sys.stdout)
    sys.stdout.flush()  # a line per run as it ends, also into a file or a pipe


def run(args: argparse.Namespace) -> int:
    from app.errors import UsageError
    from backend.common.atomic import remove_stale_staging
    from backend.sweep.provenance import current
    from backend.sweep.runner import RayUnavailable, Runs, finished_row, foreign_runs, ray_runs, ray_session, run_sweep, serial_runs

    _check_execution(args)
    specs = matrix_runs(args)
    out: pathlib.Path = args.out
    if args.dry_run:
        for spec in specs:
            print(f"{'finished' if finished_row(spec, out) is not None else 'to run':8s} {spec.run_id}")
        return 0
    try:
        with contextlib.ExitStack() as stack:
            if args.serial:
                runs: Runs = serial_runs
                where = "in this process (--serial)"
            else:
                cluster = stack.enter_context(ray_session(address=args.address, workers=args.workers))  # before --out is made
                runs = functools.partial(ray_runs, workers=args.workers)
                where = f"on {cluster.where} ({cluster.cpus:g} CPUs)"
            _prepare(out)
            print(f"sweep: {len(specs)} runs {where}, into {out}", file=sys.stderr)
            foreign = foreign_runs(specs, out)
            if foreign:
                here = current()
                print(
                    f"note: {len(foreign)} finished runs in {out} were made by other code or on another machine than {here.commit or 'this code'} on {here.machine()}"
                    f" (or do not say), e.g. {foreign[0]}: they are reused as they are; move them away to run them again",
                    file=sys.stderr,
                )
            outcome = run_sweep(specs, out, runs=runs, on_row=_print_row)
    except RayUnavailable as e:
        raise UsageError(str(e)) from None
    except KeyboardInterrupt:
        if out.is_dir():  # Ray's workers, ended with the cluster, leave their half-written runs
            remove_stale_staging(out, wait_s=STAGING_WAIT_S)
        raise KeyboardInterrupt(f"the finished runs are in {out}; the same command resumes there") from None
    _write_results(out, outcome.rows)
    print(f"{len(specs)} runs: {outcome.ran} ran, {outcome.resumed} already finished, {outcome.failed} failed; wrote {out}/{', '.join(OUTPUTS)}")
    return 1 if outcome.failed else 0


def _prepare(out: pathlib.Path) -> None:
    from app.errors import UsageError
    from backend.headless.run import OutputError, prepare_out

    try:
        prepare_out(out)
    except OutputError as e:
        raise UsageError(f"--out {e}") from None


def _write_results(out: pathlib.Path, rows: list[dict[str, Any]]) -> None:
    """results.csv, results.json, table.md and the plots: written in a staging folder and
    moved into `out` together (an interruption meanwhile leaves the older set or none)."""
    from backend.common.atomic import staged_folder, write_text_atomic
    from backend.sweep.plots import write_plots
    from backend.sweep.results import write_results
    from backend.sweep.table import table_markdown

    with staged_folder(out) as stage:
        write_results(stage, rows)
        write_text_atomic(stage / "table.md", table_markdown(rows))
        write_plots(stage, rows)
