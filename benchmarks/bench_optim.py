"""Benchmark: 10 Gauss-Newton iterations of a variant on a Monte-Carlo sequence.

Prints the median (over --repeats) wall time of the solver loop and its split into
linearization, solve (normal equations + Schur + Cholesky) and other, with the iterations
and linearizations done. The convergence tests are off, so every run does 10 iterations
unless no step lowers the cost; a rejected trial step costs a linearization (and a damped
re-solve when shortening does not help), which the `lins` column shows. Goals (issue 2):
PL-w on b under 50 ms, PL-w on a under 300 ms.

    .venv/bin/python benchmarks/bench_optim.py --sequence b --variant PL-w
"""

from __future__ import annotations

import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import argparse
import platform
import time

import numpy as np

from backend.eval import montecarlo, sequences
from backend.optim.problem import build_problem
from backend.optim.solver import optimize
from backend.optim.variant import VARIANTS


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--sequence", choices=("a", "b"), action="append")
    parser.add_argument("--variant", choices=VARIANTS, action="append")
    parser.add_argument("--repeats", type=int, default=15)
    args = parser.parse_args()
    print(f"# python {platform.python_version()}, {platform.machine()}, {os.cpu_count()} cpus, OPENBLAS_NUM_THREADS={os.environ.get('OPENBLAS_NUM_THREADS')}")
    print(f"{'seq':3s} {'variant':7s} {'total ms':>9s} {'linearize':>9s} {'solve':>9s} {'other':>9s} {'setup':>9s} {'iters':>5s} {'lins':>5s} {'solver':>6s}  (median of {args.repeats})")
    for seq in args.sequence or ["b", "a"]:
        world = sequences.make_world(seq)
        data = montecarlo.make_problem_data(world, np.random.default_rng([0, 0]))
        for variant in args.variant or list(VARIANTS):
            rows = []
            for _ in range(args.repeats):
                t0 = time.perf_counter()
                problem = build_problem(data, variant)
                problem.prepare()
                setup = 1e3 * (time.perf_counter() - t0)
                _, rep = optimize(problem, method="gn", max_iterations=10, relative_tolerance=0.0, step_tolerance=0.0)
                rows.append((rep.time_ms, rep.linearize_ms, rep.solve_ms, rep.other_ms, setup, rep.iterations, rep.linearizations))
            med = np.median(np.array(rows), axis=0)
            print(f"{seq:3s} {variant:7s} {med[0]:9.1f} {med[1]:9.1f} {med[2]:9.1f} {med[3]:9.1f} {med[4]:9.1f} {med[5]:5.0f} {med[6]:5.0f} {rep.linear_solver:>6s}")


if __name__ == "__main__":
    main()
