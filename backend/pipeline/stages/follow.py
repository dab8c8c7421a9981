"""Features followed frame to frame by optical flow (VIO, before the visual-inertial
initialization, as VINS-Mono's front end): the map points seen in the last frame and
candidate features of the recent keyframes, followed by pyramidal Lucas-Kanade flow
(`backend.frontend.flow`); a followed pixel becomes a keypoint of the frame (the ORB keypoint
within 2 px, or a new one with its descriptor computed there). A frame is tracked by
EPnP-RANSAC on the followed map points, refined with them and the projection search's matches
for the others; a candidate becomes a point once it has parallax against the keyframe that
detected it.

World frame z up, metres; pixels of the rectified left camera."""

from __future__ import annotations

import dataclasses

import cv2
import numpy as np
from scipy.spatial import cKDTree

from backend.frontend.flow import FlowTracks, follow
from backend.frontend.points import Keypoints, best_matches
from backend.geometry.camera import PinholeCamera
from backend.mapping.map import Map
from backend.pipeline.stages.mono import MonoSettings, add_two_view_points, triangulate_pixels
from backend.pipeline.stages.track import Tracked, TrackSettings, refine
from backend.pipeline.tracking import merge_matches, pnp_ransac


def _pairs_within(uv_a: np.ndarray, uv_b: np.ndarray, radius_px: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Every pair (i, j) with `|uv_a[i] - uv_b[j]| <= radius_px` (pixels), in row-major
    order, and its distance: the pairs and values of the dense distance matrix's
    `np.nonzero(d <= radius_px)`, found by a k-d tree (candidates within a slightly larger
    radius, then the same test on the same distance expression)."""
    candidates = cKDTree(uv_b).query_ball_point(uv_a, r=radius_px * (1.0 + 1e-9) + 1e-12, return_sorted=True)
    counts = np.fromiter((len(c) for c in candidates), np.int64, len(candidates))
    rows = np.repeat(np.arange(len(uv_a)), counts)
    cols = np.fromiter((j for c in candidates for j in c), np.int64, int(counts.sum()))
    diff = uv_a[rows] - uv_b[cols]
    d = np.sqrt(np.add.reduce(diff * diff, axis=1))  # as np.linalg.norm(..., axis=-1) computes it
    keep = d <= radius_px
    return rows[keep], cols[keep], d[keep]


def with_followed_keypoints(kp: Keypoints, uv: np.ndarray, image: np.ndarray, *, radius_px: float = 2.0) -> tuple[Keypoints, np.ndarray]:
    """`kp` with a keypoint for each followed pixel `uv` (M, 2) that has no ORB keypoint
    within `radius_px` (its ORB descriptor computed there, at the finest level), and the
    keypoint index of each pixel (-1 where no descriptor could be computed: too near the
    border)."""
    index = np.full(len(uv), -1, np.int64)
    if len(kp.uv) and len(uv):
        rows, cols, d = _pairs_within(uv, kp.uv, radius_px)
        index = best_matches(rows, cols, d, n_rows=len(uv), max_distance=radius_px, ratio=1.01)
    missing = np.flatnonzero(index < 0)
    if len(missing) == 0:
        return kp, index
    orb = cv2.ORB_create(edgeThreshold=19, patchSize=31)  # type: ignore[attr-defined]  # not in OpenCV's stubs
    points = [cv2.KeyPoint(float(x), float(y), 31.0, -1.0, 0.0, 0, int(j)) for j, (x, y) in zip(missing, uv[missing])]
    points, desc = orb.compute(image, points)
    if desc is None or len(points) == 0:
        return kp, index
    which = np.array([p.class_id for p in points], np.int64)
    index[which] = len(kp.uv) + np.arange(len(points))
    grown = Keypoints(uv=np.concatenate([kp.uv, uv[which]]), descriptors=np.concatenate([kp.descriptors, desc]), octave=np.concatenate([kp.octave, np.zeros(len(points), kp.octave.dtype)]))
    return grown, index


def _no_ids() -> tuple[np.ndarray, np.ndarray]:
    return np.zeros(0, np.int64), np.zeros((0, 2))


@dataclasses.dataclass
class FeatureFollower:
    """What is followed (module docstring): `tracks`, the candidate features, and
    `map_points`, the map points seen in the last frame (ids, pixels), both followed from
    `image`; in the current frame, `track_kp` and `map_kp` are each one's keypoint (-1: none)."""

    tracks: FlowTracks = dataclasses.field(default_factory=FlowTracks.empty)
    image: np.ndarray | None = None
    track_kp: np.ndarray = dataclasses.field(default_factory=lambda: np.zeros(0, np.int64))
    map_points: tuple[np.ndarray, np.ndarray] = dataclasses.field(default_factory=_no_ids)
    map_kp: np.ndarray = dataclasses.field(default_factory=lambda: np.zeros(0, np.int64))

    def clear(self) -> None:
        """Nothing followed (a new map segment)."""
        self.tracks, self.image = FlowTracks.empty(), None
        self.map_points = _no_ids()

    def follow(self, image: np.ndarray, kp: Keypoints, camera: PinholeCamera, *, R_prev_cur: np.ndarray | None) -> Keypoints:
        """The map points and candidates followed into `image` (`R_prev_cur`: the camera's
        rotation since the last frame, from the gyroscope, or None); returns `kp` with a
        keypoint at each followed pixel, each one's index in `map_kp` and `track_kp`."""
        ids, uv_map = self.map_points
        self.map_kp = np.full(len(ids), -1, np.int64)
        self.track_kp = np.full(len(self.tracks), -1, np.int64)
        if self.image is not None and len(ids) + len(self.tracks):
            uv, ok = follow(self.image, image, np.concatenate([uv_map, self.tracks.uv]), camera, R_prev_cur=R_prev_cur)
            n = len(ids)
            self.map_points = (ids[ok[:n]], uv[:n][ok[:n]])
            self.tracks = self.tracks.followed(uv[n:], ok[n:])
            kp, self.map_kp = with_followed_keypoints(kp, self.map_points[1], image)
            kp, self.track_kp = with_followed_keypoints(kp, self.tracks.uv, image)
        self.image = image
        return kp

    def track(self, result: Tracked, camera: PinholeCamera, settings: TrackSettings, kp: Keypoints, *, the_map: Map, local_points: np.ndarray, min_inliers: int, seed: int) -> Tracked:
        """The frame's pose with the followed map points as matches too (the followed ones
        first, then those the projection search found for the others: `result`), by
        EPnP-RANSAC (`min_inliers`, `seed`) and refinement; `result` where that does worse."""
        ids, _ = self.map_points
        if len(ids) == 0 or len(self.map_kp) != len(ids):
            return result
        local = local_points
        match = np.full(len(local), -1, np.int64)
        _, at_local, at_flow = np.intersect1d(local, ids, assume_unique=True, return_indices=True)
        match[at_local] = self.map_kp[at_flow]
        P = the_map.points.p_world[local]
        m = np.flatnonzero(match >= 0)
        pose = pnp_ransac(camera, P[m], kp.uv[match[m]], min_inliers=min_inliers, seed=seed)
        if pose is None:
            return result
        match[m[~pose[2]]] = -1
        if result.ok and len(result.match) == len(local):
            match = merge_matches(match, result.match, n_keypoints=len(kp.uv))
        flowed = refine(camera, settings, pose[0], pose[1], P, the_map.points.desc[local], kp, match, min_inliers=min_inliers, keep_matches=True)
        return flowed if flowed.ok and flowed.inliers >= result.inliers else result

    def in_frame(self) -> bool:
        """Whether the candidates have their keypoints in the current frame."""
        return bool(len(self.track_kp)) and len(self.track_kp) == len(self.tracks)

    def triangulate(self, the_map: Map, k: int, kp: Keypoints, claimed: np.ndarray, kf_features: dict[int, tuple[Keypoints, np.ndarray]], *, settings: MonoSettings) -> tuple[np.ndarray, np.ndarray]:
        """New points of keyframe k from the candidates with parallax between the keyframe
        that detected them and k (`stages.mono.triangulate_pixels`); a candidate whose keypoint
        is already claimed in either keyframe is left (`claimed`, and each keyframe's in
        `kf_features`, which the new points claim). Returns the new ids and their keypoint
        indices in keyframe k."""
        tr, j1 = self.tracks, self.track_kp
        cand = np.flatnonzero((j1 >= 0) & (tr.anchor < k))
        cand = cand[~claimed[j1[cand]]]
        _, first = np.unique(j1[cand], return_index=True)  # one track per keypoint
        cand = cand[np.sort(first)]
        found_ids, found_kp = [np.zeros(0, np.int64)], [np.zeros(0, np.int64)]
        for k0 in np.unique(tr.anchor[cand]):
            c = cand[tr.anchor[cand] == k0]
            if k0 in kf_features:
                c = c[~kf_features[k0][1][tr.anchor_kp[c]]]
            p_w, good = triangulate_pixels(the_map, int(k0), k, tr.uv_anchor[c], kp.uv[j1[c]], settings=settings)
            c = c[good]
            if len(c) == 0:
                continue
            ids = add_two_view_points(the_map, k, int(k0), tr.uv_anchor[c], kp.descriptors[j1[c]], p_w[good])
            if k0 in kf_features:
                kf_features[k0][1][tr.anchor_kp[c]] = True
            found_ids.append(ids)
            found_kp.append(j1[c])
        return np.concatenate(found_ids), np.concatenate(found_kp)

    def seed(self, k: int, kp: Keypoints, image: np.ndarray, claimed: np.ndarray, *, max_age_keyframes: int, min_distance_px: float, max_tracks: int) -> None:
        """After keyframe k's landmarks (`claimed`: its keypoints that have one): the
        candidates that became or met a map point, or that are older than
        `max_age_keyframes`, are dropped; k's unclaimed keypoints start new ones (at least
        `min_distance_px` apart, at most `max_tracks`)."""
        tr, j1 = self.tracks, self.track_kp
        keep = (k - tr.anchor) <= max_age_keyframes
        if len(j1) == len(tr):
            keep &= ~((j1 >= 0) & claimed[np.maximum(j1, 0)])
        tr = tr.subset(keep)
        cand = np.flatnonzero(~claimed)
        self.tracks = tr.seeded(k, kp.uv[cand], cand, min_distance_px=min_distance_px, max_tracks=max_tracks)
        self.image = image
        self.track_kp = np.zeros(0, np.int64)
