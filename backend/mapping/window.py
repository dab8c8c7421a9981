"""The sliding window between the map and the optimizer: which keyframes, landmarks and
planes a solve takes (:func:`assemble_window`, as `backend.optim.problem.ProblemData`), and
how its solution goes back into the map (:func:`write_back`). Every image engine (stereo and
VIO) solves its window through these two.

The window is the keyframes [w0, k]; observations from `oldest` <= w0 on enter the problem
(keyframes before w0 are held fixed); a landmark anchored before `oldest` enters with its
stored anchor view. Stereo observations are a second camera `baseline` to the right.
Points are parametrized by inverse depth in their anchor keyframe, lines by the orthonormal
representation; planes with at least `min_plane_support` landmarks in the window are
optimized (or those `extra_planes` names, e.g. a marginalization prior's).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable

import numpy as np

from backend.geometry import line as line_geo
from backend.geometry.se3 import Poses
from backend.mapping.map import Map
from backend.optim.problem import Observations, Problem, ProblemData, State
from backend.optim.variant import Variant


@dataclasses.dataclass
class Window:
    """One window's problem data and the map ids of its rows: keyframes `kf`, `points`,
    `lines` and `planes` (the problem's local indices are positions in these arrays)."""

    keyframe: int
    data: ProblemData
    kf: np.ndarray
    points: np.ndarray
    lines: np.ndarray
    planes: np.ndarray


@dataclasses.dataclass(frozen=True)
class WindowSettings:
    """`min_depth_m`: the least anchor depth a point's inverse depth starts from;
    `pixel_sigma`: the observations' standard deviation (px); `min_plane_support`: the
    landmarks a plane needs in the window to be optimized."""

    min_depth_m: float
    pixel_sigma: float
    min_plane_support: int


def assemble_window(
    the_map: Map,
    k: int,
    *,
    w0: int,
    oldest: int,
    settings: WindowSettings,
    fix_first: bool,
    keep_landmarks: Callable[[np.ndarray, np.ndarray], tuple[np.ndarray, np.ndarray]] | None = None,
    extra_planes: np.ndarray | None = None,
    pinned: np.ndarray | None = None,
) -> Window:
    """The window of keyframes [w0, k] (module docstring). `keep_landmarks`: masks over the
    landmarks the window's keyframes observe (points, lines) -> those the problem keeps (None:
    all). `fix_first`: hold the first pose as the gauge when no older keyframe is held.
    `pinned`: keyframes whose pose is held wherever they are in the window (the stereo
    engine's keyframes placed by optical flow: no observation ties them to the keyframes
    before them, so the solve would move them with their own few landmarks)."""
    cam = the_map.camera
    P, Lm = the_map.points, the_map.lines
    win = [the_map.observations[j] for j in range(w0, k + 1)]
    pts = np.unique(np.concatenate([o.point_id for o in win]))
    pts = pts[P.ok[pts]]
    lns = np.unique(np.concatenate([o.line_id for o in win]))
    lns = lns[Lm.ok[lns]]
    if keep_landmarks is not None:
        pts, lns = keep_landmarks(pts, lns)
    p_local = np.full(len(P), -1)
    p_local[pts] = np.arange(len(pts))
    l_local = np.full(len(Lm), -1)
    l_local[lns] = np.arange(len(lns))

    # Observations from [oldest, k]; anchors older than that enter from the stored anchor view.
    rows_p, rows_l = [], []
    for j in range(oldest, k + 1):
        o = the_map.observations[j]
        sp = p_local[o.point_id] >= 0
        rows_p.append((np.full(int(sp.sum()), j), o.point_id[sp], o.point_uv[sp], o.point_ur[sp]))
        sl = l_local[o.line_id] >= 0
        rows_l.append((np.full(int(sl.sum()), j), o.line_id[sl], o.line_uv[sl], o.line_ruv[sl]))
    old_p = pts[P.anchor[pts] < oldest]
    rows_p.append((P.anchor[old_p], old_p, P.anchor_uv[old_p], P.anchor_ur[old_p]))
    old_l = lns[Lm.anchor[lns] < oldest]
    rows_l.append((Lm.anchor[old_l], old_l, Lm.anchor_uv[old_l], Lm.anchor_ruv[old_l]))
    kf_p, id_p, uv_p, ur_p = (np.concatenate(c) for c in zip(*rows_p))
    kf_l, id_l, uv_l, ruv_l = (np.concatenate(c) for c in zip(*rows_l))
    uv_p, uv_l, ruv_l = uv_p.reshape(-1, 2), uv_l.reshape(-1, 4), ruv_l.reshape(-1, 4)

    kfs = np.unique(np.concatenate([kf_p, kf_l, np.arange(w0, k + 1)]))
    local = np.searchsorted
    fixed = kfs < w0
    if pinned is not None and len(pinned):
        fixed |= np.isin(kfs, pinned)
    if not np.any(kfs < w0) and fix_first:
        fixed[0] = True  # the gauge: the segment's first keyframe
    # Stereo: each right-image observation is a second camera `baseline` to the right.
    offset = cam.offset_right
    has_r = np.isfinite(ur_p)
    p_obs = Observations(
        np.concatenate([p_local[id_p], p_local[id_p[has_r]]]),
        local(kfs, np.concatenate([kf_p, kf_p[has_r]])),
        np.concatenate([uv_p, np.stack([ur_p[has_r], uv_p[has_r, 1]], axis=1)]),
        np.concatenate([np.zeros((len(id_p), 3)), np.tile(offset, (int(has_r.sum()), 1))]),
    )
    has_rl = np.all(np.isfinite(ruv_l), axis=1)
    l_obs = Observations(
        np.concatenate([l_local[id_l], l_local[id_l[has_rl]]]),
        local(kfs, np.concatenate([kf_l, kf_l[has_rl]])),
        np.concatenate([uv_l, ruv_l[has_rl]]),
        np.concatenate([np.zeros((len(id_l), 3)), np.tile(offset, (int(has_rl.sum()), 1))]),
    )

    owner = np.concatenate([P.plane[pts], Lm.plane[lns]])
    support = np.bincount(owner[owner >= 0], minlength=len(the_map.planes))
    planes = np.flatnonzero(support >= settings.min_plane_support)
    if extra_planes is not None and len(extra_planes):
        planes = np.union1d(planes, extra_planes)
    q_local = np.full(len(the_map.planes) + 1, -1)
    q_local[planes] = np.arange(len(planes))

    R, t = the_map.R_world_keyframe[kfs].copy(), the_map.t_world_keyframe[kfs].copy()
    a_p = local(kfs, P.anchor[pts])
    p_a = np.einsum("nji,nj->ni", R[a_p], P.p_world[pts] - t[a_p])
    rho = 1.0 / np.clip(p_a[:, 2], settings.min_depth_m, None)
    U, phi = line_geo.to_orthonormal(Lm.m[lns], Lm.v[lns]) if len(lns) else (np.zeros((0, 3, 3)), np.zeros((0, 2)))
    N, D = the_map.planes.arrays()
    data = ProblemData(
        camera=cam,
        poses=Poses(R, t),
        point_anchor=a_p,
        point_anchor_uv=P.anchor_uv[pts],
        point_rho=rho,
        point_plane=q_local[P.plane[pts]],
        point_obs=p_obs,
        line_anchor=local(kfs, Lm.anchor[lns]),
        line_anchor_uv=Lm.anchor_uv[lns],
        line_U=U,
        line_phi=phi,
        line_plane=q_local[Lm.plane[lns]],
        line_obs=l_obs,
        plane_n=N[planes],
        plane_d=D[planes],
        odometry=None,
        prior=None,
        sigma_px=settings.pixel_sigma,
        fixed_poses=fixed,
    )
    return Window(k, data, kfs, pts, lns, planes)


def write_back(the_map: Map, window: Window, problem: Problem, state: State, variant: Variant) -> None:
    """Put a solve's free poses, the landmarks (lines only when the variant optimizes them)
    and the optimized planes into the map; the planes the window did not optimize follow
    their landmarks."""
    assert window.data.fixed_poses is not None  # assemble_window always sets it
    free = ~window.data.fixed_poses
    kf_free = window.kf[free]
    the_map.R_world_keyframe[kf_free] = state.poses.R_world_camera[free]
    the_map.t_world_keyframe[kf_free] = state.poses.t_world_camera[free]
    P, Lm = the_map.points, the_map.lines
    if len(window.points):
        p = problem.point_positions(state)
        good = np.all(np.isfinite(p), axis=1)
        P.p_world[window.points[good]] = p[good]
    if len(window.lines) and variant.with_lines:
        m, v = problem.line_pluecker(state)
        norm = np.linalg.norm(v, axis=1, keepdims=True)
        good = np.all(np.isfinite(m), axis=1) & (norm[:, 0] > 1e-12)
        Lm.m[window.lines[good]], Lm.v[window.lines[good]] = m[good] / norm[good], v[good] / norm[good]
    used = problem.layout.plane_col >= 0
    for j, q in enumerate(window.planes):
        if used[j]:
            the_map.planes.n[q], the_map.planes.d[q] = state.plane_n[j].copy(), float(state.plane_d[j])
    the_map.refit_unused_planes({int(q) for q, u in zip(window.planes, used) if u})
