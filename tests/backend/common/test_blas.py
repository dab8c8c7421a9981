"""A script or notebook that imports `backend` after NumPy (so OPENBLAS_NUM_THREADS is read
too late) still gets one BLAS thread in the library's solves and engine steps, and keeps its
own thread count outside them."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[3]

PROBE = r"""
import json, sys
import numpy as np                      # NumPy first, as a notebook does: the env var is too late now
from threadpoolctl import threadpool_info, threadpool_limits
threadpool_limits(limits=2, user_api="blas")   # what a 2-core machine gives by default
import backend
from backend.eval import montecarlo, sequences
from backend.optim import solver
from backend.optim.problem import build_problem

def blas_threads():
    return sorted({lib["num_threads"] for lib in threadpool_info() if lib["user_api"] == "blas"})

seen = []
original = solver.solve_schur_blocks
def spy(*args, **kwargs):
    seen.append(blas_threads())
    return original(*args, **kwargs)
solver.solve_schur_blocks = spy

data = montecarlo.make_problem_data(sequences.make_world("b"), np.random.default_rng([0, 0]))
before = blas_threads()
solver.optimize(build_problem(data, "P-wo"), max_iterations=2)
after = blas_threads()

from backend.common.blas import single_threaded_blas
@single_threaded_blas
def outer():
    inner = single_threaded_blas(blas_threads)()   # nested: still limited, and left limited
    return inner, blas_threads()
nested, after_inner = outer()
print(json.dumps({"before": before, "inside": seen, "after": after, "nested": nested, "after_inner": after_inner, "final": blas_threads()}))
"""


def _probe(env_extra: dict[str, str]) -> dict:
    env = {k: v for k, v in os.environ.items() if k not in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "COPLANAR_BLAS_THREADS")}
    env.update(env_extra)
    done = subprocess.run([sys.executable, "-c", PROBE], cwd=ROOT, env=env, capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr
    return json.loads(done.stdout.strip().splitlines()[-1])


def test_the_solve_runs_on_one_blas_thread_and_the_callers_setting_comes_back() -> None:
    out = _probe({})
    assert out["before"] == [2]
    assert out["inside"], "the spy saw no solve"
    assert all(threads == [1] for threads in out["inside"])
    assert out["after"] == [2]
    assert out["nested"] == [1] and out["after_inner"] == [1]
    assert out["final"] == [2]


def test_the_thread_count_can_be_chosen_and_a_bad_value_is_named() -> None:
    out = _probe({"COPLANAR_BLAS_THREADS": "2"})
    assert all(threads == [2] for threads in out["inside"])
    env = {k: v for k, v in os.environ.items()}
    env["COPLANAR_BLAS_THREADS"] = "many"
    done = subprocess.run([sys.executable, "-c", PROBE], cwd=ROOT, env=env, capture_output=True, text=True, timeout=300)
    assert done.returncode != 0
    assert "COPLANAR_BLAS_THREADS='many'" in done.stderr


@pytest.mark.parametrize("engine", ["stereo", "vio", "sim"])
def test_engine_steps_are_limited(engine: str) -> None:
    """The engines' `step` is an entry point too (many small solves outside `optimize`)."""
    from backend.pipeline import sim_engine, stereo_engine, vio_engine

    cls = {"stereo": stereo_engine.StereoEngine, "vio": vio_engine.VioEngine, "sim": sim_engine.SimEngine}[engine]
    assert getattr(cls.step, "__wrapped__", None) is not None, f"{cls.__name__}.step is not under single_threaded_blas"
