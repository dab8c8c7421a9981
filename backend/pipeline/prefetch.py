"""The next frames read and their ORB keypoints detected on a worker thread while the
pipeline tracks the current one (as a camera driver delivers images while the tracker
works).

Reading (decoding and rectifying, or rendering) and ORB detection depend on the frame
alone, never on the map, so doing them ahead changes no output: the pipeline receives
exactly the arrays it would have computed itself, in the same order. OpenCV releases the
GIL in its decoding, remapping and ORB, so on a 2-core machine they overlap with
tracking's Python; up to 8 frames are kept ready, so the reader catches up while a keyframe
is processed. A failure in the worker (an unreadable image) is raised when the pipeline asks
for that frame, as if it had read it there; frames read ahead and never asked for (the run
stopped, or the engine was restored to an earlier frame) are dropped with their errors.
"""

from __future__ import annotations

import atexit
import collections
import dataclasses
import threading
import time
import weakref
from collections.abc import Callable

import numpy as np

from backend.frontend.points import Keypoints


@dataclasses.dataclass(frozen=True, eq=False)
class PreparedFrame:
    """Frame `index`'s rectified `left` and `right` images (uint8 grey, H×W) and the left
    image's ORB `keypoints`; `load_ms` and
    `detect_ms`: the reading and detection times, milliseconds of the thread that did them."""

    index: int
    left: np.ndarray
    right: np.ndarray
    keypoints: Keypoints
    load_ms: float
    detect_ms: float
    loaded_at: float = 0.0  # time.perf_counter() when the images were read
    load_wait_ms: float = 0.0  # how long the pipeline waited for the reading (set by `take`)


_READERS: weakref.WeakSet[_Reader] = weakref.WeakSet()


def _stop_readers_at_exit() -> None:
    """Stop every reader before the interpreter finalizes: a daemon thread still inside
    OpenCV then would abort the process ("terminate called without an active exception"),
    e.g. when Ctrl-C or SIGTERM ends a run while frames are read ahead."""
    for reader in list(_READERS):
        reader.stop(timeout_s=10.0)


atexit.register(_stop_readers_at_exit)


class _Reader:
    """Frames `start`, `start + 1`, ... prepared in order on one daemon thread, at most `depth`
    ready and not yet taken (a daemon: an interrupted run never waits for reads it no longer
    needs). A frame whose preparation fails is handed over with its error, and the reader
    stops there."""

    def __init__(self, prepare: Callable[[int], PreparedFrame], *, start: int, stop_at: int, depth: int) -> None:
        self.next_out = start
        self._prepare = prepare
        self._stop_at = stop_at
        self._depth = depth
        self._ready: collections.deque[tuple[PreparedFrame | None, BaseException | None]] = collections.deque()
        self._cond = threading.Condition()
        self._stopped = False
        self._thread = threading.Thread(target=self._run, args=(start,), name=f"coplanar-read-ahead-{start}", daemon=True)
        _READERS.add(self)
        self._thread.start()

    def _run(self, index: int) -> None:
        while index < self._stop_at:
            with self._cond:
                while len(self._ready) >= self._depth and not self._stopped:
                    self._cond.wait()
                if self._stopped:
                    return
            try:
                item: tuple[PreparedFrame | None, BaseException | None] = (self._prepare(index), None)
            except BaseException as error:  # handed to the pipeline's thread, raised there
                item = (None, error)
            with self._cond:
                self._ready.append(item)
                self._cond.notify_all()
                if item[1] is not None or self._stopped:
                    return
            index += 1

    def get(self) -> PreparedFrame:
        """Frame `next_out` (waiting for it); raises its preparation's error."""
        with self._cond:
            while not self._ready:
                self._cond.wait()
            frame, error = self._ready.popleft()
            self.next_out += 1
            self._cond.notify_all()
        if error is not None:
            raise error
        assert frame is not None
        return frame

    def stop(self, *, timeout_s: float | None = None) -> None:
        """Stop reading; returns when the frame being prepared, if any, is done (one reader of
        the input at a time; `timeout_s`: wait at most that long)."""
        with self._cond:
            self._stopped = True
            self._cond.notify_all()
        if self._thread is not threading.current_thread():
            self._thread.join(timeout_s)

    def stop_soon(self) -> None:
        """Stop reading without waiting (the engine is gone)."""
        with self._cond:
            self._stopped = True
            self._cond.notify_all()


class FramePrefetch:
    """Frames prepared ahead: `take(i)` returns frame i (from the reader if it is the next one
    read ahead, else read now) and keeps up to `depth` frames after it read ahead on a worker
    thread (the reader fills up while a keyframe is processed and the frames between
    keyframes then wait less). Thread-safe; shared by an engine's checkpoints (a restored
    engine asking for another frame than the next one read ahead reads its own and the
    reader starts again after it)."""

    def __init__(self, prepare: Callable[[int], PreparedFrame], *, n_frames: int, enabled: bool = True, depth: int = 8) -> None:
        self._prepare = prepare
        self._n_frames = n_frames
        self._enabled = enabled
        self._depth = depth
        self._lock = threading.Lock()
        self._reader: _Reader | None = None
        self._finalizer: weakref.finalize | None = None

    def take(self, index: int) -> PreparedFrame:
        """Frame `index`, with `load_wait_ms` the part of its reading the caller waited for
        (all of it when read now; what was left of it when the caller asked, when read ahead)."""
        asked_at = time.perf_counter()
        with self._lock:
            reader = self._reader
            if reader is not None and reader.next_out == index:
                frame = reader.get()
                return dataclasses.replace(frame, load_wait_ms=max(0.0, 1e3 * (frame.loaded_at - asked_at)))
            if reader is not None:  # read ahead from elsewhere: stop it (one reader of the input at a time)
                reader.stop()
                self._reader = None
            frame = self._prepare(index)
            if self._enabled and index + 1 < self._n_frames:
                self._reader = _Reader(self._prepare, start=index + 1, stop_at=self._n_frames, depth=self._depth)
                if self._finalizer is not None:
                    self._finalizer.detach()
                self._finalizer = weakref.finalize(self, self._reader.stop_soon)
            return dataclasses.replace(frame, load_wait_ms=frame.load_ms)


def timed_prepare(read: Callable[[int], tuple[np.ndarray, np.ndarray]], detect: Callable[[np.ndarray], Keypoints]) -> Callable[[int], PreparedFrame]:
    """A `prepare` function from the input's `read(i) -> (left, right)` and the detector."""

    def prepare(index: int) -> PreparedFrame:
        t0 = time.perf_counter()
        left, right = read(index)
        t1 = time.perf_counter()
        keypoints = detect(left)
        t2 = time.perf_counter()
        return PreparedFrame(index, left, right, keypoints, 1e3 * (t1 - t0), 1e3 * (t2 - t1), loaded_at=t1)

    return prepare
