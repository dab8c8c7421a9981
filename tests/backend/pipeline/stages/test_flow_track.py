"""A stereo frame the map cannot place, placed by optical flow from the last placed frame
(backend.pipeline.stages.flow_track), alone and in the stereo engine."""

from __future__ import annotations

import copy
import dataclasses
import functools
import re

import numpy as np

from backend.data.scenes import builtin_scene
from backend.data.synthetic import SequenceSettings, SyntheticSequence
from backend.frontend.points import detect_points
from backend.geometry import so3
from backend.optim.variant import Variant
from backend.pipeline.stages.flow_track import FlowReference, FlowTrackSettings, track_by_flow
from backend.pipeline.stereo_engine import StereoEngine, StereoSettings

_SETTINGS = StereoSettings(variant=Variant.PL_W, skip_unused_stages=True, image_scale=None, hessian=False, seed=0)  # as `coplanar run`


@functools.cache
def _low_texture() -> SyntheticSequence:
    """`low-texture`, seed 0: from frame 3 on a faint wall that ORB finds 30-60 corners on."""
    return SyntheticSequence(builtin_scene("low-texture"), settings=SequenceSettings(duration_s=2.0, seed=0), cache_frames=4)


def _reference(seq: SyntheticSequence, i: int) -> FlowReference:
    left, right = seq.rectified_pair(i)
    T = seq.T_world_rect0[i]
    return FlowReference.of(i, left, right, T[:3, :3], T[:3, 3])


def _errors(seq: SyntheticSequence, i: int, R: np.ndarray, t: np.ndarray) -> tuple[float, float]:
    """Translation (m) and rotation (degrees) error against frame i's true pose."""
    T = seq.T_world_rect0[i]
    return float(np.linalg.norm(t - T[:3, 3])), float(np.degrees(np.linalg.norm(so3.log(T[:3, :3].T @ R))))


def test_a_bare_wall_frame_that_orb_cannot_track_is_placed_by_flow() -> None:
    seq = _low_texture()
    left = seq.rectified_pair(9)[0]
    assert len(detect_points(left, settings=_SETTINGS.points).uv) < 3 * _SETTINGS.min_tracking_inliers  # too few for tracking or a new map
    pose = track_by_flow(seq.camera, _reference(seq, 8), left, seq.rectified_pair(9)[1], settings=FlowTrackSettings())
    assert pose.ok and pose.inliers >= 40
    t_err, r_err = _errors(seq, 9, pose.R_world_camera, pose.t_world_camera)
    assert t_err < 0.005 and r_err < 0.1  # the frame moved 9 mm


def test_a_strong_corner_in_view_does_not_hide_the_wall_grain() -> None:
    """A dark checkered post in a corner of the reference (as `low-texture` seed 3's frame 184
    has) makes the strongest corner ~100× the grain's: at a quality level relative to it
    (0.001, the old default) only the post's corners remain, too few to place the frame."""
    seq = _low_texture()
    reference = _reference(seq, 8)
    checker = np.kron((np.indices((8, 4)).sum(axis=0) % 2) * 255, np.ones((8, 8), np.uint8)).astype(np.uint8)  # 64 x 32 px
    post_left, post_right = reference.left.copy(), reference.right.copy()
    post_left[-64:, :32] = checker
    post_right[-64:, :32] = checker
    with_post = dataclasses.replace(reference, left=post_left, right=post_right)
    left, right = seq.rectified_pair(9)
    assert not track_by_flow(seq.camera, with_post, left, right, settings=FlowTrackSettings(quality_level=1e-3)).ok
    pose = track_by_flow(seq.camera, with_post, left, right, settings=FlowTrackSettings())
    assert pose.ok and pose.inliers >= 40
    t_err, r_err = _errors(seq, 9, pose.R_world_camera, pose.t_world_camera)
    assert t_err < 0.005 and r_err < 0.1


def test_a_fast_turn_is_placed_from_the_predicted_pose() -> None:
    """`low-texture` seed 0, frames 310 -> 311: 2.4° of turn moves the faint grain ~19 px, beyond
    what the pyramid's flow from the reference's pixels follows; started where the predicted
    pose (1° and 1 cm off the truth here) puts each corner's point, it places the frame."""
    seq = SyntheticSequence(builtin_scene("low-texture"), settings=SequenceSettings(duration_s=16.0, seed=0), cache_frames=4)
    reference = _reference(seq, 310)
    left, right = seq.rectified_pair(311)
    assert not track_by_flow(seq.camera, reference, left, right, settings=FlowTrackSettings()).ok
    T = seq.T_world_rect0[311]
    R_predicted, t_predicted = T[:3, :3] @ so3.exp(np.radians([0.5, -0.7, 0.3])), T[:3, 3] + np.array([0.006, -0.005, 0.006])
    pose = track_by_flow(seq.camera, reference, left, right, settings=FlowTrackSettings(), R_world_predicted=R_predicted, t_world_predicted=t_predicted)
    assert pose.ok and pose.inliers >= 40
    t_err, r_err = _errors(seq, 311, pose.R_world_camera, pose.t_world_camera)
    assert t_err < 0.003 and r_err < 0.1  # the frame moved 24 mm


def test_a_frame_without_texture_or_a_loose_translation_is_not_placed() -> None:
    seq = _low_texture()
    reference = _reference(seq, 8)
    left, right = seq.rectified_pair(9)
    for image in (np.zeros_like(reference.left), np.full_like(reference.left, 128)):
        assert not track_by_flow(seq.camera, reference, image, image, settings=FlowTrackSettings()).ok
    grey = dataclasses.replace(reference, left=np.full_like(reference.left, 128))  # no corners in the reference
    assert not track_by_flow(seq.camera, grey, left, right, settings=FlowTrackSettings()).ok
    strict = FlowTrackSettings(max_translation_std_m=1e-6)  # no real set of inliers holds the translation this well
    pose = track_by_flow(seq.camera, reference, left, right, settings=strict)
    assert not pose.ok and pose.inliers >= 40 and np.isfinite(pose.translation_std_m)


def test_depths_the_frame_own_stereo_contradicts_place_nothing() -> None:
    """A reference whose right image is shifted by 3 px: every corner's depth wrong the same
    way, which the left image alone fits with a wrong pose; the frame's right image refuses it."""
    seq = _low_texture()
    reference = _reference(seq, 8)
    shifted = dataclasses.replace(reference, right=np.roll(reference.right, -3, axis=1))
    left, right = seq.rectified_pair(9)
    assert not track_by_flow(seq.camera, shifted, left, right, settings=FlowTrackSettings()).ok
    assert track_by_flow(seq.camera, reference, left, right, settings=FlowTrackSettings()).ok


def test_the_reference_is_immutable_and_shared_by_copies() -> None:
    reference = _reference(_low_texture(), 3)
    assert copy.deepcopy(reference) is reference and copy.copy(reference) is reference
    assert not reference.left.flags.writeable and not reference.t_world_camera.flags.writeable


def _first_step(settings: StereoSettings) -> tuple[StereoEngine, object]:
    engine = StereoEngine(_low_texture(), settings=settings, name="low-texture")
    engine.step()  # the first keyframe
    return engine, engine.step()


def test_the_engine_places_the_bare_wall_frames_instead_of_losing_them() -> None:
    seq = _low_texture()
    _, without = _first_step(dataclasses.replace(_SETTINGS, flow_track=None))
    assert without.tracking.lost_frames > 0  # as before the flow: lost, then the map re-initialized
    engine, snapshot = _first_step(_SETTINGS)
    assert snapshot.tracking.lost_frames == 0 and snapshot.tracking.reinitializations == 0
    assert "placed by optical flow" in snapshot.message
    # Every frame placed, and each placed by flow moved from the frame before it as it truly did:
    # within the translation's gate (2 cm, its largest standard deviation) and 0.2°, 3 mm in the median.
    trajectory = engine.frame_trajectory()
    frames = trajectory.frame.tolist()
    by_flow = [int(i) for i in re.findall(r"frame (\d+): placed by optical flow", snapshot.message)]
    assert len(by_flow) >= 5
    assert frames == list(range(frames[-1] + 1)) and len(frames) > 10
    R, t = trajectory.estimate.R_world_camera, trajectory.estimate.t_world_camera
    T = seq.T_world_rect0
    errors = []
    for i in sorted(set(by_flow) & set(frames[1:])):
        R_rel, t_rel = R[i - 1].T @ R[i], R[i - 1].T @ (t[i] - t[i - 1])
        R_true, t_true = T[i - 1][:3, :3].T @ T[i][:3, :3], T[i - 1][:3, :3].T @ (T[i][:3, 3] - T[i - 1][:3, 3])
        errors.append(float(np.linalg.norm(t_rel - t_true)))
        assert errors[-1] < FlowTrackSettings().max_translation_std_m and np.degrees(np.linalg.norm(so3.log(R_true.T @ R_rel))) < 0.2, i
    assert float(np.median(errors)) < 0.003


def test_a_keyframe_placed_by_flow_keeps_its_pose_in_later_windows() -> None:
    seq = SyntheticSequence(builtin_scene("low-texture"), settings=SequenceSettings(duration_s=6.0, seed=0), cache_frames=4)
    engine = StereoEngine(seq, settings=_SETTINGS, name="low-texture")
    engine.step()
    snapshot = engine.step()
    assert snapshot.tracking.keyframe_reason == "placed by flow"  # frame 15: 64 keypoints, none matching the map
    flow_keyframes = list(engine.window_extension().pinned_poses() or ())
    assert flow_keyframes == [snapshot.keyframe]
    k = flow_keyframes[0]
    R, t = engine.core.map.R_world_keyframe[k].copy(), engine.core.map.t_world_keyframe[k].copy()
    for _ in range(3):
        engine.step()
    np.testing.assert_array_equal(engine.core.map.R_world_keyframe[k], R)
    np.testing.assert_array_equal(engine.core.map.t_world_keyframe[k], t)
