"""Benchmark: stereo pairs of a synthetic scene rendered per second on one core.

Renders the first `--pairs` rectified stereo pairs of the scene's sequence (its rig: 752×480
EuRoC-like intrinsics at 20 Hz for most scenes, `street`'s 1241×376 KITTI-like ones at 10 Hz;
its motion: a smooth random trajectory, or `street`'s drive), `--repeats` times, and prints
the median throughput. BLAS, OpenMP and OpenCV are limited to one thread. Goal (issue 4): at
least 10 pairs per second.

    .venv/bin/python benchmarks/bench_render.py --scene room
"""

from __future__ import annotations

import os

for _name in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS", "NUMBA_NUM_THREADS"):
    os.environ.setdefault(_name, "1")

import argparse
import platform
import time

import cv2
import numpy as np

from backend.data import render, scenes
from backend.data.synthetic import SequenceSettings, SyntheticSequence


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--scene", default=scenes.DEFAULT_SCENE, choices=scenes.SCENE_NAMES)
    parser.add_argument("--pairs", type=int, default=40, help="stereo pairs per run")
    parser.add_argument("--repeats", type=int, default=5, help="runs; the median is reported")
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()
    cv2.setNumThreads(1)

    scene = scenes.builtin_scene(args.scene)
    seq = SyntheticSequence(scene, settings=SequenceSettings(duration_s=(args.pairs - 1) / scene.rig.camera_rate_hz, seed=args.seed))
    camera, T_world_rect0 = seq.camera, seq.T_world_rect0[: args.pairs]

    for T in T_world_rect0:  # textures, caches
        render.render_stereo(scene, camera, T[:3, :3], T[:3, 3])
    rates = []
    for _ in range(args.repeats):
        start = time.perf_counter()
        for T in T_world_rect0:
            render.render_stereo(scene, camera, T[:3, :3], T[:3, 3])
        rates.append(args.pairs / (time.perf_counter() - start))
    print(f"scene {args.scene}: {args.pairs} stereo pairs of {camera.width}x{camera.height} per run, {args.repeats} runs, one thread")
    print(f"  pairs/s: median {np.median(rates):.1f} (min {min(rates):.1f}, max {max(rates):.1f}); goal >= 10")
    print(f"  {platform.processor() or platform.machine()}, python {platform.python_version()}, opencv {cv2.__version__}")


if __name__ == "__main__":
    main()
