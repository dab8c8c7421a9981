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

from backend.common.buffers import RowBuffer
from backend.common.timing import Stage
from backend.eval import sequences
from backend.eval.trajectory import ate_rmse, translational_rmse
from backend.geometry import line as line_geo
from backend.geometry import so3
from backend.geometry.se3 import Poses
from backend.mapping import coplanar
from backend.mapping.triangulation import triangulate_lines, triangulate_points
from backend.optim import factors
from backend.optim.problem import Observations, Odometry, PosePrior, ProblemData, build_problem
from backend.optim.solver import optimize
from backend.optim.structure import HessianStructure, hessian_structure
from backend.optim.variant import VARIANTS, Variant
from backend.pipeline.engine import EndOfSequence, EngineCheckpoint
from backend.pipeline.snapshot import (
    Detection,
    LineLandmarks,
    Metrics,
    OptimizationReport,
    PlaneLandmark,
    PointLandmarks,
    Snapshot,
    Trajectory,
    frozen,
)
from backend.pipeline.tracking import refine_pose

KEYFRAME_PERIOD_NS = 100_000_000  # 10 Hz keyframes
PRIOR_SIGMA = 1e-6


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


@dataclasses.dataclass
class _FrameObs:
    """Observations of one keyframe (world landmark ids, pixels, instance labels)."""

    point_id: np.ndarray
    point_uv: np.ndarray
    point_label: np.ndarray
    line_id: np.ndarray
    line_uv: np.ndarray
    line_label: np.ndarray


@dataclasses.dataclass
class _Window:
    """The last window problem: its data and which engine entities its rows are."""

    keyframe: int
    data: ProblemData
    kf: np.ndarray  # problem pose -> keyframe
    points: np.ndarray  # problem point -> landmark id
    lines: np.ndarray  # problem line -> landmark id
    planes: np.ndarray  # problem plane -> plane id


def _frame_index(k: int, n: int, name: str) -> int:
    """World pose index of keyframe k: a closed circle repeats (a), an open path returns (b)."""
    if name == "a":
        return k % n
    period = 2 * (n - 1)
    r = k % period
    return r if r < n else period - r


class SimEngine:
    """The Monte-Carlo sliding-window engine (implements :class:`~backend.pipeline.engine.Engine`)."""

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
        return len(self._t_est)

    def set_variant(self, variant: Variant) -> None:
        self._variant = Variant.parse(variant)

    # A checkpoint deep-copies STATE and keeps SHARED by reference (backend.pipeline.engine.EngineCheckpoint).
    STATE: tuple[str, ...] = (
        "_R_est",
        "_t_est",
        "_R_gt",
        "_t_gt",
        "_R_odo",
        "_t_odo",
        "_stamp",
        "_obs",
        "_p_world",
        "_p_anchor",
        "_p_anchor_uv",
        "_p_ok",
        "_p_plane",
        "_l_m",
        "_l_v",
        "_l_anchor",
        "_l_anchor_uv",
        "_l_ok",
        "_l_plane",
        "_planes",
        "_plane_n",
        "_plane_d",
        "_plane_consensus",
        "_variant",
        "_window",
    )
    SHARED: tuple[str, ...] = ("settings", "_world", "_last")

    def checkpoint(self) -> EngineCheckpoint:
        return EngineCheckpoint.of(self)

    def restore(self, state: EngineCheckpoint) -> None:
        state.restore_into(self)

    def reset(self) -> None:
        w = self._world
        self._R_est = RowBuffer((3, 3))
        self._t_est = RowBuffer((3,))
        self._R_gt = RowBuffer((3, 3))
        self._t_gt = RowBuffer((3,))
        self._stamp = RowBuffer((), dtype=np.int64)
        self._R_odo = RowBuffer((3, 3))  # odometry measurement from keyframe k-1 to k
        self._t_odo = RowBuffer((3,))
        self._obs: dict[int, _FrameObs] = {}
        P, L = len(w.points), len(w.segments)
        self._p_world = np.full((P, 3), np.nan)
        self._p_ok = np.zeros(P, bool)
        self._p_anchor = np.full(P, -1)
        self._p_anchor_uv = np.zeros((P, 2))
        self._p_plane = np.full(P, -1)
        self._l_m = np.full((L, 3), np.nan)
        self._l_v = np.full((L, 3), np.nan)
        self._l_ok = np.zeros(L, bool)
        self._l_anchor = np.full(L, -1)
        self._l_anchor_uv = np.zeros((L, 4))
        self._l_plane = np.full(L, -1)
        self._planes = coplanar.PlaneSet()
        self._plane_n, self._plane_d, self._plane_consensus = self._planes.n, self._planes.d, self._planes.consensus
        self._window: _Window | None = None
        self._last: Snapshot | None = None

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
        new_points, new_lines = self._triangulate(k)
        timing[Stage.TRIANGULATION] = 1e3 * (time.perf_counter() - t1)
        t1 = time.perf_counter()
        detection, state = self._detect_planes(k, new_points, new_lines, rng)
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
        s, w = self.settings, self._world
        f = _frame_index(k, len(w.t_world_camera), s.sequence)
        R_gt, t_gt = w.R_world_camera[f], w.t_world_camera[f]
        n_rot = s.odometry_rotation_sigma_rad * rng.standard_normal(3)
        n_pos = s.odometry_position_sigma_m * rng.standard_normal(3)
        if k == 0:
            R_est, t_est = R_gt.copy(), t_gt.copy()
            R_rel, t_rel = np.eye(3), np.zeros(3)
        else:  # odometry: the noisy relative pose from the previous keyframe, applied to its estimate
            R_prev, t_prev = self._R_gt[k - 1], self._t_gt[k - 1]
            R_rel = R_prev.T @ R_gt @ so3.exp(n_rot)
            t_rel = R_prev.T @ (t_gt - t_prev) + n_pos
            R_est = self._R_est[k - 1] @ R_rel
            t_est = self._t_est[k - 1] + self._R_est[k - 1] @ t_rel
        self._R_odo.append(R_rel)
        self._t_odo.append(t_rel)

        # Observations with pixel noise, drawn for every feature (a fixed stream per step).
        cam = w.camera
        p_cam = (w.points - t_gt) @ R_gt
        uv = cam.project(p_cam) + s.pixel_sigma * rng.standard_normal((len(w.points), 2))
        ok = (p_cam[:, 2] > sequences.MIN_DEPTH_M) & cam.in_image(cam.project(p_cam))
        seg_cam = (w.segments - t_gt) @ R_gt
        seg_uv = cam.project(seg_cam) + s.pixel_sigma * rng.standard_normal((len(w.segments), 2, 2))
        ok_l = np.all((seg_cam[..., 2] > sequences.MIN_DEPTH_M) & cam.in_image(cam.project(seg_cam)), axis=1)
        labels_p = self._segment(w.point_plane, ok, rng)
        labels_l = self._segment(w.segment_plane, ok_l, rng)
        ids_p, ids_l = np.flatnonzero(ok), np.flatnonzero(ok_l)
        obs = _FrameObs(ids_p, uv[ids_p], labels_p[ids_p], ids_l, seg_uv[ids_l].reshape(-1, 4), labels_l[ids_l])
        self._obs[k] = obs
        new_p = ids_p[self._p_anchor[ids_p] < 0]
        self._p_anchor[new_p], self._p_anchor_uv[new_p] = k, uv[new_p]
        new_l = ids_l[self._l_anchor[ids_l] < 0]
        self._l_anchor[new_l], self._l_anchor_uv[new_l] = k, seg_uv[new_l].reshape(-1, 4)

        # Tracking: refine the predicted pose against the triangulated points it sees.
        known = obs.point_id[self._p_ok[obs.point_id]]
        if len(known) >= 6:
            sel = self._p_ok[obs.point_id]
            ref = refine_pose(cam, R_est, t_est, self._p_world[known], obs.point_uv[sel], sigma_px=s.pixel_sigma)
            R_est, t_est = ref.R_world_camera, ref.t_world_camera
        self._R_est.append(R_est)
        self._t_est.append(t_est)
        self._R_gt.append(R_gt)
        self._t_gt.append(t_gt)
        self._stamp.append(k * KEYFRAME_PERIOD_NS)

    def _segment(self, true_label: np.ndarray, visible: np.ndarray, rng: np.random.Generator) -> np.ndarray:
        """Simulated instance segmentation: the wall id, or with probability `mislabel`
        another wall visible in this image (-1 if none is)."""
        u = rng.random(len(true_label))
        pick = rng.random(len(true_label))
        labels = true_label.copy()
        walls = np.unique(true_label[visible])
        wrong = u < self.settings.mislabel
        for i in np.flatnonzero(wrong):
            others = walls[walls != true_label[i]]
            labels[i] = others[int(pick[i] * len(others))] if len(others) else -1
        return labels

    def _views(self, kind: str, ids: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """All stored observations of landmarks `ids`: (keyframe, landmark id, uv) rows."""
        want = np.zeros(len(self._p_ok) if kind == "point" else len(self._l_ok), bool)
        want[ids] = True
        kf, lm, uv = [], [], []
        for k, o in self._obs.items():
            i, u = (o.point_id, o.point_uv) if kind == "point" else (o.line_id, o.line_uv)
            sel = want[i]
            kf.append(np.full(int(sel.sum()), k))
            lm.append(i[sel])
            uv.append(u[sel])
        width = 2 if kind == "point" else 4
        if not kf:
            return np.zeros(0, int), np.zeros(0, int), np.zeros((0, width))
        return np.concatenate(kf), np.concatenate(lm), np.concatenate(uv).reshape(-1, width)

    def _triangulate(self, k: int) -> tuple[np.ndarray, np.ndarray]:
        """Triangulate landmarks seen in keyframe k with two or more views and enough
        parallax; returns the ids of the new points and lines."""
        cam = self._world.camera
        R, t = self._R_est[:], self._t_est[:]
        min_sin = np.sin(np.deg2rad(self.settings.min_parallax_deg))
        obs = self._obs[k]

        cand = obs.point_id[~self._p_ok[obs.point_id]]
        new_points = np.zeros(0, int)
        if len(cand):
            kf, lm, uv = self._views("point", cand)
            order = np.lexsort((kf, lm))
            kf, lm, uv = kf[order], lm[order], uv[order]
            ids, start, count = np.unique(lm, return_index=True, return_counts=True)
            if np.any(count >= 2):
                x = cam.normalize(uv)
                rays = np.einsum("mij,mj->mi", R[kf], x)
                rays /= np.linalg.norm(rays, axis=1, keepdims=True)
                parallax = np.zeros(len(ids))
                np.maximum.at(parallax, np.repeat(np.arange(len(ids)), count), np.linalg.norm(so3.cross(np.repeat(rays[start], count, axis=0), rays), axis=1))
                good = (parallax >= min_sin) & (count >= 2)
                xs = [x[a : a + c] for a, c, g in zip(start, count, good) if g]
                ks = [kf[a : a + c] for a, c, g in zip(start, count, good) if g]
                ids = ids[good]
                if len(ids):
                    X = triangulate_points(xs, ks, R, t)
                    ok = np.all(np.isfinite(X), axis=1)
                    for i, (xi, ki) in enumerate(zip(xs, ks)):
                        if ok[i]:
                            p_c = np.einsum("nji,nj->ni", R[ki], X[i] - t[ki])
                            err = cam.project(p_c) - cam.project(xi)
                            ok[i] = bool(np.all(p_c[:, 2] > sequences.MIN_DEPTH_M) and np.sqrt(np.mean(err**2)) < 3.0 * self.settings.pixel_sigma + 1e-9)
                    new_points = ids[ok]
                    self._p_world[new_points] = X[ok]
                    self._p_ok[new_points] = True

        cand = obs.line_id[~self._l_ok[obs.line_id]]
        new_lines = np.zeros(0, int)
        if len(cand):
            kf, lm, uv = self._views("line", cand)
            ids, inverse, count = np.unique(lm, return_inverse=True, return_counts=True)
            keep = count[inverse] >= 2
            if np.any(keep):
                ids_k, local = np.unique(lm[keep], return_inverse=True)
                m, v, spread = triangulate_lines(cam.normalize(uv[keep, :2]), cam.normalize(uv[keep, 2:]), local, kf[keep], len(ids_k), R, t)
                ok = (spread >= min_sin) & (np.linalg.norm(v, axis=1) > 1e-12)
                new_lines = ids_k[ok]
                norm = np.linalg.norm(v[ok], axis=1, keepdims=True)
                self._l_m[new_lines], self._l_v[new_lines] = m[ok] / norm, v[ok] / norm
                self._l_ok[new_lines] = True
        return new_points, new_lines

    def _segments_world(self, ids: np.ndarray) -> np.ndarray:
        """World segments (L, 2, 3): the points of each line nearest its anchor endpoint rays."""
        if len(ids) == 0:
            return np.zeros((0, 2, 3))
        cam = self._world.camera
        a = self._l_anchor[ids]
        R_a, t_a = self._R_est[a], self._t_est[a]
        ends = []
        for j in (0, 2):
            x = cam.normalize(self._l_anchor_uv[ids, j : j + 2])
            w = np.einsum("mij,mj->mi", R_a, x)
            P, _, _ = factors.line_point_nearest_ray(self._l_m[ids], self._l_v[ids], t_a, w)
            ends.append(P)
        return np.stack(ends, axis=1)

    def _detect_planes(self, k: int, new_points: np.ndarray, new_lines: np.ndarray, rng: np.random.Generator) -> tuple[Detection, tuple]:
        """Co-planar detection on keyframe k (paper §III-A)."""
        obs = self._obs[k]
        p_sel = self._p_ok[obs.point_id]
        l_sel = self._l_ok[obs.line_id]
        p_ids, l_ids = obs.point_id[p_sel], obs.line_id[l_sel]
        det = coplanar.detect_keyframe_planes(
            point_ids=p_ids,
            point_label=obs.point_label[p_sel],
            p_world=self._p_world[p_ids],
            line_ids=l_ids,
            line_label=obs.line_label[l_sel],
            segments_world=self._segments_world(l_ids),
            point_plane=self._p_plane,
            line_plane=self._l_plane,
            planes=self._planes,
            rng=rng,
            settings=self.settings.coplanar,
        )
        self._associate_new(new_points, new_lines)
        detection = Detection(det.instance, det.candidates, det.inliers, det.accepted, det.plane)
        return detection, (p_ids, det.point_state, l_ids, det.line_state)

    def _associate_new(self, new_points: np.ndarray, new_lines: np.ndarray) -> None:
        """New landmarks join the nearest existing plane they lie on (Eq. 4 distance) when
        they fall within its inliers' extent (with a margin)."""
        if not self._plane_n:
            return
        pts = new_points[self._p_plane[new_points] < 0]
        lns = new_lines[self._l_plane[new_lines] < 0]
        N, D = self._planes.arrays()
        q_p, q_l = coplanar.associate_to_planes(
            self._p_world[pts],
            self._segments_world(lns),
            N,
            D,
            [self._hull(q) for q in range(len(N))],
            threshold_m=self.settings.coplanar.threshold_m,
        )
        self._p_plane[pts[q_p >= 0]] = q_p[q_p >= 0]
        self._l_plane[lns[q_l >= 0]] = q_l[q_l >= 0]

    def _plane_support(self, q: int) -> np.ndarray:
        """World points (K, 3) of plane q's landmarks: its points and its segments' endpoints."""
        pts = [self._p_world[(self._p_plane == q) & self._p_ok]]
        lines = np.flatnonzero((self._l_plane == q) & self._l_ok)
        if len(lines):
            pts.append(self._segments_world(lines).reshape(-1, 3))
        return np.concatenate(pts)

    def _hull(self, q: int) -> np.ndarray:
        return coplanar.plane_hull(self._plane_n[q], self._plane_d[q], self._plane_support(q))

    def _prune(self, k: int) -> None:
        """Forget observations older than the window and fixed horizon, except anchors."""
        old = k - self.settings.window - self.settings.fixed_horizon
        o = self._obs.get(old)
        if o is None:
            return
        sp = self._p_anchor[o.point_id] == old
        sl = self._l_anchor[o.line_id] == old
        self._obs[old] = _FrameObs(o.point_id[sp], o.point_uv[sp], o.point_label[sp], o.line_id[sl], o.line_uv[sl], o.line_label[sl])

    # ------------------------------------------------------------------ window bundle adjustment

    def _window_data(self, k: int) -> _Window:
        s = self.settings
        cam = self._world.camera
        w0 = max(0, k - s.window + 1)
        oldest = max(0, w0 - s.fixed_horizon)
        win_obs = [self._obs[i] for i in range(w0, k + 1)]
        pts = np.unique(np.concatenate([o.point_id for o in win_obs]))
        pts = pts[self._p_ok[pts]]
        lns = np.unique(np.concatenate([o.line_id for o in win_obs]))
        lns = lns[self._l_ok[lns]]
        kf_p, lm_p, uv_p = self._views("point", pts)
        kf_l, lm_l, uv_l = self._views("line", lns)
        use_p = (kf_p >= oldest) | (kf_p == self._p_anchor[lm_p])
        use_l = (kf_l >= oldest) | (kf_l == self._l_anchor[lm_l])
        kf_p, lm_p, uv_p = kf_p[use_p], lm_p[use_p], uv_p[use_p]
        kf_l, lm_l, uv_l = kf_l[use_l], lm_l[use_l], uv_l[use_l]
        kfs = np.unique(np.concatenate([kf_p, kf_l, np.arange(w0, k + 1), [max(w0 - 1, 0)]]))

        def to_local(keyframe: np.ndarray) -> np.ndarray:  # keyframe index -> problem pose
            return np.searchsorted(kfs, keyframe)

        p_local = np.full(len(self._p_ok), -1)
        p_local[pts] = np.arange(len(pts))
        l_local = np.full(len(self._l_ok), -1)
        l_local[lns] = np.arange(len(lns))

        # A plane is optimized only with enough of its features in the window; with a few it
        # would swing freely (its features are then free landmarks here, and the plane
        # follows its whole support by refitting).
        owner = np.concatenate([self._p_plane[pts], self._l_plane[lns]])
        support = np.bincount(owner[owner >= 0], minlength=len(self._plane_n))
        planes = np.flatnonzero(support >= s.min_plane_support)
        q_local = np.full(len(self._plane_n) + 1, -1)
        q_local[planes] = np.arange(len(planes))

        R, t = self._R_est[kfs].copy(), self._t_est[kfs].copy()
        fixed = kfs < w0
        a_p = to_local(self._p_anchor[pts])
        p_a = np.einsum("nji,nj->ni", R[a_p], self._p_world[pts] - t[a_p])
        rho = 1.0 / np.where(p_a[:, 2] > 1e-3, p_a[:, 2], 4.0)
        U, phi = line_geo.to_orthonormal(self._l_m[lns], self._l_v[lns]) if len(lns) else (np.zeros((0, 3, 3)), np.zeros((0, 2)))

        # Odometry between consecutive keyframes whose later one is in the window.
        j = np.arange(max(w0, 1), k + 1)
        i = j - 1
        odometry = Odometry(
            i=to_local(i),
            j=to_local(j),
            R_i_j=self._R_odo[j],
            t_i_j=self._t_odo[j],
            sigma_rot=max(s.odometry_rotation_sigma_rad, 1e-6),
            sigma_pos=max(s.odometry_position_sigma_m, 1e-6),
        )
        prior = None
        if not np.any(fixed):  # the gauge: the first keyframe at its true pose
            prior = PosePrior(index=np.array([0]), R_world_camera=self._R_gt[kfs[:1]], t_world_camera=self._t_gt[kfs[:1]], sigma_rot=PRIOR_SIGMA, sigma_pos=PRIOR_SIGMA)
        zeros = lambda n: np.zeros((n, 3))  # noqa: E731
        data = ProblemData(
            camera=cam,
            poses=Poses(R, t),
            point_anchor=a_p,
            point_anchor_uv=self._p_anchor_uv[pts],
            point_rho=rho,
            point_plane=q_local[self._p_plane[pts]],
            point_obs=Observations(p_local[lm_p], to_local(kf_p), uv_p, zeros(len(kf_p))),
            line_anchor=to_local(self._l_anchor[lns]),
            line_anchor_uv=self._l_anchor_uv[lns],
            line_U=U,
            line_phi=phi,
            line_plane=q_local[self._l_plane[lns]],
            line_obs=Observations(l_local[lm_l], to_local(kf_l), uv_l, zeros(len(kf_l))),
            plane_n=np.array(self._plane_n).reshape(-1, 3)[planes],
            plane_d=np.array(self._plane_d)[planes],
            odometry=odometry,
            prior=prior,
            sigma_px=s.pixel_sigma,
            fixed_poses=fixed,
        )
        return _Window(k, data, kfs, pts, lns, planes)

    def _optimize(self, k: int, detection: Detection, det_state: tuple, timing: dict[str, float], t_start: float) -> Snapshot:
        s = self.settings
        t0 = time.perf_counter()
        win = self._window_data(k)
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
        self._R_est[kf_free] = state.poses.R_world_camera[free]
        self._t_est[kf_free] = state.poses.t_world_camera[free]
        if len(win.points):
            p = problem.point_positions(state)
            good = np.all(np.isfinite(p), axis=1)
            self._p_world[win.points[good]] = p[good]
        if len(win.lines):
            if self._variant.with_lines:
                m, v = problem.line_pluecker(state)
                norm = np.linalg.norm(v, axis=1, keepdims=True)
                self._l_m[win.lines], self._l_v[win.lines] = m / norm, v / norm
            else:  # lines are not optimized: re-triangulate them from the new poses
                self._retriangulate_lines(win.lines)
        used = problem.layout.plane_col >= 0
        for i, q in enumerate(win.planes):
            if used[i]:
                self._plane_n[q], self._plane_d[q] = state.plane_n[i].copy(), float(state.plane_d[i])
        self._refit_unused_planes(set(int(q) for q, u in zip(win.planes, used) if u))
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
        self._last = self._snapshot(k, detection, det_state, report, hessian)
        return self._last

    def _retriangulate_lines(self, ids: np.ndarray) -> None:
        cam = self._world.camera
        kf, lm, uv = self._views("line", ids)
        ids_k, local = np.unique(lm, return_inverse=True)
        m, v, spread = triangulate_lines(cam.normalize(uv[:, :2]), cam.normalize(uv[:, 2:]), local, kf, len(ids_k), self._R_est[:], self._t_est[:])
        ok = np.linalg.norm(v, axis=1) > 1e-12
        norm = np.linalg.norm(v[ok], axis=1, keepdims=True)
        self._l_m[ids_k[ok]], self._l_v[ids_k[ok]] = m[ok] / norm, v[ok] / norm

    def _refit_unused_planes(self, optimized: set[int]) -> None:
        """Planes the variant does not optimize follow their landmarks (least squares)."""
        for q in range(len(self._plane_n)):
            fit = None if q in optimized else coplanar.refit_plane(self._plane_n[q], self._plane_support(q))
            if fit is not None:
                self._plane_n[q], self._plane_d[q] = fit

    # ------------------------------------------------------------------ snapshot

    def _snapshot(self, k: int, detection: Detection, det_state: tuple, report: OptimizationReport, hessian: HessianStructure) -> Snapshot:
        w0 = max(0, k - self.settings.window + 1)
        n = k + 1
        estimate = Trajectory(
            (
                (self._stamp.prefix(w0), self._R_est.prefix(w0), self._t_est.prefix(w0)),
                (frozen(self._stamp[w0:n].copy()), frozen(self._R_est[w0:n].copy()), frozen(self._t_est[w0:n].copy())),
            )
        )
        gt = Trajectory.of(self._stamp.prefix(n), self._R_gt.prefix(n), self._t_gt.prefix(n))
        p_ids = np.flatnonzero(self._p_ok)
        p_det = np.zeros(len(self._p_ok), np.uint8)
        p_det[det_state[0]] = det_state[1]
        l_ids = np.flatnonzero(self._l_ok)
        l_det = np.zeros(len(self._l_ok), np.uint8)
        l_det[det_state[2]] = det_state[3]
        segs = self._segments_world(l_ids)
        points = PointLandmarks(frozen(p_ids), frozen(self._p_world[p_ids].copy()), frozen(self._p_plane[p_ids].copy()), frozen(self._p_anchor[p_ids].copy()), frozen(p_det[p_ids]))
        lines = LineLandmarks(frozen(l_ids), frozen(segs), frozen(self._l_plane[l_ids].copy()), frozen(self._l_anchor[l_ids].copy()), frozen(l_det[l_ids]))
        planes = []
        for q in range(len(self._plane_n)):
            hull = self._hull(q)
            planes.append(
                PlaneLandmark(
                    id=q,
                    n=frozen(np.array(self._plane_n[q])),
                    d=float(self._plane_d[q]),
                    hull_world=frozen(hull),
                    n_points=int(np.sum(self._p_plane == q)),
                    n_lines=int(np.sum(self._l_plane == q)),
                    last_consensus=self._plane_consensus[q][0],
                    last_candidates=self._plane_consensus[q][1],
                )
            )
        t_est = estimate.t_world_camera
        rmse = 100.0 * translational_rmse(t_est, gt.t_world_camera)
        ate = 100.0 * ate_rmse(t_est, gt.t_world_camera, align="se3") if n >= 3 else rmse
        return Snapshot(
            keyframe=k,
            timestamp_ns=int(self._stamp[k]),
            source=self.source,
            camera=self._world.camera,
            estimate=estimate,
            ground_truth=gt,
            window=frozen(np.arange(w0, n)),
            points=points,
            lines=lines,
            planes=tuple(planes),
            detection=detection,
            report=report,
            hessian=hessian,
            metrics=Metrics(rmse_cm=rmse, ate_cm=ate),
        )


__all__ = ["SimEngine", "SimSettings", "VARIANTS"]
