"""The one error type of the dataset readers (DESIGN §8), bad input the user can fix, and
reading a text file so that every failure is one."""

from __future__ import annotations

import os
import pathlib


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


def read_text(path: pathlib.Path) -> str:
    """The UTF-8 text of `path`, or a DatasetError naming it."""
    try:
        raw = path.read_bytes()
    except FileNotFoundError:
        raise DatasetError(path, "missing file") from None
    except IsADirectoryError:
        raise DatasetError(path, "is a folder, expected a file") from None
    except OSError as error:
        raise DatasetError(path, f"cannot read ({error.strerror or error})") from None
    try:
        return raw.decode("utf-8-sig")
    except UnicodeDecodeError as error:
        raise DatasetError(path, "not UTF-8 text", line=raw[: error.start].count(b"\n") + 1) from None
