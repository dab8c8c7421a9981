"""Output files that appear complete or not at all.

A file is written under a hidden temporary name in its own folder and renamed into place
when it is complete (`os.replace`: atomic on POSIX within one file system). A set of files
(a run's outputs, a rendered sequence) is written into a hidden staging folder inside the
destination and moved into place only when every file of the set is written. A full disk,
an error or an interruption (Ctrl-C, SIGTERM) before that leaves the destination as it was:
the temporary name or the staging folder is removed.
"""

from __future__ import annotations

import contextlib
import os
import pathlib
import shutil
import signal
import threading
import time
from collections.abc import Iterator

PARTIAL_MARK = ".partial-"
STAGING_PREFIX = ".coplanar-partial-"


def partial_name(path: pathlib.Path) -> pathlib.Path:
    """The hidden temporary name `path` is written under (same folder, same suffix, so that
    writers that choose the format by the suffix still do)."""
    return path.with_name(f".{path.stem}{PARTIAL_MARK}{os.getpid()}{path.suffix}")


@contextlib.contextmanager
def atomic_path(path: pathlib.Path | str) -> Iterator[pathlib.Path]:
    """Yields a temporary path to write `path`'s content to; renamed to `path` when the
    block ends without an exception, removed otherwise."""
    target = pathlib.Path(path)
    tmp = partial_name(target)
    try:
        yield tmp
        if not tmp.exists():
            raise OSError(f"{target}: the writer produced no file")
        os.replace(tmp, target)
    except BaseException:
        with contextlib.suppress(OSError):
            tmp.unlink()
        raise


def write_bytes_atomic(path: pathlib.Path | str, data: bytes) -> None:
    """`path.write_bytes(data)`, complete or not at all."""
    with atomic_path(path) as tmp:
        tmp.write_bytes(data)


def write_text_atomic(path: pathlib.Path | str, text: str) -> None:
    """`path.write_text(text)` (UTF-8), complete or not at all."""
    with atomic_path(path) as tmp:
        tmp.write_text(text, encoding="utf-8")


def make_folder(path: pathlib.Path | str) -> None:
    """`mkdir -p` without recursion: pathlib's and os.makedirs' recurse once per missing
    level and fail with RecursionError on a path of thousands of components."""
    folder = pathlib.Path(path)
    missing = []
    while not folder.is_dir():
        missing.append(folder)
        if folder.parent == folder:
            break
        folder = folder.parent
    for level in reversed(missing):
        try:
            level.mkdir()
        except FileExistsError:
            if not level.is_dir():
                raise


def remove_stale_staging(folder: pathlib.Path, *, wait_s: float = 0.0) -> None:
    """Remove the staging folders that processes no longer running (killed: SIGKILL, power
    loss, a Ray worker ended with its cluster) left in `folder`, after waiting up to `wait_s`
    seconds for their writers to end."""
    deadline = time.monotonic() + wait_s
    while time.monotonic() < deadline and any(_running(pid) for pid in _writers(folder).values()):
        time.sleep(0.1)
    _remove_stale_staging(folder)


def _writers(folder: pathlib.Path) -> dict[pathlib.Path, int]:
    """The staging folders in `folder` of other processes, with each writer's pid (from the
    folder's name)."""
    found = {}
    for entry in folder.glob(f"{STAGING_PREFIX}*"):
        pid = entry.name[len(STAGING_PREFIX) :]
        if pid.isdigit() and int(pid) != os.getpid():
            found[entry] = int(pid)
    return found


def _running(pid: int) -> bool:
    """Whether process `pid` runs (or cannot be told: then it is left alone)."""
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except OSError:
        return True
    return True


def _remove_stale_staging(folder: pathlib.Path) -> None:
    """Staging folders a killed process (SIGKILL, power loss) left in `folder`."""
    for entry, pid in _writers(folder).items():
        if not _running(pid):
            shutil.rmtree(entry, ignore_errors=True)


@contextlib.contextmanager
def _signals_deferred() -> Iterator[list[int]]:
    """SIGINT and SIGTERM held back for the block (main thread only); the list yielded
    collects the signals that arrived."""
    pending: list[int] = []
    if threading.current_thread() is not threading.main_thread():
        yield pending
        return
    previous = {s: signal.signal(s, lambda number, _frame: pending.append(number)) for s in (signal.SIGINT, signal.SIGTERM)}
    try:
        yield pending
    finally:
        for s, handler in previous.items():
            signal.signal(s, handler)


class InterruptedAfterCommit(KeyboardInterrupt):
    """Ctrl-C or SIGTERM arrived while the finished files were moved into place: they all
    were."""


@contextlib.contextmanager
def staged_folder(destination: pathlib.Path | str) -> Iterator[pathlib.Path]:
    """Yields a hidden folder inside `destination` (which must exist) to write a set of
    files and folders into. When the block ends without an exception, each entry is moved
    into `destination` (replacing an older file of the same name) and the staging folder
    is removed; SIGINT and SIGTERM are held back while they move, and raised afterwards as
    :class:`InterruptedAfterCommit`. On an exception or an interruption inside the block the
    staging folder is removed and `destination` is left as it was."""
    out = pathlib.Path(destination)
    _remove_stale_staging(out)
    stage = out / f"{STAGING_PREFIX}{os.getpid()}"
    shutil.rmtree(stage, ignore_errors=True)
    stage.mkdir()
    try:
        yield stage
        with _signals_deferred() as pending:
            for entry in sorted(stage.iterdir()):
                target = out / entry.name
                if entry.is_dir() and target.is_dir():
                    raise FileExistsError(f"{target}: already exists")
                os.replace(entry, target)
        if pending:
            raise InterruptedAfterCommit(f"every file was already written to {out}")
    finally:
        shutil.rmtree(stage, ignore_errors=True)
