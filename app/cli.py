"""The `coplanar` command line (DESIGN §7)."""

from __future__ import annotations

import os

# The solver's dense factorizations are small (a few hundred columns): OpenBLAS threads
# cost more than they gain there. Must be set before numpy loads.
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import signal
import sys


def _interrupted_while_starting(_number: int, _frame: object) -> None:
    """Ctrl-C or SIGTERM while the command line loads: one line, nothing was started."""
    sys.stderr.write("interrupted\n")
    sys.stderr.flush()
    os._exit(130)


# Until `main` takes over (its own handlers, one line for every interruption), a signal while
# the modules below load ends the command with one line instead of a traceback. Set before
# anything else is imported (threading included); outside the main thread (a program
# importing this module from a thread) signals are not this module's to set.
try:
    _sigint = signal.signal(signal.SIGINT, _interrupted_while_starting)
    _sigterm = signal.signal(signal.SIGTERM, _interrupted_while_starting)
    _STARTING = True
except ValueError:  # "signal only works in main thread"
    _STARTING = False

import argparse  # noqa: E402
import threading  # noqa: E402
from collections.abc import Sequence  # noqa: E402
from typing import NoReturn  # noqa: E402

from app import render_command, run_command, serve_command, sim_command, sweep_command  # noqa: E402
from app.errors import EXIT_BAD_INPUT, UsageError, one_line  # noqa: E402
from backend.common.native_output import say  # noqa: E402

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


_signalled = threading.Event()  # a signal came during `main`: what fails after it was interrupted


def _interrupt(_number: int, _frame: object) -> None:
    _signalled.set()
    raise KeyboardInterrupt


_default_unraisable = sys.unraisablehook


def _unraisable(info: sys.UnraisableHookArgs) -> None:
    """A KeyboardInterrupt that C code swallowed (raised inside a callback from a library,
    e.g. llvmlite's while numba compiles, or in an object's finalizer: "Exception ignored
    in ...", and the run went on) is raised again in the main thread, where it ends the
    command in one line. The signal is sent again from a helper thread once this hook has
    returned: raised inside the hook (interrupt_main when the hook runs on the main thread)
    it would be swallowed as well, with a traceback and exit 0."""
    if isinstance(info.exc_value, KeyboardInterrupt):
        threading.Timer(0.01, os.kill, args=(os.getpid(), signal.SIGINT)).start()
        return
    _default_unraisable(info)


def main(argv: Sequence[str] | None = None) -> int:
    _signalled.clear()
    if signal.getsignal(signal.SIGTERM) is signal.SIG_DFL:
        signal.signal(signal.SIGTERM, _interrupt)  # `kill PID` ends a command like Ctrl-C: no half-written files
    on_main = threading.current_thread() is threading.main_thread()
    previous_sigint = signal.getsignal(signal.SIGINT)
    ours = on_main and previous_sigint is signal.default_int_handler  # Python's own: the same KeyboardInterrupt, remembered
    if ours:
        signal.signal(signal.SIGINT, _interrupt)
    previous_hook, sys.unraisablehook = sys.unraisablehook, _unraisable
    try:
        return _run(argv)
    finally:
        sys.unraisablehook = previous_hook
        if ours:
            signal.signal(signal.SIGINT, previous_sigint)


def _run(argv: Sequence[str] | None) -> int:
    """Parse and run the command: every expected failure one line (module docstring)."""
    try:
        parser = build_parser()  # loads the commands' options (scenes, variants): an interruption here is one line too
        args = parser.parse_args(argv)
        return int(args.run(args) or 0)
    except UsageError as e:
        say(f"error: {one_line(e)}")
        return EXIT_BAD_INPUT
    except Exception as e:  # a dataset problem the user can fix: one line, no traceback
        from backend.common.optional import MissingLibraryError
        from backend.data.errors import DatasetError

        # A Ctrl-C that compiled code wrapped (numba: "SystemError: ... returned a result with
        # an exception set") or turned into its own error (NumPy's C extensions, importing
        # `datetime` when it came: "ImportError: ... PyCapsule_Import could not import").
        if _caused_by_interrupt(e) or _signalled.is_set():
            say("interrupted")
            return 130
        if isinstance(e, (DatasetError, MissingLibraryError)):
            say(f"error: {one_line(e)}")
        elif isinstance(e, ValueError) and "null" in str(e) and ("byte" in str(e) or "character" in str(e)):
            say("error: a file name or address with a NUL character")
        elif isinstance(e, OSError):  # the environment (a full disk, a folder that went away): one line naming the file
            where = f"{e.filename}: " if e.filename else ""
            say(one_line(f"error: {where}{e.strerror}" if e.strerror else f"error: {e}"))
        else:
            raise
        return EXIT_BAD_INPUT
    except KeyboardInterrupt as e:
        say(one_line(f"interrupted: {e}") if str(e) else "interrupted")
        return 130


def _caused_by_interrupt(error: BaseException) -> bool:
    """Whether a KeyboardInterrupt lies in `error`'s chain of causes and contexts."""
    seen: set[int] = set()
    current: BaseException | None = error
    while current is not None and id(current) not in seen:
        if isinstance(current, KeyboardInterrupt):
            return True
        seen.add(id(current))
        current = current.__cause__ or current.__context__
    return False


def entry() -> int:
    """The `coplanar` command (and `python -m app.cli`): :func:`main`, then the process ends
    without a second chance to be interrupted. After an interruption (exit code 130, its one
    line printed, nothing half-written) it ends at once, so that no library's clean-up at
    exit prints a traceback of its own (llvmlite's did); after a finished command a signal
    no longer kills it while Python shuts down (the outputs are complete by then)."""
    code = main()
    if code == 130:
        sys.stdout.flush()
        sys.stderr.flush()
        os._exit(code)
    if threading.current_thread() is threading.main_thread():
        signal.signal(signal.SIGINT, signal.SIG_IGN)
        signal.signal(signal.SIGTERM, signal.SIG_IGN)
    return code


if __name__ == "__main__":  # `python -m app.cli`
    sys.exit(entry())
