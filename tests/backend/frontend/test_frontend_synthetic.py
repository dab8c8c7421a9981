"""Front end on rendered room frames with exact ground truth (depth, poses)."""

from __future__ import annotations

import functools

import numpy as np
import pytest

from backend.data.scenes import builtin_scene
from backend.data.synthetic import SequenceSettings, SyntheticSequence
from backend.frontend.lines import (
    LineSettings,
    StereoSegments,
    match_segments_temporal,
    stereo_segments,
)
from backend.frontend.points import StereoPoints, best_matches, stereo_points

FRAMES = (0, 20)


@functools.cache
def _sequence() -> SyntheticSequence:
    return SyntheticSequence(builtin_scene("room"), settings=SequenceSettings(duration_s=2.0))


@functools.cache
def _points(k: int) -> StereoPoints:
    seq = _sequence()
    left, right = seq.views(k)
    return stereo_points(left.image, right.image, camera=seq.camera)


@functools.cache
def _segments(k: int) -> StereoSegments:
    seq = _sequence()
    left, right = seq.views(k)
    return stereo_segments(left.image, right.image, camera=seq.camera)


def _depth_at(depth: np.ndarray, uv: np.ndarray) -> np.ndarray:
    h, w = depth.shape
    u = np.clip(np.rint(uv[:, 0]).astype(int), 0, w - 1)
    v = np.clip(np.rint(uv[:, 1]).astype(int), 0, h - 1)
    return depth[v, u]


def _distance_to_line(p: np.ndarray, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Distances (N,) of points p (N, D) to the infinite lines through a, b (N, D)."""
    d = (b - a) / np.linalg.norm(b - a, axis=-1, keepdims=True)
    w = p - a
    return np.linalg.norm(w - np.sum(w * d, axis=-1, keepdims=True) * d, axis=-1)


@pytest.mark.parametrize("k", FRAMES)
def test_stereo_points_depth_matches_ground_truth(k: int) -> None:
    points = _points(k)
    left, _ = _sequence().views(k)
    m = points.matched
    assert m.sum() >= 200
    assert points.descriptors.dtype == np.uint8 and points.descriptors.shape == (len(points), 32)
    assert np.all(np.isnan(points.u_right[~m])) and np.all(np.isnan(points.p_cam[~m]))
    z_gt = _depth_at(left.depth, points.uv_left[m])
    rel = np.abs(points.p_cam[m, 2] - z_gt) / z_gt
    assert np.median(rel) < 0.02
    assert np.mean(rel < 0.05) >= 0.90
    # The 3D point reprojects onto its left pixel and its right column.
    camera = _sequence().camera
    np.testing.assert_allclose(camera.project(points.p_cam[m]), points.uv_left[m], atol=1e-6)
    np.testing.assert_allclose(camera.project(points.p_cam[m] - camera.offset_right)[:, 0], points.u_right[m], atol=1e-6)


@pytest.mark.parametrize("k", FRAMES)
def test_stereo_points_are_spread_over_the_image(k: int) -> None:
    points = _points(k)
    camera = _sequence().camera
    uv = points.uv_left[points.matched]
    cell = (uv[:, 1] * 4 // camera.height).astype(int) * 4 + (uv[:, 0] * 4 // camera.width).astype(int)
    counts = np.bincount(cell, minlength=16)
    assert np.sum(counts >= 5) >= 14, counts


@pytest.mark.parametrize("k", FRAMES)
def test_stereo_segments_depth_matches_ground_truth(k: int) -> None:
    segments = _segments(k)
    left, _ = _sequence().views(k)
    m = segments.matched
    assert m.sum() >= 20
    rel = []
    for uv, p in ((segments.left.start[m], segments.p_start_cam[m]), (segments.left.end[m], segments.p_end_cam[m])):
        z_gt = _depth_at(left.depth, uv)
        rel.append(np.abs(p[:, 2] - z_gt) / z_gt)
        np.testing.assert_allclose(_sequence().camera.project(p), uv, atol=1e-6)
    assert np.median(np.concatenate(rel)) < 0.05
    # Stereo pairs are one-to-one and never near horizontal.
    j = segments.right_index[m]
    assert np.unique(j).size == j.size
    assert np.all(np.abs(segments.left.direction[m, 1]) >= np.sin(np.radians(LineSettings().min_angle_deg)) - 1e-9)


@pytest.mark.parametrize("k", FRAMES)
def test_temporal_segment_matches_are_correct(k: int) -> None:
    """A match is correct when the previous segment's endpoints, back-projected with the
    ground-truth depth (nearest surface in a 5×5 neighbourhood: endpoints lie on depth
    edges) and moved with the ground-truth poses, land within 3 px of the matched segment's
    line in the next image."""
    seq = _sequence()
    camera = seq.camera
    previous, current = _segments(k).left, _segments(k + 1).left
    matches = match_segments_temporal(previous, current)
    assert len(matches) >= 30
    left, _ = seq.views(k)
    T_next_prev = np.linalg.inv(seq.T_world_rect0[k + 1]) @ seq.T_world_rect0[k]
    offsets = np.array([(du, dv) for du in (-2, 0, 2) for dv in (-2, 0, 2)], float)
    errors = np.full((len(matches), 2), np.inf)
    for e, uv in enumerate((previous.start[matches[:, 0]], previous.end[matches[:, 0]])):
        for offset in offsets:
            z = _depth_at(left.depth, uv + offset)
            p_prev = camera.normalize(uv) * z[:, None]
            p_next = p_prev @ T_next_prev[:3, :3].T + T_next_prev[:3, 3]
            with np.errstate(invalid="ignore"):
                d = _distance_to_line(camera.project(p_next), current.start[matches[:, 1]], current.end[matches[:, 1]])
            errors[:, e] = np.minimum(errors[:, e], np.where(np.isfinite(d), d, np.inf))
    precision = np.mean(errors.max(axis=1) < 3.0)
    assert precision >= 0.90, precision
    assert np.unique(matches[:, 0]).size == len(matches) and np.unique(matches[:, 1]).size == len(matches)


def test_best_matches_ratio_and_one_to_one() -> None:
    rows = np.array([0, 0, 1, 1, 2])
    cols = np.array([0, 1, 0, 2, 0])
    dist = np.array([10, 40, 12, 50, 30])
    # Row 0 and row 1 both want column 0: row 0 is closer. Row 2 alone wants column 0 too.
    np.testing.assert_array_equal(best_matches(rows, cols, dist, n_rows=4, max_distance=35, ratio=0.8), [0, -1, -1, -1])
    # Ratio test: row 0's best (10) vs second (11) fails at 0.8.
    np.testing.assert_array_equal(best_matches(np.array([0, 0]), np.array([0, 1]), np.array([10, 11]), n_rows=1, max_distance=50, ratio=0.8), [-1])


def test_empty_images_give_no_features() -> None:
    camera = _sequence().camera
    black = np.zeros((camera.height, camera.width), np.uint8)
    points = stereo_points(black, black, camera=camera)
    segments = stereo_segments(black, black, camera=camera)
    assert len(points) == 0 and len(segments.left) == 0
    assert match_segments_temporal(segments.left, segments.left).shape == (0, 2)
