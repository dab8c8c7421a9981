"""Time the dense check adds per keyframe: the TSDF integration of one 752×480 depth map
(open3d's uniform volume, 3 cm voxels over the room), `--runs` passes over `--keyframes`
rendered keyframes of `room` at their true poses (depth rendered once, outside the timing);
prints the median per keyframe and its range over the passes, and the mesh extraction.

    .venv/bin/python benchmarks/bench_dense.py [--runs 5] [--keyframes 40]
"""

from __future__ import annotations

import argparse
import os
import pathlib
import platform
import statistics
import sys
import time

ROOT = pathlib.Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

import numpy as np

from backend.data.scenes import builtin_scene
from backend.data.synthetic import SequenceSettings, SyntheticSequence
from backend.eval.dense import DenseFusion, keyframe_depth, map_bounds


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--runs", type=int, default=5)
    p.add_argument("--keyframes", type=int, default=40)
    args = p.parse_args()
    print(f"{platform.processor() or platform.machine()}, {os.cpu_count()} CPUs, Python {platform.python_version()}")
    seq = SyntheticSequence(builtin_scene("room"), settings=SequenceSettings(duration_s=30.0))
    frames = np.linspace(0, len(seq) - 1, args.keyframes).astype(int)
    depth = {int(i): keyframe_depth(seq, int(i)) for i in frames}
    T = seq.T_world_rect0[frames]
    bounds = map_bounds(np.zeros((0, 3)), T[:, :3, 3], margin_m=3.5)
    per_keyframe, extract = [], []
    for _ in range(args.runs):
        fusion = DenseFusion(seq.camera, bounds)
        for i, Tk in zip(frames, T):
            fusion.integrate(depth[int(i)], Tk[:3, :3], Tk[:3, 3])
        per_keyframe.append(fusion.time_ms / fusion.keyframes)
        t0 = time.perf_counter()
        mesh = fusion.mesh()
        extract.append(1e3 * (time.perf_counter() - t0))
    print(
        f"integration: median {statistics.median(per_keyframe):.1f} ms per keyframe (range {min(per_keyframe):.1f}-{max(per_keyframe):.1f}, "
        f"{args.runs} passes of {args.keyframes} keyframes, {fusion.voxel_m * 100:.0f} cm voxels); mesh extraction {statistics.median(extract):.0f} ms "
        f"({len(mesh.triangles)} triangles)"
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
