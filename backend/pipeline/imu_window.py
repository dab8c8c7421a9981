"""VIO's inertial part, plugged into the shared window solve (`stages.solve`): the IMU model,
the inertial state kept beside the map, and the window extension that adds IMU factors, the
monocular scale gauge before the initialization and the marginalization prior after it.

Frames and units: world z up, metres, seconds; velocities (3,) m/s in the world; biases (6,)
as (accelerometer m/s², gyroscope rad/s); `T_body_camera` (4, 4) the rectified left camera
in the IMU body frame; keyframe ids are the map's.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from typing import Any

import numpy as np

from backend.data.motion import ImuData, ImuNoise
from backend.data.source import InertialSource
from backend.imu.preintegration import DEFAULT_MAX_GAP_NS, PreparedImuFactor, imu_factor, predict_state, preintegrate
from backend.mapping.map import Map
from backend.mapping.window import Window
from backend.optim import inertial
from backend.optim.marginalization import marginalize, remap
from backend.optim.problem import DistancePrior, Problem, ProblemData, State


@dataclasses.dataclass(frozen=True)
class ImuModel:
    """The IMU as the engine uses it (shared, never changed): its samples, noise densities,
    the rectified camera's place in the body frame and gtsam's preintegration parameters."""

    imu: ImuData
    noise: ImuNoise
    T_body_camera: np.ndarray
    params: Any

    def preintegrate(self, t0_ns: int, t1_ns: int, bias: np.ndarray) -> Any:
        return preintegrate(self.imu, int(t0_ns), int(t1_ns), bias_accel=bias[:3], bias_gyro=bias[3:], params=self.params)

    def factor(self, the_map: Map, k: int, bias: np.ndarray) -> PreparedImuFactor:
        """The preintegration from keyframe k to k + 1 with `bias`."""
        return imu_factor(self.preintegrate(int(the_map.keyframe_stamp_ns[k]), int(the_map.keyframe_stamp_ns[k + 1]), bias))

    def predict(self, the_map: Map, k: int, t_ns: int, velocity: np.ndarray, bias: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Camera pose (R, t) and body velocity at `t_ns` from keyframe k's state and the IMU."""
        R_bc, t_bc = self.T_body_camera[:3, :3], self.T_body_camera[:3, 3]
        R_wb, t_wb, _ = inertial.body_poses(the_map.R_world_keyframe[k][None], the_map.t_world_keyframe[k][None], self.T_body_camera)
        pim = self.preintegrate(int(the_map.keyframe_stamp_ns[k]), t_ns, bias)
        R_wb1, t_wb1, v1 = predict_state(pim, R_wb[0], t_wb[0], velocity, bias=bias)
        return R_wb1 @ R_bc, t_wb1 + R_wb1 @ t_bc, v1


@dataclasses.dataclass
class InertialState:
    """What VIO keeps beside the map: per keyframe velocity and biases, the preintegration
    from each keyframe to the next (`factors[k]`), the marginalization prior (global keyframe
    and plane ids), whether the IMU is in yet (`initialized`), and the first keyframe not yet
    marginalized."""

    velocity: list[np.ndarray] = dataclasses.field(default_factory=list)
    bias: list[np.ndarray] = dataclasses.field(default_factory=list)
    factors: dict[int, PreparedImuFactor] = dataclasses.field(default_factory=dict)
    prior: inertial.LinearPrior | None = None
    initialized: bool = False
    marginalized_before: int = 0
    joint_from: int | None = None  # the start's joint solve: every keyframe from this one, nothing marginalized

    def add_keyframe(self, the_map: Map, k: int, model: ImuModel) -> None:
        """Velocity and biases of the new keyframe k (the IMU's prediction after the
        initialization) and the preintegration from the previous keyframe."""
        if k == the_map.segment_start or not self.initialized:
            self.velocity.append(np.zeros(3))
            self.bias.append(self.bias[-1].copy() if self.bias else np.zeros(6))
        else:
            _, _, v = model.predict(the_map, k - 1, int(the_map.keyframe_stamp_ns[k]), self.velocity[k - 1], self.bias[k - 1])
            self.velocity.append(v)
            self.bias.append(self.bias[k - 1].copy())
        if k > the_map.segment_start:
            self.factors[k - 1] = model.factor(the_map, k - 1, self.bias[k - 1])

    def window_range(self, the_map: Map, k: int, *, window: int, init_window: int, fixed_horizon: int) -> tuple[int, int]:
        """The window [w0, k] and the first keyframe whose observations enter: before the
        initialization the last `init_window` keyframes, older ones held fixed
        (`fixed_horizon`); after it the last `window`, the prior standing for everything
        before them; in the start's joint solve every keyframe from `joint_from`."""
        if self.initialized and self.joint_from is not None:
            return self.joint_from, self.joint_from
        if self.initialized:
            w0 = max(the_map.segment_start, k - window + 1, self.marginalized_before)
            return w0, w0
        w0 = max(the_map.segment_start, k - max(window, init_window) + 1)
        return w0, max(the_map.segment_start, w0 - fixed_horizon)


@dataclasses.dataclass(frozen=True)
class InertialWindowSettings:
    """`window`: keyframes per window (a full one marginalizes its oldest); a preintegration
    is redone when the bias estimate moves more than `rebias_accel` / `rebias_gyro` from the
    one it was made with."""

    window: int
    rebias_accel: float
    rebias_gyro: float


class InertialWindow:
    """`stages.solve.WindowExtension` of VIO for one solve of `the_map`'s window."""

    def __init__(self, state: InertialState, the_map: Map, model: ImuModel, settings: InertialWindowSettings) -> None:
        self.state = state
        self.map = the_map
        self.model = model
        self.settings = settings

    def keep_landmarks(self, w0: int) -> Callable[[np.ndarray, np.ndarray], tuple[np.ndarray, np.ndarray]] | None:
        """After the initialization, landmarks marginalized with their anchor stay out."""
        if not self.state.initialized:
            return None
        points, lines = self.map.points, self.map.lines
        return lambda pts, lns: (pts[points.anchor[pts] >= w0], lns[lines.anchor[lns] >= w0])

    def extra_planes(self) -> np.ndarray | None:
        """The planes the marginalization prior holds."""
        prior = self.state.prior
        if self.state.initialized and prior is not None and len(prior.plane_index):
            return prior.plane_index
        return None

    def fix_first_pose(self) -> bool:
        """Before the initialization the first pose is the gauge; after it, the prior is."""
        return not self.state.initialized

    def pinned_poses(self) -> None:
        """None: VIO places every keyframe against the map or by the IMU."""
        return None

    def problem_data(self, window: Window) -> ProblemData:
        """Before the initialization the scale gauge; after it the IMU factors and the prior."""
        data, kfs, st, the_map = window.data, window.kf, self.state, self.map
        if not st.initialized:
            # The monocular scale gauge before the IMU gives it: the distance of the segment's
            # first two keyframes, where both are in the window.
            k0 = the_map.segment_start
            if k0 in kfs and k0 + 1 in kfs:
                i, j = np.searchsorted(kfs, [k0, k0 + 1])
                dist = float(np.linalg.norm(the_map.t_world_keyframe[k0 + 1] - the_map.t_world_keyframe[k0]))
                data = dataclasses.replace(data, distance_prior=DistancePrior(np.array([i]), np.array([j]), np.array([dist]), 1e-4 * max(dist, 1e-6)))
            return data
        self._refresh_preintegrations(kfs)
        n = len(kfs)
        pose_map = np.full(len(the_map), -1)
        pose_map[kfs] = np.arange(n)
        pairs = [(a, a + 1) for a in kfs[:-1] if a + 1 in set(kfs.tolist())]
        imu_i = np.array([pose_map[a] for a, _ in pairs], np.int64)
        imu_j = np.array([pose_map[b] for _, b in pairs], np.int64)
        factors = tuple(st.factors[a] for a, _ in pairs)
        dt = np.array([(int(the_map.keyframe_stamp_ns[b]) - int(the_map.keyframe_stamp_ns[a])) * 1e-9 for a, b in pairs])
        prior = None
        if st.prior is not None:
            plane_map = np.full(len(the_map.planes), -1)
            plane_map[window.planes] = np.arange(len(window.planes))
            prior = remap(st.prior, pose_map=pose_map, plane_map=plane_map)
        assert data.fixed_poses is not None
        ine = inertial.InertialData(
            T_body_camera=self.model.T_body_camera,
            velocity=np.array([st.velocity[k] for k in kfs]),
            bias=np.array([st.bias[k] for k in kfs]),
            free=~data.fixed_poses,
            imu_i=imu_i,
            imu_j=imu_j,
            imu=factors,
            dt_s=dt,
            noise=self.model.noise,
            prior=prior,
        )
        return dataclasses.replace(data, inertial=ine)

    def _refresh_preintegrations(self, kfs: np.ndarray) -> None:
        """Re-preintegrate the intervals whose bias estimate moved beyond the first-order
        correction's comfort (`rebias_accel`, `rebias_gyro`)."""
        s, st = self.settings, self.state
        for a in kfs[:-1]:
            f = st.factors.get(int(a))
            if f is None:
                continue
            hat = np.asarray(f.pim.biasHatVector()).ravel()
            d = st.bias[a] - hat
            if np.max(np.abs(d[:3])) > s.rebias_accel or np.max(np.abs(d[3:])) > s.rebias_gyro:
                st.factors[int(a)] = self.model.factor(self.map, int(a), st.bias[int(a)])

    def after_solve(self, window: Window, problem: Problem, state: State) -> None:
        """Velocities and biases back from the solution; marginalize when the window is full."""
        st = self.state
        if not st.initialized or state.velocity is None or state.bias is None:
            return
        assert window.data.fixed_poses is not None
        free = ~window.data.fixed_poses
        for j, k in enumerate(window.kf):
            if free[j]:
                st.velocity[k] = state.velocity[j].copy()
                st.bias[k] = state.bias[j].copy()
        # Slide: when the window is full, marginalize its oldest keyframe and its landmarks
        # (not in the start's joint solve: the start sets the next window's prior).
        if len(window.kf) >= self.settings.window and st.joint_from is None:
            oldest = int(window.kf[0])
            p_local = np.flatnonzero(self.map.points.anchor[window.points] == oldest)
            l_local = np.flatnonzero(self.map.lines.anchor[window.lines] == oldest)
            prior = marginalize(problem, state, poses=np.array([0]), points=p_local, lines=l_local)
            st.prior = (
                None
                if prior is None
                else dataclasses.replace(prior, pose_index=window.kf[prior.pose_index], inertial_index=window.kf[prior.inertial_index], plane_index=window.planes[prior.plane_index])
            )
            st.marginalized_before = oldest + 1


def check_imu_coverage(imu: ImuData, source: InertialSource) -> None:
    """The IMU must cover the frames with no gap longer than a frame interval."""
    from backend.data.errors import DatasetError

    stamps = imu.timestamp_ns
    frames = np.asarray(source.timestamps_ns, dtype=np.int64)
    label = source.imu_label
    if len(stamps) < 2 or stamps[0] > frames[0] or stamps[-1] + DEFAULT_MAX_GAP_NS < frames[-1]:
        raise DatasetError(label, f"the IMU samples ({len(stamps)}) do not cover the camera frames")
    period = np.min(np.diff(frames)) if len(frames) > 1 else 0
    inside = (stamps >= frames[0]) & (stamps <= frames[-1])
    gaps = np.diff(stamps[inside]) if inside.sum() > 1 else np.zeros(0)
    if len(gaps) and period and gaps.max() > period:
        j = int(np.argmax(gaps))
        raise DatasetError(label, f"IMU gap of {gaps[j] * 1e-6:.1f} ms after {stamps[inside][j]} ns, longer than a frame interval ({period * 1e-6:.1f} ms)")
