"""Benchmark: the cost of gtsam's Python CustomFactor, the alternative to our compiled
per-observation kernels. Builds sequence b's PL-w reprojection factors as one CustomFactor
per observation (each evaluating the same residual and Jacobian code for one observation)
and times one `graph.linearize(values)`, i.e. one of the 10 Gauss-Newton iterations.

    .venv/bin/python benchmarks/bench_gtsam_customfactor.py
"""

from __future__ import annotations

import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import time

import gtsam
import numpy as np

from backend.eval import montecarlo, sequences
from backend.optim.problem import build_problem


def main() -> None:
    world = sequences.make_world("b")
    data = montecarlo.make_problem_data(world, np.random.default_rng([0, 0]))
    problem = build_problem(data, "PL-w")
    state = problem.initial_state()
    lin = problem.linearize(state)
    batch = next(b for b in lin.batches if b.name == "points")
    n_obs = batch.residual.shape[0]

    # One CustomFactor per observation over three Vector variables of the right sizes; its
    # callback returns that observation's (precomputed) residual and Jacobian blocks, so the
    # time measured is gtsam's per-factor Python overhead alone (a lower bound).
    graph = gtsam.NonlinearFactorGraph()
    values = gtsam.Values()
    keys = sorted({int(c) for c in batch.cols[:, [0, 6, 9]].ravel() if c >= 0})
    for c in keys:
        values.insert(c, np.zeros(3 if c >= problem.layout.group_start["planes"] else 6))
    noise = gtsam.noiseModel.Unit.Create(2)
    for m in range(n_obs):
        cols = [int(batch.cols[m, 0]), int(batch.cols[m, 6]), int(batch.cols[m, 9])]
        if min(cols) < 0 or len(set(cols)) < 3:
            continue
        blocks = [batch.jacobian[m][:, 0:6], batch.jacobian[m][:, 6:9], batch.jacobian[m][:, 9:15]]
        res = batch.residual[m].copy()

        def error(this: gtsam.CustomFactor, v: gtsam.Values, H: list | None, res=res, blocks=blocks) -> np.ndarray:
            if H is not None:
                for i, B in enumerate(blocks):
                    H[i] = B
            return res

        graph.add(gtsam.CustomFactor(noise, [cols[0], cols[1], cols[2]], error))
    graph.linearize(values)
    times = []
    for _ in range(7):
        t0 = time.perf_counter()
        graph.linearize(values)
        times.append(time.perf_counter() - t0)
    med = 1e3 * float(np.median(times))
    print(f"gtsam CustomFactor: {graph.size()} point factors, linearize {med:.1f} ms ({1e3 * med / graph.size():.1f} µs per factor) — one of 10 iterations, median of 7")
    t0 = time.perf_counter()
    for _ in range(7):
        problem.linearize(state)
    n_all = sum(b.residual.shape[0] for b in lin.batches)
    print(f"compiled kernels: the whole PL-w problem ({n_all} factors: points, lines, odometry, prior) linearizes in {1e3 * (time.perf_counter() - t0) / 7:.1f} ms")


if __name__ == "__main__":
    main()
