"""One bundle-adjustment problem, built for any of the six variants from the same data.

:class:`ProblemData` holds the landmarks, their observations, the plane assignment, the
odometry and prior factors and the initial values. :func:`build_problem` picks the optimized
variables and factor sets of a variant (DESIGN §3); :meth:`Problem.linearize` evaluates every
factor type vectorized over its observations and returns the whitened residual vector and the
sparse Jacobian, columns grouped as cameras | points | lines | planes.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import scipy.sparse as sp

from backend.geometry import line as line_geo
from backend.geometry import plane as plane_geo
from backend.geometry import so3
from backend.geometry.camera import PinholeCamera
from backend.geometry.se3 import Poses
from backend.optim import factors, inertial, kernels
from backend.optim.hessian_image import GroupKind
from backend.optim.variant import PlaneMode, Variant

GROUPS: tuple[GroupKind, ...] = ("cameras", "points", "lines", "planes")

# A ray or back-projection plane within this angle of parallel to its plane is rejected.
MIN_PLANE_ANGLE_RAD = np.deg2rad(3.0)

# -r residuals are distances to the plane relative to the anchor camera's distance to it
# (DESIGN §3): σ_rel is their standard deviation as a fraction of that distance, 0.01 = 1 cm
# for an anchor 1 m from the plane (3 cm at 3 m). Chosen as a physical tolerance: the order of
# real walls' flatness plus plane-fit and segmentation error at indoor ranges, and well above
# the pixel-noise floor σ_px/f ≈ 0.002 so that a plane does not overrule the images. In the
# Monte-Carlo study (10 runs, sequences a and b, `coplanar sim --sigma-rel`) -r is level with
# or ahead of -wo in median RMSE for every σ_rel from 0.002 to 0.05. Pairs whose anchor is
# closer to the plane than MIN_ANCHOR_PLANE_DISTANCE_M (initial values) are not used (the
# normalization degenerates).
SIGMA_REL_DEFAULT = 0.01
MIN_ANCHOR_PLANE_DISTANCE_M = 1e-3
# -r does not use a (feature, plane) pair whose initial relative residual exceeds this
# (the feature starts more than 30 % of its anchor's distance off its plane, about 1 m at
# 3 m): pulling such a feature onto its plane through the nonlinear residual traps the
# solve in a local minimum. In the study's sequence a a median of 16-26 of the 100 lines
# per run start that badly; without the gate PL-r ended 9 and 12 % behind PL-wo in two of
# four worlds and, started from PL-wo's solution, reached a lower cost and the better
# trajectory. A pipeline's plane association (Eq. 4 distance, 15 cm) never pairs
# such a feature; -w is unaffected (it builds the feature on its plane).
MAX_INITIAL_RELATIVE_RESIDUAL = 0.3


@dataclasses.dataclass(frozen=True)
class Observations:
    """Image observations of landmarks. Points: `uv` (M, 2) pixels. Lines: `uv` (M, 4) =
    start and end pixels. `offset` (M, 3): observing camera centre in the left camera frame
    (zero for the left image, `(b, 0, 0)` for the right image of a stereo pair)."""

    landmark: np.ndarray
    pose: np.ndarray
    uv: np.ndarray
    offset: np.ndarray

    def __len__(self) -> int:
        return int(self.landmark.shape[0])

    def select(self, mask: np.ndarray) -> Observations:
        return Observations(self.landmark[mask], self.pose[mask], self.uv[mask], self.offset[mask])

    @staticmethod
    def empty(width: int) -> Observations:
        return Observations(np.zeros(0, int), np.zeros(0, int), np.zeros((0, width)), np.zeros((0, 3)))


@dataclasses.dataclass(frozen=True)
class Odometry:
    """Relative pose measurements: pose j in pose i's frame, with standard deviations
    (radians per axis, metres per axis)."""

    i: np.ndarray
    j: np.ndarray
    R_i_j: np.ndarray
    t_i_j: np.ndarray
    sigma_rot: float
    sigma_pos: float


@dataclasses.dataclass(frozen=True)
class PosePrior:
    index: np.ndarray
    R_world_camera: np.ndarray
    t_world_camera: np.ndarray
    sigma_rot: float
    sigma_pos: float


@dataclasses.dataclass(frozen=True)
class DistancePrior:
    """Measured distances (metres) between the positions of pose pairs (i, j), standard
    deviation `sigma` (metres). One pair fixes the scale gauge of a monocular problem (its
    seventh freedom) without constraining anything else."""

    i: np.ndarray
    j: np.ndarray
    distance: np.ndarray
    sigma: float


@dataclasses.dataclass(frozen=True)
class ProblemData:
    """Everything a variant needs; landmark states are initial values.

    Points: anchor pose index, anchor left pixel (its normalized ray defines the point),
    initial inverse depth ρ (1/m) in the anchor, plane index (-1: non-planar).
    Lines: anchor pose index, anchor left segment (start, end pixels), initial world line in
    orthonormal form, plane index (-1: non-planar). Planes: initial world (n, d).
    Observations include the anchors' own (each variant drops those that are identically
    zero for it).
    """

    camera: PinholeCamera
    poses: Poses
    point_anchor: np.ndarray
    point_anchor_uv: np.ndarray
    point_rho: np.ndarray
    point_plane: np.ndarray
    point_obs: Observations
    line_anchor: np.ndarray
    line_anchor_uv: np.ndarray
    line_U: np.ndarray
    line_phi: np.ndarray
    line_plane: np.ndarray
    line_obs: Observations
    plane_n: np.ndarray
    plane_d: np.ndarray
    odometry: Odometry | None
    prior: PosePrior | None
    sigma_px: float = 1.0
    sigma_rel: float = SIGMA_REL_DEFAULT  # -r: σ of (plane distance) / (anchor's distance to the plane), dimensionless
    fixed_poses: np.ndarray | None = None  # bool (N,): held constant (no columns)
    distance_prior: DistancePrior | None = None
    inertial: inertial.InertialData | None = None  # VIO: velocities, biases, IMU factors, prior


@dataclasses.dataclass
class State:
    """Current estimate of all variables (also of those a variant does not optimize).

    Treat the arrays as read-only: :meth:`Problem.retract` returns a new state that shares
    the arrays of the variables it did not move."""

    poses: Poses
    rho: np.ndarray
    line_U: np.ndarray
    line_phi: np.ndarray
    plane_n: np.ndarray
    plane_d: np.ndarray
    velocity: np.ndarray | None = None  # (N, 3) m/s, world (VIO)
    bias: np.ndarray | None = None  # (N, 6) (b_a m/s², b_g rad/s) (VIO)

    def copy(self) -> State:
        return State(
            self.poses.copy(),
            self.rho.copy(),
            self.line_U.copy(),
            self.line_phi.copy(),
            self.plane_n.copy(),
            self.plane_d.copy(),
            None if self.velocity is None else self.velocity.copy(),
            None if self.bias is None else self.bias.copy(),
        )


@dataclasses.dataclass(frozen=True)
class Layout:
    """Column layout: start column per variable or -1 (not optimized), and group extents."""

    pose_col: np.ndarray
    point_col: np.ndarray
    line_col: np.ndarray
    plane_col: np.ndarray
    group_start: dict[str, int]
    group_size: dict[str, int]
    group_items: dict[str, int]
    inertial_col: np.ndarray | None = None  # VIO: start column of each pose's (δv, δb_a, δb_g) or -1

    @property
    def n_params(self) -> int:
        return int(sum(self.group_size.values()))

    @property
    def n_items(self) -> int:
        return int(sum(self.group_items.values()))

    @property
    def n_pose_params(self) -> int:
        """Columns of the camera poses (6 each), the start of the camera group; VIO's
        inertial states follow them inside the group."""
        n_inertial = 0 if self.inertial_col is None else int(np.count_nonzero(self.inertial_col >= 0))
        return self.group_size["cameras"] - 9 * n_inertial

    @property
    def n_landmark_params(self) -> int:
        """Columns of the landmark variables (points, lines), eliminated by the Schur step."""
        return self.group_size["points"] + self.group_size["lines"]


@dataclasses.dataclass(frozen=True)
class FactorBatch:
    """One factor type's linearization: whitened (and robustly reweighted) residuals
    (M, r), the Jacobian rows (M, r, D) over the concatenated slots, and the global column
    of each of the D Jacobian columns (M, D), -1 where the variable is held fixed."""

    name: str
    residual: np.ndarray
    jacobian: np.ndarray
    cols: np.ndarray


@dataclasses.dataclass(frozen=True)
class Linearization:
    """All factor batches at one state, with the cost `Σ ½|r|²` per factor type (robust
    factors report the Cauchy cost)."""

    batches: tuple[FactorBatch, ...]
    costs: dict[str, float]
    n_params: int

    @property
    def cost(self) -> float:
        return float(sum(self.costs.values()))

    @property
    def residual(self) -> np.ndarray:
        """All whitened residuals, stacked (m,)."""
        return np.concatenate([b.residual.ravel() for b in self.batches]) if self.batches else np.zeros(0)

    @property
    def jacobian(self) -> sp.csr_matrix:
        """The sparse whitened Jacobian (m, n_params), rows in the order of :attr:`residual`."""
        rows, cols, vals = [], [], []
        offset = 0
        for b in self.batches:
            M, r, D = b.jacobian.shape
            row = offset + np.arange(M * r).reshape(M, r, 1)
            col = np.broadcast_to(b.cols[:, None, :], (M, r, D))
            keep = col >= 0
            rows.append(np.broadcast_to(row, (M, r, D))[keep])
            cols.append(col[keep])
            vals.append(b.jacobian[keep])
            offset += M * r
        if not rows:
            return sp.csr_matrix((0, self.n_params))
        return sp.csr_matrix((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))), shape=(offset, self.n_params))

    def normal_equations(self) -> tuple[np.ndarray, np.ndarray]:
        """Dense `H = JᵀJ` (n, n) and `g = -Jᵀr` (n,), summed over the observations' blocks."""
        n = self.n_params
        H = np.zeros((n, n))
        g = np.zeros(n)
        for b in self.batches:
            kernels.accumulate_normal_equations(b.jacobian, b.residual, b.cols, H, g)
        kernels.mirror_upper(H)
        return H, g

    def normal_blocks(self, layout: Layout) -> NormalBlocks:
        """The same normal equations as :meth:`normal_equations`, in Schur blocks
        (:class:`NormalBlocks`): memory and time grow with cameras × landmarks, not with
        (cameras + landmarks)², which matters for windows with thousands of landmarks."""
        n = self.n_params
        lo, mid, hi = layout.group_start["points"], layout.group_start["lines"], layout.group_start["planes"]
        reduced = np.r_[0:lo, hi:n]
        rmap = np.full(n, -1, dtype=np.int64)
        rmap[reduced] = np.arange(len(reduced))
        H_rr = np.zeros((len(reduced), len(reduced)))
        H_rl = np.zeros((len(reduced), hi - lo))
        d_points = np.zeros(mid - lo)
        B_lines = np.zeros(((hi - mid) // 4, 4, 4))
        g = np.zeros(n)
        for b in self.batches:
            kernels.accumulate_normal_blocks(b.jacobian, b.residual, b.cols, rmap, lo, mid, hi, H_rr, H_rl, d_points, B_lines, g)
        return NormalBlocks(reduced, H_rr, H_rl, d_points, B_lines, g)


@dataclasses.dataclass
class NormalBlocks:
    """`H = JᵀJ` and `g = -Jᵀr` in the blocks the Schur complement uses, without the dense
    landmark × landmark part (block-diagonal: points 1×1, lines 4×4): `H_rr` (r, r) over the
    reduced columns `reduced` (cameras, then planes), `H_rl` (r, l) against the landmark
    columns, `d_points` (P,), `B_lines` (L, 4, 4), and g (n,). `shared`: what the Schur
    solve derives from `H_rl` and `g` alone, kept for the damped copies of the same blocks
    (:meth:`damped` shares both, and this)."""

    reduced: np.ndarray
    H_rr: np.ndarray
    H_rl: np.ndarray
    d_points: np.ndarray
    B_lines: np.ndarray
    g: np.ndarray
    shared: dict = dataclasses.field(default_factory=dict, repr=False, compare=False)

    def diagonal(self) -> np.ndarray:
        """diag(H) (n,) in the problem's column order."""
        diag = np.empty(len(self.g))
        is_landmark = np.ones(len(self.g), bool)
        is_landmark[self.reduced] = False
        landmarks = np.flatnonzero(is_landmark)
        diag[self.reduced] = np.diagonal(self.H_rr)
        P = len(self.d_points)
        diag[landmarks[:P]] = self.d_points
        diag[landmarks[P:]] = np.diagonal(self.B_lines, axis1=1, axis2=2).ravel()
        return diag

    def damped(self, lam: float) -> NormalBlocks:
        """Marquardt's `H + λ diag(H)` (a copy; g shared)."""
        H_rr = self.H_rr.copy()
        H_rr[np.diag_indices_from(H_rr)] *= 1.0 + lam
        B = self.B_lines.copy()
        idx = np.arange(4)
        B[:, idx, idx] *= 1.0 + lam
        return NormalBlocks(self.reduced, H_rr, self.H_rl, self.d_points * (1.0 + lam), B, self.g, self.shared)


class _Assembler:
    """Collects whitened factor batches."""

    def __init__(self, n_params: int, cache: dict) -> None:
        self.batches: list[FactorBatch] = []
        self.costs: dict[str, float] = {}
        self.n_params = n_params
        self.cache = cache

    def add(self, name: str, residual: np.ndarray, jacobian: np.ndarray, slots: list[tuple[np.ndarray, int]] | np.ndarray, *, scale: float = 1.0, robust: float | None = None) -> None:
        """residual (M, r) and Jacobian (M, r, D) whose columns are the concatenated `slots`
        (first column (M,) of the variable or -1 if fixed, dimension), or given as they are
        (an (M, D) array of columns, -1 where fixed); `scale` whitens; `robust` is the Cauchy
        scale on the whitened residual norm (None: plain squares)."""
        M, r = residual.shape
        if M == 0:
            return
        res = residual * scale
        sq = np.sum(res**2, axis=1)
        if robust is not None:
            # Cauchy kernel by iteratively reweighted least squares: √w = 1/√(1 + e²/c²).
            w = scale / np.sqrt(1.0 + sq / robust**2)
            self.costs[name] = self.costs.get(name, 0.0) + float(0.5 * robust**2 * np.sum(np.log1p(sq / robust**2)))
            res = residual * w[:, None]
            J = jacobian * w[:, None, None]
        else:
            self.costs[name] = self.costs.get(name, 0.0) + float(0.5 * np.sum(sq))
            J = jacobian * scale if scale != 1.0 else jacobian
        self.batches.append(FactorBatch(name, res, J, slots if isinstance(slots, np.ndarray) else self._columns(name, M, slots)))

    def _columns(self, name: str, M: int, slots: list[tuple[np.ndarray, int]]) -> np.ndarray:
        """The (M, D) columns of the concatenated `slots`, kept in the problem's cache (they
        depend only on its structure)."""
        key = ("cols", len(self.batches), name, M)
        cols = self.cache.get(key)
        if cols is None:
            cols = self.cache[key] = np.concatenate([np.where(c[:, None] >= 0, c[:, None] + np.arange(dim), -1) for c, dim in slots], axis=1)
        return cols

    def build(self) -> Linearization:
        return Linearization(tuple(self.batches), self.costs, self.n_params)


@dataclasses.dataclass(frozen=True)
class Problem:
    """A variant's problem: which variables are optimized and which factors are active."""

    data: ProblemData
    variant: Variant
    layout: Layout
    point_obs_inv_depth: Observations  # -wo/-r points and non-planar points of -w
    point_obs_planar: Observations  # -w points (anchor ray on a plane)
    line_obs_free: Observations  # orthonormal lines
    line_obs_planar: Observations  # -w lines (back-projection plane ∩ plane)
    point_plane_pairs: np.ndarray  # -r: (K, 2) point index, plane index
    line_plane_pairs: np.ndarray  # -r: (K, 2) line index, plane index
    robust_px: float | None = None  # Cauchy scale on reprojection residuals (whitened), None = off
    cache: dict = dataclasses.field(default_factory=dict, compare=False, repr=False)

    # ------------------------------------------------------------------ state

    def prepare(self) -> None:
        """Build the structure-only caches (column maps, normalized observations) and compile
        the kernels once, so that a timed optimization measures the numeric work only."""
        self.linearize(self.initial_state()).normal_blocks(self.layout)

    def initial_state(self) -> State:
        d = self.data
        vel = bias = None
        if d.inertial is not None:
            vel, bias = d.inertial.velocity.astype(float).copy(), d.inertial.bias.astype(float).copy()
        return State(d.poses.copy(), d.point_rho.astype(float).copy(), d.line_U.copy(), d.line_phi.astype(float).copy(), d.plane_n.copy(), d.plane_d.astype(float).copy(), vel, bias)

    def retract(self, state: State, delta: np.ndarray) -> State:
        """Apply a step (n_params,) to the optimized variables; the others are shared."""
        idx = self.cache.get("retract")
        if idx is None:  # which variables move and where their columns are (structure only)
            L = self.layout
            idx = self.cache["retract"] = tuple(
                (np.flatnonzero(col >= 0), col[col >= 0][:, None] + np.arange(dim)) for col, dim in ((L.pose_col, 6), (L.point_col, 1), (L.line_col, 4), (L.plane_col, 3))
            )
        (pi, pc), (qi, qc), (li, lc), (ni, nc) = idx
        R, t = state.poses.R_world_camera, state.poses.t_world_camera
        if len(pi):
            R, t = R.copy(), t.copy()
            step = delta[pc]
            R[pi] = R[pi] @ so3.exp(step[:, :3])
            t[pi] += step[:, 3:]
        rho = state.rho
        if len(qi):
            rho = rho.copy()
            rho[qi] += delta[qc[:, 0]]
        line_U, line_phi = state.line_U, state.line_phi
        if len(li):
            line_U, line_phi = line_U.copy(), line_phi.copy()
            line_U[li], line_phi[li] = line_geo.retract(state.line_U[li], state.line_phi[li], delta[lc])
        plane_n, plane_d = state.plane_n, state.plane_d
        if len(ni):
            plane_n, plane_d = plane_n.copy(), plane_d.copy()
            plane_n[ni], plane_d[ni] = plane_geo.retract(state.plane_n[ni], state.plane_d[ni], delta[nc])
        vel, bias = state.velocity, state.bias
        if self.layout.inertial_col is not None and vel is not None:
            col = self.layout.inertial_col
            ii = np.flatnonzero(col >= 0)
            if len(ii):
                step = delta[col[ii][:, None] + np.arange(inertial.INERTIAL_DIM)]
                assert bias is not None  # a VIO state has both velocities and biases
                vel, bias = vel.copy(), bias.copy()
                vel[ii] += step[:, :3]
                bias[ii] += step[:, 3:]
        return State(Poses(R, t), rho, line_U, line_phi, plane_n, plane_d, vel, bias)

    # ------------------------------------------------------------------ world geometry

    def point_positions(self, state: State) -> np.ndarray:
        """World positions (P, 3) of all points under this variant (NaN where undefined)."""
        d = self.data
        x_a = d.camera.normalize(d.point_anchor_uv)
        R_a = state.poses.R_world_camera[d.point_anchor]
        t_a = state.poses.t_world_camera[d.point_anchor]
        p, _ = factors.point_world_inverse_depth(x_a, state.rho, R_a, t_a)
        planar = self._planar_points()
        if np.any(planar):
            q = d.point_plane[planar]
            n, dd = state.plane_n[q], state.plane_d[q]
            pw, _, h = factors.point_world_on_plane(x_a[planar], n, dd, plane_geo.tangent_basis(n), R_a[planar], t_a[planar])
            pw[h <= 0] = np.nan
            p[planar] = pw
        return p

    def line_pluecker(self, state: State) -> tuple[np.ndarray, np.ndarray]:
        """World Plücker (m, v) (L, 3) of all lines under this variant."""
        d = self.data
        m, v, _, _ = factors.line_world_orthonormal(state.line_U, state.line_phi)
        planar = self._planar_lines()
        if np.any(planar):
            q = d.line_plane[planar]
            n, dd = state.plane_n[q], state.plane_d[q]
            a = d.line_anchor[planar]
            n_l = self._backprojection_normals()[planar]
            mw, vw, _, _ = factors.line_world_on_plane(n_l, n, dd, plane_geo.tangent_basis(n), state.poses.R_world_camera[a], state.poses.t_world_camera[a])
            m, v = m.copy(), v.copy()
            m[planar], v[planar] = mw, vw
        return m, v

    def _planar_points(self) -> np.ndarray:
        return (self.layout.point_col < 0) & (self.data.point_plane >= 0) & self._uses_planes_w()

    def _planar_lines(self) -> np.ndarray:
        return (self.layout.line_col < 0) & (self.data.line_plane >= 0) & self._uses_planes_w()

    def _uses_planes_w(self) -> bool:
        return self.variant.plane_mode is PlaneMode.PARAMETRIZED

    def _normalized(self, key: str, uv: np.ndarray) -> np.ndarray:
        """Normalized coordinates of fixed observations, computed once per problem."""
        out = self.cache.get(("normalized", key))
        if out is None:
            out = self.cache[("normalized", key)] = self.data.camera.normalize(uv)
        return out

    def _backprojection_normals(self) -> np.ndarray:
        d = self.data
        xs = d.camera.normalize(d.line_anchor_uv[:, :2])
        xe = d.camera.normalize(d.line_anchor_uv[:, 2:])
        n = so3.cross(xs, xe)
        return n / np.linalg.norm(n, axis=-1, keepdims=True)

    # ------------------------------------------------------------------ linearization

    def linearize(self, state: State) -> Linearization:
        """Whitened residuals and sparse Jacobian of all active factors at `state`."""
        d = self.data
        L = self.layout
        cam = d.camera
        poses = state.poses
        asm = _Assembler(L.n_params, self.cache)
        inv_px = 1.0 / d.sigma_px

        R_all, t_all = poses.R_world_camera, poses.t_world_camera
        B_planes = plane_geo.tangent_basis(state.plane_n) if len(state.plane_n) else np.zeros((0, 3, 2))
        x_anchor = self._normalized("point_anchor", d.point_anchor_uv)

        # Points with an inverse-depth variable: world position per landmark, then per observation.
        obs = self.point_obs_inv_depth
        if len(obs):
            pw_l, Jw_l = factors.point_world_inverse_depth(x_anchor, state.rho, R_all[d.point_anchor], t_all[d.point_anchor])
            Jcat_l = np.concatenate([Jw_l["anchor"], Jw_l["rho"]], axis=2)
            lm, k = obs.landmark, obs.pose
            res, J, _ = factors.point_reprojection(cam, pw_l, Jcat_l, lm, R_all, t_all, k, obs.offset, obs.uv)
            asm.add("points", res, J, [(L.pose_col[d.point_anchor[lm]], 6), (L.point_col[lm], 1), (L.pose_col[k], 6)], scale=inv_px, robust=self.robust_px)

        # Co-planar (-w) points: the anchor ray meets the plane.
        obs = self.point_obs_planar
        if len(obs):
            sel = self._planar_points()
            a, q = d.point_anchor[sel], d.point_plane[sel]
            n = state.plane_n[q]
            pw_s, Jw_s, _ = factors.point_world_on_plane(x_anchor[sel], n, state.plane_d[q], B_planes[q], R_all[a], t_all[a])  # J: anchor | plane
            row = np.cumsum(sel) - 1  # landmark -> row among the planar ones
            r = row[obs.landmark]
            k = obs.pose
            res, J, _ = factors.point_reprojection(cam, pw_s, Jw_s, r, R_all, t_all, k, obs.offset, obs.uv)
            asm.add("points", res, J, [(L.pose_col[a[r]], 6), (L.plane_col[q[r]], 3), (L.pose_col[k], 6)], scale=inv_px, robust=self.robust_px)

        # Lines in orthonormal form.
        obs = self.line_obs_free
        if len(obs):
            m, v, J_m, J_v = factors.line_world_orthonormal(state.line_U, state.line_phi)
            J_mv = np.concatenate([J_m, J_v], axis=1)
            lm, k = obs.landmark, obs.pose
            x_s, x_e = self._normalized("line_free_s", obs.uv[:, :2]), self._normalized("line_free_e", obs.uv[:, 2:])
            res, J = factors.line_reprojection(cam, m, v, J_mv, lm, R_all, t_all, k, obs.offset, x_s, x_e)
            asm.add("lines", res, J, [(L.line_col[lm], 4), (L.pose_col[k], 6)], scale=inv_px, robust=self.robust_px)

        # Co-planar (-w) lines.
        obs = self.line_obs_planar
        if len(obs):
            sel = self._planar_lines()
            a, q = d.line_anchor[sel], d.line_plane[sel]
            n = state.plane_n[q]
            m, v, J_mv, _ = factors.line_world_on_plane(self._backprojection_normals()[sel], n, state.plane_d[q], B_planes[q], R_all[a], t_all[a])
            r = (np.cumsum(sel) - 1)[obs.landmark]
            k = obs.pose
            x_s, x_e = self._normalized("line_planar_s", obs.uv[:, :2]), self._normalized("line_planar_e", obs.uv[:, 2:])
            res, J = factors.line_reprojection(cam, m, v, J_mv, r, R_all, t_all, k, obs.offset, x_s, x_e)
            asm.add("lines", res, J, [(L.pose_col[a[r]], 6), (L.plane_col[q[r]], 3), (L.pose_col[k], 6)], scale=inv_px, robust=self.robust_px)

        # -r: point-to-plane distances relative to the anchor's distance to the plane.
        pairs = self.point_plane_pairs
        if len(pairs):
            i, q = pairs[:, 0], pairs[:, 1]
            a = d.point_anchor[i]
            res, J = factors.point_plane_relative(x_anchor[i], state.rho[i], R_all[a], t_all[a], state.plane_n[q], state.plane_d[q], B_planes[q])
            asm.add("point_plane", res, J, [(L.pose_col[a], 6), (L.point_col[i], 1), (L.plane_col[q], 3)], scale=1.0 / d.sigma_rel)

        # -r: line-to-plane distances of the line points nearest the anchor endpoint rays.
        pairs = self.line_plane_pairs
        if len(pairs):
            res, J, cols = self._line_plane_residuals(state, pairs, B_planes)
            asm.add("line_plane", res, J, cols, scale=1.0 / d.sigma_rel)

        # Odometry and prior.
        od = d.odometry
        if od is not None and len(od.i):
            res, J = factors.relative_pose_error(poses.R_world_camera, poses.t_world_camera, od.i, od.j, od.R_i_j, od.t_i_j)
            scale = np.array([1 / od.sigma_rot] * 3 + [1 / od.sigma_pos] * 3)
            asm.add("odometry", res * scale, J * scale[:, None], [(L.pose_col[od.i], 6), (L.pose_col[od.j], 6)])
        pr = d.prior
        if pr is not None and len(pr.index):
            res, J_prior = factors.pose_prior_error(poses.R_world_camera[pr.index], poses.t_world_camera[pr.index], pr.R_world_camera, pr.t_world_camera)
            scale = np.array([1 / pr.sigma_rot] * 3 + [1 / pr.sigma_pos] * 3)
            asm.add("prior", res * scale, J_prior["pose"] * scale[:, None], [(L.pose_col[pr.index], 6)])
        dp = d.distance_prior
        if dp is not None and len(dp.i):
            res, J = factors.pose_distance_error(poses.t_world_camera, dp.i, dp.j, dp.distance)
            asm.add("distance_prior", res, J, [(L.pose_col[dp.i], 6), (L.pose_col[dp.j], 6)], scale=1.0 / dp.sigma)
        if d.inertial is not None:
            self._add_inertial(asm, state)
        return asm.build()

    def _add_inertial(self, asm: _Assembler, state: State) -> None:
        """IMU preintegration, bias random walk and the linear (marginalization) prior."""
        d, L = self.data, self.layout
        ine = d.inertial
        assert ine is not None  # called only for VIO data
        icol = L.inertial_col
        R_all, t_all = state.poses.R_world_camera, state.poses.t_world_camera
        if len(ine.imu_i):
            i, j = ine.imu_i, ine.imu_j
            assert state.velocity is not None and state.bias is not None and icol is not None  # a VIO state and layout
            res, J = inertial.imu_residuals(R_all, t_all, state.velocity, state.bias, ine)
            asm.add("imu", res, J, [(L.pose_col[i], 6), (icol[i], 9), (L.pose_col[j], 6), (icol[j], 9)])
            res, J = inertial.bias_walk_residuals(state.bias, ine)
            asm.add("bias_walk", res, J, [(icol[i], 9), (icol[j], 9)])
        pr = ine.prior
        if pr is not None and len(pr.b):
            assert state.velocity is not None and state.bias is not None and icol is not None  # a VIO state and layout
            vb = np.concatenate([state.velocity, state.bias], axis=1)[pr.inertial_index]
            res, J = inertial.prior_residual(pr, R_all[pr.pose_index], t_all[pr.pose_index], vb, state.plane_n[pr.plane_index], state.plane_d[pr.plane_index])
            slots = [(L.pose_col[pr.pose_index], 6), (icol[pr.inertial_index], 9), (L.plane_col[pr.plane_index], 3)]
            cols = np.concatenate([np.where(c[:, None] >= 0, c[:, None] + np.arange(k), -1).ravel() for c, k in slots])
            asm.add("marginalization", res[None, :], J[None, :, :], cols[None, :])

    def _line_plane_residuals(self, state: State, pairs: np.ndarray, B_planes: np.ndarray) -> tuple[np.ndarray, np.ndarray, list[tuple[np.ndarray, int]]]:
        """-r line-to-plane residuals (K, 2) of the (line, plane) `pairs` (K, 2), their
        Jacobian (K, 2, 13) and column slots [anchor (6) | line (4) | plane (3)]
        (:func:`factors.line_plane_relative`)."""
        d = self.data
        L = self.layout
        i, q = pairs[:, 0], pairs[:, 1]
        a = d.line_anchor[i]
        m, v, J_m, J_v = factors.line_world_orthonormal(state.line_U[i], state.line_phi[i])
        J_mv = np.concatenate([J_m, J_v], axis=1)
        x_s = self._normalized("line_anchor_s", d.line_anchor_uv[:, :2])[i]
        x_e = self._normalized("line_anchor_e", d.line_anchor_uv[:, 2:])[i]
        R_all, t_all = state.poses.R_world_camera, state.poses.t_world_camera
        res, J = factors.line_plane_relative(m, v, J_mv, np.arange(len(i)), x_s, x_e, R_all[a], t_all[a], state.plane_n[q], state.plane_d[q], B_planes[q])
        return res, J, [(L.pose_col[a], 6), (L.line_col[i], 4), (L.plane_col[q], 3)]


def _point_plane_valid(data: ProblemData) -> np.ndarray:
    """Points whose anchor ray meets their plane at a usable angle and in front (DESIGN §3)."""
    ok = data.point_plane >= 0
    if not np.any(ok):
        return ok
    idx = np.flatnonzero(ok)
    a = data.point_anchor[idx]
    ray = np.einsum("mij,mj->mi", data.poses.R_world_camera[a], data.camera.normalize(data.point_anchor_uv[idx]))
    ray /= np.linalg.norm(ray, axis=-1, keepdims=True)
    n = data.plane_n[data.point_plane[idx]]
    s = np.sum(n * ray, axis=-1)
    q = np.sum(n * data.poses.t_world_camera[a], axis=-1) + data.plane_d[data.point_plane[idx]]
    good = (np.abs(s) > np.sin(MIN_PLANE_ANGLE_RAD)) & (-q / np.where(s == 0, 1, s) > 0)
    ok[idx] = good
    return ok


def _line_plane_valid(data: ProblemData) -> np.ndarray:
    """Lines whose anchor back-projection plane is not near parallel to their plane."""
    ok = data.line_plane >= 0
    if not np.any(ok):
        return ok
    idx = np.flatnonzero(ok)
    xs = data.camera.normalize(data.line_anchor_uv[idx, :2])
    xe = data.camera.normalize(data.line_anchor_uv[idx, 2:])
    n_l = so3.cross(xs, xe)
    n_l /= np.linalg.norm(n_l, axis=-1, keepdims=True)
    N = np.einsum("mij,mj->mi", data.poses.R_world_camera[data.line_anchor[idx]], n_l)
    s = np.linalg.norm(so3.cross(N, data.plane_n[data.line_plane[idx]]), axis=-1)
    ok[idx] = s > np.sin(MIN_PLANE_ANGLE_RAD)
    return ok


def _anchor_off_plane(data: ProblemData, anchor: np.ndarray, plane: np.ndarray) -> np.ndarray:
    """Features (anchor pose, plane index per feature) whose anchor camera centre is at least
    MIN_ANCHOR_PLANE_DISTANCE_M from their plane at the initial values: the -r residuals
    divide by that distance."""
    q = np.sum(data.plane_n[plane] * data.poses.t_world_camera[anchor], axis=-1) + data.plane_d[plane]
    return np.abs(q) >= MIN_ANCHOR_PLANE_DISTANCE_M


def _initially_near_plane(data: ProblemData, kind: str, index: np.ndarray) -> np.ndarray:
    """-r pairs (points or lines `index`, with their planes) whose initial relative residual
    (:func:`factors.point_plane_relative`, :func:`factors.line_plane_relative`) is at most
    MAX_INITIAL_RELATIVE_RESIDUAL; the anchor must be off the plane
    (:func:`_anchor_off_plane`)."""
    if len(index) == 0:
        return np.zeros(0, bool)
    if kind == "point":
        a, q = data.point_anchor[index], data.point_plane[index]
        res, _ = factors.point_plane_relative(
            data.camera.normalize(data.point_anchor_uv[index]),
            data.point_rho[index],
            data.poses.R_world_camera[a],
            data.poses.t_world_camera[a],
            data.plane_n[q],
            data.plane_d[q],
            plane_geo.tangent_basis(data.plane_n[q]),
        )
    else:
        a, q = data.line_anchor[index], data.line_plane[index]
        m, v, J_m, J_v = factors.line_world_orthonormal(data.line_U[index], data.line_phi[index])
        res, _ = factors.line_plane_relative(
            m,
            v,
            np.concatenate([J_m, J_v], axis=1),
            np.arange(len(index)),
            data.camera.normalize(data.line_anchor_uv[index, :2]),
            data.camera.normalize(data.line_anchor_uv[index, 2:]),
            data.poses.R_world_camera[a],
            data.poses.t_world_camera[a],
            data.plane_n[q],
            data.plane_d[q],
            plane_geo.tangent_basis(data.plane_n[q]),
        )
    return np.all(np.isfinite(res), axis=1) & (np.max(np.abs(res), axis=1) <= MAX_INITIAL_RELATIVE_RESIDUAL)


def build_problem(data: ProblemData, variant: Variant | str, *, robust_px: float | None = None) -> Problem:
    """Choose the variables and factors of `variant` (DESIGN §3) for `data`.

    -wo: every point is an inverse depth, every line orthonormal, no planes. -r: as -wo plus
    point/line-to-plane residuals and one 3-DoF variable per used plane. -w: features assigned
    to a plane have no variable (their plane and anchor define them), the others stay as in
    -wo. Features whose geometry with their plane is degenerate are treated as non-planar;
    for -r also those whose anchor camera is (nearly) on their plane or that start far off it
    (MAX_INITIAL_RELATIVE_RESIDUAL).
    """
    variant = Variant.parse(variant)
    with_lines, mode = variant.with_lines, variant.plane_mode
    n_poses = len(data.poses)
    n_points = len(data.point_anchor)
    n_lines = len(data.line_anchor) if with_lines else 0
    n_planes = len(data.plane_n)
    fixed = np.zeros(n_poses, bool) if data.fixed_poses is None else np.asarray(data.fixed_poses, bool)

    point_planar = _point_plane_valid(data) if mode is not PlaneMode.WITHOUT else np.zeros(n_points, bool)
    line_planar = _line_plane_valid(data)[:n_lines] if (mode is not PlaneMode.WITHOUT and with_lines) else np.zeros(n_lines, bool)
    if mode is PlaneMode.RESIDUAL:  # the relative -r residuals need the anchor off the plane and a sane start
        pp, lp = np.flatnonzero(point_planar), np.flatnonzero(line_planar)
        point_planar[pp] = _anchor_off_plane(data, data.point_anchor[pp], data.point_plane[pp])
        line_planar[lp] = _anchor_off_plane(data, data.line_anchor[lp], data.line_plane[lp])
        pp, lp = np.flatnonzero(point_planar), np.flatnonzero(line_planar)
        point_planar[pp] = _initially_near_plane(data, "point", pp)
        line_planar[lp] = _initially_near_plane(data, "line", lp)

    point_var = np.ones(n_points, bool) if mode is not PlaneMode.PARAMETRIZED else ~point_planar
    line_var = np.ones(n_lines, bool) if mode is not PlaneMode.PARAMETRIZED else ~line_planar
    used_planes = np.zeros(n_planes, bool)
    used_planes[data.point_plane[point_planar]] = True
    if with_lines:
        used_planes[data.line_plane[:n_lines][line_planar]] = True
    if mode is not PlaneMode.WITHOUT and data.inertial is not None and data.inertial.prior is not None:
        used_planes[data.inertial.prior.plane_index] = True  # a marginalization prior keeps its planes in the window

    # Column layout: cameras (poses, then VIO's inertial states) | points | lines | planes.
    pose_col = np.full(n_poses, -1)
    pose_col[~fixed] = 6 * np.arange(int(np.sum(~fixed)))
    start = {"cameras": 0}
    size = {"cameras": 6 * int(np.sum(~fixed))}
    inertial_col = None
    n_inertial = 0
    if data.inertial is not None:
        free_i = np.asarray(data.inertial.free, bool)
        n_inertial = int(np.sum(free_i))
        inertial_col = np.full(n_poses, -1)
        inertial_col[free_i] = size["cameras"] + inertial.INERTIAL_DIM * np.arange(n_inertial)
        size["cameras"] += inertial.INERTIAL_DIM * n_inertial
    point_col = np.full(n_points, -1)
    start["points"] = size["cameras"]
    point_col[point_var] = start["points"] + np.arange(int(np.sum(point_var)))
    size["points"] = int(np.sum(point_var))
    line_col = np.full(len(data.line_anchor), -1)
    start["lines"] = start["points"] + size["points"]
    line_col[:n_lines][line_var] = start["lines"] + 4 * np.arange(int(np.sum(line_var)))
    size["lines"] = 4 * int(np.sum(line_var))
    plane_col = np.full(n_planes, -1)
    start["planes"] = start["lines"] + size["lines"]
    plane_col[used_planes] = start["planes"] + 3 * np.arange(int(np.sum(used_planes)))
    size["planes"] = 3 * int(np.sum(used_planes))
    items = {"cameras": int(np.sum(~fixed)) + n_inertial, "points": size["points"], "lines": size["lines"] // 4, "planes": size["planes"] // 3}
    layout = Layout(pose_col, point_col, line_col, plane_col, start, size, items, inertial_col)

    # Observations per factor type. A point's own left anchor observation is identically
    # satisfied by construction (its ray defines it) and is dropped.
    po = data.point_obs
    is_anchor_left = (po.pose == data.point_anchor[po.landmark]) & np.all(po.offset == 0, axis=1)
    po = po.select(~is_anchor_left)
    planar_obs = point_planar[po.landmark] & ~point_var[po.landmark]
    lo = data.line_obs.select(data.line_obs.landmark < n_lines) if with_lines else Observations.empty(4)
    lplanar_obs = line_planar[lo.landmark] & ~line_var[lo.landmark] if len(lo) else np.zeros(0, bool)
    lo_planar = lo.select(lplanar_obs)
    # A -w line's own left anchor segment spans its back-projection plane: identically zero.
    anchor_left = (lo_planar.pose == data.line_anchor[lo_planar.landmark]) & np.all(lo_planar.offset == 0, axis=1)
    lo_planar = lo_planar.select(~anchor_left)

    if mode is PlaneMode.RESIDUAL:
        pp = np.flatnonzero(point_planar)
        point_pairs = np.stack([pp, data.point_plane[pp]], axis=1)
        lp = np.flatnonzero(line_planar)
        line_pairs = np.stack([lp, data.line_plane[lp]], axis=1)
    else:
        point_pairs = np.zeros((0, 2), int)
        line_pairs = np.zeros((0, 2), int)

    def grouped(obs: Observations, anchor: np.ndarray) -> Observations:
        """Order observations by (anchor, observing pose) so that those with the same
        variables are adjacent: their Hessian blocks are summed before touching H."""
        return obs.select(np.lexsort((obs.landmark, obs.pose, anchor[obs.landmark])))

    return Problem(
        data=data,
        variant=variant,
        layout=layout,
        point_obs_inv_depth=po.select(~planar_obs),
        point_obs_planar=grouped(po.select(planar_obs), data.point_anchor),
        line_obs_free=lo.select(~lplanar_obs) if len(lo) else lo,
        line_obs_planar=grouped(lo_planar, data.line_anchor),
        point_plane_pairs=point_pairs,
        line_plane_pairs=line_pairs,
        robust_px=robust_px,
    )
