"""A sliding-window engine over the Monte-Carlo worlds (DESIGN §4): the debugger's built-in
scene until the rendered worlds and the stereo pipeline exist.

One keyframe arrives per step with noisy pixel observations (σ = 1 px) of the visible
points and segments, an odometry measurement (the true relative pose of the previous
keyframe, perturbed by `odometry_*_sigma` per axis) and a simulated plane-instance segmentation: each observation is
labelled with its wall, except a settable fraction that gets another visible wall's label
(or none). Per step:

1. the new pose is predicted by odometry and refined against the triangulated points;
2. landmarks with two views (and enough parallax) are triangulated;
3. co-planar detection on the keyframe: the features of each instance go through RANSAC
   with Eq. 4 distances, θ_cp = 80 %; accepted planes merge with existing ones, and new
   landmarks are tested against existing planes;
4. bundle adjustment of the last `window` keyframes with the selected variant; older
   keyframes that see window landmarks are held fixed, and while the first keyframe is in
   the window a prior holds it at its true pose (the gauge, as in the study).

With `loop=True` the trajectory continues past the sequence's last pose (sequence a is a
closed circle; b runs back and forth), so the engine can run indefinitely.
"""

from __future__ import annotations

import dataclasses
import time

import numpy as np

from backend.common.blas import single_threaded_blas
from backend.common.timing import Stage
from backend.eval import sequences
from backend.mapping import coplanar
from backend.mapping.window import Window
from backend.optim.problem import build_problem
from backend.optim.solver import optimize
from backend.optim.structure import HessianStructure, hessian_structure
from backend.optim.variant import VARIANTS, Variant
from backend.pipeline.engine import EndOfSequence, EngineCheckpoint
from backend.pipeline.sim_stages.measure import simulate_keyframe, track_keyframe
from backend.pipeline.sim_stages.planes import detect_planes, refit_unused_planes
from backend.pipeline.sim_stages.snapshot import build_snapshot
from backend.pipeline.sim_stages.state import FrameObs, SimKeyframes, SimLandmarks, keep_anchor_views
from backend.pipeline.sim_stages.triangulate import retriangulate_lines, triangulate_new
from backend.pipeline.sim_stages.window import assemble_window, window_start
from backend.pipeline.snapshot import Detection, OptimizationReport, Snapshot

KEYFRAME_PERIOD_NS = 100_000_000  # 10 Hz keyframes


@dataclasses.dataclass(frozen=True)
class SimSettings:
    """Settings of the Monte-Carlo engine.

    Noise: `pixel_sigma` (px) on every observation, as in DESIGN §4. Odometry: the true
    relative pose from the previous keyframe, rotated by exp(n_θ) and shifted by n_p, with
    `odometry_rotation_sigma_rad` / `odometry_position_sigma_m` per axis. (The study's
    perturbation of absolute poses by 1° and 10 cm amounts to odometry steps of √2·10 cm
    on 6 cm of motion: an incremental pipeline cannot bootstrap triangulation from that.)
    `mislabel`: fraction of observations whose instance label is wrong. `window`: keyframes
    optimized per step; `fixed_horizon`: older keyframes whose observations of window
    landmarks enter as fixed poses. `min_parallax_deg`: smallest ray angle (points) or
    back-projection plane angle (lines) to triangulate. `min_plane_support`: features of a
    plane that must be in the window for the plane to be optimized there.
    """

    sequence: str = "a"
    seed: int = 0
    variant: Variant = Variant.PL_W
    window: int = 10
    fixed_horizon: int = 10
    mislabel: float = 0.1
    pixel_sigma: float = 1.0
    odometry_rotation_sigma_rad: float = float(np.deg2rad(0.5))
    odometry_position_sigma_m: float = 0.02
    min_parallax_deg: float = 1.5
    min_plane_support: int = 10
    max_iterations: int = 10
    method: str = "gn"
    loop: bool = True
    coplanar: coplanar.CoplanarSettings = coplanar.CoplanarSettings()

    def __post_init__(self) -> None:
        if self.sequence not in sequences.SEQUENCES:
            raise ValueError(f"unknown sequence {self.sequence!r}; expected one of {', '.join(sequences.SEQUENCES)}")
        object.__setattr__(self, "variant", Variant.parse(self.variant))  # a name given as text is parsed here, once
        if self.window < 2:
            raise ValueError("window must be at least 2 keyframes")
        if not 0.0 <= self.mislabel <= 1.0:
            raise ValueError("mislabel must be a fraction in [0, 1]")


class SimEngine:
    """The Monte-Carlo sliding-window engine (implements :class:`~backend.pipeline.engine.Engine`).

    It runs the steps of `backend.pipeline.sim_stages` on its state: the keyframes
    (`_keyframes`), what each observed (`_obs`; pruned to anchor views past the window and
    fixed horizon), the landmarks (`_landmarks`) and the planes (`_planes`)."""

    def __init__(self, settings: SimSettings = SimSettings()) -> None:
        self.settings = settings
        self._variant = settings.variant
        self._world = sequences.make_world(settings.sequence, seed=settings.seed)
        self.reset()

    # ------------------------------------------------------------------ Engine interface

    @property
    def source(self) -> str:
        return f"Monte-Carlo sequence {self.settings.sequence} (seed {self.settings.seed})"

    @property
    def variant(self) -> Variant:
        return self._variant

    @property
    def keyframes(self) -> int:
        return len(self._keyframes)

    def set_variant(self, variant: Variant) -> None:
        self._variant = Variant.parse(variant)

    # A checkpoint deep-copies STATE and keeps SHARED by reference (backend.pipeline.engine.EngineCheckpoint).
    STATE: tuple[str, ...] = ("_keyframes", "_obs", "_landmarks", "_planes", "_variant", "_window")
    SHARED: tuple[str, ...] = ("settings", "_world", "_last")

    def checkpoint(self) -> EngineCheckpoint:
        return EngineCheckpoint.of(self)

    def restore(self, state: EngineCheckpoint) -> None:
        state.restore_into(self)

    def reset(self) -> None:
        w = self._world
        self._keyframes = SimKeyframes()
        self._obs: dict[int, FrameObs] = {}
        self._landmarks = SimLandmarks.empty(len(w.points), len(w.segments))
        self._planes = coplanar.PlaneSet()
        self._window: Window | None = None
        self._last: Snapshot | None = None

    @single_threaded_blas
    def step(self) -> Snapshot:
        s = self.settings
        k = self.keyframes
        n_world = len(self._world.t_world_camera)
        if not s.loop and k >= n_world:
            raise EndOfSequence(f"sequence {s.sequence} has {n_world} keyframes")
        timing: dict[str, float] = {}
        t0 = time.perf_counter()
        rng = np.random.default_rng([s.seed, k, 0x5E])
        self._add_keyframe(k, rng)
        timing[Stage.TRACKING] = 1e3 * (time.perf_counter() - t0)
        t1 = time.perf_counter()
        new_points, new_lines = triangulate_new(
            self._landmarks, self._obs, k, camera=self._world.camera, poses=self._keyframes.estimate(), min_parallax_deg=s.min_parallax_deg, pixel_sigma=s.pixel_sigma
        )
        timing[Stage.TRIANGULATION] = 1e3 * (time.perf_counter() - t1)
        t1 = time.perf_counter()
        detection, state = detect_planes(
            self._landmarks, self._obs[k], new_points, new_lines, rng, planes=self._planes, camera=self._world.camera, poses=self._keyframes.estimate(), settings=s.coplanar
        )
        timing[Stage.DETECTION] = 1e3 * (time.perf_counter() - t1)
        self._prune(k)
        return self._optimize(k, detection, state, timing, t0)

    def reoptimize(self) -> Snapshot:
        if self._last is None:
            raise RuntimeError("nothing to re-optimize before the first step")
        last = self._last
        timing: dict[str, float] = {}
        state = (last.points.id, last.points.detection, last.lines.id, last.lines.detection)
        return self._optimize(last.keyframe, last.detection, state, timing, time.perf_counter())

    def compare_hessians(self, variants: tuple[Variant, ...]) -> dict[Variant, HessianStructure]:
        if self._window is None:
            return {}
        return {v: hessian_structure(build_problem(self._window.data, v)) for v in variants}

    # ------------------------------------------------------------------ one keyframe

    def _add_keyframe(self, k: int, rng: np.random.Generator) -> None:
        """Keyframe k's odometry and observations (sim_stages.measure), the landmarks it
        anchors, and its pose tracked against the triangulated points."""
        s, w = self.settings, self._world
        sim = simulate_keyframe(
            w,
            self._keyframes,
            k,
            rng,
            sequence=s.sequence,
            pixel_sigma=s.pixel_sigma,
            rotation_sigma_rad=s.odometry_rotation_sigma_rad,
            position_sigma_m=s.odometry_position_sigma_m,
            mislabel=s.mislabel,
        )
        self._obs[k] = sim.obs
        self._landmarks.anchor_new(k, sim.obs)
        R_est, t_est = track_keyframe(self._landmarks, sim.obs, sim.R_pred, sim.t_pred, camera=w.camera, pixel_sigma=s.pixel_sigma)
        self._keyframes.append(R_est=R_est, t_est=t_est, R_gt=sim.R_gt, t_gt=sim.t_gt, R_odo=sim.R_odo, t_odo=sim.t_odo, stamp_ns=k * KEYFRAME_PERIOD_NS)

    def _prune(self, k: int) -> None:
        """Forget observations older than the window and fixed horizon, except anchors."""
        old = k - self.settings.window - self.settings.fixed_horizon
        o = self._obs.get(old)
        if o is not None:
            self._obs[old] = keep_anchor_views(o, self._landmarks, old)

    # ------------------------------------------------------------------ window bundle adjustment

    def _optimize(self, k: int, detection: Detection, det_state: tuple, timing: dict[str, float], t_start: float) -> Snapshot:
        s = self.settings
        cam = self._world.camera
        L = self._landmarks
        t0 = time.perf_counter()
        win = assemble_window(
            L,
            self._obs,
            self._keyframes,
            self._planes,
            k,
            camera=cam,
            window=s.window,
            fixed_horizon=s.fixed_horizon,
            min_plane_support=s.min_plane_support,
            pixel_sigma=s.pixel_sigma,
            odometry_rotation_sigma_rad=s.odometry_rotation_sigma_rad,
            odometry_position_sigma_m=s.odometry_position_sigma_m,
        )
        self._window = win
        problem = build_problem(win.data, self._variant)
        timing[Stage.SETUP] = 1e3 * (time.perf_counter() - t0)
        state, rep = optimize(problem, method=s.method, max_iterations=s.max_iterations)
        timing[Stage.OPTIMIZATION] = rep.time_ms
        timing[Stage.LINEARIZE] = rep.linearize_ms
        timing[Stage.SOLVE] = rep.solve_ms
        t0 = time.perf_counter()
        assert win.data.fixed_poses is not None
        free = ~win.data.fixed_poses
        kf_free = win.kf[free]
        self._keyframes.R_est[kf_free] = state.poses.R_world_camera[free]
        self._keyframes.t_est[kf_free] = state.poses.t_world_camera[free]
        if len(win.points):
            p = problem.point_positions(state)
            good = np.all(np.isfinite(p), axis=1)
            L.p_world[win.points[good]] = p[good]
        if len(win.lines):
            if self._variant.with_lines:
                m, v = problem.line_pluecker(state)
                norm = np.linalg.norm(v, axis=1, keepdims=True)
                L.l_m[win.lines], L.l_v[win.lines] = m / norm, v / norm
            else:  # lines are not optimized: re-triangulate them from the new poses
                retriangulate_lines(L, self._obs, win.lines, camera=cam, poses=self._keyframes.estimate())
        used = problem.layout.plane_col >= 0
        for i, q in enumerate(win.planes):
            if used[i]:
                self._planes.n[q], self._planes.d[q] = state.plane_n[i].copy(), float(state.plane_d[i])
        optimized = set(int(q) for q, u in zip(win.planes, used) if u)
        refit_unused_planes(L, self._planes, optimized, camera=cam, poses=self._keyframes.estimate())
        timing[Stage.UPDATE] = 1e3 * (time.perf_counter() - t0)
        t0 = time.perf_counter()
        hessian = hessian_structure(problem, state)
        timing[Stage.HESSIAN] = 1e3 * (time.perf_counter() - t0)
        timing[Stage.TOTAL] = 1e3 * (time.perf_counter() - t_start)
        report = OptimizationReport(
            variant=self._variant,
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
        w0 = window_start(k, window=s.window)
        self._last = build_snapshot(L, self._keyframes, self._planes, k, w0, detection, det_state, report, hessian, camera=cam, source=self.source)
        return self._last


__all__ = ["SimEngine", "SimSettings", "VARIANTS"]
