"""A full disk or an interruption never leaves half-written output (issue 16): `run`,
`render` and `sim` write into temporary names and move complete files into place; the
command says what happened in one line."""

from __future__ import annotations

import os
import pathlib
import resource
import signal
import subprocess
import sys
import time

import pytest

ROOT = pathlib.Path(__file__).resolve().parents[2]
FILE_LIMIT_BYTES = 12_000  # larger than any probe, smaller than the outputs


def _coplanar(*argv: str, file_limit: int | None = None, **kwargs) -> subprocess.Popen:
    def limit() -> None:
        # Ctrl-C as in a terminal, even where the tests themselves run with SIGINT ignored (a
        # background job of a non-interactive shell inherits SIG_IGN, and so would the child).
        signal.signal(signal.SIGINT, signal.SIG_DFL)
        if file_limit is not None:  # a file-size limit stands in for a full disk: writes past it fail (EFBIG)
            signal.signal(signal.SIGXFSZ, signal.SIG_IGN)
            resource.setrlimit(resource.RLIMIT_FSIZE, (file_limit, file_limit))

    env = {**os.environ, "PYTHONDONTWRITEBYTECODE": "1"}
    return subprocess.Popen([sys.executable, "-m", "app.cli", *argv], cwd=ROOT, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, preexec_fn=limit, **kwargs)


def _finish(process: subprocess.Popen, timeout: float = 300) -> tuple[int, str]:
    _, err = process.communicate(timeout=timeout)
    return process.returncode, err


def _one_line(err: str, *words: str) -> str:
    assert "Traceback" not in err, err
    lines = [line for line in err.strip().splitlines() if line.strip()]
    assert len(lines) == 1 and all(w in lines[0] for w in words), err
    return lines[0]


def _visible(folder: pathlib.Path) -> list[str]:
    return sorted(p.name for p in folder.rglob("*")) if folder.exists() else []


RUN_FILES = ["cameras.ply", "groundtruth.txt", "keyframes.txt", "lines.ply", "map.ply", "metrics.json", "planes.ply", "points.ply", "trajectory.txt"]


def test_ctrl_c_during_run_writes_nothing_and_a_second_run_works(tmp_path: pathlib.Path) -> None:
    out = tmp_path / "out"
    process = _coplanar("run", "--scene", "room", "--variant", "PL-w", "--frames", "500", "--out", str(out))
    time.sleep(8.0)  # past start-up, into the frames
    assert process.poll() is None, "the run ended before the interruption"
    process.send_signal(signal.SIGINT)
    rc, err = _finish(process)
    assert rc == 130
    assert _one_line(err.splitlines()[-1], "interrupted: nothing written to", str(out))
    assert _visible(out) == []  # no file, no staging folder

    rc, err = _finish(_coplanar("run", "--scene", "room", "--variant", "PL-w", "--frames", "12", "--out", str(out)))
    assert rc == 0, err
    assert _visible(out) == RUN_FILES

    metrics = (out / "metrics.json").read_bytes()
    process = _coplanar("run", "--scene", "room", "--variant", "P-wo", "--frames", "500", "--out", str(out))
    time.sleep(8.0)
    process.terminate()  # SIGTERM: the same as Ctrl-C
    rc, err = _finish(process)
    assert rc == 130 and "the files already there are as they were" in err.splitlines()[-1]
    assert _visible(out) == RUN_FILES and (out / "metrics.json").read_bytes() == metrics


def test_run_on_a_full_disk_is_one_line_and_leaves_nothing(tmp_path: pathlib.Path) -> None:
    out = tmp_path / "out"
    rc, err = _finish(_coplanar("run", "--scene", "room", "--variant", "PL-w", "--frames", "12", "--out", str(out), file_limit=FILE_LIMIT_BYTES))
    assert rc == 2
    _one_line(err, f"error: --out {out}: cannot write", "nothing was written there")
    assert _visible(out) == []


def test_render_on_a_full_disk_is_one_line_and_leaves_no_mav0(tmp_path: pathlib.Path) -> None:
    out = tmp_path / "seq"
    rc, err = _finish(_coplanar("render", "--scene", "room", "--duration", "0.3", "--out", str(out), file_limit=FILE_LIMIT_BYTES))
    assert rc == 2
    _one_line(err, f"error: --out {out}: cannot write", "no mav0 was left there")
    assert _visible(out) == []


def test_sim_on_a_full_disk_writes_neither_file(tmp_path: pathlib.Path) -> None:
    rc, err = _finish(_coplanar("sim", "--sequence", "a", "--runs", "1", "--variants", "P-wo", "--json", str(tmp_path / "study.json"), file_limit=FILE_LIMIT_BYTES))
    assert rc == 2
    # Usually "error: cannot write --plot …: File too large; neither file was written"; where a
    # library's own cache write (matplotlib's font list on a fresh machine) meets the limit
    # first, the line names no file, but it is still one line, exit 2, nothing written.
    _one_line(err, "error: ", "File too large")
    assert _visible(tmp_path) == []


def _tmpfs(path: pathlib.Path, size: str) -> bool:
    path.mkdir()
    try:
        return subprocess.run(["mount", "-t", "tmpfs", "-o", f"size={size}", "tmpfs", str(path)], capture_output=True).returncode == 0
    except OSError:
        return False


def test_a_really_full_disk_too(tmp_path: pathlib.Path) -> None:
    """The same on a tiny tmpfs (where this machine lets the tests mount one)."""
    disk = tmp_path / "disk"
    if not _tmpfs(disk, "48k"):
        pytest.skip("cannot mount a tmpfs here (not root, or no mount permission)")
    try:
        rc, err = _finish(_coplanar("run", "--scene", "room", "--variant", "PL-w", "--frames", "12", "--out", str(disk / "out")))
        assert rc == 2
        _one_line(err, "No space left on device", "nothing was written there")
        rc, err = _finish(_coplanar("render", "--scene", "room", "--duration", "0.3", "--out", str(disk / "seq")))
        assert rc == 2
        _one_line(err, "No space left on device", "no mav0 was left there")
        assert _visible(disk) == []  # not even the folders they made
    finally:
        subprocess.run(["umount", str(disk)], check=False)
