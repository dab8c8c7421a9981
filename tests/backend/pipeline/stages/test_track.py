"""Frame tracking (`backend.pipeline.stages.track`): a frame of a bare wall whose few corners
cannot place it alone is placed with the local map's lines (PL variants), and is lost
without them."""

from __future__ import annotations

import functools

import numpy as np

from backend.data.scenes import builtin_scene
from backend.data.synthetic import SequenceSettings, SyntheticSequence
from backend.frontend.lines import detect_segments
from backend.frontend.points import Keypoints, detect_points, nearest_hamming
from backend.geometry import so3
from backend.geometry.camera import PinholeCamera
from backend.optim.variant import Variant
from backend.pipeline.engine import EngineCheckpoint
from backend.pipeline.stages.track import LineAid, Tracked, nearest_ahead, rows_of, track_frame
from backend.pipeline.stereo_engine import StereoEngine, StereoSettings
from backend.pipeline.tracking import relocalize

_SETTINGS = StereoSettings(variant=Variant.PL_W, skip_unused_stages=True, image_scale=None, hessian=False, seed=0)  # as `coplanar run`
_FRAME = 72  # low-texture, seed 0: a faint wall, 35 keypoints (tracking needs 20 point inliers)


@functools.cache
def _map_before_frame() -> tuple[StereoEngine, SyntheticSequence]:
    """The engine with the map as it stood when frame `_FRAME` was tracked (the last
    keyframe before it)."""
    seq = SyntheticSequence(builtin_scene("low-texture"), settings=SequenceSettings(duration_s=5.0, seed=0), cache_frames=8)
    engine = StereoEngine(seq, settings=_SETTINGS, name="low-texture")
    saved: EngineCheckpoint = engine.checkpoint()
    while True:
        snapshot = engine.step()
        if int(engine.core.map.keyframe_frame[-1]) >= _FRAME:
            engine.restore(saved)
            return engine, seq
        saved = engine.checkpoint()
        assert snapshot.keyframe < 60


def _true_motion_from_last_keyframe() -> tuple[np.ndarray, np.ndarray]:
    """The true motion from the map's last keyframe to frame `_FRAME`: `(R_kf_frame,
    t_kf_frame)` (the map's own error since its start is not the tracker's)."""
    engine, seq = _map_before_frame()
    m = engine.core.map
    T_kf, T = seq.T_world_rect0[int(m.keyframe_frame[-1])], seq.T_world_rect0[_FRAME]
    return T_kf[:3, :3].T @ T[:3, :3], T_kf[:3, :3].T @ (T[:3, 3] - T_kf[:3, 3])


def _error_from_last_keyframe(tracked: Tracked) -> tuple[float, float]:
    """The tracked pose's error relative to the map's last keyframe: translation (m) and
    rotation (degrees)."""
    m = _map_before_frame()[0].core.map
    R_est, t_est = m.R_world_keyframe[-1].T @ tracked.R, m.R_world_keyframe[-1].T @ (tracked.t - m.t_world_keyframe[-1])
    R_true, t_true = _true_motion_from_last_keyframe()
    return float(np.linalg.norm(t_est - t_true)), float(np.degrees(np.linalg.norm(so3.log(R_est.T @ R_true))))


def _predicted(offset_m: float) -> tuple[np.ndarray, np.ndarray]:
    """The map's last keyframe moved by the true motion to the frame, then `offset_m` off
    along each axis and 0.2° off in yaw: a motion model a little off."""
    m = _map_before_frame()[0].core.map
    R_rel, t_rel = _true_motion_from_last_keyframe()
    R, t = m.R_world_keyframe[-1] @ R_rel, m.R_world_keyframe[-1] @ t_rel + m.t_world_keyframe[-1]
    return R @ so3.exp(np.array([0.0, 0.004, 0.0])), t + np.array([offset_m, -offset_m, 0.5 * offset_m])


def _track(*, with_lines: bool, offset_m: float, max_translation_std_m: float = 0.02) -> Tracked:
    engine, seq = _map_before_frame()
    c = engine.core
    left, _ = seq.rectified_pair(_FRAME)
    kp = detect_points(left, settings=_SETTINGS.points)
    aid = LineAid(c.local_lines, lambda: detect_segments(left, settings=_SETTINGS.lines), _SETTINGS.lines, _SETTINGS.line_search_px, _SETTINGS.min_depth_m, max_translation_std_m=max_translation_std_m)
    lines = aid if with_lines else None
    return track_frame(c.camera, c.track_settings(), _FRAME, kp, the_map=c.map, local_points=c.local_points, predicted=_predicted(offset_m), last_frame=None, messages=[], lines=lines)


def test_a_frame_too_bare_for_its_points_is_lost_without_lines() -> None:
    assert not _track(with_lines=False, offset_m=0.01).ok


def test_the_local_map_lines_place_a_frame_too_bare_for_its_points() -> None:
    tracked = _track(with_lines=True, offset_m=0.01)
    assert tracked.ok
    assert tracked.line_inliers >= 3
    assert tracked.inliers < _SETTINGS.min_tracking_inliers  # the points alone were not enough
    error_m, error_deg = _error_from_last_keyframe(tracked)
    assert error_m < 0.03
    assert error_deg < 0.5


def test_lines_do_not_rescue_a_prediction_far_off() -> None:
    """A prediction 30 cm off: the lines' projections miss their segments; the frame is lost
    (not placed wrongly)."""
    tracked = _track(with_lines=True, offset_m=0.3)
    assert not tracked.ok or _error_from_last_keyframe(tracked)[0] < 0.03


def test_a_loosely_constrained_pose_is_refused() -> None:
    """With the gate on the pose's uncertainty shut (1 mm), the same frame is lost: a pose
    the marks of one wall leave loose is not taken."""
    assert not _track(with_lines=True, offset_m=0.01, max_translation_std_m=0.001).ok


def test_relocalizing_against_a_subset_with_the_whole_maps_search_is_the_same_as_searching_it() -> None:
    """Tracking searches the local map's descriptors once and relocalizes against the last
    keyframe's points with that search's rows (`rows_of`): the same pose and matches as a
    search of the subset alone."""
    rng = np.random.default_rng(4)
    camera = PinholeCamera(fx=458.0, fy=457.0, cx=367.0, cy=248.0, width=752, height=480)
    p_world = np.column_stack([rng.uniform(-2.0, 2.0, 300), rng.uniform(-1.5, 1.5, 300), rng.uniform(3.0, 8.0, 300)])
    desc = rng.integers(0, 256, (300, 32), dtype=np.uint8)
    uv = camera.project(p_world)
    seen = np.flatnonzero(camera.in_image(uv))
    kp_uv = uv[seen] + rng.normal(0.0, 0.5, (len(seen), 2))
    kp_desc = desc[seen] ^ (rng.random((len(seen), 32)) < 0.02).astype(np.uint8)
    subset = np.sort(rng.choice(300, 120, replace=False))
    whole = nearest_hamming(desc, kp_desc, k=2)
    alone = relocalize(camera, p_world[subset], desc[subset], kp_uv, kp_desc, max_hamming=50, ratio=0.9, min_inliers=20, seed=1)
    shared = relocalize(camera, p_world[subset], desc[subset], kp_uv, kp_desc, max_hamming=50, ratio=0.9, min_inliers=20, seed=1, candidates=rows_of(whole, subset, n_rows=300))
    assert alone is not None and shared is not None
    for a, b in zip(alone, shared, strict=True):
        np.testing.assert_array_equal(a, b)
    assert (alone[2] >= 0).sum() > 60
    np.testing.assert_allclose(alone[1], 0.0, atol=0.02)  # the camera at the world origin


def test_relocalization_searches_only_the_points_in_front_of_the_last_frame() -> None:
    """The points a drive has passed lie behind the camera and cannot be in view: the
    relocalization's descriptor search leaves them out (`nearest_ahead`, rows still
    indexing the whole local map), and finds the same pose and matches as searching every
    point, look-alikes behind the camera included (repeated texture along a street)."""
    rng = np.random.default_rng(5)
    camera = PinholeCamera(fx=458.0, fy=457.0, cx=367.0, cy=248.0, width=752, height=480)
    front = np.column_stack([rng.uniform(-2.0, 2.0, 300), rng.uniform(-1.5, 1.5, 300), rng.uniform(3.0, 8.0, 300)])
    behind = front[:200] * np.array([1.0, 1.0, -1.0])  # passed: mirrored behind the camera
    p_world = np.concatenate([front, behind])
    desc_front = rng.integers(0, 256, (300, 32), dtype=np.uint8)
    desc = np.concatenate([desc_front, desc_front[:200]])  # the same texture again
    uv = camera.project(front)
    seen = np.flatnonzero(camera.in_image(uv))
    kp = Keypoints(uv=uv[seen] + rng.normal(0.0, 0.5, (len(seen), 2)), descriptors=desc_front[seen] ^ (rng.random((len(seen), 32)) < 0.02).astype(np.uint8), octave=np.zeros(len(seen), np.int32))
    ahead = nearest_ahead(p_world, desc, kp, (np.eye(3), np.zeros(3)))
    assert ahead[0].max() < 300 and len(np.unique(ahead[0])) == 300  # every point in front, none behind
    everything = np.arange(len(p_world))
    found = relocalize(camera, p_world, desc, kp.uv, kp.descriptors, max_hamming=50, ratio=0.9, min_inliers=20, seed=1, candidates=rows_of(ahead, everything, n_rows=len(p_world)))
    searched_all = relocalize(camera, p_world, desc, kp.uv, kp.descriptors, max_hamming=50, ratio=0.9, min_inliers=20, seed=1)
    assert found is not None and searched_all is not None
    for a, b in zip(found, searched_all, strict=True):
        np.testing.assert_array_equal(a, b)
    assert (found[2] >= 0).sum() > 100 and np.all(found[2][300:] < 0)
    np.testing.assert_allclose(found[1], 0.0, atol=0.02)
