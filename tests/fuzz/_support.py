"""Shared by the fuzz suite: its profiles and the outcome every bad input must have.

Profiles (environment variable `COPLANAR_FUZZ`):

- `ci` (default): a fixed, derandomized set of examples per test, small enough for CI;
- `long`: ten times as many examples, freshly random each run, for a local soak:
  `COPLANAR_FUZZ=long .venv/bin/python -m pytest tests/fuzz --hypothesis-show-statistics`.
"""

from __future__ import annotations

import contextlib
import io
import json
import os
import pathlib
import shutil

import pytest
from hypothesis import HealthCheck, settings

from app import cli

PROFILE = os.environ.get("COPLANAR_FUZZ", "ci")
if PROFILE not in ("ci", "long"):
    raise RuntimeError(f"COPLANAR_FUZZ={PROFILE!r}: use ci or long")


def fuzz_settings(ci_examples: int) -> settings:
    """`ci_examples` examples in the CI profile, ten times as many in the long one."""
    long = PROFILE == "long"
    return settings(
        max_examples=ci_examples * (10 if long else 1),
        deadline=None,
        derandomize=not long,
        database=None,
        suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow, HealthCheck.data_too_large],
    )


def run_cli(argv: list[str], capfd: pytest.CaptureFixture[str]) -> tuple[int, str]:
    """`coplanar ARGV` in this process: its exit code and everything it printed on stderr,
    including what C libraries (libpng, OpenCV, open3d) wrote straight to file descriptor 2."""
    capfd.readouterr()
    err = io.StringIO()
    with contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(err):
        rc = cli.main(argv)
    return rc, err.getvalue() + capfd.readouterr().err


def walk(folder: pathlib.Path) -> list[pathlib.Path]:
    """Everything under `folder`, without recursion (a drawn path may nest thousands deep,
    past what pathlib's rglob and shutil's rmtree recurse through)."""
    found, pending = [], [folder]
    while pending:
        with os.scandir(pending.pop()) as entries:
            for entry in entries:
                found.append(pathlib.Path(entry.path))
                if entry.is_dir(follow_symlinks=False):
                    pending.append(pathlib.Path(entry.path))
    return found


def remove(folder: pathlib.Path) -> None:
    """`shutil.rmtree` for folders of any depth: the deepest first."""
    if not folder.is_dir():
        return
    entries = walk(folder)
    for path in sorted(entries, key=lambda p: len(p.parts), reverse=True):
        if path.is_dir() and not path.is_symlink():
            os.rmdir(path)
        else:
            path.unlink()
    shutil.rmtree(folder, ignore_errors=True)


def check_outcome(rc: int, stderr: str, *, written: list[pathlib.Path] = (), folders: list[pathlib.Path] = ()) -> None:
    """What a user is promised for any input: exit 0 or 2; for 2, exactly one `error:` line
    on stderr and nothing else; never a traceback; and no half-written output: each path of
    `written` is absent on 2, and present and complete on 0 (JSON parses, PLY has its
    header); no temporary or staging file left in `folders`."""
    assert "Traceback" not in stderr, stderr
    assert rc in (0, 2), f"exit {rc}: {stderr}"
    if rc == 2:
        lines = [line for line in stderr.splitlines() if line.strip()]
        assert len(lines) == 1 and lines[0].startswith("error: "), stderr
        assert "\n" not in lines[0]
        for path in written:
            assert not path.exists(), f"{path} left behind by a failed command"
    else:
        for path in written:
            assert path.is_file(), f"{path} missing after exit 0"
            if path.suffix == ".json":
                json.loads(path.read_text())
            elif path.suffix == ".ply":
                head = path.read_bytes()[:4096]
                assert head.startswith(b"ply\n") and b"end_header\n" in head, path
    for folder in folders:
        if folder.is_dir():
            leftovers = [p.name for p in walk(folder) if ".partial-" in p.name or p.name.startswith(".coplanar-")]
            assert not leftovers, f"temporary files left in {folder}: {leftovers}"
