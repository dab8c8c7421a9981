"""Benchmark: our six variants against gtsam's built-in C++ factors and g2o, on identical data.

The peer is what a user could pick instead of this package: the traditional
parametrization in gtsam, one `Pose3` per camera (camera to world) and one `Point3` per
point landmark, `GenericProjectionFactorCal3_S2` for every point observation (the anchor
observations included: for a 3-DoF landmark they carry information), `BetweenFactorPose3`
for the odometry, `PriorFactorPose3` and `RangeFactorPose3` for the gauge, solved by
`GaussNewtonOptimizer` with its defaults (multifrontal Cholesky, COLAMD ordering). gtsam
has no built-in line factor: it is the peer of P-wo, and the PL variants are compared
against it too (the ratio column).

The second peer is g2o as ORB-SLAM2 uses it (benchmarks/peer_g2o.py): `VertexSE3Expmap`
cameras, marginalized `VertexPointXYZ` points (the Schur complement), `EdgeSE3ProjectXYZ`,
`BlockSolverSE3` over `LinearSolverEigenSE3`, first camera fixed; "g2o GN" with
`OptimizationAlgorithmGaussNewton`, "g2o LM" with `OptimizationAlgorithmLevenberg`
(ORB-SLAM's choice). g2o has no stopping test of its own (LM stops only when no damped step
lowers the cost): at equal work and by default both run 10 iterations; under the same
stopping rule g2o's own `SparseOptimizerTerminateAction` stops them at a relative gain of
10⁻⁵ (gain measured against the new cost, not the old: the same to first order). Its time
is `optimize()`, which includes g2o's symbolic structure build in the first iteration;
its setup is graph building and `initialize_optimization()`. Neither g2o nor gtsam runs
more than one thread here (the wheels load no OpenMP or TBB runtime; the script checks).

For every sequence and noise draw (DESIGN §4, run r seeded `(seed, r)`), both sides solve
the same `ProblemData` in one process, in three regimes:

- equal work: 10 Gauss-Newton iterations each, no convergence test on either side — the
  speed comparison. gtsam takes every full step; ours keeps its step control (it never
  accepts a step that raises the cost: it halves or damps, a rejected trial costing one
  more linearization, column "lin") and stops early only when no step lowers the cost
  any more (converged to rounding); the table lists such draws;
- same stopping rule: both stop when an iteration lowers the cost by less than gtsam's
  default relative tolerance (1e-5), at most 10 iterations;
- default: each side's default stopping rules, at most 10 iterations — what a user gets
  (ours stops at a relative decrease of 1e-10, gtsam at 1e-5: not equal work).

gtsam's plain Gauss-Newton has no step control: on some draws of sequence a it moves a
far point behind its cameras and raises IndeterminantLinearSystemException; such draws
are listed and left out of gtsam's medians.

Time is the solver loop only, the median of --repeats per draw, then the median over
draws: ours `SolveReport.time_ms` (the initial linearization included), gtsam
`optimizer.optimize()`. Setup is reported apart: ours `build_problem` + `prepare()`
(structure caches, kernel compilation), gtsam graph + values + optimizer construction (its
constructor computes the COLAMD ordering and the initial error). RMSE is the translational
RMSE of the final camera positions against the truth, in cm, without alignment (the prior
and the distance prior fix all seven gauge freedoms). Before the tables, each sequence's
first draw checks that the gtsam graph is the same problem as our P-wo, factor type by
factor type, at the initial values and at P-wo's solution. They differ by design in one
respect: P-wo's point lies on its anchor ray (the anchor observation is taken as exact and
dropped), gtsam's 3-DoF point may leave it, so gtsam's minimum is lower.

    .venv/bin/python benchmarks/bench_peer.py --runs 5
    .venv/bin/python benchmarks/bench_peer.py --runs 5 --no-g2o    # gtsam only
    .venv/bin/python benchmarks/bench_peer.py --sequence b --runs 2 --repeats 5
"""

from __future__ import annotations

import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
os.environ.setdefault("OMP_NUM_THREADS", "1")

import argparse
import dataclasses
import importlib.metadata
import pathlib
import platform
import sys
import time
from collections.abc import Sequence

import gtsam
import numpy as np
from gtsam.symbol_shorthand import L, X

from backend.eval import montecarlo, sequences
from backend.eval.trajectory import translational_rmse
from backend.optim.problem import ProblemData, State, build_problem
from backend.optim.solver import optimize
from backend.optim.variant import VARIANTS

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parent))
try:
    import peer_g2o
except ImportError:  # g2opy comes with the test tools (scripts/setup.sh --test)
    peer_g2o = None

MAX_ITERATIONS = 10
PEER = "gtsam"
G2O_PEERS: dict[str, str] = {"g2o GN": "gn", "g2o LM": "lm"}
# Ours at equal work: no convergence test. Its step control stays on: the solver never
# accepts a step that raises the cost, so it halves or damps an overshooting step (sequence
# a does that in its first iterations); a rejected trial costs a linearization, counted in
# the "lin" column. Once converged to rounding no step lowers the cost and it stops early
# ("stalled"): the table prints the iterations it did.
OURS_EQUAL_WORK: dict[str, float] = {"relative_tolerance": 0.0, "step_tolerance": 0.0}
# gtsam at equal work. Its test `currentError - newError <= absoluteErrorTol` would still fire
# at a tolerance of 0 as soon as an iteration does not decrease the error (rounding, once
# converged), so the absolute tolerance is -inf; a relative tolerance of 0 disables that test.
PEER_EQUAL_WORK: dict[str, float] = {"relative_tolerance": 0.0, "absolute_tolerance": -np.inf}
# The same stopping rule on both sides: ours stops at gtsam's default relative decrease.
OURS_SAME_RULE: dict[str, float] = {"relative_tolerance": gtsam.GaussNewtonParams().getRelativeErrorTol()}
REGIMES: dict[str, str] = {
    "equal": "equal work: 10 Gauss-Newton iterations each",
    "same": f"same stopping rule: both stop when the cost decreases by less than {OURS_SAME_RULE['relative_tolerance']:g} (relative; gtsam's default), at most 10 iterations",
    "default": "default: each side's default stopping rules, at most 10 iterations",
}


@dataclasses.dataclass(frozen=True)
class Solve:
    """One solve of one draw: solver-loop and setup wall time (ms, medians over repeats),
    iterations, linearizations (residuals and Jacobians evaluated, including the initial
    one; gtsam evaluates one per iteration plus error-only evaluations), how the solve
    ended, final cost (`Σ ½|r|²` of the whitened residuals) and translational RMSE of the
    final camera positions against the truth (cm, no alignment)."""

    time_ms: float
    setup_ms: float
    iterations: int
    linearizations: int
    termination: str
    final_cost: float
    rmse_cm: float
    failed: str = ""  # why the solve raised (gtsam), empty if it did not


@dataclasses.dataclass(frozen=True)
class PeerGraph:
    """The gtsam problem: graph, initial values, and the graph's factor indices per factor
    type ("points", "anchors", "odometry", "prior", "distance_prior")."""

    graph: gtsam.NonlinearFactorGraph
    values: gtsam.Values
    groups: dict[str, list[int]]
    n_poses: int


def initial_points_world(data: ProblemData) -> np.ndarray:
    """World positions (P, 3), metres, of the points from our inverse-depth initialization:
    `X_w = R_a x̂_a / ρ + t_a` in the initial anchor pose `a` (camera to world)."""
    x_a = data.camera.normalize(data.point_anchor_uv)
    R_a = data.poses.R_world_camera[data.point_anchor]
    t_a = data.poses.t_world_camera[data.point_anchor]
    return np.einsum("pij,pj->pi", R_a, x_a) / data.point_rho[:, None] + t_a


def anchor_observations(data: ProblemData) -> np.ndarray:
    """Mask of the point observations that are their landmark's own left anchor view (P-wo
    drops them: they are identically zero for an inverse depth)."""
    obs = data.point_obs
    return (obs.pose == data.point_anchor[obs.landmark]) & np.all(obs.offset == 0, axis=1)


def build_peer_graph(data: ProblemData) -> PeerGraph:
    """gtsam's traditional-parametrization graph of `data`: `X(i)` = `Pose3` camera to
    world, `L(p)` = `Point3` in the world frame (metres); factors with gtsam's built-in
    C++ implementations only."""
    cam = data.camera
    if np.any(data.point_obs.offset != 0):
        raise ValueError("stereo (right image) observations are not supported by the peer graph")
    graph = gtsam.NonlinearFactorGraph()
    values = peer_values(data.poses.R_world_camera, data.poses.t_world_camera, initial_points_world(data))
    groups: dict[str, list[int]] = {"points": [], "anchors": [], "odometry": [], "prior": [], "distance_prior": []}

    K = gtsam.Cal3_S2(cam.fx, cam.fy, 0.0, cam.cx, cam.cy)
    pixel = gtsam.noiseModel.Isotropic.Sigma(2, data.sigma_px)
    obs = data.point_obs
    is_anchor = anchor_observations(data)
    for m in range(len(obs)):
        groups["anchors" if is_anchor[m] else "points"].append(graph.size())
        graph.add(gtsam.GenericProjectionFactorCal3_S2(obs.uv[m], pixel, X(int(obs.pose[m])), L(int(obs.landmark[m])), K))

    od = data.odometry
    if od is not None:
        # gtsam's Pose3 tangent order is (rotation, translation).
        model = gtsam.noiseModel.Diagonal.Sigmas(np.r_[np.full(3, od.sigma_rot), np.full(3, od.sigma_pos)])
        for i, j, R_ij, t_ij in zip(od.i, od.j, od.R_i_j, od.t_i_j):
            groups["odometry"].append(graph.size())
            graph.add(gtsam.BetweenFactorPose3(X(int(i)), X(int(j)), gtsam.Pose3(gtsam.Rot3(R_ij), t_ij), model))
    pr = data.prior
    if pr is not None:
        model = gtsam.noiseModel.Diagonal.Sigmas(np.r_[np.full(3, pr.sigma_rot), np.full(3, pr.sigma_pos)])
        for k, R_p, t_p in zip(pr.index, pr.R_world_camera, pr.t_world_camera):
            groups["prior"].append(graph.size())
            graph.add(gtsam.PriorFactorPose3(X(int(k)), gtsam.Pose3(gtsam.Rot3(R_p), t_p), model))
    dp = data.distance_prior
    if dp is not None:
        model = gtsam.noiseModel.Isotropic.Sigma(1, dp.sigma)
        for i, j, dist in zip(dp.i, dp.j, dp.distance):
            groups["distance_prior"].append(graph.size())
            graph.add(gtsam.RangeFactorPose3(X(int(i)), X(int(j)), float(dist), model))
    return PeerGraph(graph, values, groups, len(data.poses.t_world_camera))


def peer_values(R_world_camera: np.ndarray, t_world_camera: np.ndarray, p_world: np.ndarray) -> gtsam.Values:
    """gtsam values: `X(i)` = camera-to-world pose (N, 3, 3) / (N, 3) metres, `L(p)` = world
    point (P, 3) metres."""
    values = gtsam.Values()
    for i, (R, t) in enumerate(zip(R_world_camera, t_world_camera)):
        values.insert(X(i), gtsam.Pose3(gtsam.Rot3(R), t))
    for p, X_w in enumerate(p_world):
        values.insert(L(p), X_w)
    return values


def peer_params(*, equal_work: bool) -> gtsam.GaussNewtonParams:
    """Gauss-Newton parameters: gtsam's defaults (linear solver, ordering, tolerances) with
    at most 10 iterations; `equal_work` disables every convergence test."""
    params = gtsam.GaussNewtonParams()
    params.setMaxIterations(MAX_ITERATIONS)
    if equal_work:
        params.setRelativeErrorTol(PEER_EQUAL_WORK["relative_tolerance"])
        params.setAbsoluteErrorTol(PEER_EQUAL_WORK["absolute_tolerance"])
    return params


def peer_positions(result: gtsam.Values, n_poses: int) -> np.ndarray:
    """Camera positions (N, 3) in the world frame, metres."""
    return np.array([result.atPose3(X(i)).translation() for i in range(n_poses)])


def solve_peer(data: ProblemData, world: sequences.World, *, equal_work: bool, repeats: int) -> Solve:
    """Build and solve the gtsam graph `repeats` times; medians of the times. A solve that
    raises (gtsam's plain Gauss-Newton takes full steps: a far point can be moved behind its
    cameras, and its system becomes indeterminate) is returned with `failed` set and NaNs."""
    times, setups = [], []
    for _ in range(repeats):
        t0 = time.perf_counter()
        peer = build_peer_graph(data)
        optimizer = gtsam.GaussNewtonOptimizer(peer.graph, peer.values, peer_params(equal_work=equal_work))
        t1 = time.perf_counter()
        try:
            result = optimizer.optimize()
        except RuntimeError as e:  # gtsam's IndeterminantLinearSystemException
            why = str(e).strip().splitlines()[0] + " " + next((line for line in str(e).splitlines() if "Symbol" in line), "").strip()
            return Solve(np.nan, 1e3 * (t1 - t0), int(optimizer.iterations()), 0, "", np.nan, np.nan, failed=why)
        t2 = time.perf_counter()
        setups.append(1e3 * (t1 - t0))
        times.append(1e3 * (t2 - t1))
    rmse = 100.0 * translational_rmse(peer_positions(result, peer.n_poses), world.t_world_camera)
    iterations = int(optimizer.iterations())
    return Solve(float(np.median(times)), float(np.median(setups)), iterations, iterations, "", float(peer.graph.error(result)), rmse)


def solve_g2o(data: ProblemData, world: sequences.World, name: str, *, regime: str, repeats: int) -> Solve:
    """Build and solve the g2o graph with the algorithm of peer `name` ("g2o GN" or "g2o
    LM") `repeats` times; medians of the times. Under the "same" regime g2o's terminate
    action stops at a relative gain of 10⁻⁵. A run whose linear solve fails (g2o then
    stops early without raising: no iteration done, or Gauss-Newton ending before 10
    iterations without the terminate action) or whose cost ends non-finite is returned
    with `failed`."""
    algorithm = G2O_PEERS[name]
    times, setups = [], []
    for _ in range(repeats):
        t0 = time.perf_counter()
        graph = peer_g2o.build_g2o_graph(data, points_world=initial_points_world(data), algorithm=algorithm)  # type: ignore[arg-type]
        graph.optimizer.initialize_optimization()
        stop = None
        if regime == "same":
            stop = peer_g2o.g2opy.SparseOptimizerTerminateAction()
            stop.set_gain_threshold(OURS_SAME_RULE["relative_tolerance"])
            stop.set_max_iterations(MAX_ITERATIONS)
            graph.optimizer.add_post_iteration_action(stop)
        t1 = time.perf_counter()
        iterations = int(graph.optimizer.optimize(MAX_ITERATIONS))
        t2 = time.perf_counter()
        setups.append(1e3 * (t1 - t0))
        times.append(1e3 * (t2 - t1))
    cost = graph.total_cost()
    stopped_by_action = bool(graph.optimizer.terminate())
    if not np.isfinite(cost) or iterations == 0 or (algorithm == "gn" and iterations < MAX_ITERATIONS and not stopped_by_action):
        return Solve(np.nan, float(np.median(setups)), iterations, 0, "", np.nan, np.nan, failed="the linear solve failed (g2o stops without raising)")
    termination = "" if iterations == MAX_ITERATIONS else ("gain below 1e-05 (terminate action)" if stopped_by_action else "no damped step lowered the cost")
    rmse = 100.0 * translational_rmse(graph.positions(), world.t_world_camera)
    return Solve(float(np.median(times)), float(np.median(setups)), iterations, 0, termination, cost, rmse)


def solve_ours(data: ProblemData, world: sequences.World, variant: str, *, regime: str, repeats: int) -> Solve:
    """Build, prepare and solve one variant `repeats` times; medians of the times."""
    options = {"equal": OURS_EQUAL_WORK, "same": OURS_SAME_RULE, "default": {}}[regime]
    times, setups = [], []
    for _ in range(repeats):
        t0 = time.perf_counter()
        problem = build_problem(data, variant)
        problem.prepare()
        setups.append(1e3 * (time.perf_counter() - t0))
        state, report = optimize(problem, method="gn", max_iterations=MAX_ITERATIONS, **options)
        times.append(report.time_ms)
    rmse = 100.0 * translational_rmse(state.poses.t_world_camera, world.t_world_camera)
    return Solve(float(np.median(times)), float(np.median(setups)), report.iterations, report.linearizations, report.termination, report.final_cost, rmse)


@dataclasses.dataclass(frozen=True)
class CostCheck:
    """Costs `Σ ½|r|²` (whitened) per factor type of ours (P-wo) and of gtsam's graph at
    the same state. "anchors" are the anchor observations, which P-wo drops (zero wherever
    the point lies on its anchor ray, as every P-wo state does)."""

    ours: dict[str, float]
    peer: dict[str, float]
    g2o: dict[str, float] | None = None  # no "prior": g2o fixes the first camera instead


def cost_check(data: ProblemData, *, g2o: bool = True) -> tuple[CostCheck, CostCheck, int]:
    """Evaluate the problems (ours P-wo, gtsam's graph, g2o's graph if `g2o`) at the same
    states, factor type by factor type: the initial values, and the state P-wo converges
    to (its points mapped to world points). Also returns the number of point observations."""
    problem = build_problem(data, "P-wo")
    peer = build_peer_graph(data)
    g2o_graph = peer_g2o.build_g2o_graph(data, points_world=initial_points_world(data), algorithm="gn") if g2o else None

    def at(state: State) -> CostCheck:
        costs = problem.linearize(state).costs
        values = peer_values(state.poses.R_world_camera, state.poses.t_world_camera, problem.point_positions(state))
        ours = {name: float(costs.get(name, 0.0)) for name in peer.groups}
        theirs = {name: float(sum(peer.graph.at(k).error(values) for k in idx)) for name, idx in peer.groups.items()}
        if g2o_graph is None:
            return CostCheck(ours, theirs)
        g2o_graph.set_state(state.poses.R_world_camera, state.poses.t_world_camera, problem.point_positions(state))
        return CostCheck(ours, theirs, g2o_graph.costs())

    solved, _ = optimize(problem, method="gn", max_iterations=MAX_ITERATIONS)
    return at(problem.initial_state()), at(solved), len(data.point_obs)


def threading_note() -> str:
    """Which threading runtimes the loaded gtsam and g2o use (from the process's mapped libraries)."""
    with open("/proc/self/maps") as f:
        maps = f.read()
    found = [name for name in ("libtbb", "libgomp", "libomp", "libiomp") if name in maps]
    if not found:
        return "gtsam, g2o: no TBB/OpenMP loaded (single-threaded)"
    return f"gtsam, g2o: {', '.join(found)} loaded (may run multi-threaded)"


def machine_line() -> str:
    """Python, processor, CPU count, BLAS threads, gtsam version and threading, and the
    1-minute load average (timings are only comparable on an otherwise idle machine)."""
    cpu = platform.processor() or platform.machine()
    try:
        with open("/proc/cpuinfo") as f:
            cpu = next((line.split(":", 1)[1].strip() for line in f if line.startswith("model name")), cpu)
    except OSError:
        pass
    return (
        f"# python {platform.python_version()}, {cpu}, {os.cpu_count()} cpus, "
        f"OPENBLAS_NUM_THREADS={os.environ.get('OPENBLAS_NUM_THREADS')}, "
        f"gtsam {importlib.metadata.version('gtsam')}, g2opy {importlib.metadata.version('g2opy') if peer_g2o else '(not installed)'}; {threading_note()}; load average {os.getloadavg()[0]:.2f}"
    )


def _median(values: Sequence[float]) -> float:
    """Median over the finite values (NaN: a failed solve), NaN if none."""
    v = np.asarray(values, dtype=float)
    v = v[np.isfinite(v)]
    return float(np.median(v)) if len(v) else float("nan")


def _range(values: Sequence[int]) -> str:
    lo, hi = min(values), max(values)
    return f"{lo}" if lo == hi else f"{lo}-{hi}"


def print_table(title: str, solves: dict[str, list[Solve]]) -> None:
    """Medians over draws per solver (iterations and linearizations: their range; "-"
    where the bindings do not tell), failed solves left out; the ratios are time / each
    peer's time. Solves that stopped before 10 iterations or failed are listed with the
    reason."""
    print(title)
    peers = [name for name in (PEER, *G2O_PEERS) if name in solves]
    ratio_heads = " ".join(f"{'vs ' + name:>10s}" for name in peers)
    print(f"  {'variant':7s} {'time ms':>9s} {'ms/iter':>8s} {'iters':>6s} {'lin':>6s} {'setup ms':>9s} {'RMSE cm':>8s} {ratio_heads}")
    peer_times = {name: _median([s.time_ms for s in solves[name]]) for name in peers}
    for name, rows in solves.items():
        ok = [s for s in rows if not s.failed]
        if not ok:
            print(f"  {name:7s} {'failed on every draw':>40s}")
            continue
        t = _median([s.time_ms for s in ok])
        per_iter = _median([s.time_ms / max(s.iterations, 1) for s in ok])
        lin = _range([s.linearizations for s in ok]) if all(s.linearizations for s in ok) else "-"
        ratios = " ".join(f"{t / peer_times[p]:9.2f}x" for p in peers)
        print(f"  {name:7s} {t:9.2f} {per_iter:8.3f} {_range([s.iterations for s in ok]):>6s} {lin:>6s} {_median([s.setup_ms for s in ok]):9.2f} {_median([s.rmse_cm for s in ok]):8.3f} {ratios}")
    notes: dict[tuple[str, str], list[int]] = {}
    for name, rows in solves.items():
        for s in rows:
            if s.failed:
                notes.setdefault((name, f"FAILED in iteration {s.iterations + 1}: {s.failed}"), []).append(s.iterations)
            elif s.iterations < MAX_ITERATIONS:
                notes.setdefault((name, f"stopped: {s.termination or 'its convergence test held'}"), []).append(s.iterations)
    for (name, why), its in notes.items():
        verb = "" if why.startswith("FAILED") else f" after {_range(its)} iterations"
        print(f"    {name}: {len(its)} of {len(solves[name])} draws{verb}, {why}")


def print_cost_check(initial: CostCheck, solved: CostCheck) -> None:
    """Per factor type: ours (P-wo), and gtsam's and g2o's costs as ratios to ours, at the
    initial values and at P-wo's solution. g2o has no prior (its first camera is fixed):
    its total is compared with ours without the prior."""
    peers = "gtsam and g2o graphs" if initial.g2o is not None else "gtsam graph"
    print(f"  same problem? Σ ½|r|² (whitened) per factor type, run 0, ours P-wo vs the {peers} at the same state (ratios to ours):")
    print(f"    {'factor':15s} {'initial: ours':>14s} {'gtsam':>11s} {'g2o':>11s}   {'P-wo solution: ours':>20s} {'gtsam':>11s} {'g2o':>11s}")

    def ratio(o: float, p: float | None) -> str:
        return f"{p / o:11.6f}" if p is not None and o > 1e-9 else f"{'-':>11s}"  # "-": nothing to compare (both ~0)

    def cells(check: CostCheck, name: str, width: int) -> str:
        if name == "total":
            ours = sum(check.ours.values())
            g2o = ratio(ours - check.ours["prior"], None if check.g2o is None else sum(check.g2o.values()))
            return f"{ours:{width}.6g} {ratio(ours, sum(check.peer.values()))} {g2o}"
        g2o_cost = None if check.g2o is None else check.g2o.get(name)
        return f"{check.ours[name]:{width}.6g} {ratio(check.ours[name], check.peer[name])} {ratio(check.ours[name], g2o_cost)}"

    for name in [*initial.peer, "total"]:
        print(f"    {name:15s} {cells(initial, name, 14)}   {cells(solved, name, 20)}")
    if initial.g2o is not None:
        print("    (g2o fixes the first camera instead of a prior: its total is compared with ours without the prior)")


def run_sequence(seq: str, *, runs: int, repeats: int, seed: int, g2o: bool) -> None:
    """Every regime on `runs` draws of sequence `seq`; prints the cost check and a table
    per regime (g2o's two algorithms as peers too if `g2o`)."""
    world = sequences.make_world(seq, seed=seed)
    g2o_names = list(G2O_PEERS) if g2o else []
    names = [*VARIANTS, PEER, *g2o_names]
    solves: dict[str, dict[str, list[Solve]]] = {regime: {name: [] for name in names} for regime in REGIMES}
    for r in range(runs):
        data = montecarlo.make_problem_data(world, np.random.default_rng([seed, r]))
        if r == 0:
            initial, solved, n_obs = cost_check(data, g2o=g2o)
        for regime, by_name in solves.items():
            for variant in VARIANTS:
                by_name[variant].append(solve_ours(data, world, variant, regime=regime, repeats=repeats))
            by_name[PEER].append(solve_peer(data, world, equal_work=regime == "equal", repeats=repeats))
            for name in g2o_names:
                by_name[name].append(solve_g2o(data, world, name, regime=regime, repeats=repeats))
    n_points = len(data.point_anchor)
    print(f"\n## sequence {seq}: {len(world.t_world_camera)} cameras, {n_points} points, {n_obs} point observations; {runs} draws (seed {seed}), median of {repeats} repeats per draw")
    print_cost_check(initial, solved)
    equal = solves["equal"]
    print(
        f"  final cost after 10 iterations (median): ours P-wo {_median([s.final_cost for s in equal['P-wo']]):.6g}, "
        f"gtsam {_median([s.final_cost for s in equal[PEER]]):.6g}"
        + "".join(f", {name} {_median([s.final_cost for s in equal[name]]):.6g}" for name in g2o_names)
        + " (the peers' points are 3-DoF: they may leave their anchor rays; g2o's cost has no prior term)"
    )
    for regime, title in REGIMES.items():
        print_table(title, solves[regime])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--sequence", choices=("a", "b"), action="append", help="repeatable; default: both")
    parser.add_argument("--runs", type=int, default=5, help="noise draws per sequence")
    parser.add_argument("--repeats", type=int, default=3, help="timing repeats per draw (median)")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--no-g2o", action="store_true", help="gtsam as the only peer")
    args = parser.parse_args()
    if args.runs < 1 or args.repeats < 1:
        parser.error("--runs and --repeats must be at least 1")
    if peer_g2o is None and not args.no_g2o:
        parser.error("g2opy is not installed (bash scripts/setup.sh --test installs it); --no-g2o runs without the g2o peer")
    print(machine_line())
    for seq in args.sequence or ["a", "b"]:
        run_sequence(seq, runs=args.runs, repeats=args.repeats, seed=args.seed, g2o=not args.no_g2o)


if __name__ == "__main__":
    main()
