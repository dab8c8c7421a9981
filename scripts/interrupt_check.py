"""Interrupt `coplanar run` and `coplanar sweep` at random moments and check what they leave
(issue 29).

    .venv/bin/python scripts/interrupt_check.py                   # 50 on room, 50 on the MH_01 slice
    .venv/bin/python scripts/interrupt_check.py --times 10 --inputs room
    .venv/bin/python scripts/interrupt_check.py --times 20 --inputs sweep-ray sweep-serial

Each trial starts the command as a user would, in a new process group as a terminal starts
it, and at a random moment between its start and the end of an uninterrupted run of the
same input (measured first) sends SIGINT as Ctrl-C does (to the whole group: with Ray, its
raylet and workers get it too) or SIGTERM as `kill PID` does (to the command only). It
checks:
- no traceback on stderr, and the last line of stderr is the command's one line
  ("interrupted: ..."), or the command finished before the signal came;
- `run`: the output folder holds either every file of a run (`backend.headless.run.RUN_FILES`)
  and the exit code is 0, or none of them (no staging folder left either) and the exit code
  is 130: never a partial set, never exit 0 without the whole set;
- `sweep`: each run's folder is complete (its run.json and every run file), the results
  (results.csv, results.json, table.md and the plots) are all there or none, no staging
  folder is left, exit 0 only with every run and the results; and no process of the
  command's group (Ray's raylet, GCS, workers) outlives it by more than a few seconds;
  the same command then resumes and finishes.
A signal in Python's own start-up (the first ~30 ms, before any of the project's code runs:
"Fatal Python error: init_import_site") is outside the project's reach; such trials are
counted apart. Prints one line per trial that fails and a summary per input; exit code 1
if any failed.
"""

from __future__ import annotations

import argparse
import contextlib
import dataclasses
import functools
import os
import pathlib
import random
import re
import signal
import subprocess
import sys
import tempfile
import time

ROOT = pathlib.Path(__file__).resolve().parents[1]
SHARED = ROOT.parent / "shared" / "data"
RUN = ["run", "--variant", "P-wo"]
SWEEP = ["sweep", "--scenes", "room", "--duration", "1", "--variants", "P-wo,PL-w"]
INPUTS = {
    "room": [*RUN, "--scene", "room", "--duration", "2"],
    "mh01": [*RUN, "--dataset", str(SHARED / "euroc_mh01_slice"), "--frames", "40"],
    "sweep-ray": [*SWEEP, "--workers", "2"],
    "sweep-serial": [*SWEEP, "--serial"],
}
RUN_FILES = ("trajectory.txt", "keyframes.txt", "groundtruth.txt", "metrics.json", "map.ply", "points.ply", "lines.ply", "planes.ply", "cameras.ply")
SWEEP_RUNS = ("room_P-wo_stereo_geometric_seed0_1s", "room_PL-w_stereo_geometric_seed0_1s")
SWEEP_RESULTS = ("ate_by_variant.png", "results.csv", "results.json", "table.md", "time_by_stage.png")
ORPHAN_GRACE_S = 10.0  # Ray's processes end within a few seconds of the driver
CLI = ROOT / "app" / "cli.py"


@functools.cache
def _handler_line() -> int:
    """The line of app/cli.py that sets its first signal handler: before it, nothing of the
    project can answer a signal."""
    return next(n for n, line in enumerate(CLI.read_text().splitlines(), start=1) if "signal.signal(signal.SIGINT, _interrupted_while_starting)" in line)


def _before_any_handler(frame: tuple[str, int]) -> bool:
    """A traceback frame of Python's start-up: its frozen modules, code outside the project
    (the standard library, or an import hook a site-packages .pth installed, such as
    setuptools' `_distutils_hack`), or app/cli.py above its first signal handler (importing
    `signal` itself). Any other frame of the project means its handlers were in place."""
    path, line = frame
    if path.startswith("<frozen "):
        return True
    resolved = pathlib.Path(path).resolve()
    if resolved == CLI.resolve():
        return line < _handler_line()
    in_project = resolved.is_relative_to(ROOT) and not resolved.is_relative_to(ROOT / ".venv")
    return not in_project


@dataclasses.dataclass(frozen=True)
class Trial:
    """One interrupted run: when and how, and what it left."""

    at_s: float
    signal_name: str
    returncode: int
    files: tuple[str, ...]
    stderr: str
    sweep: bool = False
    run_folders: dict[str, tuple[str, ...]] = dataclasses.field(default_factory=dict)  # sweep: each run's files
    survivors: tuple[str, ...] = ()  # processes of the command's group still alive after it

    @property
    def in_interpreter_startup(self) -> bool:
        """The signal came while Python itself started, before the project's code could
        answer it: Python's own fatal error, killed by the signal before any handler existed
        (no output), or a KeyboardInterrupt whose traceback holds, of the project, only
        app/cli.py above its first handler (`python -m` importing the package `app`, whose
        __init__ is empty, then app/cli.py importing `signal`)."""
        killed_at_once = self.returncode < 0 and not self.stderr.strip() and self.at_s < 0.1
        frames = [(path, int(line)) for path, line in re.findall(r'^\s*File "([^"]*)", line (\d+)', self.stderr, flags=re.MULTILINE)]
        before_handler = bool(frames) and all(_before_any_handler(f) for f in frames) and self.stderr.strip().endswith("KeyboardInterrupt")
        return not self.files and ("init_import_site" in self.stderr or killed_at_once or before_handler)

    @property
    def problem(self) -> str:
        """Why the trial fails ('' when it passes, or when it came in Python's start-up)."""
        if self.in_interpreter_startup:
            return ""
        if "Traceback" in self.stderr:
            return "a traceback"
        if self.survivors:
            return f"processes outlived it: {list(self.survivors)}"
        if self.sweep:
            return self._sweep_problem()
        outputs = {f for f in self.files if not f.startswith(".")}
        hidden = [f for f in self.files if f.startswith(".")]
        if hidden:
            return f"left {hidden}"
        if outputs and outputs != set(RUN_FILES):
            return f"a partial set: {sorted(outputs)}"
        if self.returncode == 0 and not outputs:
            return "exit 0 without the outputs"
        if self.returncode not in (0, 130):
            return f"exit code {self.returncode}"
        if self.returncode == 130:
            if outputs:
                return "exit 130 with the outputs written"
            last = self.stderr.strip().splitlines()[-1] if self.stderr.strip() else ""
            if not last.startswith("interrupted"):
                return f"last line {last!r}"
        return ""

    def _sweep_problem(self) -> str:
        hidden = [f for f in self.files if f.startswith(".")]
        if hidden:
            return f"left {hidden}"
        partial = {name: files for name, files in self.run_folders.items() if set(files) != {*RUN_FILES, "run.json"}}
        if partial:
            return f"a partial run: {partial}"
        results = {f for f in self.files if f in SWEEP_RESULTS}
        if results and results != set(SWEEP_RESULTS):
            return f"a partial set of results: {sorted(results)}"
        strangers = set(self.files) - set(SWEEP_RESULTS) - set(SWEEP_RUNS)
        if strangers:
            return f"unexpected entries {sorted(strangers)}"
        if self.returncode == 0:
            if set(self.run_folders) != set(SWEEP_RUNS) or not results:
                return "exit 0 without every run and the results"
            return ""
        if self.returncode != 130:
            return f"exit code {self.returncode}"
        last = self.stderr.strip().splitlines()[-1] if self.stderr.strip() else ""
        if not last.startswith("interrupted"):
            return f"last line {last!r}"
        return ""


def start(argv: list[str], out: pathlib.Path) -> subprocess.Popen:
    """`coplanar ARGV --out OUT` (ARGV: a command and its options) in a new process that
    leads a new process group, as a shell starts a command, Ctrl-C acting as in a terminal."""
    env = {**os.environ, "PYTHONDONTWRITEBYTECODE": "1", "OPENBLAS_NUM_THREADS": "1"}
    return subprocess.Popen(
        [sys.executable, "-m", "app.cli", *argv, "--out", str(out)],
        cwd=ROOT,
        env=env,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE,
        text=True,
        process_group=0,
        preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL),
    )


def group_members(group: int) -> list[str]:
    """The processes (pid and name) of process group `group`, from /proc."""
    members = []
    for entry in pathlib.Path("/proc").iterdir():
        if not entry.name.isdigit():
            continue
        try:
            stat = (entry / "stat").read_text()
        except OSError:
            continue
        name, fields = stat[stat.index("(") + 1 : stat.rindex(")")], stat[stat.rindex(")") + 2 :].split()
        if int(fields[2]) == group and fields[0] != "Z":  # fields: state, ppid, pgrp, ...
            members.append(f"{entry.name} {name}")
    return members


def survivors(group: int) -> tuple[str, ...]:
    """Members of `group` still alive ORPHAN_GRACE_S after its leader ended; killed then."""
    deadline = time.monotonic() + ORPHAN_GRACE_S
    while (left := group_members(group)) and time.monotonic() < deadline:
        time.sleep(0.2)
    if left:
        with contextlib.suppress(ProcessLookupError):
            os.killpg(group, signal.SIGKILL)
    return tuple(left)


def full_run_s(argv: list[str], folder: pathlib.Path) -> float:
    """Seconds an uninterrupted run of `argv` takes (a new process, imports included)."""
    t = time.perf_counter()
    process = start(argv, folder / "full")
    _, err = process.communicate(timeout=600)
    if process.returncode != 0:
        raise SystemExit(f"error: the uninterrupted run failed: {err.strip().splitlines()[-1:]}")
    return time.perf_counter() - t


def trial(argv: list[str], folder: pathlib.Path, *, at_s: float, number: int) -> Trial:
    """One run of `argv` signalled `at_s` seconds after its start."""
    out = folder / f"out{number}"
    process = start(argv, out)
    time.sleep(at_s)
    name = "none (finished first)"
    if process.poll() is None:
        if number % 2 == 0:
            name = "SIGINT"
            with contextlib.suppress(ProcessLookupError):
                os.killpg(process.pid, signal.SIGINT)  # Ctrl-C: the terminal signals the whole foreground group
        else:
            name = "SIGTERM"
            process.send_signal(signal.SIGTERM)  # `kill PID`: the command alone
    _, err = process.communicate(timeout=600)
    left = survivors(process.pid)
    files = tuple(sorted(os.listdir(out))) if out.is_dir() else ()
    sweep = argv[0] == "sweep"
    runs = {f: tuple(sorted(os.listdir(out / f))) for f in files if sweep and (out / f).is_dir() and not f.startswith(".")}
    return Trial(at_s=at_s, signal_name=name, returncode=process.returncode, files=files, stderr=err, sweep=sweep, run_folders=runs, survivors=left)


def resumes(argv: list[str], trials: list[Trial], folder: pathlib.Path) -> list[str]:
    """For a sweep: the same command in each interrupted trial's folder finishes (exit 0,
    every run and the results); the folders where it did not, with why."""
    failed = []
    for number, t in enumerate(trials):
        if t.returncode != 130 or t.problem:
            continue
        process = start(argv, folder / f"out{number}")
        _, err = process.communicate(timeout=600)
        files = set(os.listdir(folder / f"out{number}"))
        if process.returncode != 0 or files != {*SWEEP_RUNS, *SWEEP_RESULTS}:
            failed.append(f"out{number}: the resumed sweep gave exit {process.returncode}, {sorted(files)}; {err.strip()[-200:]!r}")
    return failed


def check(name: str, *, times: int, seed: int) -> list[Trial | str]:
    """`times` trials of input `name` at random moments (seeded); the failing ones (and, for
    a sweep, the folders it did not resume in)."""
    argv = INPUTS[name]
    rng = random.Random(seed)
    with tempfile.TemporaryDirectory() as tmp:
        folder = pathlib.Path(tmp)
        span = full_run_s(argv, folder)
        trials = [trial(argv, folder, at_s=rng.uniform(0.0, span), number=i) for i in range(times)]
        not_resumed = resumes(argv, trials, folder) if argv[0] == "sweep" else []
    failed = [t for t in trials if t.problem]
    finished = sum(t.returncode == 0 for t in trials)
    startup = sum(t.in_interpreter_startup for t in trials)
    print(f"{name}: {times} signals over {span:.1f} s: {finished} runs finished first, {times - finished - startup} interrupted, {startup} in Python's own start-up; {len(failed)} failed")
    for t in failed:
        print(f"  at {t.at_s:.2f} s ({t.signal_name}): {t.problem}; exit {t.returncode}; stderr {t.stderr.strip()[-300:]!r}")
    for line in not_resumed:
        print(f"  {line}")
    return [*failed, *not_resumed]


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--times", type=int, default=50)
    parser.add_argument("--inputs", nargs="+", choices=sorted(INPUTS), default=["room", "mh01"])
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()
    failed: list[Trial | str] = []
    for name in args.inputs:
        if name == "mh01" and not (SHARED / "euroc_mh01_slice").is_dir():
            print("mh01: ../shared/data/euroc_mh01_slice is absent, skipped")
            continue
        failed += check(name, times=args.times, seed=args.seed)
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
