"""What the Monte-Carlo engine keeps between steps: the keyframes' poses (estimated, true,
odometry), the observations of each keyframe and the landmarks.

Poses are `T_world_camera` (rotation (3, 3), position (3,) in metres, world frame z up);
landmark ids are the world's point and segment indices (every landmark has its row from
the start; `ok` says whether it is triangulated); pixels are the world camera's."""

from __future__ import annotations

import dataclasses
from typing import Literal

import numpy as np

from backend.common.buffers import RowBuffer
from backend.geometry.camera import PinholeCamera
from backend.geometry.se3 import Poses
from backend.mapping import coplanar
from backend.optim import factors

LandmarkKind = Literal["point", "line"]


@dataclasses.dataclass
class FrameObs:
    """Observations of one keyframe: world point ids (M,), their pixels (M, 2) and instance
    labels (M,; -1: none); world segment ids (L,), their endpoint pixels (L, 4: u0 v0 u1 v1)
    and instance labels (L,)."""

    point_id: np.ndarray
    point_uv: np.ndarray
    point_label: np.ndarray
    line_id: np.ndarray
    line_uv: np.ndarray
    line_label: np.ndarray


@dataclasses.dataclass
class SimKeyframes:
    """Per keyframe (row = keyframe id): the estimated pose, the true pose, the odometry
    measurement from the previous keyframe (`R_odo`, `t_odo`: pose of k in k-1's camera
    frame; identity for keyframe 0) and the timestamp (ns)."""

    R_est: RowBuffer = dataclasses.field(default_factory=lambda: RowBuffer((3, 3)))
    t_est: RowBuffer = dataclasses.field(default_factory=lambda: RowBuffer((3,)))
    R_gt: RowBuffer = dataclasses.field(default_factory=lambda: RowBuffer((3, 3)))
    t_gt: RowBuffer = dataclasses.field(default_factory=lambda: RowBuffer((3,)))
    stamp: RowBuffer = dataclasses.field(default_factory=lambda: RowBuffer((), dtype=np.int64))
    R_odo: RowBuffer = dataclasses.field(default_factory=lambda: RowBuffer((3, 3)))
    t_odo: RowBuffer = dataclasses.field(default_factory=lambda: RowBuffer((3,)))

    def __len__(self) -> int:
        return len(self.t_est)

    def append(self, *, R_est: np.ndarray, t_est: np.ndarray, R_gt: np.ndarray, t_gt: np.ndarray, R_odo: np.ndarray, t_odo: np.ndarray, stamp_ns: int) -> None:
        """Add the next keyframe's row."""
        self.R_odo.append(R_odo)
        self.t_odo.append(t_odo)
        self.R_est.append(R_est)
        self.t_est.append(t_est)
        self.R_gt.append(R_gt)
        self.t_gt.append(t_gt)
        self.stamp.append(stamp_ns)

    def estimate(self) -> Poses:
        """The estimated poses of all keyframes, as views (valid until the next append)."""
        return Poses(self.R_est[:], self.t_est[:])


@dataclasses.dataclass
class SimLandmarks:
    """The landmarks, one row per world point (`p_*`) and world segment (`l_*`).

    Points: `p_world` (P, 3) world position (m; NaN before triangulation), `p_ok`
    triangulated, `p_anchor` the first keyframe that saw it (-1: none yet) and its pixel
    `p_anchor_uv` (P, 2), `p_plane` plane id (-1: none). Lines: Plücker `l_m`, `l_v` (L, 3;
    unit `l_v`, world), `l_ok`, `l_anchor`, the anchor keyframe's endpoint pixels
    `l_anchor_uv` (L, 4) and `l_plane`."""

    p_world: np.ndarray
    p_ok: np.ndarray
    p_anchor: np.ndarray
    p_anchor_uv: np.ndarray
    p_plane: np.ndarray
    l_m: np.ndarray
    l_v: np.ndarray
    l_ok: np.ndarray
    l_anchor: np.ndarray
    l_anchor_uv: np.ndarray
    l_plane: np.ndarray

    @staticmethod
    def empty(n_points: int, n_lines: int) -> SimLandmarks:
        """No landmark triangulated, anchored or on a plane yet."""
        P, L = n_points, n_lines
        return SimLandmarks(
            p_world=np.full((P, 3), np.nan),
            p_ok=np.zeros(P, bool),
            p_anchor=np.full(P, -1),
            p_anchor_uv=np.zeros((P, 2)),
            p_plane=np.full(P, -1),
            l_m=np.full((L, 3), np.nan),
            l_v=np.full((L, 3), np.nan),
            l_ok=np.zeros(L, bool),
            l_anchor=np.full(L, -1),
            l_anchor_uv=np.zeros((L, 4)),
            l_plane=np.full(L, -1),
        )

    def anchor_new(self, k: int, obs: FrameObs) -> None:
        """Keyframe k becomes the anchor of the landmarks it is the first to observe."""
        sp = self.p_anchor[obs.point_id] < 0
        new_p = obs.point_id[sp]
        self.p_anchor[new_p], self.p_anchor_uv[new_p] = k, obs.point_uv[sp]
        sl = self.l_anchor[obs.line_id] < 0
        new_l = obs.line_id[sl]
        self.l_anchor[new_l], self.l_anchor_uv[new_l] = k, obs.line_uv[sl]

    def views(self, observations: dict[int, FrameObs], kind: LandmarkKind, ids: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """All stored observations of landmarks `ids` of `kind`: (keyframe, landmark id, uv)
        rows, uv (N, 2) for points and (N, 4) for segments, in keyframe order."""
        want = np.zeros(len(self.p_ok) if kind == "point" else len(self.l_ok), bool)
        want[ids] = True
        kf, lm, uv = [], [], []
        for k, o in observations.items():
            i, u = (o.point_id, o.point_uv) if kind == "point" else (o.line_id, o.line_uv)
            sel = want[i]
            kf.append(np.full(int(sel.sum()), k))
            lm.append(i[sel])
            uv.append(u[sel])
        width = 2 if kind == "point" else 4
        if not kf:
            return np.zeros(0, int), np.zeros(0, int), np.zeros((0, width))
        return np.concatenate(kf), np.concatenate(lm), np.concatenate(uv).reshape(-1, width)

    def segments_world(self, ids: np.ndarray, *, camera: PinholeCamera, poses: Poses) -> np.ndarray:
        """World segments (L, 2, 3) of lines `ids`: the points of each line nearest the rays
        of its anchor endpoints; `poses`: the keyframes' estimated poses."""
        if len(ids) == 0:
            return np.zeros((0, 2, 3))
        a = self.l_anchor[ids]
        R_a, t_a = poses.R_world_camera[a], poses.t_world_camera[a]
        ends = []
        for j in (0, 2):
            x = camera.normalize(self.l_anchor_uv[ids, j : j + 2])
            w = np.einsum("mij,mj->mi", R_a, x)
            P, _, _ = factors.line_point_nearest_ray(self.l_m[ids], self.l_v[ids], t_a, w)
            ends.append(P)
        return np.stack(ends, axis=1)

    def plane_support(self, q: int, *, camera: PinholeCamera, poses: Poses) -> np.ndarray:
        """World points (K, 3) of plane q's landmarks: its points and its segments' endpoints."""
        pts = [self.p_world[(self.p_plane == q) & self.p_ok]]
        lines = np.flatnonzero((self.l_plane == q) & self.l_ok)
        if len(lines):
            pts.append(self.segments_world(lines, camera=camera, poses=poses).reshape(-1, 3))
        return np.concatenate(pts)

    def hull(self, q: int, planes: coplanar.PlaneSet, *, camera: PinholeCamera, poses: Poses) -> np.ndarray:
        """Plane q's hull (H, 3, world): its support projected onto it (coplanar.plane_hull)."""
        return coplanar.plane_hull(planes.n[q], planes.d[q], self.plane_support(q, camera=camera, poses=poses))


def keep_anchor_views(obs: FrameObs, landmarks: SimLandmarks, keyframe: int) -> FrameObs:
    """Keyframe `keyframe`'s observations reduced to the views that anchor a landmark."""
    sp = landmarks.p_anchor[obs.point_id] == keyframe
    sl = landmarks.l_anchor[obs.line_id] == keyframe
    return FrameObs(obs.point_id[sp], obs.point_uv[sp], obs.point_label[sp], obs.line_id[sl], obs.line_uv[sl], obs.line_label[sl])
