"""Libraries the project can run without: importing one that is missing or broken is a
one-line error that says what to install (DESIGN §8). An interruption (Ctrl-C, SIGTERM)
during such an import is held until the import has finished and then raised as
KeyboardInterrupt: open3d's extension turned a Ctrl-C during its import into "ImportError:
initialization failed", which read as a missing library (a run then wrote map.ply only and
exited 0)."""

from __future__ import annotations

import contextlib
import importlib
import signal
import threading
from collections.abc import Iterator
from types import ModuleType


class MissingLibraryError(Exception):
    """open3d cannot be imported (a missing system library): one line, exit code 2."""


@contextlib.contextmanager
def interrupts_held() -> Iterator[None]:
    """SIGINT and SIGTERM that arrive inside the block are held and raised as
    KeyboardInterrupt when it ends (on the main thread; elsewhere the block runs as is)."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    held: list[int] = []
    previous = {number: signal.signal(number, lambda n, _frame: held.append(n)) for number in (signal.SIGINT, signal.SIGTERM)}
    try:
        yield
    finally:
        for number, handler in previous.items():
            signal.signal(number, handler)
    if held:
        raise KeyboardInterrupt


def _import(name: str) -> ModuleType:
    """`import name`, an interruption during it held until it has finished."""
    with interrupts_held():
        try:
            return importlib.import_module(name)
        except BaseException as error:  # re-raised after the held interruption, if any
            failure = error
    raise failure


def require_open3d():
    """The open3d module, or a one-line :class:`MissingLibraryError` that says what to install."""
    try:
        open3d = _import("open3d")
    except (ImportError, OSError) as error:
        text = " ".join(str(error).split())
        if "libusb" in text:
            raise MissingLibraryError(
                "open3d cannot be imported: the system library libusb-1.0 is missing (Debian: apt-get install libusb-1.0-0; `bash scripts/setup.sh` installs it when run as root)"
            ) from None
        raise MissingLibraryError(f"open3d cannot be imported: {text}") from None
    return open3d
