"""Step 5 of a keyframe: the sliding-window bundle adjustment with the selected variant.

The window is assembled from the map (`backend.mapping.window`), extended by what the
engine's window adds (:class:`WindowExtension`: VIO's inertial factors and marginalization
prior), built into a problem for the variant, solved, and written back into the map."""

from __future__ import annotations

import dataclasses
import time
from collections.abc import Callable
from typing import Protocol

import numpy as np

from backend.common.timing import Stage
from backend.mapping.map import Map
from backend.mapping.window import Window, WindowSettings, assemble_window, write_back
from backend.optim.problem import Problem, ProblemData, State, build_problem
from backend.optim.solver import Damping, optimize
from backend.optim.structure import HessianStructure, hessian_structure
from backend.optim.variant import Variant
from backend.pipeline.snapshot import OptimizationReport


class WindowExtension(Protocol):
    """What an engine adds to the plain visual window (the stereo engine adds nothing)."""

    def keep_landmarks(self, w0: int) -> Callable[[np.ndarray, np.ndarray], tuple[np.ndarray, np.ndarray]] | None:
        """Which of the landmarks the window's keyframes observe its problem keeps (None: all)."""

    def extra_planes(self) -> np.ndarray | None:
        """Planes the window optimizes besides those its landmarks support."""

    def fix_first_pose(self) -> bool:
        """Whether the first window pose is held as the gauge when no older one is."""

    def pinned_poses(self) -> np.ndarray | None:
        """Keyframes whose pose the window holds wherever they are (None: none)."""

    def problem_data(self, window: Window) -> ProblemData:
        """The window's data as solved (e.g. with inertial factors)."""

    def after_solve(self, window: Window, problem: Problem, state: State) -> None:
        """Called with the solution after the map is updated (e.g. velocities, biases, marginalization)."""


@dataclasses.dataclass(frozen=True)
class VisualWindow:
    """The plain visual window: every observed landmark, the first pose as the gauge, and
    the `pinned` keyframes' poses held (the stereo engine's keyframes placed by flow)."""

    pinned: np.ndarray | None = None

    def pinned_poses(self) -> np.ndarray | None:
        return self.pinned

    def keep_landmarks(self, w0: int) -> None:
        return None

    def extra_planes(self) -> None:
        return None

    def fix_first_pose(self) -> bool:
        return True

    def problem_data(self, window: Window) -> ProblemData:
        return window.data

    def after_solve(self, window: Window, problem: Problem, state: State) -> None:
        pass


@dataclasses.dataclass(frozen=True)
class SolveSettings:
    """The solver (`method`, `max_iterations`, Cauchy kernel width `cauchy` in px), whether
    to compute the Hessian's structure for the debugger, and the window's settings."""

    method: str
    max_iterations: int
    cauchy: float | None
    hessian: bool
    window: WindowSettings
    damping: Damping = Damping.MARQUARDT


def solve_window(
    the_map: Map,
    k: int,
    variant: Variant,
    *,
    w0: int,
    oldest: int,
    extension: WindowExtension,
    settings: SolveSettings,
    timing: dict[str, float],
) -> tuple[Window, OptimizationReport, HessianStructure | None]:
    """Solve keyframe k's window [w0, k] (observations from `oldest` on) with `variant` and
    write the solution into the map. Times (ms) go into `timing`: setup, optimization
    (linearize, solve), update, hessian. Returns the window, the report and the Hessian's
    structure (None when nothing was solved or it was not asked for)."""
    s = settings
    t0 = time.perf_counter()
    win = assemble_window(
        the_map,
        k,
        w0=w0,
        oldest=oldest,
        settings=s.window,
        fix_first=extension.fix_first_pose(),
        keep_landmarks=extension.keep_landmarks(w0),
        extra_planes=extension.extra_planes(),
        pinned=extension.pinned_poses(),
    )
    win = dataclasses.replace(win, data=extension.problem_data(win))
    problem = build_problem(win.data, variant, robust_px=s.cauchy)
    timing[Stage.SETUP] = 1e3 * (time.perf_counter() - t0)
    assert win.data.fixed_poses is not None  # assemble_window always sets it
    free = ~win.data.fixed_poses
    if not np.any(free) or problem.layout.n_params == 0:  # a segment's first keyframe: nothing to solve
        timing[Stage.OPTIMIZATION] = timing[Stage.LINEARIZE] = timing[Stage.SOLVE] = 0.0
        report = OptimizationReport(variant, s.method, 0, 0.0, 0.0, True, problem.layout.n_items, problem.layout.n_params, int(free.sum()), int((~free).sum()), timing)
        return win, report, None
    state, rep = optimize(problem, method=s.method, max_iterations=s.max_iterations, damping=s.damping)
    timing[Stage.OPTIMIZATION] = rep.time_ms
    timing[Stage.LINEARIZE] = rep.linearize_ms
    timing[Stage.SOLVE] = rep.solve_ms
    t0 = time.perf_counter()
    write_back(the_map, win, problem, state, variant)
    extension.after_solve(win, problem, state)
    timing[Stage.UPDATE] = 1e3 * (time.perf_counter() - t0)
    hessian = None
    if s.hessian:
        t0 = time.perf_counter()
        hessian = hessian_structure(problem, state)
        timing[Stage.HESSIAN] = 1e3 * (time.perf_counter() - t0)
    report = OptimizationReport(
        variant=variant,
        method=s.method,
        iterations=rep.iterations,
        initial_cost=rep.initial_cost,
        final_cost=rep.final_cost,
        converged=rep.converged,
        items=rep.items,
        params=rep.params,
        window=int(free.sum()),
        fixed_poses=int((~free).sum()),
        timing_ms=timing,
        termination=rep.termination,
        dropped_landmarks=rep.dropped_landmarks,
    )
    return win, report, hessian
