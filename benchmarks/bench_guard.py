"""Benchmarks of the debugger's websocket guard (viewer/guard.py, viewer/inbound.py).

    .venv/bin/python benchmarks/bench_guard.py burst      # N Step clicks at once, then Reset
    .venv/bin/python benchmarks/bench_guard.py check      # the cost of checking one frame

burst: the debugger on `--scene` (default room, the stereo pipeline `coplanar serve` runs)
takes one step to warm up; then a raw websocket client sends `--clicks` Step clicks and
`--keys` → key presses at once, then Reset. Prints the seconds from the Reset click until
the debugger says "reset" and the steps that ran in between, per run and their median.

check: `InboundFilter.check` on a camera message and on a GUI value (the two a browser sends
most), against a debugger's real controls; microseconds per frame, median of `--runs`.
"""

from __future__ import annotations

import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import argparse
import pathlib
import platform
import statistics
import sys
import time

import msgspec

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parents[1]))  # the raw client of the tests
from tests.viewer.raw_client import CAMERA, RawClient, free_port


def _debugger(scene: str):
    from app.serve_command import DEFAULT_DURATION_S
    from backend.pipeline.factory import EngineConfig, make_engine
    from viewer.app import Debugger

    d = Debugger(make_engine(EngineConfig(scene=scene, duration_s=DEFAULT_DURATION_S, interactive=True)), port=free_port())
    d.server.scene.configure_environment_map(hdri=None)
    return d


def burst(args: argparse.Namespace) -> None:
    took, ran = [], []
    for run in range(args.runs):
        d = _debugger(args.scene)
        try:
            d.submit("step")
            d.wait_idle(timeout=300)
            with RawClient(d.port) as client:
                time.sleep(0.5)  # the camera message handled: the client counts as connected
                step, reset = client.uuid("Step"), client.uuid("Reset")
                step_key = client.command("Step")
                before = d.steps_done
                for _ in range(args.clicks):
                    client.click(step)
                for _ in range(args.keys):
                    client.send("CommandTriggerMessage", uuid=step_key)
                client.click(reset)
                t0 = time.monotonic()
                while "reset" not in d.status.content:
                    if time.monotonic() - t0 > args.limit:
                        break
                    time.sleep(0.01)
                took.append(time.monotonic() - t0)
                ran.append(d.steps_done - before)
            print(f"run {run}: Reset done {took[-1]:.2f} s after its click; {ran[-1]} of {args.clicks + args.keys} requested steps ran", flush=True)
        finally:
            d.stop()
    print(
        f"burst on {args.scene}: {args.clicks} clicks + {args.keys} keys, then Reset: median {statistics.median(took):.2f} s to reset, "
        f"{statistics.median(ran):g} steps ran (median of {args.runs}; {platform.processor() or platform.machine()}, one BLAS thread)"
    )


def check(args: argparse.Namespace) -> None:
    from backend.pipeline.sim_engine import SimEngine, SimSettings
    from viewer.app import Debugger, ViewerSettings

    d = Debugger(SimEngine(SimSettings(window=4, max_iterations=2)), port=free_port(), settings=ViewerSettings(compare=False, plots=False))
    try:
        with RawClient(d.port) as client:
            time.sleep(0.3)
            frames = {
                "camera": msgspec.msgpack.encode({"type": "ViewerCameraMessage", **CAMERA}),
                "slider value": msgspec.msgpack.encode({"type": "GuiUpdateMessage", "uuid": client.uuid("Rate (Hz)"), "updates": {"value": 7.5}}),
                "refused value": msgspec.msgpack.encode({"type": "GuiUpdateMessage", "uuid": client.uuid("Rate (Hz)"), "updates": {"value": float("nan")}}),
                "garbage": b"\xc1" * 64,
            }
            for name, frame in frames.items():
                times = []
                for _ in range(args.runs):
                    t0 = time.perf_counter()
                    for _ in range(args.frames):
                        d.guard.inbound.check(0, frame)
                    times.append((time.perf_counter() - t0) / args.frames * 1e6)
                print(f"{name:>14}: {statistics.median(times):6.1f} µs per frame (median of {args.runs} x {args.frames})")
    finally:
        d.stop()


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = parser.add_subparsers(dest="what", required=True)
    b = sub.add_parser("burst")
    b.add_argument("--scene", default="room")
    b.add_argument("--clicks", type=int, default=200)
    b.add_argument("--keys", type=int, default=60)
    b.add_argument("--runs", type=int, default=3)
    b.add_argument("--limit", type=float, default=600.0, help="give up waiting for the reset after this many seconds")
    c = sub.add_parser("check")
    c.add_argument("--frames", type=int, default=2000)
    c.add_argument("--runs", type=int, default=5)
    args = parser.parse_args()
    {"burst": burst, "check": check}[args.what](args)


if __name__ == "__main__":
    main()
