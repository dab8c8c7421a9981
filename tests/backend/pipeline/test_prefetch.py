"""Reading ahead changes nothing but the time: the pipeline gets every frame it asks for, in
its order, one reader of the input at a time, a bad frame's error where it is asked for, and
the same trajectory as reading on one thread."""

from __future__ import annotations

import threading
import time

import numpy as np
import pytest

from backend.frontend.points import Keypoints
from backend.pipeline.engine import EndOfSequence
from backend.pipeline.factory import EngineConfig, make_engine
from backend.pipeline.prefetch import FramePrefetch, PreparedFrame


class FakeInput:
    """Frames whose content is their index; frame `bad` cannot be read. Records which thread
    read each frame and the most readers it ever had at once."""

    def __init__(self, *, bad: int | None = None, delay_s: float = 0.001) -> None:
        self.bad = bad
        self.delay_s = delay_s
        self.readers = 0
        self.most_readers = 0
        self.read: list[int] = []
        self.threads: set[int] = set()
        self._lock = threading.Lock()

    def prepare(self, index: int) -> PreparedFrame:
        with self._lock:
            self.readers += 1
            self.most_readers = max(self.most_readers, self.readers)
        try:
            time.sleep(self.delay_s)
            if index == self.bad:
                raise OSError(f"frame {index}: unreadable")
            self.read.append(index)
            self.threads.add(threading.get_ident())
            image = np.full((2, 2), index, np.uint8)
            empty = Keypoints(uv=np.zeros((0, 2)), descriptors=np.zeros((0, 32), np.uint8), octave=np.zeros(0, np.int32))
            return PreparedFrame(index, image, image, empty, 1.0, 1.0, loaded_at=time.perf_counter())
        finally:
            with self._lock:
                self.readers -= 1


def test_frames_come_in_order_read_on_a_worker() -> None:
    source = FakeInput()
    prefetch = FramePrefetch(source.prepare, n_frames=30)
    got = [int(prefetch.take(i).left[0, 0]) for i in range(30)]
    assert got == list(range(30))
    assert len(source.threads - {threading.get_ident()}) >= 1  # frames after the first came from the worker
    assert source.most_readers == 1
    assert sorted(source.read) == list(range(30))  # each read once, none beyond the input


def test_a_restored_engine_going_back_gets_the_frame_it_asks_for() -> None:
    source = FakeInput()
    prefetch = FramePrefetch(source.prepare, n_frames=40)
    for i in range(10):
        prefetch.take(i)
    assert int(prefetch.take(3).left[0, 0]) == 3  # scrubbed back: the reader's frames 10.. are dropped
    assert [int(prefetch.take(i).left[0, 0]) for i in range(4, 12)] == list(range(4, 12))
    assert source.most_readers == 1


def test_an_unreadable_frame_fails_where_it_is_asked_for() -> None:
    source = FakeInput(bad=5)
    prefetch = FramePrefetch(source.prepare, n_frames=20)
    for i in range(5):
        prefetch.take(i)  # frame 5 was read ahead and failed: nothing raised yet
    with pytest.raises(OSError, match="frame 5: unreadable"):
        prefetch.take(5)


def test_reading_ahead_changes_no_output() -> None:
    """The stereo pipeline on the rendered room: the same keyframe poses and stage outcomes
    with the next frames read on a worker as on one thread."""

    def run(read_ahead: bool) -> tuple[np.ndarray, np.ndarray, list[int]]:
        engine = make_engine(EngineConfig(scene="room", duration_s=4.0, read_ahead=read_ahead))
        frames = []
        while True:
            try:
                snapshot = engine.step()
            except EndOfSequence:
                break
            frames.append(snapshot.tracking.frames)
        return snapshot.estimate.R_world_camera, snapshot.estimate.t_world_camera, frames

    R_on, t_on, frames_on = run(True)
    R_off, t_off, frames_off = run(False)
    assert len(frames_on) >= 3 and frames_on == frames_off
    np.testing.assert_array_equal(R_on, R_off)
    np.testing.assert_array_equal(t_on, t_off)


EXIT_WHILE_READING = """
import sys
from backend.pipeline.factory import EngineConfig, make_engine
engine = make_engine(EngineConfig(scene="room", duration_s=4.0))
engine.step()
sys.exit(0)  # the next frames are being read and detected on the reader thread now
"""


def test_a_script_that_ends_while_frames_are_read_ahead_exits_cleanly() -> None:
    """The reader is stopped before the interpreter finalizes: a thread still inside OpenCV
    then aborted the process ("terminate called without an active exception", exit 134) in
    about one exit in three, and Ctrl-C or SIGTERM during a run the same way."""
    import os
    import subprocess
    import sys
    from pathlib import Path

    root = Path(__file__).resolve().parents[3]
    for _ in range(6):
        done = subprocess.run([sys.executable, "-c", EXIT_WHILE_READING], cwd=root, env={**os.environ, "OPENBLAS_NUM_THREADS": "1"}, capture_output=True, text=True, timeout=120)
        assert done.returncode == 0 and "terminate called" not in done.stderr, done.stderr[-500:]
