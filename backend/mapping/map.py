"""The map of one run: keyframes with their estimated and true poses, the frames tracked
against them, the landmarks (points and lines), the planes and what each keyframe observed.

One object owns all of it, so that an engine's pipeline stages read and write the same map
and a checkpoint is an explicit copy (:meth:`Map.copy`). Frames and units: world frame z up,
metres; `T_world_keyframe` is the rectified left camera's pose at a keyframe; pixels of
`camera`; landmark and keyframe ids are row indices that never change (a removed landmark
keeps its row with `ok` False).

Landmarks:

- points: `p_world` (3,), their anchor keyframe and its left pixel `anchor_uv` and right
  column `anchor_ur` (NaN: none), ORB descriptor `desc`, plane id `plane` (-1: none), how
  many keyframes re-observed them (`n_kf`) and the keyframe from which re-observations are
  counted (`born`);
- lines: Plücker `m`, `v` (unit `v`), anchor segment (`anchor_uv`: start and end pixels;
  `anchor_ruv`: the right image's, NaN: none), LBD descriptor and the same bookkeeping.
"""

from __future__ import annotations

import copy
import dataclasses

import numpy as np

from backend.common.buffers import RowBuffer
from backend.geometry import so3
from backend.geometry.camera import PinholeCamera
from backend.mapping import coplanar
from backend.optim import factors


class LandmarkStore:
    """Landmark attributes as growable columns (RowBuffers), indexed by landmark id."""

    def __init__(self, columns: dict[str, tuple[tuple[int, ...], type]]) -> None:
        self._cols = {name: RowBuffer(shape, dtype=dtype) for name, (shape, dtype) in columns.items()}

    def __len__(self) -> int:
        return len(next(iter(self._cols.values())))

    def __getattr__(self, name: str) -> RowBuffer:
        try:
            return self.__dict__["_cols"][name]
        except KeyError:
            raise AttributeError(name) from None

    def add(self, **values: np.ndarray) -> np.ndarray:
        """Append rows (one per entry of each column's values); returns their ids. `born`
        (the keyframe from which re-observations are counted) defaults to the anchor."""
        if "born" in self._cols and "born" not in values:
            values["born"] = values["anchor"]
        count = len(next(iter(values.values())))
        start = len(self)
        for name, col in self._cols.items():
            for row in values[name]:
                col.append(row)
        return np.arange(start, start + count)

    def reobserve(self, local: np.ndarray, match: np.ndarray, descriptors: np.ndarray, *, n_features: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """A keyframe's re-observations of landmarks: `local` (M,) their ids, `match` (M,)
        each one's feature in the keyframe (-1: none). The newest view's `descriptors` (one
        row per feature) describe them best, and each counts one more keyframe (`n_kf`).
        Returns the re-observed ids, their feature indices, and which of the keyframe's
        `n_features` features they claim (bool)."""
        m = np.flatnonzero(match >= 0)
        j = match[m]
        ids = local[m]
        self.desc[ids] = descriptors[j]
        self.n_kf[ids] = self.n_kf[ids] + 1
        claimed = np.zeros(n_features, bool)
        claimed[j] = True
        return ids, j, claimed


def point_store() -> LandmarkStore:
    return LandmarkStore(
        {
            "p_world": ((3,), float),
            "ok": ((), bool),
            "anchor": ((), np.int64),
            "anchor_uv": ((2,), float),
            "anchor_ur": ((), float),
            "plane": ((), np.int64),
            "desc": ((32,), np.uint8),
            "n_kf": ((), np.int64),
            "born": ((), np.int64),
        }
    )


def line_store() -> LandmarkStore:
    return LandmarkStore(
        {
            "m": ((3,), float),
            "v": ((3,), float),
            "ok": ((), bool),
            "anchor": ((), np.int64),
            "anchor_uv": ((4,), float),
            "anchor_ruv": ((4,), float),
            "plane": ((), np.int64),
            "desc": ((32,), np.uint8),
            "n_kf": ((), np.int64),
            "born": ((), np.int64),
        }
    )


@dataclasses.dataclass(frozen=True)
class KeyframeObservations:
    """What one keyframe observed: landmark ids, left pixels and right columns (NaN: no
    stereo match) of points; left segments (start, end) and right segments (NaN: none).
    A value: its arrays are made read-only, and a change (culling) stores a new one, so
    that copies of the map share the observations instead of copying them."""

    point_id: np.ndarray
    point_uv: np.ndarray
    point_ur: np.ndarray
    line_id: np.ndarray
    line_uv: np.ndarray
    line_ruv: np.ndarray

    def __post_init__(self) -> None:
        for field in dataclasses.fields(self):
            getattr(self, field.name).setflags(write=False)


class Map:
    """Keyframes, tracked frames, landmarks, planes and observations (module docstring)."""

    # What copy() copies; everything else an instance holds is shared (the camera) or, for
    # VALUE_DICTS, a new dict of the same immutable values. A new attribute must be added to
    # one of the three (tests/backend/mapping/test_map.py).
    COPIED = (
        "R_world_keyframe",
        "t_world_keyframe",
        "R_world_keyframe_true",
        "t_world_keyframe_true",
        "keyframe_stamp_ns",
        "keyframe_frame",
        "frame_index",
        "frame_reference",
        "R_reference_frame",
        "t_reference_frame",
        "points",
        "lines",
        "planes",
        "segment_start",
    )
    SHARED = ("camera",)
    # Dicts of immutable values (KeyframeObservations): copy() makes a new dict of the same values.
    VALUE_DICTS = ("observations",)

    def __init__(self, camera: PinholeCamera) -> None:
        self.camera = camera
        # Keyframes: estimated pose, true pose (NaN: unknown), timestamp and frame index.
        self.R_world_keyframe = RowBuffer((3, 3))
        self.t_world_keyframe = RowBuffer((3,))
        self.R_world_keyframe_true = RowBuffer((3, 3))
        self.t_world_keyframe_true = RowBuffer((3,))
        self.keyframe_stamp_ns = RowBuffer((), dtype=np.int64)
        self.keyframe_frame = RowBuffer((), dtype=np.int64)
        # Every tracked frame: its index, reference keyframe and pose T_reference_frame.
        self.frame_index = RowBuffer((), dtype=np.int64)
        self.frame_reference = RowBuffer((), dtype=np.int64)
        self.R_reference_frame = RowBuffer((3, 3))
        self.t_reference_frame = RowBuffer((3,))
        self.observations: dict[int, KeyframeObservations] = {}
        self.points = point_store()
        self.lines = line_store()
        self.planes = coplanar.PlaneSet()
        self.segment_start = 0  # first keyframe of the current map segment (a re-initialization starts one)

    def __len__(self) -> int:
        """Keyframes so far."""
        return len(self.t_world_keyframe)

    def copy(self) -> Map:
        """An independent copy (the camera shared)."""
        new = Map.__new__(Map)
        for name in self.SHARED:
            setattr(new, name, getattr(self, name))
        for name in self.COPIED:
            setattr(new, name, copy.deepcopy(getattr(self, name)))
        for name in self.VALUE_DICTS:
            setattr(new, name, dict(getattr(self, name)))
        return new

    # ---------------------------------------------------------------- keyframes and frames

    def add_keyframe(self, frame: int, R_world_camera: np.ndarray, t_world_camera: np.ndarray, *, stamp_ns: int, T_world_true: np.ndarray | None) -> int:
        """A new keyframe from frame `frame` at the given pose (`T_world_true`: its true pose,
        None: unknown); it is its own reference frame. Returns its id."""
        self.R_world_keyframe.append(R_world_camera)
        self.t_world_keyframe.append(t_world_camera)
        if T_world_true is not None:
            self.R_world_keyframe_true.append(T_world_true[:3, :3])
            self.t_world_keyframe_true.append(T_world_true[:3, 3])
        else:
            self.R_world_keyframe_true.append(np.full((3, 3), np.nan))
            self.t_world_keyframe_true.append(np.full(3, np.nan))
        self.keyframe_stamp_ns.append(int(stamp_ns))
        self.keyframe_frame.append(frame)
        k = len(self) - 1
        self.record_frame(frame, k, R_world_camera, t_world_camera)  # its own reference: identity
        return k

    def record_frame(self, frame: int, reference: int, R_world_camera: np.ndarray, t_world_camera: np.ndarray) -> None:
        """Frame `frame` tracked at the given world pose: kept as T_reference_frame against
        keyframe `reference`, so that it follows that keyframe's later optimization."""
        R_ref, t_ref = self.R_world_keyframe[reference], self.t_world_keyframe[reference]
        self.frame_index.append(frame)
        self.frame_reference.append(reference)
        self.R_reference_frame.append(R_ref.T @ R_world_camera)
        self.t_reference_frame.append(R_ref.T @ (t_world_camera - t_ref))

    def scale_frame_offsets(self, *, first_keyframe: int, scale: float) -> None:
        """The tracked frames whose reference keyframe is `first_keyframe` or later: their
        offsets from it times `scale` (the map from there on scaled: VIO's start and its
        refinement), so that they stay where the scaled map puts them."""
        moved = np.flatnonzero(self.frame_reference[:] >= first_keyframe)
        if len(moved):
            self.t_reference_frame[moved] = scale * self.t_reference_frame[moved]

    def frame_poses(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Every tracked frame: index, reference keyframe, and world pose (R, t) composed with
        the reference keyframe's latest estimate."""
        ref = self.frame_reference[:].copy()
        frame = self.frame_index[:].copy()
        R_kf, t_kf = self.R_world_keyframe[ref], self.t_world_keyframe[ref]
        R = so3.project_to_so3(R_kf @ self.R_reference_frame[:]) if len(ref) else np.zeros((0, 3, 3))
        t = np.einsum("nij,nj->ni", R_kf, self.t_reference_frame[:]) + t_kf
        return frame, ref, R, t

    # ---------------------------------------------------------------- landmarks and planes

    def segments_world(self, ids: np.ndarray) -> np.ndarray:
        """World segments (L, 2, 3) of lines `ids`: the points of each line nearest its anchor
        endpoints' rays."""
        if len(ids) == 0:
            return np.zeros((0, 2, 3))
        L = self.lines
        a = L.anchor[ids]
        R_a, t_a = self.R_world_keyframe[a], self.t_world_keyframe[a]
        m, v = L.m[ids], L.v[ids]
        ends = []
        for j in (0, 2):
            x = self.camera.normalize(L.anchor_uv[ids][:, j : j + 2])
            w = np.einsum("mij,mj->mi", R_a, x)
            P, _, _ = factors.line_point_nearest_ray(m, v, t_a, w)
            ends.append(P)
        return np.stack(ends, axis=1)

    def plane_support(self, q: int) -> np.ndarray:
        """World points (K, 3) of plane q's landmarks: its points and its segments' endpoints."""
        P, L = self.points, self.lines
        pts = [P.p_world[(P.plane[:] == q) & P.ok[:]]]
        lines = np.flatnonzero((L.plane[:] == q) & L.ok[:])
        if len(lines):
            pts.append(self.segments_world(lines).reshape(-1, 3))
        return np.concatenate(pts)

    def plane_supports(self) -> list[np.ndarray]:
        """:meth:`plane_support` of every plane (world points, metres), in one pass over the
        landmarks: each plane's points, then its segments' endpoints, in landmark order."""
        P, L = self.points, self.lines
        Q = len(self.planes)
        p_ids = np.flatnonzero(P.ok[:] & (P.plane[:] >= 0))
        l_ids = np.flatnonzero(L.ok[:] & (L.plane[:] >= 0))
        p_by_plane = _split_by(P.plane[p_ids], Q)
        l_by_plane = _split_by(L.plane[l_ids], Q)
        p_world = P.p_world[p_ids]
        ends = self.segments_world(l_ids).reshape(-1, 2, 3)
        supports = []
        for q in range(Q):
            pts = [p_world[p_by_plane[q]]]
            if len(l_by_plane[q]):
                pts.append(ends[l_by_plane[q]].reshape(-1, 3))
            supports.append(np.concatenate(pts))
        return supports

    def hull(self, q: int) -> np.ndarray:
        """Plane q's convex hull of its landmarks' support (world points, metres)."""
        return coplanar.plane_hull(self.planes.n[q], self.planes.d[q], self.plane_support(q))

    def hulls(self) -> list[np.ndarray]:
        """:meth:`hull` of every plane, from one pass over the landmarks."""
        return [coplanar.plane_hull(self.planes.n[q], self.planes.d[q], support) for q, support in enumerate(self.plane_supports())]

    def refit_unused_planes(self, optimized: set[int]) -> None:
        """Planes the window did not optimize follow their landmarks (least squares)."""
        if all(q in optimized for q in range(len(self.planes))):
            return
        for q, support in enumerate(self.plane_supports()):
            fit = None if q in optimized else coplanar.refit_plane(self.planes.n[q], support)
            if fit is not None:
                self.planes.n[q], self.planes.d[q] = fit


def _split_by(label: np.ndarray, count: int) -> list[np.ndarray]:
    """Positions in `label` of each value 0..count-1, each in increasing order."""
    order = np.argsort(label, kind="stable")
    bounds = np.searchsorted(label[order], np.arange(count + 1))
    return [order[bounds[q] : bounds[q + 1]] for q in range(count)]
