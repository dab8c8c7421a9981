"""The `coplanar` command line (DESIGN §7)."""

from __future__ import annotations

import os

# The solver's dense factorizations are small (a few hundred columns): OpenBLAS threads
# cost more than they gain there. Must be set before numpy loads.
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import signal
import sys
import threading


def _interrupted_while_starting(_number: int, _frame: object) -> None:
    """Ctrl-C or SIGTERM while the command line loads: one line, nothing was started."""
    sys.stderr.write("interrupted\n")
    sys.stderr.flush()
    os._exit(130)


# Until `main` takes over (its own handlers, one line for every interruption), a signal while
# the modules below load ends the command with one line instead of a traceback.
_STARTING = threading.current_thread() is threading.main_thread()
if _STARTING:
    _sigint = signal.signal(signal.SIGINT, _interrupted_while_starting)
    _sigterm = signal.signal(signal.SIGTERM, _interrupted_while_starting)

import argparse  # noqa: E402
from collections.abc import Sequence  # noqa: E402
from typing import NoReturn  # noqa: E402

from app import render_command, run_command, serve_command, sim_command, sweep_command  # noqa: E402
from app.errors import EXIT_BAD_INPUT, UsageError, one_line  # noqa: E402

if _STARTING:
    signal.signal(signal.SIGINT, _sigint)
    signal.signal(signal.SIGTERM, _sigterm)


class _Parser(argparse.ArgumentParser):
    def error(self, message: str) -> NoReturn:  # one line instead of usage + message
        raise UsageError(f"{self.prog}: {message}")


def build_parser() -> argparse.ArgumentParser:
    parser = _Parser(prog="coplanar", description="Co-planar parametrization SLAM debugger and studies.")
    sub = parser.add_subparsers(dest="command", required=True, parser_class=_Parser)
    serve_command.add_parser(sub)
    run_command.add_parser(sub)
    render_command.add_parser(sub)
    sim_command.add_parser(sub)
    sweep_command.add_parser(sub)
    return parser


def _interrupt(_number: int, _frame: object) -> None:
    raise KeyboardInterrupt


def main(argv: Sequence[str] | None = None) -> int:
    if signal.getsignal(signal.SIGTERM) is signal.SIG_DFL:
        signal.signal(signal.SIGTERM, _interrupt)  # `kill PID` ends a command like Ctrl-C: no half-written files
    try:
        parser = build_parser()  # loads the commands' options (scenes, variants): an interruption here is one line too
        args = parser.parse_args(argv)
        return int(args.run(args) or 0)
    except UsageError as e:
        print(f"error: {one_line(e)}", file=sys.stderr)
        return EXIT_BAD_INPUT
    except Exception as e:  # a dataset problem the user can fix: one line, no traceback
        from backend.common.optional import MissingLibraryError
        from backend.data.errors import DatasetError

        if isinstance(e, (DatasetError, MissingLibraryError)):
            print(f"error: {one_line(e)}", file=sys.stderr)
        elif isinstance(e, ValueError) and "null" in str(e) and ("byte" in str(e) or "character" in str(e)):
            print("error: a file name or address with a NUL character", file=sys.stderr)
        elif isinstance(e, OSError):  # the environment (a full disk, a folder that went away): one line naming the file
            where = f"{e.filename}: " if e.filename else ""
            print(one_line(f"error: {where}{e.strerror}" if e.strerror else f"error: {e}"), file=sys.stderr)
        else:
            raise
        return EXIT_BAD_INPUT
    except KeyboardInterrupt as e:
        print(one_line(f"interrupted: {e}") if str(e) else "interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":  # `python -m app.cli`
    sys.exit(main())
