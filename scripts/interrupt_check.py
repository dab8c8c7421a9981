"""Interrupt `coplanar run` at random moments and check what it leaves (issue 29).

    .venv/bin/python scripts/interrupt_check.py                   # 50 on room, 50 on the MH_01 slice
    .venv/bin/python scripts/interrupt_check.py --times 10 --inputs room

Each trial starts `coplanar run` as a user would (a new process), sends SIGINT (Ctrl-C) or
SIGTERM (`kill`) at a random moment between its start and the end of an uninterrupted run
of the same input (measured first), and checks:
- no traceback on stderr, and the last line of stderr is the command's one line
  ("interrupted: ..."), or the run finished before the signal came;
- the output folder holds either every file of a run (`backend.headless.run.RUN_FILES`) and
  the exit code is 0, or none of them (no staging folder left either) and the exit code is
  130: never a partial set, never exit 0 without the whole set.
A signal in Python's own start-up (the first ~30 ms, before any of the project's code runs:
"Fatal Python error: init_import_site") is outside the project's reach; such trials are
counted apart. Prints one line per trial that fails and a summary per input; exit code 1
if any failed.
"""

from __future__ import annotations

import argparse
import dataclasses
import os
import pathlib
import random
import signal
import subprocess
import sys
import tempfile
import time

ROOT = pathlib.Path(__file__).resolve().parents[1]
SHARED = ROOT.parent / "shared" / "data"
INPUTS = {
    "room": ["--scene", "room", "--duration", "2"],
    "mh01": ["--dataset", str(SHARED / "euroc_mh01_slice"), "--frames", "40"],
}
RUN_FILES = ("trajectory.txt", "keyframes.txt", "groundtruth.txt", "metrics.json", "map.ply", "points.ply", "lines.ply", "planes.ply", "cameras.ply")


@dataclasses.dataclass(frozen=True)
class Trial:
    """One interrupted run: when and how, and what it left."""

    at_s: float
    signal_name: str
    returncode: int
    files: tuple[str, ...]
    stderr: str

    @property
    def in_interpreter_startup(self) -> bool:
        """The signal came while Python itself started, before the project's code ran: its
        own fatal error, or killed by the signal before any handler existed (no output)."""
        killed_at_once = self.returncode < 0 and not self.stderr.strip() and self.at_s < 0.1
        return not self.files and ("init_import_site" in self.stderr or killed_at_once)

    @property
    def problem(self) -> str:
        """Why the trial fails ('' when it passes, or when it came in Python's start-up)."""
        if self.in_interpreter_startup:
            return ""
        if "Traceback" in self.stderr:
            return "a traceback"
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


def start(argv: list[str], out: pathlib.Path) -> subprocess.Popen:
    """`coplanar run ARGV --variant P-wo --out OUT` in a new process, Ctrl-C acting as in a terminal."""
    env = {**os.environ, "PYTHONDONTWRITEBYTECODE": "1", "OPENBLAS_NUM_THREADS": "1"}
    return subprocess.Popen(
        [sys.executable, "-m", "app.cli", "run", *argv, "--variant", "P-wo", "--out", str(out)],
        cwd=ROOT,
        env=env,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE,
        text=True,
        preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL),
    )


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
    name = "SIGINT"
    if process.poll() is None:
        number_ = signal.SIGINT if number % 2 == 0 else signal.SIGTERM
        name = number_.name
        process.send_signal(number_)
    _, err = process.communicate(timeout=600)
    files = tuple(sorted(os.listdir(out))) if out.is_dir() else ()
    return Trial(at_s=at_s, signal_name=name, returncode=process.returncode, files=files, stderr=err)


def check(name: str, *, times: int, seed: int) -> list[Trial]:
    """`times` trials of input `name` at random moments (seeded); the failing ones."""
    argv = INPUTS[name]
    rng = random.Random(seed)
    with tempfile.TemporaryDirectory() as tmp:
        folder = pathlib.Path(tmp)
        span = full_run_s(argv, folder)
        trials = [trial(argv, folder, at_s=rng.uniform(0.0, span), number=i) for i in range(times)]
    failed = [t for t in trials if t.problem]
    finished = sum(t.returncode == 0 for t in trials)
    startup = sum(t.in_interpreter_startup for t in trials)
    print(f"{name}: {times} signals over {span:.1f} s: {finished} runs finished first, {times - finished - startup} interrupted, {startup} in Python's own start-up; {len(failed)} failed")
    for t in failed:
        print(f"  at {t.at_s:.2f} s ({t.signal_name}): {t.problem}; exit {t.returncode}; stderr {t.stderr.strip()[-300:]!r}")
    return failed


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--times", type=int, default=50)
    parser.add_argument("--inputs", nargs="+", choices=sorted(INPUTS), default=sorted(INPUTS, reverse=True))
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()
    failed = []
    for name in args.inputs:
        if name == "mh01" and not (SHARED / "euroc_mh01_slice").is_dir():
            print("mh01: ../shared/data/euroc_mh01_slice is absent, skipped")
            continue
        failed += check(name, times=args.times, seed=args.seed)
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
