"""Benchmark: stereo pairs of a synthetic scene rendered per second on one core.

Renders `--pairs` rectified stereo pairs (752×480, EuRoC-like intrinsics, baseline 0.11 m)
along a smooth random trajectory (`backend.data.motion.random_trajectory`, camera looking
along the body's x axis), `--repeats` times, and prints the median throughput. BLAS, OpenMP
and OpenCV are limited to one thread. Goal (issue 4): at least 10 pairs per second.

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

from backend.data import motion, render, scenes
from backend.geometry.camera import PinholeCamera

CAMERA = PinholeCamera(fx=458.0, fy=458.0, cx=367.0, cy=248.0, width=752, height=480, baseline=0.11)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--scene", default=scenes.DEFAULT_SCENE, choices=scenes.SCENE_NAMES)
    parser.add_argument("--pairs", type=int, default=40, help="stereo pairs per run")
    parser.add_argument("--repeats", type=int, default=5, help="runs; the median is reported")
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()
    cv2.setNumThreads(1)

    scene = scenes.builtin_scene(args.scene)
    centre, half_extent = scene.camera_region
    trajectory = motion.random_trajectory(
        np.random.default_rng(args.seed),
        centre=np.array([centre[0], centre[1], 0.0]),
        half_extent=half_extent,
        height=float(centre[2]),
    )
    times_s = np.arange(args.pairs) / 20.0  # 20 Hz
    R_world_camera = trajectory.rotation(times_s) @ render.R_BODY_CAMERA_FORWARD
    t_world_camera = trajectory.position(times_s)

    render.render_stereo(scene, CAMERA, R_world_camera[0], t_world_camera[0])  # textures, caches
    rates = []
    for _ in range(args.repeats):
        start = time.perf_counter()
        for R, t in zip(R_world_camera, t_world_camera, strict=True):
            render.render_stereo(scene, CAMERA, R, t)
        rates.append(args.pairs / (time.perf_counter() - start))
    print(f"scene {args.scene}: {args.pairs} stereo pairs of {CAMERA.width}x{CAMERA.height} per run, {args.repeats} runs, one thread")
    print(f"  pairs/s: median {np.median(rates):.1f} (min {min(rates):.1f}, max {max(rates):.1f}); goal >= 10")
    print(f"  {platform.processor() or platform.machine()}, python {platform.python_version()}, opencv {cv2.__version__}")


if __name__ == "__main__":
    main()
