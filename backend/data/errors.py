"""The one error type of the dataset readers (DESIGN §8), bad input the user can fix, and
reading a dataset's files so that every failure is one: only regular files are read (a FIFO,
a device or a socket is refused without waiting on it), and a read that stalls (a hung
network mount) ends after `READ_TIMEOUT_S` with an error instead of hanging the run."""

from __future__ import annotations

import os
import pathlib
import stat
import threading

#: Seconds one file may take to read before the run stops with an error.
READ_TIMEOUT_S = 60.0
_KINDS = ((stat.S_ISFIFO, "a FIFO"), (stat.S_ISCHR, "a character device"), (stat.S_ISBLK, "a block device"), (stat.S_ISSOCK, "a socket"), (stat.S_ISDIR, "a folder"))


class DatasetError(Exception):
    """A missing or malformed dataset file or folder.

    The message is one line that names the file (and the 1-based line for text files), e.g.
    `mav0/imu0/data.csv line 17: NaN in column w_RS_S_y`. The command line prints it as
    `error: <message>` and exits with code 2.
    """

    def __init__(self, path: str | os.PathLike[str], reason: str, *, line: int | None = None) -> None:
        self.path = os.fspath(path)
        self.line = line
        self.reason = " ".join(str(reason).split())  # one line, whatever the reason held
        shown = self.path.replace("\n", "\\n").replace("\r", "\\r")
        where = shown if line is None else f"{shown} line {line}"
        super().__init__(f"{where}: {self.reason}")


def not_regular(mode: int) -> str | None:
    """What a file of `mode` (`os.stat`'s `st_mode`) is when it is not a regular file
    ("a FIFO", "a folder", ...); None for a regular file."""
    if stat.S_ISREG(mode):
        return None
    return next((name for test, name in _KINDS if test(mode)), "not a regular file")


def read_bytes(path: pathlib.Path, *, what: str = "file", timeout_s: float = READ_TIMEOUT_S) -> bytes:
    """The bytes of the regular file `path`, or a DatasetError naming it: missing, a folder,
    a FIFO or a device (refused without blocking on it: opened non-blocking, checked with
    fstat), unreadable, or a read that takes more than `timeout_s` seconds. `what` names the
    file in the messages ("image", "file")."""
    try:
        fd = os.open(path, os.O_RDONLY | os.O_NONBLOCK | getattr(os, "O_CLOEXEC", 0))
    except FileNotFoundError:
        raise DatasetError(path, f"missing {what}") from None
    except IsADirectoryError:
        raise DatasetError(path, f"is a folder, expected a {what}") from None
    except OSError as error:
        raise DatasetError(path, f"cannot read {what} ({error.strerror or error})") from None
    kind = not_regular(os.fstat(fd).st_mode)
    if kind is not None:
        os.close(fd)
        raise DatasetError(path, f"is a folder, expected a {what}" if kind == "a folder" else f"is {kind}, not a regular {what}: refused")
    data: list[bytes] = []
    failures: list[OSError] = []

    def read() -> None:
        try:
            with os.fdopen(fd, "rb") as f:
                data.append(f.read())
        except OSError as error:
            failures.append(error)

    reader = threading.Thread(target=read, name="coplanar-read", daemon=True)
    reader.start()
    reader.join(timeout_s)
    if reader.is_alive():  # the thread keeps the descriptor; the run stops here
        raise DatasetError(path, f"reading the {what} took more than {timeout_s:g} s (a stalled disk or network mount?)")
    if failures:
        raise DatasetError(path, f"cannot read {what} ({failures[0].strerror or failures[0]})")
    return data[0]


def read_text(path: pathlib.Path) -> str:
    """The UTF-8 text of `path`, or a DatasetError naming it (`read_bytes`)."""
    raw = read_bytes(path)
    try:
        return raw.decode("utf-8-sig")
    except UnicodeDecodeError as error:
        raise DatasetError(path, "not UTF-8 text", line=raw[: error.start].count(b"\n") + 1) from None
