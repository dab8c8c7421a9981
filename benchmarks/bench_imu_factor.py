"""Benchmark: time per `imu_factor_error` call (whitened 9-vector residual and its five
whitened Jacobian blocks, project retraction) on a 0.5 s preintegration at 200 Hz, single
thread; median over 1000 calls. Two ways: with the prepared factor (`imu_factor(pim)`, built
once per preintegration, as a solver would) and with the raw preintegration (the factor and
its noise model rebuilt on every call). Also the cost of one 0.5 s `preintegrate`.

    .venv/bin/python benchmarks/bench_imu_factor.py
"""

from __future__ import annotations

import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import time

import numpy as np

from backend.data.motion import ImuNoise, imu_samples, random_trajectory
from backend.geometry import so3
from backend.imu.preintegration import imu_factor, imu_factor_error, preintegrate, preintegration_params

N_CALLS = 1000


def _median_us(fn, n: int) -> float:
    times = np.empty(n)
    for k in range(n):
        t0 = time.perf_counter()
        fn()
        times[k] = time.perf_counter() - t0
    return float(np.median(times) * 1e6)


def main() -> None:
    rng = np.random.default_rng(0)
    trajectory = random_trajectory(rng)
    imu = imu_samples(trajectory, start_ns=0, end_ns=2_000_000_000)
    params = preintegration_params(ImuNoise())
    t0_ns, t1_ns = 1_000_000_000, 1_500_000_000
    pim = preintegrate(imu, t0_ns, t1_ns, bias_accel=np.zeros(3), bias_gyro=np.zeros(3), params=params)
    t = np.array([t0_ns, t1_ns]) * 1e-9
    R, p, v = trajectory.rotation(t), trajectory.position(t), trajectory.velocity(t)
    R_i, R_j = R[0] @ so3.exp(rng.normal(0, 0.01, 3)), R[1] @ so3.exp(rng.normal(0, 0.01, 3))
    bias = rng.normal(0, 0.01, 6)
    term = imu_factor(pim)
    args = (R_i, p[0], v[0], R_j, p[1], v[1], bias)
    for _ in range(50):  # warm-up
        imu_factor_error(term, *args)
        imu_factor_error(pim, *args)
    prepared_us = _median_us(lambda: imu_factor_error(term, *args), N_CALLS)
    raw_us = _median_us(lambda: imu_factor_error(pim, *args), N_CALLS)
    build_us = _median_us(lambda: imu_factor(pim), N_CALLS)
    integrate_us = _median_us(lambda: preintegrate(imu, t0_ns, t1_ns, bias_accel=np.zeros(3), bias_gyro=np.zeros(3), params=params), 200)
    print(f"imu_factor_error, prepared factor:  {prepared_us:7.1f} µs per call (median of {N_CALLS})")
    print(f"imu_factor_error, raw preintegration: {raw_us:7.1f} µs per call (median of {N_CALLS})")
    print(f"imu_factor (factor + noise model):    {build_us:7.1f} µs per call (median of {N_CALLS})")
    print(f"preintegrate, 0.5 s at 200 Hz:        {integrate_us:7.1f} µs per call (median of 200)")


if __name__ == "__main__":
    main()
