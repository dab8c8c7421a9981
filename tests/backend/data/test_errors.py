"""Reading a dataset's files: only regular files, never blocking on a FIFO, and a read that
stalls ends with one line naming the file."""

from __future__ import annotations

import os
import time

import pytest

from backend.data import errors
from backend.data.errors import DatasetError, read_bytes, read_text
from backend.data.scenes import SceneFileError, load_scene


def test_a_regular_file_reads_and_a_fifo_or_folder_is_refused_at_once(tmp_path) -> None:
    (tmp_path / "ok.txt").write_text("hello")
    assert read_bytes(tmp_path / "ok.txt") == b"hello" and read_text(tmp_path / "ok.txt") == "hello"
    os.mkfifo(tmp_path / "pipe")  # nothing writes to it: opening it for reading would block
    start = time.perf_counter()
    with pytest.raises(DatasetError, match="pipe: is a FIFO, not a regular image: refused"):
        read_bytes(tmp_path / "pipe", what="image")
    assert time.perf_counter() - start < 5.0
    with pytest.raises(DatasetError, match="is a folder, expected a file"):
        read_text(tmp_path)
    with pytest.raises(DatasetError, match="missing file"):
        read_text(tmp_path / "absent.yaml")


def test_a_stalled_read_ends_with_one_line(tmp_path, monkeypatch) -> None:
    (tmp_path / "slow.png").write_bytes(b"x")
    real = os.fdopen

    def stalled(fd, *args, **kwargs):
        time.sleep(2.0)  # a hung network mount
        return real(fd, *args, **kwargs)

    monkeypatch.setattr(errors.os, "fdopen", stalled)
    with pytest.raises(DatasetError, match=r"slow.png: reading the image took more than 0.2 s \(a stalled disk or network mount\?\)"):
        read_bytes(tmp_path / "slow.png", what="image", timeout_s=0.2)


def test_a_scene_file_that_is_a_fifo_is_refused(tmp_path) -> None:
    os.mkfifo(tmp_path / "scene.json")
    with pytest.raises(SceneFileError, match="scene.json: is a FIFO, not a regular file: refused"):
        load_scene(tmp_path / "scene.json")
