"""Running a sweep's runs: each one by `backend.headless.run_headless` (what `coplanar run`
does) into its own folder `OUT/<run-id>/`, complete or not at all, in this process
(:func:`serial_runs`) or as one Ray task per run (:func:`ray_runs`, within
:func:`ray_session`).

A run's folder is written inside a hidden staging folder of `OUT` and moved into place
whole when its last file (`run.json`: the parameters and the wall time) is written
(`backend.common.atomic.staged_folder`): a folder there is a finished run, which
:func:`run_sweep` does not run again, so a killed sweep resumes where it stopped. A run that
fails (a bad dataset, an exception) leaves no folder and becomes a `failed` row with its
reason; it is tried again by the next sweep of the same folder.
"""

from __future__ import annotations

import contextlib
import dataclasses
import json
import os
import pathlib
import signal
import socket
import sys
import threading
import time
from collections.abc import Callable, Iterator, Sequence
from typing import Any

from backend.sweep import provenance
from backend.sweep.matrix import RunSpec
from backend.sweep.results import FAILED, failed_row, ok_row

RUN_RECORD = "run.json"
Row = dict[str, Any]
Runs = Callable[[Sequence[RunSpec], pathlib.Path], Iterator[tuple[RunSpec, Row]]]


class RayUnavailable(Exception):
    """Ray is not installed, or could not start or reach its cluster: one line."""


@dataclasses.dataclass(frozen=True)
class SweepOutcome:
    """The rows of every run in the matrix's order, and how many ran now, were found
    finished in the folder (`resumed`) and failed."""

    rows: list[Row]
    ran: int
    resumed: int
    failed: int


def execute(spec: RunSpec, out: pathlib.Path) -> Row:
    """Run `spec` in this process into `out / spec.run_id` (complete or not at all) and
    return its row; a failure (any Exception) is a failed row with its one-line reason, not
    an exception. The function each Ray task runs."""
    from backend.common.atomic import staged_folder
    from backend.export.output_frame import TrajectoryFrame
    from backend.headless.run import run_headless

    start = time.perf_counter()
    folder = out / spec.run_id
    try:
        if folder.exists():
            return failed_row(spec, f"{folder} exists but holds no finished run ({RUN_RECORD} missing): move it away to run it again")
        with staged_folder(out) as stage:
            frame = TrajectoryFrame(spec.trajectory_frame)
            result = run_headless(spec.config(), stage / spec.run_id, keyframes=spec.keyframes, dense=spec.dense, trajectory_frame=frame, progress=False)
            record = {"run_id": spec.run_id, "parameters": spec.parameters(), "wall_s": result.wall_s, "provenance": provenance.current().to_dict()}
            (stage / spec.run_id / RUN_RECORD).write_text(json.dumps(record, indent=2) + "\n")
        return ok_row(spec, result.metrics, wall_s=result.wall_s)
    except Exception as e:  # one run's failure is a row of the table, not the sweep's end
        return failed_row(spec, reason(e), wall_s=time.perf_counter() - start)


def reason(error: BaseException) -> str:
    """`error` as one line: its type and its message's first line."""
    lines = str(error).strip().splitlines()
    return f"{type(error).__name__}: {lines[0]}" if lines else type(error).__name__


def finished_row(spec: RunSpec, out: pathlib.Path) -> Row | None:
    """The row of `spec`'s run from its folder in `out` when it is finished (its run.json and
    metrics.json there), else None; a failed row when the folder holds a finished run of
    other parameters (a calibration, topics or segmenter model the folder name does not
    tell), which is kept, not run over."""
    folder = out / spec.run_id
    try:
        record = json.loads((folder / RUN_RECORD).read_text())
        metrics = json.loads((folder / "metrics.json").read_text())
    except (OSError, ValueError):
        return None
    recorded = record.get("parameters") if isinstance(record, dict) else None
    differ = _differing(recorded if isinstance(recorded, dict) else {}, spec.parameters())
    if differ:
        return failed_row(spec, f"{folder} holds a finished run with other {', '.join(differ)}: move it away to run it again")
    return ok_row(spec, metrics, wall_s=float(record["wall_s"]))


def foreign_runs(specs: Sequence[RunSpec], out: pathlib.Path) -> list[str]:
    """The run ids of `specs` whose finished run in `out` was made by other code or on
    another machine than this process (or does not say), as a resumed sweep reuses them."""
    here = provenance.current()
    foreign = []
    for spec in specs:
        if finished_row(spec, out) is None:
            continue
        record = json.loads((out / spec.run_id / RUN_RECORD).read_text())  # finished_row read it
        recorded = provenance.Provenance.from_dict(record.get("provenance") if isinstance(record, dict) else None)
        if recorded is None or recorded.commit != here.commit or recorded.machine() != here.machine():
            foreign.append(spec.run_id)
    return foreign


# Parameters absent from older run.json files, at the value they had then (every window was 10).
_LATER_PARAMETERS = {"window": 10, "keyframes_limit": None, "dense": False, "trajectory_frame": "truth", "topics": None, "segmenter_model": None}
_PATHS = ("input_path", "calib", "segmenter_model")  # compared by name: the same sweep resumes where its files are mounted elsewhere


def _differing(recorded: dict[str, Any], wanted: dict[str, Any]) -> list[str]:
    """The parameters in which a run's run.json (`recorded`) differs from `wanted`; a
    parameter older folders lack counts as its default value; paths count by their name."""

    def value(parameters: dict[str, Any], key: str) -> Any:
        v = parameters.get(key, _LATER_PARAMETERS.get(key))
        return pathlib.PurePath(v).name if key in _PATHS and isinstance(v, str) else v

    return [key for key in wanted if value(recorded, key) != value(wanted, key)]


def serial_runs(specs: Sequence[RunSpec], out: pathlib.Path) -> Iterator[tuple[RunSpec, Row]]:
    """Each run in this process, one after the other (`--serial`)."""
    for spec in specs:
        yield spec, execute(spec, out)


def ray_runs(specs: Sequence[RunSpec], out: pathlib.Path, *, workers: int | None = None) -> Iterator[tuple[RunSpec, Row]]:
    """Each run as a Ray task of one CPU (inside :func:`ray_session`), at most `workers` at
    once (None: as many as Ray schedules), yielded as they finish. A task Ray itself lost (a
    worker killed, out of memory) is a failed row."""
    import ray

    task = ray.remote(num_cpus=1)(execute)
    queue = list(specs)
    pending: dict[Any, RunSpec] = {}
    limit = workers or max(len(queue), 1)
    try:
        while queue or pending:
            while queue and len(pending) < limit:
                spec = queue.pop(0)
                pending[task.remote(spec, out)] = spec
            ready, _ = ray.wait(list(pending), num_returns=1)
            for ref in ready:
                spec = pending.pop(ref)
                try:
                    row = ray.get(ref)
                except ray.exceptions.RayError as e:
                    row = failed_row(spec, f"Ray: {reason(e)}")
                yield spec, row
    finally:
        for ref in pending:
            with contextlib.suppress(Exception):
                ray.cancel(ref, force=True)


@dataclasses.dataclass(frozen=True)
class RayCluster:
    """Where a sweep's tasks run (`where`, for the user) and the CPUs Ray has there."""

    where: str
    cpus: float


@contextlib.contextmanager
def ray_session(*, address: str | None = None, workers: int | None = None) -> Iterator[RayCluster]:
    """A new Ray instance on this machine with `workers` CPUs (None: all of them), or the
    cluster at `address` (`RAY_ADDRESS` when None and set; `auto`: the one `ray start` started
    here); shut down (or disconnected from) after. RayUnavailable (one line) when Ray is
    missing or cannot start or connect."""
    import logging

    try:
        import ray
    except ImportError:
        raise RayUnavailable("Ray is not installed (pip install ray, as pyproject.toml pins it), or run with --serial") from None
    address = address or os.environ.get("RAY_ADDRESS") or None
    options: dict[str, Any] = {"include_dashboard": False, "log_to_driver": False, "logging_level": logging.ERROR}
    if address is None:
        options.update(address="local", num_cpus=workers)  # "local": a new instance, never a stale ray_current_cluster
        where = "Ray on this machine"
    else:
        check_reachable(address)
        options["address"] = address
        where = f"the Ray cluster at {address}"
    try:
        _init_whole(ray, options)
    except Exception as e:  # ConnectionError, RuntimeError, ValueError: Ray's reasons vary
        raise RayUnavailable(f"cannot start {where}: {reason(e)} (--serial runs without Ray)") from None
    try:
        yield RayCluster(where=where, cpus=float(ray.cluster_resources().get("CPU", 0.0)))
    finally:
        _shutdown_whole(ray)


def _init_whole(ray: Any, options: dict[str, Any]) -> None:
    """`ray.init(**options)` with SIGINT and SIGTERM held until it has returned, then raised
    as KeyboardInterrupt after Ray is shut down again: interrupted half-way, Ray left its
    processes running (its dashboard and runtime-env agents outlived the command). Ray's own
    SIGTERM handler (it ends the driver at once, exit 15, no line) is kept out: Ray sets it
    through `ray._private.utils.set_sigterm_handler`, which is a no-op while it starts."""
    from backend.common.optional import interrupts_held

    utils: Any = getattr(getattr(ray, "_private", None), "utils", None)
    setter = getattr(utils, "set_sigterm_handler", None)
    handlers = _signal_handlers()
    try:
        with interrupts_held():
            if setter is not None:
                utils.set_sigterm_handler = lambda handler: None
            try:
                ray.init(**options)
            finally:
                if setter is not None:
                    utils.set_sigterm_handler = setter
    except KeyboardInterrupt:
        _shutdown_whole(ray)
        raise
    finally:
        _restore(handlers)  # what the command set, whatever Ray set meanwhile


def _shutdown_whole(ray: Any) -> None:
    """`ray.shutdown()` with SIGINT and SIGTERM held until it has returned (interrupted, it
    left Ray's processes running), then raised as KeyboardInterrupt. Ray's core worker, as it
    goes, resets SIGTERM's action to the default (with SIGSEGV's, SIGABRT's ...): a `kill`
    in the second Ray then spends ending its processes killed the command outright (exit
    -15, no line, a worker's half-written run left). The holding handlers are put back as
    soon as the core worker has gone, before Ray ends its processes
    (`Node.kill_all_processes`), and the command's after."""
    from backend.common.optional import interrupts_held

    node = getattr(getattr(getattr(ray, "_private", None), "worker", None), "_global_node", None)
    kill_all = getattr(node, "kill_all_processes", None)
    with interrupts_held():
        if node is not None and kill_all is not None:

            def kill_with_handlers(*args: Any, **kwargs: Any) -> Any:
                _restore(_signal_handlers())  # the holding handlers, as Python still knows them
                return kill_all(*args, **kwargs)

            node.kill_all_processes = kill_with_handlers
        ray.shutdown()


def _signal_handlers() -> dict[int, Any]:
    """SIGINT's and SIGTERM's handlers now (main thread only: elsewhere none are set)."""
    if threading.current_thread() is not threading.main_thread():
        return {}
    return {number: signal.getsignal(number) for number in (signal.SIGINT, signal.SIGTERM)}


def _restore(handlers: dict[int, Any]) -> None:
    for number, handler in handlers.items():
        if handler is not None:
            signal.signal(number, handler)


def check_reachable(address: str, *, timeout_s: float = 5.0) -> None:
    """RayUnavailable at once when `address` (`HOST:PORT`, `ray://HOST:PORT`) names a port
    nothing answers on within `timeout_s` seconds: Ray itself retries for minutes. Other forms
    (`auto`) are Ray's to judge."""
    host, sep, port = address.split("://", 1)[-1].rpartition(":")
    if not sep or not host or not port.isdigit():
        return
    try:
        socket.create_connection((host.strip("[]"), int(port)), timeout=timeout_s).close()
    except OSError as e:
        raise RayUnavailable(f"cannot reach the Ray cluster at {address}: {e.strerror or e} (--serial runs without Ray)") from None


def run_sweep(specs: Sequence[RunSpec], out: pathlib.Path, *, runs: Runs, progress: bool = True, on_row: Callable[[Row], None] | None = None) -> SweepOutcome:
    """Every run of `specs` that has no finished folder in `out`, through `runs`
    (:func:`serial_runs` or :func:`ray_runs`), with a progress bar on stderr (tqdm: runs done,
    ETA; drawn on a terminal only) and `on_row` called with each new row; the rows of all
    runs, the finished ones read back from their folders."""
    from tqdm import tqdm

    rows: dict[str, Row | None] = {spec.run_id: finished_row(spec, out) for spec in specs}
    todo = [spec for spec in specs if rows[spec.run_id] is None]
    failed = 0
    with tqdm(total=len(specs), initial=len(specs) - len(todo), desc="sweep", unit="run", file=sys.stderr, disable=None if progress else True, dynamic_ncols=True) as bar:
        for spec, row in runs(todo, out):
            rows[spec.run_id] = row
            failed += row["status"] == FAILED
            bar.update(1)
            bar.set_postfix(failed=failed, refresh=False)
            if on_row is not None:
                on_row(row)
    final = [rows[spec.run_id] for spec in specs]
    assert all(row is not None for row in final)
    return SweepOutcome(rows=[row for row in final if row is not None], ran=len(todo), resumed=len(specs) - len(todo), failed=sum(row["status"] == FAILED for row in final if row is not None))
