"""The stereo pipeline on rendered scenes: accuracy, planes, every variant, the engine
interface, and recovery from black frames and sudden jumps."""

from __future__ import annotations

import functools

import numpy as np
import pytest

from backend.data.scenes import builtin_scene
from backend.data.synthetic import SequenceSettings, SyntheticSequence
from backend.eval.planes import recovered_planes
from backend.optim.variant import VARIANTS
from backend.pipeline.engine import EndOfSequence, Engine
from backend.pipeline.overlay import decode_keyframe_image
from backend.pipeline.snapshot import Snapshot
from backend.pipeline.stages.culling import CullSettings, cull
from backend.pipeline.stereo_engine import StereoEngine, StereoSettings


class _Perturbed:
    """A source whose frames `black` are all black, or that jumps over `skip` frames at
    frame `skip_at` (a sudden large motion)."""

    def __init__(self, source: SyntheticSequence, *, black: range = range(0), skip_at: int | None = None, skip: int = 0) -> None:
        self.source = source
        self.black = black
        index = np.arange(len(source))
        if skip_at is not None:
            index = np.concatenate([index[:skip_at], index[skip_at + skip :]])
        self.index = index
        self.timestamps_ns = source.timestamps_ns[index]
        self.T_world_rect0 = source.T_world_rect0[index]
        self.camera = source.camera
        self.ground_truth_valid = source.ground_truth_valid[index]
        self.ground_truth_frame = source.ground_truth_frame
        self.T_truth_rect0 = source.T_truth_rect0

    def __len__(self) -> int:
        return len(self.index)

    def rectified_pair(self, i: int) -> tuple[np.ndarray, np.ndarray]:
        left, right = self.source.rectified_pair(int(self.index[i]))
        if i in self.black:
            return np.zeros_like(left), np.zeros_like(right)
        return left, right


@functools.cache
def _sequence(duration_s: float) -> SyntheticSequence:
    return SyntheticSequence(builtin_scene("room"), settings=SequenceSettings(duration_s=duration_s), cache_frames=200)


def _run(engine: StereoEngine, *, max_steps: int = 10_000) -> list[Snapshot]:
    snapshots = []
    for _ in range(max_steps):
        try:
            snapshots.append(engine.step())
        except EndOfSequence:
            break
    return snapshots


@functools.cache
def _room_pl_w() -> tuple[StereoEngine, tuple[Snapshot, ...]]:
    engine = StereoEngine(_sequence(8.0), settings=StereoSettings(variant="PL-w"), name="room")
    return engine, tuple(_run(engine))


def test_room_trajectory_is_accurate_and_complete() -> None:
    engine, snapshots = _room_pl_w()
    last = snapshots[-1]
    assert isinstance(engine, Engine)
    assert engine.frames == len(_sequence(8.0))
    assert last.keyframe == len(snapshots) - 1 >= 5
    # Measured 0.2-0.3 cm over 8 s (keyframe ATE after SE(3) alignment); the goal is 3 cm.
    assert last.metrics.ate_cm < 3.0
    assert sum(s.tracking.lost_frames for s in snapshots) == 0
    assert sum(s.tracking.frames for s in snapshots) <= engine.frames
    assert last.tracking.tracked_points > 100 and last.tracking.tracked_lines > 5
    assert len(last.points) > 500 and len(last.lines) > 30
    # Keyframe poses are rotations, timestamps those of the frames.
    R = last.estimate.R_world_camera
    np.testing.assert_allclose(R @ np.swapaxes(R, 1, 2), np.broadcast_to(np.eye(3), R.shape), atol=1e-9)
    assert set(last.estimate.timestamp_ns) <= set(_sequence(8.0).timestamps_ns)


def test_room_keyframes_follow_the_paper_rule_or_the_fallback() -> None:
    _, snapshots = _room_pl_w()
    gaps = [s.tracking.frames for s in snapshots[1:]]
    min_gap, min_fallback_gap = StereoSettings().keyframe_gap_frames(0.05)  # the room's 20 Hz
    assert (min_gap, min_fallback_gap) == (20, 2)  # the paper's frame counts
    assert min(gaps) >= min_fallback_gap
    assert max(gaps) <= min_gap


def test_room_planes_are_walls_floor_and_boxes() -> None:
    _, snapshots = _room_pl_w()
    last = snapshots[-1]
    table = _sequence(8.0).plane_table
    ids = sorted(table)
    n_true = np.array([table[i][:3] for i in ids])
    d_true = np.array([table[i][3] for i in ids])
    found = recovered_planes(np.array([p.n for p in last.planes]), np.array([p.d for p in last.planes]), n_true, d_true)
    # The floor (normal +z) and at least two walls are among the recovered planes.
    assert np.any(found & (np.abs(n_true[:, 2]) > 0.9))
    assert np.sum(found & (np.abs(n_true[:, 2]) < 0.1)) >= 2
    planar_points = np.mean(last.points.plane >= 0)
    assert planar_points > 0.3
    # Every accepted detection reached θ_cp.
    for snapshot in snapshots:
        det = snapshot.detection
        for candidates, inliers, accepted in zip(det.candidates, det.inliers, det.accepted):
            assert accepted == (inliers >= 0.8 * candidates)


def test_plane_hulls_are_each_planes_own_landmarks() -> None:
    """The hulls computed for all planes in one pass (snapshots, association) are each
    plane's own: the points and segment ends labelled with it and not culled, in the order
    plane_support gives them; the last snapshot shows them with its support counts."""
    engine, snapshots = _room_pl_w()
    the_map = engine.map
    P, Lm = the_map.points, the_map.lines
    assert len(the_map.planes) >= 3 and np.any(~P.ok[:]) and np.any((Lm.plane[:] >= 0) & Lm.ok[:])
    for q, (support, hull) in enumerate(zip(the_map.plane_supports(), the_map.hulls(), strict=True)):
        np.testing.assert_array_equal(support, the_map.plane_support(q))
        np.testing.assert_array_equal(hull, the_map.hull(q))
    shown = {p.id: p for p in snapshots[-1].planes}
    for q, plane in shown.items():
        assert plane.n_points == np.sum((P.plane[:] == q) & P.ok[:]) and plane.n_lines == np.sum((Lm.plane[:] == q) & Lm.ok[:])
        np.testing.assert_array_equal(plane.hull_world, the_map.hull(q))


def test_snapshots_carry_the_keyframe_image_and_hessian() -> None:
    _, snapshots = _room_pl_w()
    last = snapshots[-1]
    image = decode_keyframe_image(last.image)
    scale = StereoSettings().image_scale
    assert image.shape == (round(480 * scale), round(752 * scale), 3)
    assert last.hessian is not None and last.report.items > 0
    assert {"point_dm", "line_dm", "plane_seg", "plane_fit", "optimization", "total", "total_per_frame"} <= set(last.report.timing_ms)


@pytest.mark.parametrize("variant", VARIANTS)
def test_every_variant_runs_on_room(variant: str) -> None:
    engine = StereoEngine(_sequence(3.0), settings=StereoSettings(variant=variant, image_scale=None, hessian=False, skip_unused_stages=True))
    snapshots = _run(engine)
    last = snapshots[-1]
    assert last.variant == variant
    assert last.metrics.ate_cm < 3.0
    with_lines = variant.startswith("PL")
    assert (len(last.lines) > 0) == with_lines  # P variants skip line D&M in this mode
    assert (len(last.planes) > 0) == (not variant.endswith("-wo"))  # -wo skips segmentation


def test_variant_switch_reoptimize_compare_and_reset() -> None:
    engine = StereoEngine(_sequence(3.0), settings=StereoSettings(variant="PL-w", image_scale=None))
    for _ in range(4):
        engine.step()
    engine.set_variant("PL-r")
    again = engine.reoptimize()
    assert again.variant == "PL-r" and again.keyframe == 3
    structures = engine.compare_hessians(("PL-wo", "PL-r", "PL-w"))
    assert set(structures) == {"PL-wo", "PL-r", "PL-w"}
    # -r adds the plane variables to -wo; -w drops the planar features' variables.
    assert structures["PL-r"].items > structures["PL-wo"].items > structures["PL-w"].items
    with pytest.raises(ValueError):
        engine.set_variant("Q-w")
    engine.reset()
    assert engine.keyframes == 0 and engine.frames == 0
    assert engine.step().keyframe == 0


def test_black_frames_are_reported_and_the_run_recovers() -> None:
    source = _Perturbed(_sequence(5.0), black=range(30, 50))
    engine = StereoEngine(source, settings=StereoSettings(image_scale=None, hessian=False))
    snapshots = _run(engine)
    assert engine.frames == len(source)
    lost = sum(s.tracking.lost_frames for s in snapshots)
    assert lost >= 20
    messages = " ".join(s.message for s in snapshots)
    assert "lost" in messages or "relocalized" in messages
    after = [s for s in snapshots if s.timestamp_ns > source.timestamps_ns[50]]
    assert len(after) >= 3 and after[-1].tracking.tracked_points > 100
    assert np.isfinite(snapshots[-1].metrics.ate_cm)
    # Lost frames have no pose: the per-frame trajectory leaves them out (a re-initialization
    # frame becomes a keyframe and has one).
    frames = engine.frame_trajectory()
    reinitializations = sum(s.tracking.reinitializations for s in snapshots)
    assert len(frames) == engine.frames - lost + reinitializations
    assert not set(range(30, 50)) & set(frames.frame.tolist())


def test_sudden_large_motion_is_survived() -> None:
    source = _Perturbed(_sequence(5.0), skip_at=30, skip=40)  # 2 s of motion in one frame
    engine = StereoEngine(source, settings=StereoSettings(image_scale=None, hessian=False))
    snapshots = _run(engine)
    assert engine.frames == len(source)
    messages = " ".join(s.message for s in snapshots)
    assert "re-initialized" in messages or "relocalized" in messages
    assert snapshots[-1].tracking.tracked_points > 100
    assert np.isfinite(snapshots[-1].metrics.ate_cm)


def test_settings_are_checked() -> None:
    with pytest.raises(ValueError):
        StereoSettings(variant="PL-x")
    with pytest.raises(ValueError):
        StereoSettings(window=1)


def _inverse_compose(R_a: np.ndarray, t_a: np.ndarray, R_b: np.ndarray, t_b: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """T_a⁻¹ T_b for stacks of poses."""
    return np.einsum("nki,nkj->nij", R_a, R_b), np.einsum("nki,nk->ni", R_a, t_b - t_a)


def test_frame_trajectory_follows_the_reference_keyframes() -> None:
    """Every tracked frame has a pose; keyframes are their own reference; a frame's pose
    relative to its reference keyframe stays fixed while the window moves the keyframe."""
    source = _sequence(3.0)
    engine = StereoEngine(source, settings=StereoSettings(variant="PL-w", image_scale=None, hessian=False))
    snapshots = [engine.step() for _ in range(3)]
    early = engine.frame_trajectory()
    early_kf = snapshots[-1].estimate
    snapshots += _run(engine)
    final = engine.frame_trajectory()
    est, kf = final.estimate, snapshots[-1].estimate

    assert len(final) == engine.frames == len(source)  # nothing lost on the room
    np.testing.assert_array_equal(final.frame, np.arange(len(source)))
    np.testing.assert_array_equal(est.timestamp_ns, source.timestamps_ns)
    assert np.all(np.diff(final.reference_keyframe) >= 0)
    # Keyframes: their own reference, at the keyframe estimate.
    assert int(final.is_keyframe.sum()) == len(kf)
    np.testing.assert_array_equal(final.reference_keyframe[final.is_keyframe], np.arange(len(kf)))
    np.testing.assert_array_equal(est.timestamp_ns[final.is_keyframe], kf.timestamp_ns)
    np.testing.assert_allclose(est.t_world_camera[final.is_keyframe], kf.t_world_camera, atol=1e-12)
    np.testing.assert_allclose(est.R_world_camera[final.is_keyframe], kf.R_world_camera, atol=1e-9)
    # Every other frame: tracked after its reference keyframe, before the next one.
    kf_frame = final.frame[final.is_keyframe]
    ref_frame = kf_frame[final.reference_keyframe]
    assert np.all(final.frame >= ref_frame)
    nxt = np.append(kf_frame[1:], np.iinfo(np.int64).max)[final.reference_keyframe]
    assert np.all(final.frame < nxt)
    # Ground truth of every frame (the room has it everywhere).
    np.testing.assert_allclose(final.ground_truth.t_world_camera, source.T_world_rect0[:, :3, 3])
    # T_refkf_frame is constant; the world poses moved with the optimized keyframes.
    n = len(early)
    ref = early.reference_keyframe
    assert not np.allclose(early_kf.t_world_camera[ref], kf.t_world_camera[ref], atol=1e-9, rtol=0)
    rel_early = _inverse_compose(early_kf.R_world_camera[ref], early_kf.t_world_camera[ref], early.estimate.R_world_camera, early.estimate.t_world_camera)
    rel_final = _inverse_compose(kf.R_world_camera[ref], kf.t_world_camera[ref], est.R_world_camera[:n], est.t_world_camera[:n])
    np.testing.assert_allclose(rel_final[0], rel_early[0], atol=1e-9)
    np.testing.assert_allclose(rel_final[1], rel_early[1], atol=1e-9)
    R = est.R_world_camera
    np.testing.assert_allclose(np.einsum("nki,nkj->nij", R, R), np.broadcast_to(np.eye(3), R.shape), atol=1e-12)


def test_lines_out_of_range_or_not_finite_are_culled() -> None:
    """A line a solve pushed to infinity (its nearest point to the anchor camera 100 m away,
    or its coordinates overflowed) is removed at the next culling, also when no keyframe of
    the window observes it (no reprojection test reaches it); the others stay."""
    engine = StereoEngine(_sequence(8.0), settings=StereoSettings(variant="PL-w", image_scale=None, hessian=False))
    _run(engine)
    k = engine.keyframes - 1
    w0, _ = engine.window_range(k)
    Lm = engine.map.lines
    in_window = np.unique(np.concatenate([engine.map.observations[j].line_id for j in range(w0, k + 1)]))
    ids = np.setdiff1d(np.flatnonzero(Lm.ok[:]), in_window)
    assert len(ids) >= 3
    far, broken, kept = ids[:3]
    c = engine.map.t_world_keyframe[Lm.anchor[far]]
    v = Lm.v[far] / np.linalg.norm(Lm.v[far])
    away = np.cross(v, [0.0, 0.0, 1.0] if abs(v[2]) < 0.9 else [1.0, 0.0, 0.0])
    p = c + 100.0 * away / np.linalg.norm(away)  # a point of the line 100 m from the anchor camera
    Lm.m[far], Lm.v[far] = np.cross(p, v), v
    Lm.m[broken] = np.array([np.inf, 0.0, np.nan])
    st = engine.settings
    cull(engine.map, k, w0, settings=CullSettings(st.outlier_px, st.min_depth_m, st.max_depth_m, st.cull_after_keyframes, st.min_keyframe_observations))
    assert not Lm.ok[far] and not Lm.ok[broken]
    assert Lm.ok[kept]
