"""Steps 4 of a keyframe: plane-instance segmentation and the co-planar detection (paper
§III-A) on the keyframe's features, which assigns landmarks to planes in the map."""

from __future__ import annotations

import dataclasses

import numpy as np

from backend.frontend.segmentation import PlaneMasks, PlaneSegmenter
from backend.geometry.camera import PinholeCamera
from backend.mapping import coplanar
from backend.mapping.map import KeyframeObservations, Map
from backend.pipeline.snapshot import Detection


@dataclasses.dataclass(frozen=True)
class FeatureStates:
    """The keyframe's usable landmarks and their state in the last detection (the
    snapshot's RANSAC in/outliers): point ids and states, line ids and states."""

    point_ids: np.ndarray
    point_state: np.ndarray
    line_ids: np.ndarray
    line_state: np.ndarray

    @staticmethod
    def undetected(the_map: Map, obs: KeyframeObservations) -> FeatureStates:
        """The keyframe's usable landmarks before (or without) a detection: state 0."""
        p_ids = obs.point_id[the_map.points.ok[obs.point_id]]
        l_ids = obs.line_id[the_map.lines.ok[obs.line_id]]
        return FeatureStates(p_ids, np.zeros(len(p_ids), np.uint8), l_ids, np.zeros(len(l_ids), np.uint8))

    def as_tuple(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        return self.point_ids, self.point_state, self.line_ids, self.line_state


@dataclasses.dataclass(frozen=True)
class PlaneResult:
    """The detection, the features' states, and per segmentation instance the plane it
    merged into or created (-1: none)."""

    detection: Detection
    features: FeatureStates
    instance_plane: np.ndarray


def segment_keyframe(segmenter: PlaneSegmenter, frame: int, left: np.ndarray, right: np.ndarray, camera: PinholeCamera) -> PlaneMasks:
    """Plane instances of frame `frame`: from the segmenter's images, or by frame for the
    oracle of rendered scenes (`segment_frame`)."""
    by_frame = getattr(segmenter, "segment_frame", None)
    if by_frame is not None:
        return by_frame(frame)
    return segmenter.segment(left, right, camera)


def detect_planes(
    the_map: Map,
    obs: KeyframeObservations,
    masks: PlaneMasks,
    new_points: np.ndarray,
    new_lines: np.ndarray,
    rng: np.random.Generator,
    *,
    settings: coplanar.CoplanarSettings,
) -> PlaneResult:
    """Co-planar detection on the keyframe (paper §III-A), features labelled by the
    instance masks: a point by its pixel, a segment when both endpoints (pulled 3 px
    inward) fall in the same instance. New landmarks the detection did not place are tested
    against the existing planes."""
    labels = masks.labels
    P, Lm = the_map.points, the_map.lines
    p_sel = P.ok[obs.point_id]
    l_sel = Lm.ok[obs.line_id]
    p_ids, l_ids = obs.point_id[p_sel], obs.line_id[l_sel]
    p_lab = labels_at(labels, obs.point_uv[p_sel])
    seg = obs.line_uv[l_sel]
    direction = seg[:, 2:] - seg[:, :2]
    direction /= np.maximum(np.linalg.norm(direction, axis=1, keepdims=True), 1e-9)
    lab_s = labels_at(labels, seg[:, :2] + 3.0 * direction)
    lab_e = labels_at(labels, seg[:, 2:] - 3.0 * direction)
    l_lab = np.where(lab_s == lab_e, lab_s, -1)
    det = coplanar.detect_keyframe_planes(
        point_ids=p_ids,
        point_label=p_lab,
        p_world=P.p_world[p_ids],
        line_ids=l_ids,
        line_label=l_lab,
        segments_world=the_map.segments_world(l_ids),
        point_plane=P.plane[:],
        line_plane=Lm.plane[:],
        planes=the_map.planes,
        rng=rng,
        settings=settings,
    )
    pts = new_points[P.plane[new_points] < 0]
    lns = new_lines[Lm.plane[new_lines] < 0]
    if len(the_map.planes) and (len(pts) or len(lns)):
        N, D = the_map.planes.arrays()
        q_p, q_l = coplanar.associate_to_planes(P.p_world[pts], the_map.segments_world(lns), N, D, the_map.hulls(), threshold_m=settings.threshold_m)
        P.plane[pts[q_p >= 0]] = q_p[q_p >= 0]
        Lm.plane[lns[q_l >= 0]] = q_l[q_l >= 0]
    instance_plane = np.full(masks.count, -1, np.int64)
    for q, plane, accepted in zip(det.instance, det.plane, det.accepted):
        if accepted and 0 <= q < masks.count:
            instance_plane[q] = plane
    return PlaneResult(
        Detection(det.instance, det.candidates, det.inliers, det.accepted, det.plane),
        FeatureStates(p_ids, det.point_state, l_ids, det.line_state),
        instance_plane,
    )


def labels_at(labels: np.ndarray, uv: np.ndarray) -> np.ndarray:
    """Instance label (-1: none) at pixels (M, 2), -1 outside the image."""
    h, w = labels.shape
    u = np.rint(uv[:, 0]).astype(np.int64)
    v = np.rint(uv[:, 1]).astype(np.int64)
    inside = (u >= 0) & (u < w) & (v >= 0) & (v < h)
    out = np.full(len(uv), -1, np.int64)
    out[inside] = labels[v[inside], u[inside]]
    return out
