"""`coplanar serve`: the debugger in the browser (DESIGN §7)."""

from __future__ import annotations

import argparse
import threading

SCENES: dict[str, str] = {
    "mc-a": "Monte-Carlo sequence a: four walls, camera on a circle (DESIGN §4)",
    "mc-b": "Monte-Carlo sequence b: one wall, camera sliding along it",
}
DEFAULT_SCENE = "mc-a"


def add_parser(sub: argparse._SubParsersAction) -> None:
    from backend.optim.problem import VARIANTS

    p = sub.add_parser("serve", help="start the debugger (open the printed address in a browser)")
    source = p.add_mutually_exclusive_group()
    source.add_argument("--scene", default=None, help=f"built-in scene: {', '.join(SCENES)} (default {DEFAULT_SCENE})")
    source.add_argument("--dataset", default=None, help="EuRoC ASL folder (read and checked; the stereo pipeline that runs on it is not implemented yet)")
    p.add_argument("--variant", default="PL-w", choices=VARIANTS, help="parametrization to start with (default PL-w)")
    p.add_argument("--host", default="127.0.0.1", help="address to bind (default 127.0.0.1: this machine only)")
    p.add_argument("--port", type=int, default=8080, help="port (default 8080; the next free one if taken)")
    p.add_argument("--seed", type=int, default=0, help="seed of the scene and its noise (default 0)")
    p.add_argument("--mislabel", type=float, default=0.1, help="fraction of features with a wrong plane-instance label (default 0.1)")
    p.add_argument("--window", type=int, default=10, help="keyframes optimized per step (default 10)")
    p.add_argument("--history", type=int, default=500, help="snapshots kept for the keyframe slider (default 500)")
    p.add_argument("--play", action="store_true", help="start playing at once")
    p.set_defaults(run=run)


def build_engine(args: argparse.Namespace):  # noqa: ANN201
    """The engine for `--scene` / `--dataset`; UsageError for bad values."""
    from app.cli import UsageError
    from backend.pipeline.sim_engine import SimEngine, SimSettings

    if args.dataset is not None:
        from backend.data.euroc import EurocDataset

        dataset = EurocDataset(args.dataset)  # DatasetError: one line naming the bad file
        raise UsageError(
            f"--dataset {args.dataset}: read {len(dataset.timestamps_ns)} stereo frames, but the stereo pipeline that runs on "
            f"datasets is not implemented yet; use --scene {' | '.join(SCENES)}"
        )
    scene = args.scene or DEFAULT_SCENE
    if scene not in SCENES:
        raise UsageError(f"--scene {scene}: unknown scene; expected one of {', '.join(SCENES)}")
    if not 0.0 <= args.mislabel <= 1.0:
        raise UsageError(f"--mislabel {args.mislabel}: must be a fraction in [0, 1]")
    if args.window < 2:
        raise UsageError(f"--window {args.window}: must be at least 2")
    if args.history < 1:
        raise UsageError(f"--history {args.history}: must be at least 1")
    return SimEngine(SimSettings(sequence=scene[-1], seed=args.seed, variant=args.variant, window=args.window, mislabel=args.mislabel))


def run(args: argparse.Namespace) -> int:
    from app.cli import UsageError

    if not 0 <= args.port <= 65535:
        raise UsageError(f"--port {args.port}: not a port number")
    engine = build_engine(args)
    from viewer.app import Debugger, ViewerSettings

    try:
        debugger = Debugger(engine, host=args.host, port=args.port, settings=ViewerSettings(history=args.history))
    except OSError as e:
        raise UsageError(f"cannot serve on {args.host}:{args.port}: {e.strerror or e}") from None
    print(f"coplanar debugger: http://{args.host}:{debugger.port} ({engine.source}); Ctrl-C stops", flush=True)
    if args.play:
        debugger.play.value = True
    try:
        threading.Event().wait()
    finally:
        debugger.stop()
    return 0
