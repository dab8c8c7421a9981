"""The map of a run (backend/mapping/map.py): what a copy holds, and the frame poses that
follow their keyframes."""

from __future__ import annotations

import numpy as np
import pytest

from backend.geometry import so3
from backend.geometry.camera import PinholeCamera
from backend.mapping.map import KeyframeObservations, Map

CAMERA = PinholeCamera(fx=400.0, fy=400.0, cx=320.0, cy=240.0, width=640, height=480, baseline=0.1)


def _map_with_two_keyframes() -> Map:
    m = Map(CAMERA)
    m.add_keyframe(0, np.eye(3), np.zeros(3), stamp_ns=0, T_world_true=np.eye(4))
    m.record_frame(1, 0, so3.exp(np.array([0.0, 0.0, 0.1])), np.array([0.1, 0.0, 0.0]))
    m.add_keyframe(2, np.eye(3), np.array([0.2, 0.0, 0.0]), stamp_ns=100, T_world_true=None)
    m.points.add(
        p_world=np.ones((2, 3)),
        ok=np.ones(2, bool),
        anchor=np.zeros(2, np.int64),
        anchor_uv=np.zeros((2, 2)),
        anchor_ur=np.zeros(2),
        plane=np.full(2, -1),
        desc=np.zeros((2, 32), np.uint8),
        n_kf=np.ones(2, np.int64),
    )
    return m


def test_every_attribute_is_either_copied_or_shared() -> None:
    """A new attribute of the map must say how a checkpoint treats it."""
    m = _map_with_two_keyframes()
    assert set(vars(m)) == set(Map.COPIED) | set(Map.SHARED) | set(Map.VALUE_DICTS)
    assert len(Map.COPIED) + len(Map.SHARED) + len(Map.VALUE_DICTS) == len(set(Map.COPIED) | set(Map.SHARED) | set(Map.VALUE_DICTS))


def test_a_copy_shares_the_observations_which_cannot_be_changed_in_place() -> None:
    """A checkpoint shares each keyframe's observations instead of copying them: they are
    read-only, and replacing one in a copy (as culling does) leaves the original alone."""
    m = _map_with_two_keyframes()
    m.observations[0] = KeyframeObservations(np.array([0, 1]), np.zeros((2, 2)), np.zeros(2), np.zeros(0, np.int64), np.zeros((0, 4)), np.zeros((0, 4)))
    c = m.copy()
    assert c.observations[0] is m.observations[0] and c.observations is not m.observations
    with pytest.raises(ValueError, match="read-only"):
        c.observations[0].point_id[0] = 5
    c.observations[0] = KeyframeObservations(np.array([1]), np.zeros((1, 2)), np.zeros(1), np.zeros(0, np.int64), np.zeros((0, 4)), np.zeros((0, 4)))
    assert m.observations[0].point_id.tolist() == [0, 1]


def test_a_copy_holds_the_rows_in_use_only_and_grows_again() -> None:
    m = _map_with_two_keyframes()
    c = m.copy()
    assert len(c.t_world_keyframe._data) == 2 < len(m.t_world_keyframe._data)
    np.testing.assert_array_equal(c.t_world_keyframe[:], m.t_world_keyframe[:])
    for _ in range(5):
        c.t_world_keyframe.append(np.ones(3))
    assert len(c.t_world_keyframe) == 7 and len(m.t_world_keyframe) == 2
    np.testing.assert_array_equal(c.t_world_keyframe[:2], m.t_world_keyframe[:])


def test_a_copy_is_independent() -> None:
    m = _map_with_two_keyframes()
    c = m.copy()
    assert c.camera is m.camera and len(c) == 2 and len(c.points) == 2
    c.points.p_world[0] = [5.0, 5.0, 5.0]
    c.t_world_keyframe[1] = [9.0, 9.0, 9.0]
    c.add_keyframe(3, np.eye(3), np.zeros(3), stamp_ns=200, T_world_true=None)
    np.testing.assert_array_equal(m.points.p_world[0], [1.0, 1.0, 1.0])
    np.testing.assert_array_equal(m.t_world_keyframe[1], [0.2, 0.0, 0.0])
    assert len(m) == 2 and len(c) == 3


def test_frames_follow_their_reference_keyframe() -> None:
    m = _map_with_two_keyframes()
    frame, ref, R, t = m.frame_poses()
    assert frame.tolist() == [0, 1, 2] and ref.tolist() == [0, 0, 1]
    np.testing.assert_allclose(t[1], [0.1, 0.0, 0.0])
    m.t_world_keyframe[0] = [1.0, 0.0, 0.0]  # the reference keyframe moved after a solve
    _, _, R2, t2 = m.frame_poses()
    np.testing.assert_allclose(t2[1], [1.1, 0.0, 0.0])
    np.testing.assert_allclose(R2[1], R[1])
    assert np.isnan(m.t_world_keyframe_true[1]).all() and m.keyframe_stamp_ns[1] == 100


def test_a_reobserved_landmark_takes_the_newest_descriptor_and_claims_its_feature() -> None:
    m = _map_with_two_keyframes()
    descriptors = np.arange(3 * 32, dtype=np.uint8).reshape(3, 32)  # three features in the new keyframe
    local = np.array([0, 1])
    match = np.array([-1, 2])  # point 0 unmatched, point 1 seen as feature 2
    ids, features, claimed = m.points.reobserve(local, match, descriptors, n_features=3)
    np.testing.assert_array_equal(ids, [1])
    np.testing.assert_array_equal(features, [2])
    np.testing.assert_array_equal(claimed, [False, False, True])
    np.testing.assert_array_equal(m.points.desc[1], descriptors[2])
    np.testing.assert_array_equal(m.points.desc[0], np.zeros(32, np.uint8))
    np.testing.assert_array_equal(m.points.n_kf[:], [1, 2])


def test_scaled_frame_offsets_follow_a_scaled_segment_only() -> None:
    """VIO's start scales the segment's map: the frames tracked against its keyframes keep
    their place in it (their offsets scaled), those of an older segment stay."""
    m = _map_with_two_keyframes()
    m.record_frame(3, 1, np.eye(3), np.array([0.5, 0.0, 0.0]))
    m.scale_frame_offsets(first_keyframe=1, scale=0.5)
    m.t_world_keyframe[1] = 0.5 * m.t_world_keyframe[1]  # the segment from keyframe 1, scaled about the origin
    _, _, _, t = m.frame_poses()
    np.testing.assert_allclose(t[1], [0.1, 0.0, 0.0])  # keyframe 0's frame: not moved
    np.testing.assert_allclose(t[3], [0.25, 0.0, 0.0])  # tracked at 0.5 m: 0.5 · 0.5
