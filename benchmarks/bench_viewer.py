"""Benchmarks of the debugger served to headless Chromium (issue 3's measurements).

    .venv/bin/python benchmarks/bench_viewer.py latency   # Step click -> updated scene
    .venv/bin/python benchmarks/bench_viewer.py points    # a 100k-point map
    .venv/bin/python benchmarks/bench_viewer.py memory    # server RSS over 1000 steps
    .venv/bin/python benchmarks/bench_viewer.py switch    # choosing a variant -> its result shown

latency: the debugger on Monte-Carlo sequence a, warmed up by `--warmup` keyframes (the
window full, the map grown); then `--clicks` clicks on Step, each timed inside the page
from the click to the moment the "Shown" field changes (the server sets it last, in the
same atomic update as the scene, so the scene has arrived), and to the next rendered
animation frame after it.

points: a snapshot whose map holds `--points` points (the real snapshot's other layers
kept) is drawn and sent; reports the server-side draw time, the time until the browser
has it, and Step latency while it is shown.

switch: after `--warmup` keyframes, `--clicks` rounds of: a Step (not timed), then a
variant chosen in the page's Variant menu (one not yet computed at that keyframe: the window
re-optimized) and PL-w chosen again (kept: shown without recomputing), each timed from the
choice to the "Shown" field naming it; `--pause` ms before each choice.

memory: `--steps` engine steps through the debugger (every snapshot drawn, the history
capped at its default) with one browser tab connected; prints the server's resident set
size every 100 steps. The server runs in a process of its own, as `coplanar serve` does
(this script starts it again as `memory-server` and drives the page from here): the
browser driver's client and the test helpers' imports are not the server's memory.
"""

from __future__ import annotations

import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import argparse
import dataclasses
import pathlib
import platform
import statistics
import subprocess
import sys
import time

import numpy as np

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parents[1]))  # the project and the browser test helpers
from tests.viewer.raw_client import free_port  # without pytest, which the server does not load

# Click Step and wait (in the page) until the "Shown" field differs from its old value;
# returns [ms to the field change, ms to the next animation frame after it].
_CLICK_JS = """
async () => {
  const label = [...document.querySelectorAll('label')].find(l => l.textContent === 'Shown');
  const input = label.closest('.mantine-Flex-root').querySelector('input');
  const button = [...document.querySelectorAll('button')].find(b => b.textContent === 'Step');
  const old = input.value;
  const t0 = performance.now();
  button.click();
  while (input.value === old) { await new Promise(r => setTimeout(r, 1)); }
  const t1 = performance.now();
  await new Promise(r => requestAnimationFrame(() => r()));
  return [t1 - t0, performance.now() - t0];
}
"""


# Wait (in the page) until the "Shown" field reads `expected`.
_WAIT_JS = """
async (expected) => {
  const label = [...document.querySelectorAll('label')].find(l => l.textContent === 'Shown');
  const input = label.closest('.mantine-Flex-root').querySelector('input');
  while (input.value !== expected) { await new Promise(r => setTimeout(r, 1)); }
}
"""


def _rss_mib() -> float:
    with open("/proc/self/status") as f:
        for line in f:
            if line.startswith("VmRSS:"):
                return int(line.split()[1]) / 1024.0
    return float("nan")


def _rollup_mib() -> dict[str, float]:
    """This process's /proc/self/smaps_rollup, MiB by field (empty where there is none)."""
    try:
        with open("/proc/self/smaps_rollup") as f:
            return {line.split(":")[0]: int(line.split()[1]) / 1024.0 for line in f if line.rstrip().endswith("kB")}
    except OSError:
        return {}


def _summary(values: list[float]) -> str:
    v = sorted(values)
    return f"median {statistics.median(v):.1f} ms, p90 {v[int(0.9 * (len(v) - 1))]:.1f} ms, min {v[0]:.1f}, max {v[-1]:.1f} (n={len(v)})"


def _clicks(page, n: int, *, pause_ms: float = 0.0) -> tuple[list[float], list[float]]:
    updated, rendered = [], []
    for _ in range(n):
        if pause_ms > 0:
            page.wait_for_timeout(pause_ms)  # the user looks at the keyframe before the next click
        a, b = page.evaluate(_CLICK_JS)
        updated.append(a)
        rendered.append(b)
    return updated, rendered


def _room_debugger(*, duration_s: float | None = None, history_mb: float | None = None):
    """The debugger on the stereo pipeline over the rendered room (as `coplanar serve`)."""
    from app.serve_command import DEFAULT_DURATION_S
    from backend.common.allocator import limit_arenas

    limit_arenas()  # as `coplanar serve` does before the engine's threads start
    from backend.pipeline.factory import EngineConfig, make_engine
    from viewer.app import Debugger
    from viewer.settings import ViewerSettings

    engine = make_engine(EngineConfig(scene="room", duration_s=duration_s or DEFAULT_DURATION_S, interactive=True))
    settings = ViewerSettings() if history_mb is None else ViewerSettings(history_mb=history_mb)
    debugger = Debugger(engine, port=free_port(), settings=settings)
    debugger.server.scene.configure_environment_map(hdri=None)
    return debugger


def bench_latency(browser, args: argparse.Namespace) -> None:
    from tests.browser.conftest import open_page, start_debugger, wait_shown

    debugger = _room_debugger() if args.scene == "room" else start_debugger(sequence=args.sequence)
    try:
        for _ in range(args.warmup):
            debugger.submit("step")
        debugger.wait_idle(timeout=300)
        # Server side: from the click's arrival (the command is queued) to the scene flushed.
        queued: list[float] = []
        flushed: list[float] = []
        put, draw = debugger._commands.put, debugger.scene.draw
        debugger._commands.put = lambda item, *a, **k: (queued.append(time.perf_counter()) if item == "step" else None, put(item, *a, **k))[1]

        def timed_draw(snapshot, **options):
            draw(snapshot, **options)
            flushed.append(time.perf_counter())

        debugger.scene.draw = timed_draw
        page = open_page(browser, debugger, width=args.width, height=args.height)
        wait_shown(page, f"{args.warmup - 1} (PL-w)")
        _clicks(page, 3)  # warm the page
        queued.clear()
        flushed.clear()
        n0 = debugger.session.keyframes
        updated, rendered = _clicks(page, args.clicks, pause_ms=args.pause)
        server = [1e3 * (b - a) for a, b in zip(queued, flushed)]
        totals = [debugger.history[i].report.timing_ms["total"] for i in range(n0 - debugger.session.keyframes, 0)]
        what = "rendered room (stereo pipeline)" if args.scene == "room" else f"sequence {args.sequence}"
        print(f"{what}, window {debugger.engine.settings.window}, after {args.warmup} keyframes, page {args.width}x{args.height}, {args.pause:g} ms between clicks:")
        print(f"  click -> scene received:  {_summary(updated)}")
        print(f"  click -> next frame:      {_summary(rendered)}")
        print(f"  server: click -> sent:    {_summary(server)}")
        print(f"  engine step (computed ahead while idle, or after the click): {_summary(totals)}")
    finally:
        debugger.stop()


def bench_switch(browser, args: argparse.Namespace) -> None:
    from tests.browser.conftest import field, open_page, start_debugger, wait_shown

    debugger = _room_debugger() if args.scene == "room" else start_debugger(sequence=args.sequence)
    others = ("P-wo", "PL-wo", "P-r", "PL-r", "P-w")
    try:
        for _ in range(args.warmup):
            debugger.submit("step")
        debugger.wait_idle(timeout=300)
        page = open_page(browser, debugger, width=args.width, height=args.height)
        wait_shown(page, f"{args.warmup - 1} (PL-w)")
        new, kept = [], []
        for i in range(args.clicks):
            page.get_by_role("button", name="Step").click()
            k = args.warmup + i
            page.evaluate(_WAIT_JS, f"{k} (PL-w)")
            for variant, times in ((others[i % len(others)], new), ("PL-w", kept)):
                if args.pause > 0:
                    page.wait_for_timeout(args.pause)
                field(page, "Variant").click()
                option = page.get_by_role("option", name=variant, exact=True)
                t0 = time.perf_counter()
                option.click()
                page.evaluate(_WAIT_JS, f"{k} ({variant})")
                times.append(1e3 * (time.perf_counter() - t0))
        what = "rendered room (stereo pipeline)" if args.scene == "room" else f"sequence {args.sequence}"
        print(f"{what}, after {args.warmup} keyframes, page {args.width}x{args.height}, {args.pause:g} ms before each choice:")
        print(f"  a new variant (window re-optimized) -> shown: {_summary(new)}")
        print(f"  back to a kept one (PL-w) -> shown:           {_summary(kept)}")
    finally:
        debugger.stop()


def bench_points(browser, args: argparse.Namespace) -> None:
    from backend.pipeline.snapshot import PointLandmarks, frozen
    from tests.browser.conftest import open_page, start_debugger, wait_shown

    debugger = start_debugger(sequence="a")
    try:
        for _ in range(20):
            debugger.submit("step")
        debugger.wait_idle(timeout=300)
        page = open_page(browser, debugger)
        wait_shown(page, "19 (PL-w)")
        base = debugger.history[-1]
        rng = np.random.default_rng(0)
        n = args.points
        p_world = rng.uniform([-4, -4, -1.5], [4, 4, 1.5], (n, 3))
        points = PointLandmarks(
            id=frozen(np.arange(n)),
            p_world=frozen(p_world),
            plane=frozen(rng.integers(-1, 4, n)),
            anchor=frozen(np.zeros(n, int)),
            detection=frozen(rng.integers(0, 3, n).astype(np.uint8)),
        )
        draw, seen = [], []
        for i in range(args.repeats):  # alternate the label so that each draw is visible
            variant = ("PL-wo", "PL-w")[i % 2]
            snap = dataclasses.replace(base, points=points, report=dataclasses.replace(base.report, variant=variant))
            t0 = time.perf_counter()
            debugger._show(snap)  # the worker is idle: the benchmark draws as the worker would
            draw.append(1e3 * (time.perf_counter() - t0))
            page.evaluate(_WAIT_JS, f"{snap.keyframe} ({variant})")
            seen.append(1e3 * (time.perf_counter() - t0))
        print(f"{n:,} points (plus {len(base.lines)} lines, {len(base.planes)} planes, {len(base.estimate)} frustums):")
        print(f"  server draw + send:       {_summary(draw)}")
        print(f"  until the browser has it: {_summary(seen)}")
        updated, rendered = _clicks(page, args.clicks)  # Step while the big map was shown
        print(f"  Step click -> received:   {_summary(updated)}")
        print(f"  Step click -> next frame: {_summary(rendered)}")
    finally:
        debugger.stop()


def bench_memory(browser, args: argparse.Namespace) -> None:
    """The page, driven from here, of the server that `memory_server` runs in a child process
    (which prints the table)."""
    from tests.browser.conftest import TIMEOUT_MS, wait_shown

    argv = [
        sys.executable,
        str(pathlib.Path(__file__).resolve()),
        "memory-server",
        "--scene",
        args.scene,
        "--sequence",
        args.sequence,
        "--steps",
        str(args.steps),
        "--variants-every",
        str(args.variants_every),
    ]
    if args.history_mb is not None:
        argv += ["--history-mb", str(args.history_mb)]
    server = subprocess.Popen(argv, stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True, bufsize=1)
    assert server.stdin is not None and server.stdout is not None
    try:
        page = None
        for line in server.stdout:
            if line.startswith("PORT "):
                page = browser.new_page(viewport={"width": 1400, "height": 900})
                page.set_default_timeout(TIMEOUT_MS)
                page.goto(f"http://127.0.0.1:{int(line.split()[1])}/?fixedDpr=1")
                page.get_by_role("button", name="Step").wait_for()
                server.stdin.write("open\n")
            elif line.startswith("SHOWN "):
                assert page is not None
                wait_shown(page, line[len("SHOWN ") :].rstrip("\n"))  # the newest keyframe reached the page
                server.stdin.write("shown\n")
            else:
                print(line, end="", flush=True)
        if server.wait(timeout=120) != 0:
            raise SystemExit(f"the memory server failed (exit code {server.returncode})")
    finally:
        if server.poll() is None:
            server.kill()


def memory_server(args: argparse.Namespace) -> None:
    """The debugger alone in this process: `--steps` steps (every variant at every
    `--variants-every`-th), its RSS every 100 steps; the page is opened by the parent
    (`bench_memory`), told the port on stdout and answering on stdin."""
    import gc

    if args.scene == "room":  # long enough for --steps keyframes (200 s of room's path gave 279)
        debugger = _room_debugger(duration_s=max(60.0, 0.8 * args.steps), history_mb=args.history_mb)
    else:
        from backend.pipeline.sim_engine import SimEngine, SimSettings
        from viewer.app import Debugger

        debugger = Debugger(SimEngine(SimSettings(sequence=args.sequence)), port=free_port())
        debugger.server.scene.configure_environment_map(hdri=None)
    try:
        print(f"PORT {debugger.port}", flush=True)
        if sys.stdin.readline().strip() != "open":
            raise SystemExit("the page was not opened")
        every = f", every variant at every {args.variants_every}th keyframe" if args.variants_every else ""
        print(f"{args.scene}{every}, history cap {debugger.session.history.capacity} keyframes / {debugger.session.history.max_bytes / 2**20:.0f} MiB; the server's own process")
        print(f"{'steps':>6s} {'RSS MiB':>8s} {'history':>8s} {'kept MiB':>8s} {'s/100 steps':>11s}")
        print(f"{0:6d} {_rss_mib():8.1f} {0:8d}", flush=True)
        t0 = time.perf_counter()
        for done in range(100, args.steps + 1, 100):
            for i in range(done - 100, done):
                debugger.submit("step")
                if args.variants_every and i % args.variants_every == 0:
                    debugger.submit("all_variants")
            debugger.wait_idle(timeout=1200)
            gc.collect()
            print(f"{done:6d} {_rss_mib():8.1f} {len(debugger.history):8d} {debugger.session.history.bytes / 2**20:8.1f} {time.perf_counter() - t0:11.1f}", flush=True)
            t0 = time.perf_counter()
        print(f"SHOWN {debugger.history[-1].keyframe} (PL-w)", flush=True)  # the newest keyframe (a sequence may end before --steps)
        if sys.stdin.readline().strip() != "shown":
            raise SystemExit("the page did not show the newest keyframe")
        rollup = _rollup_mib()
        anonymous, rss = rollup.get("Anonymous", float("nan")), rollup.get("Rss", float("nan"))
        print(f"{'end':>6s} {_rss_mib():8.1f} (the page up to date; anonymous {anonymous:.1f} MiB, file-backed {rss - anonymous:.1f})", flush=True)
    finally:
        debugger.stop()


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("which", choices=("latency", "points", "memory", "switch", "memory-server"), help="memory-server: memory's server process (started by memory)")
    parser.add_argument("--scene", choices=("mc-a", "room"), default="mc-a", help="latency, memory, switch: Monte-Carlo sequence (--sequence) or the rendered room")
    parser.add_argument("--sequence", choices=("a", "b"), default="a")
    parser.add_argument("--warmup", type=int, default=30)
    parser.add_argument("--clicks", type=int, default=30)
    parser.add_argument("--variants-every", type=int, default=0, help="memory: compute every variant at every N-th keyframe (0: never)")
    parser.add_argument("--pause", type=float, default=0.0, help="latency: ms between a scene received and the next click (0: at once; the debugger computes the next step while the user looks)")
    parser.add_argument("--points", type=int, default=100_000)
    parser.add_argument("--repeats", type=int, default=10)
    parser.add_argument("--steps", type=int, default=1000)
    parser.add_argument("--history-mb", type=float, default=None, help="memory, room: the history's byte cap (default: the debugger's)")
    parser.add_argument("--width", type=int, default=1400, help="page size in CSS pixels (latency)")
    parser.add_argument("--height", type=int, default=900)
    args = parser.parse_args()
    if args.which == "memory-server":
        memory_server(args)
        return
    print(f"# python {platform.python_version()}, {platform.machine()}, {os.cpu_count()} cpus, chromium headless (software WebGL)")
    from playwright.sync_api import sync_playwright

    from tests.browser.conftest import CHROMIUM, FLAGS

    with sync_playwright() as p:
        browser = p.chromium.launch(executable_path=str(CHROMIUM), args=FLAGS)
        {"latency": bench_latency, "points": bench_points, "memory": bench_memory, "switch": bench_switch}[args.which](browser, args)
        browser.close()


if __name__ == "__main__":
    main()
