"""Benchmark: front-end time per stereo frame on 20 rendered room frames, single thread.
"point D&M": ORB detection in both images, stereo matching, sub-pixel disparity and
triangulation; "line D&M": LSD + LBD in both images, stereo matching and triangulation,
plus temporal matching against the previous frame's left segments (the paper's Table III
stages).

    .venv/bin/python benchmarks/bench_frontend.py
"""

from __future__ import annotations

import time

import cv2
import numpy as np

from backend.data.scenes import builtin_scene
from backend.data.synthetic import SequenceSettings, SyntheticSequence
from backend.frontend.lines import match_segments_temporal, stereo_segments
from backend.frontend.points import stereo_points

N_FRAMES = 20


def main() -> None:
    cv2.setNumThreads(1)
    seq = SyntheticSequence(builtin_scene("room"), settings=SequenceSettings(duration_s=(N_FRAMES + 1) / 20.0))
    pairs = [seq.rectified_pair(k) for k in range(N_FRAMES)]
    stereo_points(*pairs[0], camera=seq.camera)  # warm-up (detector construction)
    point_ms, line_ms, n_points, n_lines = [], [], [], []
    previous = None
    for left, right in pairs:
        t0 = time.perf_counter()
        points = stereo_points(left, right, camera=seq.camera)
        t1 = time.perf_counter()
        segments = stereo_segments(left, right, camera=seq.camera)
        if previous is not None:
            match_segments_temporal(previous.left, segments.left)
        t2 = time.perf_counter()
        previous = segments
        point_ms.append(1e3 * (t1 - t0))
        line_ms.append(1e3 * (t2 - t1))
        n_points.append(int(points.matched.sum()))
        n_lines.append(int(segments.matched.sum()))
    print(f"{N_FRAMES} stereo frames 752x480, 1 thread")
    print(f"point D&M: {np.mean(point_ms):6.1f} ms/frame  ({np.mean(n_points):.0f} stereo points)")
    print(f"line D&M:  {np.mean(line_ms):6.1f} ms/frame  ({np.mean(n_lines):.0f} stereo segments)")


if __name__ == "__main__":
    main()
