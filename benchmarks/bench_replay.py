"""Record and replay a debugger session (issue 28's measurement).

    .venv/bin/python benchmarks/bench_replay.py            # `coplanar serve`'s room, 60 s
    .venv/bin/python benchmarks/bench_replay.py --write    # also the table in docs/results/debugger.md

A live debugger on `coplanar serve`'s default input (the rendered room, 60 s), Record ticked
before the first Step, is stepped to the end of the sequence; at every tenth keyframe (5,
15, ...) P-wo is chosen (the window re-optimized) and then PL-w again, as a user comparing
variants would. After each keyframe the benchmark keeps the snapshot shown and what every
panel shows (viewer/screen.py: every tab's text and images, plots included, the status
line, the Shown and Variant fields). The recording is then written to a file and opened in
a second debugger (`coplanar serve --replay FILE`), stepped through, and compared keyframe
for keyframe: the snapshot (every value: backend/pipeline/snapshot_codec.py `same`) and the
panels. Prints the file's size, the time to open it (the whole archive checked) and to show
its first keyframe, and the replay's time per keyframe (median).
"""

from __future__ import annotations

import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import argparse
import pathlib
import platform
import statistics
import sys
import tempfile
import time

ROOT = pathlib.Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "scripts"))
sys.path.insert(0, str(ROOT / "benchmarks"))


def _debugger(engine):
    import socket

    from viewer.app import Debugger

    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    d = Debugger(engine, port=port)
    d.server.scene.configure_environment_map(hdri=None)
    return d


def _settle(d) -> None:
    d.wait_idle(timeout=300)
    d.wait_plots(timeout=120)


def live_session(argv: list[str], *, switch_every: int) -> tuple[list, object, float]:
    """Step `coplanar serve ARGV`'s engine to its end with Record ticked; per keyframe the
    snapshot and the panels; the recorder and the live seconds."""
    from app.cli import build_parser
    from app.serve_command import build_engine
    from viewer.screen import screen_contents

    d = _debugger(build_engine(build_parser().parse_args(["serve", *argv])))
    shown = []
    start = time.perf_counter()
    try:
        d.submit("record", True)
        while True:
            before = d.session.keyframes
            d.submit("step")
            _settle(d)
            if d.session.keyframes == before:  # the end of the sequence
                break
            k = d.shown.keyframe
            if k % switch_every == switch_every // 2:
                for variant in ("P-wo", "PL-w"):
                    d.submit("variant", variant)
                    _settle(d)
            shown.append((d.shown, screen_contents(d, source=d.engine.source)))
            print(f"\rlive: keyframe {k}", end="", file=sys.stderr, flush=True)
    finally:
        d.stop()
    print(file=sys.stderr)
    return shown, d.session.recorder, time.perf_counter() - start


def replay_session(path: pathlib.Path, shown: list) -> dict[str, float]:
    """Open `path` in a replay debugger, step through, compare with `shown`."""
    from backend.pipeline.recording import Recording
    from backend.pipeline.replay_engine import ReplayEngine
    from backend.pipeline.snapshot_codec import same
    from viewer.screen import screen_contents

    t0 = time.perf_counter()
    recording = Recording.open(path)
    opened = time.perf_counter() - t0
    d = _debugger(ReplayEngine(recording))
    steps, snapshots_differ, panels_differ = [], 0, 0
    try:
        for i, (snapshot, contents) in enumerate(shown):
            t = time.perf_counter()
            d.submit("step")
            d.wait_idle(timeout=300)
            steps.append(time.perf_counter() - t)
            if i == 0:
                first = time.perf_counter() - t0
            d.wait_plots(timeout=120)
            snapshots_differ += not same(d.shown, snapshot)
            replayed = screen_contents(d, source=d.engine.source)
            differ = [key for key in contents if replayed.get(key) != contents[key]]
            if differ:
                panels_differ += 1
                print(f"keyframe {snapshot.keyframe}: panels differ: {differ}", file=sys.stderr)
    finally:
        d.stop()
    return {"open_s": opened, "first_shown_s": first, "step_ms": 1000 * statistics.median(steps), "snapshots_differ": snapshots_differ, "panels_differ": panels_differ}


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--duration", type=float, default=60.0, help="seconds of the rendered room (default 60: serve's default)")
    parser.add_argument("--switch-every", type=int, default=10)
    parser.add_argument("--write", action="store_true", help="write the table into docs/results/debugger.md")
    args = parser.parse_args()
    argv = ["--scene", "room"] + ([] if args.duration == 60.0 else ["--duration", f"{args.duration:g}"])
    shown, recorder, live_s = live_session(argv, switch_every=args.switch_every)
    with tempfile.TemporaryDirectory() as folder:
        path = pathlib.Path(folder) / "room.recording.zip"
        t = time.perf_counter()
        recorder.write(path)
        write_s = time.perf_counter() - t
        size = path.stat().st_size
        result = replay_session(path, shown)
    switched = sum(1 for s, _ in shown if s.keyframe % args.switch_every == args.switch_every // 2)
    from bench_speed import cpu_name

    cpu = cpu_name() or platform.machine()
    lines = [
        f"| `coplanar serve --scene room` ({args.duration:g} s), Record ticked before the first Step | |",
        "|---|---|",
        f"| keyframes recorded (P-wo then PL-w chosen at {switched} of them) | {len(shown)} |",
        f"| recording file | {size / 2**20:.1f} MB ({size / len(shown) / 1024:.0f} kB per keyframe) |",
        f"| writing it | {write_s:.2f} s |",
        f"| opening it (every entry's checksum checked) | {result['open_s']:.2f} s |",
        f"| open to the first keyframe shown | {result['first_shown_s']:.2f} s |",
        f"| replay Step, median | {result['step_ms']:.0f} ms |",
        f"| keyframes whose snapshot differs from the live one | {result['snapshots_differ']} of {len(shown)} |",
        f"| keyframes whose panels differ from the live ones | {result['panels_differ']} of {len(shown)} |",
    ]
    body = "\n".join(lines) + f"\n\n`benchmarks/bench_replay.py`, {cpu}, one BLAS thread; the live session took {live_s:.0f} s."
    print(body)
    if args.write:
        from results_doc import write_block

        print(f"wrote {write_block('replay-table', body)}", file=sys.stderr)
    return 1 if result["snapshots_differ"] or result["panels_differ"] else 0


if __name__ == "__main__":
    sys.exit(main())
