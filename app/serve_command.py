"""`coplanar serve`: the debugger in the browser (DESIGN §7)."""

from __future__ import annotations

import argparse
import pathlib
import sys
import threading

DEFAULT_DURATION_S = 60.0


def add_parser(sub: argparse._SubParsersAction) -> None:
    from app.options import path
    from app.sources import add_source_arguments
    from backend.optim.variant import VARIANT_NAMES

    p = sub.add_parser("serve", help="start the debugger (open the printed address in a browser)")
    add_source_arguments(p, duration_default=DEFAULT_DURATION_S)
    p.add_argument("--variant", default="PL-w", choices=VARIANT_NAMES, help="parametrization to start with (default PL-w)")
    p.add_argument("--host", default="127.0.0.1", help="address to bind (default 127.0.0.1: this machine only; another address warns)")
    p.add_argument("--port", type=int, default=8080, help="port (default 8080; 0: any free one; a port in use is an error)")
    p.add_argument(
        "--allow-origin",
        action="append",
        default=[],
        metavar="URL",
        help="also admit pages of this origin, e.g. https://slam.lab.example behind a reverse proxy (repeatable; by default only the debugger's own page connects)",
    )
    p.add_argument("--share", action="store_true", help="show viser's share button: a public address through viser's relay (off: share requests are dropped)")
    p.add_argument("--history", type=int, default=500, help="snapshots kept for the keyframe slider (default 500)")
    p.add_argument("--history-mb", type=float, default=60.0, help="at most this many MiB of kept snapshots (oldest dropped first; default 60)")
    p.add_argument("--play", action="store_true", help="start playing at once")
    p.add_argument("--sweep", default=None, metavar="DIR", help="also show the results of `coplanar sweep --out DIR` (its Sweep tab)")
    p.add_argument(
        "--replay",
        default=None,
        metavar="FILE",
        type=path,
        help="open a recording (`coplanar run --record FILE`, or the debugger's Record folder) instead of running an engine: no dataset needed",
    )
    p.set_defaults(run=run)


def build_engine(args: argparse.Namespace):
    """The debugger's engine for `--scene` / `--dataset` (app.sources), or the replay of
    `--replay FILE`; UsageError for bad values or a file that is not a recording. The stereo
    pipeline runs every stage and draws the keyframe image and Hessian."""
    from app.sources import build_engine as build

    if getattr(args, "replay", None) is not None:
        return replay_engine(args)
    return build(args, headless=False)


#: Options that choose or shape an engine, which a replay has none of.
_ENGINE_OPTIONS = ("scene", "dataset", "calib", "topic", "duration", "frames", "stride", "speed", "mislabel", "window", "segmenter", "segmenter_model")


def replay_engine(args: argparse.Namespace):
    """The ReplayEngine of `--replay FILE`; UsageError (one line) for engine options given
    with it or a file that is not a readable recording."""
    from app.errors import UsageError
    from backend.pipeline.recording import Recording, RecordingError
    from backend.pipeline.replay_engine import ReplayEngine

    given = [f"--{name.replace('_', '-')}" for name in _ENGINE_OPTIONS if getattr(args, name, None) not in (None, [], ())]
    if getattr(args, "mode", "stereo") != "stereo":
        given.append("--mode")
    if given:
        raise UsageError(f"--replay: {', '.join(given)} not used (a replay shows the recorded run)")
    try:
        return ReplayEngine(Recording.open(args.replay))
    except RecordingError as e:
        raise UsageError(f"--replay {e}") from None


def check_bindable(host: str, port: int) -> None:
    """UsageError (one line) unless `host` resolves and `port` can be bound there (0: any
    free port). The socket is closed again at once."""
    import socket

    from app.errors import UsageError

    try:
        family, kind, proto, _, address = socket.getaddrinfo(host, port, type=socket.SOCK_STREAM)[0]
    except (socket.gaierror, UnicodeError) as e:
        raise UsageError(f"--host {host}: not an address of this machine ({getattr(e, 'strerror', None) or e})") from None
    with socket.socket(family, kind, proto) as probe:
        probe.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        try:
            probe.bind(address)
        except OSError as e:
            raise UsageError(f"cannot serve on {host}:{port}: {e.strerror or e}") from None


def access_settings(args: argparse.Namespace):
    """The server's AccessSettings from `--allow-origin` and `--share`; UsageError for an
    origin that is not http(s)://HOST[:PORT]."""
    from app.errors import UsageError
    from viewer.access import AccessSettings, OriginError

    try:
        return AccessSettings(allowed_origins=tuple(args.allow_origin), share=args.share)
    except OriginError as e:
        raise UsageError(f"--allow-origin {e}") from None


def exposure_warnings(args: argparse.Namespace) -> list[str]:
    """One line per way the options expose the debugger beyond this machine's own pages."""
    from viewer.access import is_loopback_bind

    warnings = []
    if not is_loopback_bind(args.host):
        where = "every network interface" if args.host.strip("[]") in ("0.0.0.0", "::", "") else "a network address"
        warnings.append(
            f"warning: --host {args.host} serves the debugger on {where}: anyone who can reach port {args.port} can drive it and "
            "download the map (the default 127.0.0.1 and an SSH tunnel keep it to you)"
        )
    if args.share:
        warnings.append("warning: --share: any open tab can publish the debugger on a public address through viser's relay; anyone with the link can drive it and download the map")
    return warnings


def sweep_folder(args: argparse.Namespace) -> pathlib.Path | None:
    """`--sweep DIR`: a folder holding a sweep's results.json; UsageError (one line) otherwise."""
    from app.errors import UsageError

    if args.sweep is None:
        return None
    folder = pathlib.Path(args.sweep)
    if not (folder / "results.json").is_file():
        raise UsageError(f"--sweep {folder}: no results.json there (the folder `coplanar sweep --out` writes)")
    return folder


def run(args: argparse.Namespace) -> int:
    from app.errors import UsageError

    if not 0 <= args.port <= 65535:
        raise UsageError(f"--port {args.port}: not a port number")
    sweep = sweep_folder(args)
    access = access_settings(args)
    check_bindable(args.host, args.port)  # the server binds in a thread of its own, where a failure would go unseen
    from backend.common.allocator import limit_arenas

    limit_arenas()  # before the engine and the server start their threads (backend/common/allocator.py)
    engine = build_engine(args)
    from viewer.app import Debugger, ViewerSettings

    for line in exposure_warnings(args):
        print(line, file=sys.stderr, flush=True)
    try:
        debugger = Debugger(engine, host=args.host, port=args.port, settings=ViewerSettings(history=args.history, history_mb=args.history_mb, sweep=sweep), access=access)
    except OSError as e:
        raise UsageError(f"cannot serve on {args.host}:{args.port}: {e.strerror or e}") from None
    print(f"coplanar debugger: http://{args.host}:{debugger.port} ({engine.source}); Ctrl-C stops", flush=True)
    if args.play:
        debugger.play.value = True  # type: ignore[misc]  # viser's setter, which mypy does not see through its generic handle
    try:
        threading.Event().wait()
    finally:
        debugger.stop()
    return 0
