"""Files complete or not at all (backend.common.atomic): what `run`, `render` and `sim`
rely on so that a full disk or Ctrl-C never leaves half-written output."""

from __future__ import annotations

import os
import pathlib
import signal
import subprocess
import sys

import pytest

from backend.common.atomic import STAGING_PREFIX, InterruptedAfterCommit, atomic_path, staged_folder, write_bytes_atomic, write_text_atomic


def test_atomic_write_replaces_the_file_whole(tmp_path: pathlib.Path) -> None:
    target = tmp_path / "metrics.json"
    target.write_text("old")
    write_text_atomic(target, "new")
    assert target.read_text() == "new"
    write_bytes_atomic(target, b"\x00\x01")
    assert target.read_bytes() == b"\x00\x01"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["metrics.json"]


def test_a_failed_write_leaves_the_old_file_and_no_temporary(tmp_path: pathlib.Path) -> None:
    target = tmp_path / "map.ply"
    target.write_bytes(b"complete old map")
    with pytest.raises(OSError, match="disk full"):
        with atomic_path(target) as tmp:
            tmp.write_bytes(b"half a ma")
            raise OSError(28, "disk full")
    assert target.read_bytes() == b"complete old map"
    assert [p.name for p in tmp_path.iterdir()] == ["map.ply"]


def test_the_temporary_keeps_the_suffix_for_writers_that_read_it(tmp_path: pathlib.Path) -> None:
    with atomic_path(tmp_path / "plot.png") as tmp:
        assert tmp.suffix == ".png" and tmp.parent == tmp_path and tmp.name.startswith(".")
        tmp.write_bytes(b"png")
    assert (tmp_path / "plot.png").read_bytes() == b"png"


def test_a_writer_that_wrote_nothing_is_an_error(tmp_path: pathlib.Path) -> None:
    with pytest.raises(OSError, match="no file"):
        with atomic_path(tmp_path / "mesh.ply"):
            pass
    assert not any(tmp_path.iterdir())


def test_staged_files_move_in_together(tmp_path: pathlib.Path) -> None:
    (tmp_path / "trajectory.txt").write_text("earlier run")
    with staged_folder(tmp_path) as stage:
        assert stage.parent == tmp_path and stage.name.startswith(STAGING_PREFIX)
        (stage / "trajectory.txt").write_text("this run")
        (stage / "metrics.json").write_text("{}")
        assert (tmp_path / "trajectory.txt").read_text() == "earlier run"  # nothing moves before the end
    assert (tmp_path / "trajectory.txt").read_text() == "this run"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["metrics.json", "trajectory.txt"]


@pytest.mark.parametrize("error", [OSError(28, "No space left on device"), KeyboardInterrupt()])
def test_an_error_or_interrupt_in_the_stage_leaves_the_folder_as_it_was(tmp_path: pathlib.Path, error: BaseException) -> None:
    (tmp_path / "trajectory.txt").write_text("earlier run")
    with pytest.raises(type(error)):
        with staged_folder(tmp_path) as stage:
            (stage / "trajectory.txt").write_text("this r")
            raise error
    assert [p.name for p in tmp_path.iterdir()] == ["trajectory.txt"]
    assert (tmp_path / "trajectory.txt").read_text() == "earlier run"


def test_a_stale_staging_folder_of_a_killed_process_is_removed(tmp_path: pathlib.Path) -> None:
    dead = subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"], capture_output=True, text=True, check=True)
    stale = tmp_path / f"{STAGING_PREFIX}{int(dead.stdout)}"
    stale.mkdir()
    (stale / "map.ply").write_bytes(b"half")
    with staged_folder(tmp_path) as stage:
        (stage / "map.ply").write_bytes(b"whole")
    assert [p.name for p in tmp_path.iterdir()] == ["map.ply"]


def test_ctrl_c_while_the_files_move_in_is_held_until_all_have(tmp_path: pathlib.Path) -> None:
    original = os.replace
    calls = []
    before = signal.getsignal(signal.SIGINT)  # (ignored where the tests run as a background job)

    def replace_and_interrupt(src, dst):
        calls.append(dst)
        if len(calls) == 1:
            os.kill(os.getpid(), signal.SIGINT)  # arrives between two renames
        original(src, dst)

    os.replace = replace_and_interrupt
    try:
        with pytest.raises(InterruptedAfterCommit, match="already written"):
            with staged_folder(tmp_path) as stage:
                for name in ("a.txt", "b.txt", "c.txt"):
                    (stage / name).write_text(name)
    finally:
        os.replace = original
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a.txt", "b.txt", "c.txt"]
    assert signal.getsignal(signal.SIGINT) is before  # the handler is put back as it was
