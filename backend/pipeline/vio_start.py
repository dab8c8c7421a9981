"""The start of VIO: the visual-inertial alignment (VINS-Mono's loosely coupled
initialization, `backend.vio.alignment`) over the keyframes of a map segment's visual window
(`thinned` to a minimum interval), and what it changes when it succeeds: the segment's map
scaled and rotated into a gravity-aligned world, velocities and the gyroscope bias, the
preintegrations, and the gauge prior of the first window with IMU factors. The start's
state says how far it got (the snapshots show it).

Frames and units: world z up, metres, seconds; keyframe ids are the map's.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable

import numpy as np

from backend.data.source import RenderedTruth, StereoSource
from backend.eval.trajectory import umeyama_alignment
from backend.geometry import so3
from backend.mapping.map import Map
from backend.optim import inertial
from backend.pipeline.imu_window import ImuModel, InertialState
from backend.pipeline.snapshot import ImuState, frozen
from backend.pipeline.vio_settings import VioSettings
from backend.vio.alignment import Alignment, AlignmentSettings, align_visual_inertial


def _yaw_between(R_target: np.ndarray, R: np.ndarray) -> np.ndarray:
    """The rotation about world z that turns `R`'s heading into `R_target`'s (both
    `R_world_x`; their tilts may differ)."""
    M = R_target @ R.T
    yaw = np.arctan2(M[1, 0] - M[0, 1], M[0, 0] + M[1, 1])
    return so3.exp(np.array([0.0, 0.0, yaw]))


def similarity_plucker(m: np.ndarray, v: np.ndarray, *, scale: float, R: np.ndarray, c: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Plücker lines (m, v) (N, 3) under the similarity x ↦ scale·R·x + c, with |v| = 1: v ↦ R v,
    m ↦ scale·R m + c × R v. Exact also for a line far from the origin (|m| ≫ 1), whose two
    points, transformed and differenced, would cancel to nothing."""
    v_new = v @ R.T
    m_new = scale * (m @ R.T) + np.cross(c, v_new)
    norm = np.linalg.norm(v_new, axis=1, keepdims=True)
    return m_new / norm, v_new / norm


def thinned(stamps_ns: np.ndarray, *, min_interval_s: float) -> np.ndarray:
    """Indices of increasing `stamps_ns` (ns) kept for the alignment: the first, then each at
    least `min_interval_s` after the last kept, and the newest (replacing the last kept when
    it is nearer than that). Positions differenced over short intervals carry the visual
    noise into the accelerations the scale is fitted to, which biases it towards zero."""
    t = (np.asarray(stamps_ns, np.int64) - int(stamps_ns[0])) * 1e-9
    keep = [0]
    for i in range(1, len(t)):
        if t[i] - t[keep[-1]] >= min_interval_s - 1e-9:
            keep.append(i)
    if keep[-1] != len(t) - 1:
        if len(keep) > 1 and t[-1] - t[keep[-1]] < min_interval_s:
            keep[-1] = len(t) - 1
        else:
            keep.append(len(t) - 1)
    return np.array(keep, np.int64)


@dataclasses.dataclass(frozen=True)
class StartContext:
    """What one initialization attempt works on: the map, the inertial state, the IMU model,
    the input (its ground truth anchors the unobservable yaw and position, and rendered
    inputs report the alignment's errors), the VIO settings and the step's messages."""

    map: Map
    inertial: InertialState
    model: ImuModel
    source: StereoSource
    settings: VioSettings
    messages: list[str]


@dataclasses.dataclass
class VioStart:
    """How far the start got: a status line, the last alignment's report and keyframe, and
    the first successful initialization's keyframe and report (-1: none yet)."""

    status: str = "structure from motion: waiting for parallax"
    report: dict = dataclasses.field(default_factory=dict)
    keyframe: int = -1
    first: tuple[int, dict] = (-1, {})
    refined: int = 0  # scale refinements done since the last successful start (`refine`)
    refine_retry_at_s: float = 0.0  # after a rejected refinement: seconds after the start of its next try

    def try_initialize(self, k: int, ctx: StartContext) -> None:
        """Visual-inertial alignment over the segment's last `init_window` keyframes, thinned
        (module docstring); the keyframes between the aligned ones take their velocity from
        the IMU."""
        s = ctx.settings
        first = max(ctx.map.segment_start, k + 1 - max(s.window, s.init_window))
        kfs = np.arange(first, k + 1)
        n_kf = len(kfs)
        span = (int(ctx.map.keyframe_stamp_ns[k]) - int(ctx.map.keyframe_stamp_ns[first])) * 1e-9
        if n_kf < s.init_keyframes or span < s.init_min_span_s:
            self.status = f"structure from motion: {n_kf} keyframes over {span:.1f} s (alignment after {s.init_keyframes} keyframes over {s.init_min_span_s:.1f} s)"
            return
        used, result = _align(kfs, span, ctx, s.alignment)
        self.report = {"keyframes": n_kf, "aligned_keyframes": len(used), "span_s": span, **result.to_dict()}
        if not result.success:
            self.status = f"alignment rejected at keyframe {k} ({n_kf} keyframes, {span:.1f} s): {result.reason}; retrying"
            ctx.messages.append(self.status)
            return
        self._apply_alignment(kfs[used], result, ctx)
        ctx.inertial.initialized = True
        self.keyframe = k
        self.refined = 0
        self.refine_retry_at_s = 0.0
        truth = self._init_truth(kfs, result, ctx)
        self.report.update(truth)
        if self.first[0] < 0:
            self.first = (k, dict(self.report))
        self.status = f"initialized at keyframe {k} ({n_kf} keyframes, {span:.1f} s): scale {result.scale:.3f}, gyro bias {np.round(result.bias_gyro, 4).tolist()} rad/s"
        ctx.messages.append(self.status)

    def _apply_alignment(self, kfs: np.ndarray, result: Alignment, ctx: StartContext) -> None:
        """Scale and rotate the segment's map into the gravity-aligned world; velocities and
        the gyro bias from the alignment; the gauge prior on the first aligned keyframe for
        the joint solve (then `narrow`)."""
        k0 = int(kfs[0])
        R_v0, t_v0 = ctx.map.R_world_keyframe[k0].copy(), ctx.map.t_world_keyframe[k0].copy()
        R_w_c0 = result.R_world_c0
        # Yaw and position of the first aligned keyframe (the gauge: unobservable): at the
        # first start from the ground truth where known (chosen so that estimate and truth are
        # drawn together); after a restart (an earlier start succeeded) the estimate's own,
        # that is the pose the segment started from, so that a restart learns nothing from the
        # truth and the trajectory goes on from where it was.
        t_w_c0 = np.zeros(3)
        i0 = int(ctx.map.keyframe_frame[k0])
        scale = float(result.scale)
        Rz = np.eye(3)
        if self.first[0] >= 0:
            # A restart: the segment's first keyframe keeps its pose (yaw and position).
            s0 = ctx.map.segment_start
            R_s0, t_s0 = ctx.map.R_world_keyframe[s0], ctx.map.t_world_keyframe[s0]
            Rz = _yaw_between(R_s0, R_w_c0 @ R_v0.T @ R_s0)
            R_w_c0 = Rz @ R_w_c0
            t_w_c0 = t_s0 - scale * ((t_s0 - t_v0) @ R_v0) @ R_w_c0.T
        elif bool(ctx.source.ground_truth_valid[i0]):
            T = ctx.source.T_world_rect0[i0]
            Rz = _yaw_between(T[:3, :3], R_w_c0)
            R_w_c0 = Rz @ R_w_c0
            t_w_c0 = T[:3, 3].copy()
        vel_world = result.velocity_world @ Rz.T

        def to_world(p_v: np.ndarray) -> np.ndarray:
            return scale * ((p_v - t_v0) @ R_v0) @ R_w_c0.T + t_w_c0

        R_wv = R_w_c0 @ R_v0.T
        similarity_segment(ctx.map, moved=to_world, scale=scale, R=R_wv, c=t_w_c0 - scale * (R_wv @ t_v0))
        for j, kf in enumerate(kfs):
            ctx.inertial.velocity[kf] = vel_world[j].copy()
        # The keyframes between the aligned ones (thinned): velocity by the IMU from the previous.
        for kf in range(int(kfs[0]) + 1, int(kfs[-1])):
            if kf not in kfs:
                _, _, ctx.inertial.velocity[kf] = ctx.model.predict(ctx.map, kf - 1, int(ctx.map.keyframe_stamp_ns[kf]), ctx.inertial.velocity[kf - 1], np.r_[result.bias_accel, result.bias_gyro])
        # The accelerometer bias starts at zero as before: the alignment's estimate serves its
        # scale, but it is weakly determined (mostly its prior's) and, as the windows' prior
        # mean (σ `bias_sigma_accel`), held them off (MH_01: scale error -2.5 % against -1.0 %).
        for kf in range(ctx.map.segment_start, len(ctx.map)):
            ctx.inertial.bias[kf] = np.r_[np.zeros(3), result.bias_gyro]
        for kf in range(ctx.map.segment_start, len(ctx.map) - 1):
            ctx.inertial.factors[kf] = ctx.model.factor(ctx.map, kf, ctx.inertial.bias[kf])
        # The joint solve: every aligned keyframe with IMU factors, the gauge prior on the first
        # (then `narrow`); landmarks anchored before it are frozen from here on.
        ctx.inertial.joint_from = k0
        ctx.inertial.marginalized_before = k0
        ctx.inertial.prior = self._gauge_prior(k0, ctx)

    def refine(self, k: int, ctx: StartContext) -> None:
        """The scale again, keeping the inertial state: once keyframe k is
        `refine_after_s[i]` seconds after the start, the alignment over the segment's last
        `refine_window` keyframes (thinned as the start's; already metric and gravity-aligned,
        so its scale is the factor still missing), accepted by `refine_alignment` (a tighter
        σ than the start's, and a χ²/dof of at most 1: the keyframes' motion must fit the
        IMU's). The segment's keyframe positions, landmarks and planes are
        scaled about keyframe k's position, its velocities by the factor, and the
        marginalization prior's linearization point with them (its weights stay); rotations,
        biases and preintegrations are kept. A rejected alignment is tried again
        `refine_retry_s` later, not at the next keyframe: each try is a noisy measurement,
        and trying at every keyframe until one passes the σ bound took the first noisy one
        that did (CHANGELOG 2026-12-08). The start accepts a scale σ of 30 %, which the windows alone correct slowly
        (their marginalization prior holds the scale); at 5 s as well the refinement was
        noise (CHANGELOG, issue 26)."""
        s = ctx.settings
        m = ctx.map
        if self.keyframe < 0 or self.refined >= len(s.refine_after_s):
            return
        since = (int(m.keyframe_stamp_ns[k]) - int(m.keyframe_stamp_ns[self.keyframe])) * 1e-9
        if since < max(s.refine_after_s[self.refined], self.refine_retry_at_s):
            return
        first = max(m.segment_start, k + 1 - s.refine_window)
        kfs = np.arange(first, k + 1)
        span = (int(m.keyframe_stamp_ns[k]) - int(m.keyframe_stamp_ns[first])) * 1e-9
        if len(kfs) < s.init_keyframes:
            return
        kept, result = _align(kfs, span, ctx, s.refine_alignment)
        used = kfs[kept]
        if not result.success:
            self.report["refinement_rejections"] = int(self.report.get("refinement_rejections", 0)) + 1  # tried again `refine_retry_s` later
            self.report["refinement_last_rejection"] = result.reason
            self.refine_retry_at_s = since + s.refine_retry_s
            return
        sigma = float(result.quality.scale_rel_std)
        while self.refined < len(s.refine_after_s) and since >= s.refine_after_s[self.refined]:
            self.refined += 1
        scale = float(result.scale)
        truth = bool(np.all(ctx.source.ground_truth_valid[m.keyframe_frame[used]]))
        before = _scale_error_pct(used, ctx) if truth else None
        scale_segment(ctx.map, ctx.inertial, scale=scale, center_world=m.t_world_keyframe[k].copy())
        entry: dict[str, float | int | None] = {
            "keyframe": k,
            "after_start_s": since,
            "aligned_keyframes": len(used),
            "scale": scale,
            "scale_rel_std": sigma,
            "chi2_per_dof": float(result.quality.chi2_per_dof),
        }
        if truth:
            entry["scale_error_before_pct"] = before
            entry["scale_error_pct"] = _scale_error_pct(used, ctx)
        self.report.setdefault("refinements", []).append(entry)
        ctx.messages.append(f"scale refined at keyframe {k} ({since:.1f} s after the start): ×{scale:.3f} (σ {100 * sigma:.1f} %)")

    def narrow(self, ctx: StartContext) -> None:
        """After the start's joint solve: the usual window of the last `window` keyframes,
        the gauge prior (VioSettings' σ) on its first keyframe's solved state; the keyframes
        before it leave the optimization."""
        assert ctx.inertial.joint_from is not None, "narrow() follows a successful try_initialize()"
        joint = np.arange(ctx.inertial.joint_from, len(ctx.map))
        if "scale_error_pct" in self.report and bool(np.all(ctx.source.ground_truth_valid[ctx.map.keyframe_frame[joint]])):
            self.report["joint_scale_error_pct"] = _scale_error_pct(joint, ctx)
            if self.first[0] == self.keyframe:
                self.first = (self.keyframe, dict(self.report))
        w0 = max(ctx.map.segment_start, len(ctx.map) - ctx.settings.window + 1)  # the next window's first keyframe
        ctx.inertial.joint_from = None
        ctx.inertial.marginalized_before = w0
        ctx.inertial.prior = self._gauge_prior(w0, ctx)

    def _gauge_prior(self, k: int, ctx: StartContext) -> inertial.LinearPrior:
        """What the start knows about keyframe k: position and yaw (the gauge), roll and pitch
        from the aligned gravity, velocity and biases (VioSettings' σ)."""
        s = ctx.settings
        R, t = ctx.map.R_world_keyframe[k], ctx.map.t_world_keyframe[k]
        A = np.zeros((15, 15))
        A[:3, :3] = np.diag([1 / s.gauge_sigma_tilt_rad, 1 / s.gauge_sigma_tilt_rad, 1 / s.gauge_sigma_yaw_rad]) @ R  # world-axis rotation errors
        A[3:6, 3:6] = np.eye(3) / s.gauge_sigma_m
        A[6:9, 6:9] = np.eye(3) / s.velocity_sigma
        A[9:12, 9:12] = np.eye(3) / s.bias_sigma_accel
        A[12:15, 12:15] = np.eye(3) / s.bias_sigma_gyro
        return inertial.LinearPrior(
            pose_index=np.array([k]),
            inertial_index=np.array([k]),
            plane_index=np.zeros(0, np.int64),
            R=R[None].copy(),
            t=t[None].copy(),
            inertial=np.r_[ctx.inertial.velocity[k], ctx.inertial.bias[k]][None],
            plane_n=np.zeros((0, 3)),
            plane_d=np.zeros(0),
            A=A,
            b=np.zeros(15),
        )

    def _init_truth(self, kfs: np.ndarray, result: Alignment, ctx: StartContext) -> dict:
        """The alignment against the truth where the source has it (rendered scenes)."""
        out: dict = {}
        src = ctx.source
        if isinstance(src, RenderedTruth):
            stamps = ctx.map.keyframe_stamp_ns[kfs]
            imu_t = ctx.model.imu.timestamp_ns  # the source's own IMU samples
            at = np.clip(np.searchsorted(imu_t, stamps), 0, len(imu_t) - 1)
            b_true = np.mean(src.bias_gyro[at], axis=0)
            out["bias_gyro_true"] = b_true.tolist()
            out["bias_gyro_error"] = float(np.linalg.norm(result.bias_gyro - b_true))
            out["bias_gyro_error_pct"] = float(100.0 * np.linalg.norm(result.bias_gyro - b_true) / max(float(np.linalg.norm(b_true)), 1e-12))
        i0 = int(ctx.map.keyframe_frame[kfs[0]])
        if bool(src.ground_truth_valid[i0]):
            R_gt_c0 = src.T_world_rect0[i0][:3, :3]
            g_true_c0 = R_gt_c0.T @ np.array([0.0, 0.0, -9.81])
            g = result.gravity_c0
            out["gravity_error_deg"] = float(np.degrees(np.arccos(np.clip(g @ g_true_c0 / (np.linalg.norm(g) * 9.81), -1.0, 1.0))))
            # Scale: the aligned keyframes' positions against the true ones, by the similarity
            # (Umeyama) that fits them best: the estimate's scale over the truth's, minus one.
            out["scale_error_pct"] = _scale_error_pct(kfs, ctx)
        return out


def similarity_segment(the_map: Map, *, moved: Callable[[np.ndarray], np.ndarray], scale: float, R: np.ndarray, c: np.ndarray) -> None:
    """The map segment under the similarity x ↦ scale·R·x + c (world frame, m), which `moved`
    applies to positions (N, 3): keyframe rotations and positions, the frames'
    offsets from their keyframes, the points and lines anchored in the segment, and the
    planes they lie on. Lines never triangulated (v = 0) or left degenerate by a solve (not
    finite) stay as they are."""
    s0 = the_map.segment_start
    seg = np.arange(s0, len(the_map))
    the_map.R_world_keyframe[seg] = np.einsum("ij,njk->nik", R, the_map.R_world_keyframe[seg])
    the_map.t_world_keyframe[seg] = moved(the_map.t_world_keyframe[seg])
    the_map.scale_frame_offsets(first_keyframe=s0, scale=scale)
    P, Lm = the_map.points, the_map.lines
    pts = np.flatnonzero(P.anchor[:] >= s0)
    P.p_world[pts] = moved(P.p_world[pts])
    segment_lines = np.flatnonzero(Lm.anchor[:] >= s0)
    m_v, v_v = Lm.m[segment_lines], Lm.v[segment_lines]
    lns = segment_lines[np.all(np.isfinite(m_v), axis=1) & (np.linalg.norm(v_v, axis=1) > 0)]  # NaN > 0 is False
    if len(lns):
        Lm.m[lns], Lm.v[lns] = similarity_plucker(Lm.m[lns], Lm.v[lns], scale=scale, R=R, c=c)
    used_planes = np.unique(np.concatenate([P.plane[pts], Lm.plane[segment_lines]]))
    for q in used_planes[used_planes >= 0]:
        n_v, d_v = the_map.planes.n[q], the_map.planes.d[q]
        n_w = R @ n_v
        x_v = -d_v * n_v  # a point of the plane
        the_map.planes.n[q], the_map.planes.d[q] = n_w, float(-n_w @ moved(x_v[None])[0])


def scale_segment(the_map: Map, state: InertialState, *, scale: float, center_world: np.ndarray) -> None:
    """The map segment under x ↦ c + scale·(x - c) (world frame, c = `center_world`, m):
    keyframe positions, the points and lines anchored in it, the planes they lie on; the
    segment's velocities times `scale`; the marginalization prior's linearization point
    (positions, velocities, plane offsets) with them. Rotations and plane normals stay."""
    c = np.asarray(center_world, float)

    def moved(x: np.ndarray) -> np.ndarray:
        return c + scale * (x - c)

    similarity_segment(the_map, moved=moved, scale=scale, R=np.eye(3), c=(1.0 - scale) * c)

    def moved_d(n: np.ndarray, d: float) -> float:
        return float(-n @ moved(-d * n))  # the plane's point nearest the origin, moved

    for kf in range(the_map.segment_start, len(the_map)):
        state.velocity[kf] = scale * state.velocity[kf]
    prior = state.prior
    if prior is not None:
        inert = prior.inertial.copy()
        inert[:, :3] *= scale
        state.prior = dataclasses.replace(
            prior,
            t=moved(prior.t),
            inertial=inert,
            plane_d=np.array([moved_d(n, float(d)) for n, d in zip(prior.plane_n, prior.plane_d, strict=True)]).reshape(-1),
        )


def _align(kfs: np.ndarray, span_s: float, ctx: StartContext, settings: AlignmentSettings) -> tuple[np.ndarray, Alignment]:
    """The visual-inertial alignment over keyframes `kfs` (spanning `span_s` seconds), thinned
    (`thinned`: at least `init_alignment_interval_s` apart, fewer where the span holds fewer
    than `init_keyframes`), their poses taken relative to the first kept one. Returns the
    kept indices into `kfs` and the alignment."""
    s = ctx.settings
    m = ctx.map
    kept = thinned(m.keyframe_stamp_ns[kfs], min_interval_s=min(s.init_alignment_interval_s, span_s / (s.init_keyframes - 1)))
    R_v, t_v = m.R_world_keyframe[kfs[kept]], m.t_world_keyframe[kfs[kept]]
    R_c0 = np.einsum("ji,njk->nik", R_v[0], R_v)
    p_c0 = np.einsum("ji,nj->ni", R_v[0], t_v - t_v[0])
    result = align_visual_inertial(m.keyframe_stamp_ns[kfs[kept]], R_c0, p_c0, ctx.model.imu, T_body_cam0=ctx.model.T_body_camera, noise=ctx.model.noise, settings=settings)
    return kept, result


def _scale_error_pct(kfs: np.ndarray, ctx: StartContext) -> float:
    """The similarity (Umeyama) that fits keyframes `kfs` best to their true positions: the
    estimate's scale over the truth's, minus one, in per cent (they must have ground truth)."""
    t_gt = ctx.source.T_world_rect0[ctx.map.keyframe_frame[kfs]][:, :3, 3]
    _, _, s_fit = umeyama_alignment(ctx.map.t_world_keyframe[kfs], t_gt, with_scale=True)
    return float(100.0 * (1.0 / s_fit - 1.0)) if s_fit > 0 else float("nan")


def imu_state(the_map: Map, k: int, state: InertialState, start: VioStart, source: object, imu_stamps_ns: np.ndarray) -> ImuState:
    """The snapshot's IMU part at keyframe k: how far the start got, the keyframes'
    velocities and biases, and on rendered inputs their true values (the biases per IMU
    sample, at `imu_stamps_ns`)."""
    vel = np.array(state.velocity[: k + 1]).reshape(-1, 3)
    bias = np.array(state.bias[: k + 1]).reshape(-1, 6)
    truth_v = truth_b = None
    src = source
    if isinstance(src, RenderedTruth):
        t = the_map.keyframe_stamp_ns[: k + 1] * 1e-9
        truth_v = src.trajectory.velocity(t)
        at = np.clip(np.searchsorted(imu_stamps_ns, the_map.keyframe_stamp_ns[: k + 1]), 0, len(imu_stamps_ns) - 1)
        truth_b = np.concatenate([src.bias_accel[at], src.bias_gyro[at]], axis=1)
    return ImuState(
        initialized=state.initialized,
        status=start.status,
        init_keyframe=start.keyframe,
        report=dict(start.report),
        first_init_keyframe=start.first[0],
        first_report=dict(start.first[1]),
        velocity_world=frozen(vel),
        bias=frozen(bias),
        gravity_world=frozen(np.array([0.0, 0.0, -9.81]) if state.initialized else np.full(3, np.nan)),
        velocity_true=None if truth_v is None else frozen(truth_v),
        bias_true=None if truth_b is None else frozen(truth_b),
    )
