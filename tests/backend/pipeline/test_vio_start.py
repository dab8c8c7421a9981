"""The VIO start (`vio_start`): its choice of keyframes for the visual-inertial alignment, and
the similarity that scales a map segment (the start and its scale refinement)."""

from __future__ import annotations

import numpy as np

from backend.data.scenes import builtin_scene
from backend.data.synthetic import SequenceSettings, SyntheticSequence
from backend.geometry import line as line_geo
from backend.geometry import so3
from backend.geometry.camera import PinholeCamera
from backend.mapping.map import Map
from backend.optim import inertial
from backend.pipeline.imu_window import InertialState
from backend.pipeline.vio_start import scale_segment, similarity_plucker, thinned
from backend.vio.alignment import AlignmentSettings, align_visual_inertial
from tests.backend.vio.test_alignment import VISUAL_SCALE, keyframes


def test_thinned_keeps_the_first_and_the_newest_at_least_the_interval_apart() -> None:
    stamps_ns = (np.arange(0.0, 4.01, 0.2) * 1e9).astype(np.int64)  # 21 keyframes, 0.2 s apart
    kept = thinned(stamps_ns, min_interval_s=0.5)
    assert kept[0] == 0 and kept[-1] == len(stamps_ns) - 1
    gaps = np.diff(stamps_ns[kept]) * 1e-9
    assert np.all(gaps >= 0.5 - 1e-9)
    assert kept.tolist() == [0, 3, 6, 9, 12, 15, 20]  # the newest (4.0 s) replaces 3.6 s, 0.4 s before it
    assert thinned(stamps_ns, min_interval_s=0.1).tolist() == list(range(len(stamps_ns)))
    assert thinned(stamps_ns[:1], min_interval_s=0.5).tolist() == [0]


def test_thinning_removes_the_scale_bias_of_noisy_positions_at_a_slow_pace() -> None:
    """Room at speed 1 (accelerations ~0.2 m/s²), keyframes every 0.2 s with ~3 mm of
    position noise (as a monocular map's): differenced over 0.2 s the noise is as large as
    the motion's accelerations, and the least-squares scale shrinks towards zero (errors in
    the regressor) while its σ looks acceptable; the same keyframes 0.5 s apart give it."""
    seq = SyntheticSequence(builtin_scene("room"), settings=SequenceSettings(duration_s=8.2, seed=0, speed=1.0))
    kf = keyframes(seq, 8.0, rate_hz=5.0, position_fraction=0.075, seed=0)
    kwargs = dict(T_body_cam0=seq.T_body_cam0, noise=seq.settings.imu_noise, settings=AlignmentSettings(max_scale_rel_std=0.15, accel_bias_sigma=0.2))
    every = align_visual_inertial(kf.timestamps_ns, kf.R_c0_cam, kf.p_c0_cam, seq.imu, **kwargs)
    kept = thinned(kf.timestamps_ns, min_interval_s=0.5)
    sparse = align_visual_inertial(kf.timestamps_ns[kept], kf.R_c0_cam[kept], kf.p_c0_cam[kept], seq.imu, **kwargs)
    assert every.success and sparse.success, (every.reason, sparse.reason)
    assert every.scale * VISUAL_SCALE - 1.0 < -0.25
    assert abs(sparse.scale * VISUAL_SCALE - 1.0) < 0.05


def test_similarity_plucker_moves_lines_as_their_points_and_keeps_far_ones_finite() -> None:
    """The start's scaling and rotation of the map's lines: the same line as through its two
    transformed points; a line 1e43 from the origin (a degenerate line a solve left in the map,
    seen on `room` at speed 1) stays finite instead of 0 / 0."""
    rng = np.random.default_rng(3)
    R, c, scale = so3.exp(np.array([0.3, -0.2, 1.1])), np.array([1.0, -2.0, 0.5]), 0.8
    p, q = rng.normal(size=(5, 3)), rng.normal(size=(5, 3))
    m, v = line_geo.from_points(p, q)
    n = np.linalg.norm(v, axis=1, keepdims=True)
    m_new, v_new = similarity_plucker(m / n, v / n, scale=scale, R=R, c=c)
    m_ref, v_ref = line_geo.from_points(scale * p @ R.T + c, scale * q @ R.T + c)
    n_ref = np.linalg.norm(v_ref, axis=1, keepdims=True)
    assert np.allclose(m_new, m_ref / n_ref) and np.allclose(v_new, v_ref / n_ref)
    far_m, far_v = np.array([[0.0, 1e43, 0.0]]), np.array([[1.0, 0.0, 0.0]])
    m_far, v_far = similarity_plucker(far_m, far_v, scale=scale, R=R, c=c)
    assert np.all(np.isfinite(m_far)) and np.allclose(np.linalg.norm(v_far), 1.0)


def _segment_map() -> tuple[Map, InertialState]:
    """Two keyframes before the segment, three in it, a point on a plane and a line in it,
    a point of the old segment, frames between the keyframes, and a marginalization prior."""
    m = Map(PinholeCamera(fx=400.0, fy=400.0, cx=320.0, cy=240.0, width=640, height=480, baseline=0.1))
    state = InertialState()
    for k in range(5):
        m.add_keyframe(2 * k, so3.exp(np.array([0.0, 0.1 * k, 0.0])), np.array([0.3 * k, 0.1, 0.0]), stamp_ns=k * 10**8, T_world_true=None)
        m.record_frame(2 * k + 1, k, np.eye(3), np.array([0.3 * k + 0.1, 0.2, 0.0]))
        state.velocity.append(np.array([1.0, 0.0, 0.5]))
        state.bias.append(np.full(6, 0.01))
    m.segment_start = 2
    m.planes.n.append(np.array([0.0, 0.0, 1.0]))
    m.planes.d.append(-2.0)  # z = 2
    m.planes.consensus.append((1.0, 10))
    m.points.add(
        p_world=np.array([[1.0, 1.0, 2.0], [5.0, 5.0, 5.0]]),
        ok=np.ones(2, bool),
        anchor=np.array([3, 0]),
        anchor_uv=np.zeros((2, 2)),
        anchor_ur=np.zeros(2),
        plane=np.array([0, -1]),
        desc=np.zeros((2, 32), np.uint8),
        n_kf=np.ones(2, np.int64),
        born=np.array([3, 0]),
    )
    lm, lv = line_geo.from_points(np.array([[0.0, 0.0, 2.0]]), np.array([[1.0, 0.0, 2.0]]))
    m.lines.add(
        m=lm,
        v=lv,
        ok=np.ones(1, bool),
        anchor=np.array([2]),
        anchor_uv=np.zeros((1, 4)),
        anchor_ruv=np.zeros((1, 4)),
        plane=np.array([0]),
        desc=np.zeros((1, 32), np.uint8),
        n_kf=np.ones(1, np.int64),
        born=np.array([2]),
    )
    state.prior = inertial.LinearPrior(
        pose_index=np.array([2]),
        inertial_index=np.array([2]),
        plane_index=np.array([0]),
        R=m.R_world_keyframe[2][None].copy(),
        t=m.t_world_keyframe[2][None].copy(),
        inertial=np.r_[state.velocity[2], state.bias[2]][None],
        plane_n=np.array([[0.0, 0.0, 1.0]]),
        plane_d=np.array([-2.0]),
        A=np.eye(18),
        b=np.zeros(18),
    )
    return m, state


def test_scale_segment_scales_the_segment_about_a_point_and_keeps_it_consistent() -> None:
    """The scale refinement's similarity: the segment's keyframes, frames, landmarks, plane,
    velocities and the prior's linearization point scaled about the newest keyframe, which
    stays; landmarks stay on their plane; the old segment, rotations and biases stay."""
    m, state = _segment_map()
    before = m.copy()
    _, _, R_frames, t_frames = m.frame_poses()
    c = m.t_world_keyframe[4].copy()
    scale_segment(m, state, scale=1.25, center_world=c)

    def moved(x: np.ndarray) -> np.ndarray:
        return c + 1.25 * (x - c)

    np.testing.assert_allclose(m.t_world_keyframe[:2], before.t_world_keyframe[:2])
    np.testing.assert_allclose(m.t_world_keyframe[2:], moved(before.t_world_keyframe[2:]))
    np.testing.assert_allclose(m.t_world_keyframe[4], c)
    np.testing.assert_allclose(m.R_world_keyframe[:], before.R_world_keyframe[:])
    _, ref, R_after, t_after = m.frame_poses()
    np.testing.assert_allclose(t_after[ref < 2], t_frames[ref < 2], atol=1e-12)
    np.testing.assert_allclose(t_after[ref >= 2], moved(t_frames[ref >= 2]), atol=1e-12)
    np.testing.assert_allclose(R_after, R_frames)
    np.testing.assert_allclose(m.points.p_world[0], moved(np.array([1.0, 1.0, 2.0])))
    np.testing.assert_allclose(m.points.p_world[1], [5.0, 5.0, 5.0])
    n, d = m.planes.n[0], m.planes.d[0]
    assert abs(n @ m.points.p_world[0] + d) < 1e-12
    p_line = np.cross(m.lines.v[0], m.lines.m[0])  # the line's point nearest the origin (m = p × v, |v| = 1)
    assert abs(n @ p_line + d) < 1e-12 and abs(n @ m.lines.v[0]) < 1e-12
    np.testing.assert_allclose(state.velocity[:2], [[1.0, 0.0, 0.5]] * 2)
    np.testing.assert_allclose(state.velocity[2:], [[1.25, 0.0, 0.625]] * 3)
    np.testing.assert_allclose(state.bias, [np.full(6, 0.01)] * 5)
    assert state.prior is not None
    np.testing.assert_allclose(state.prior.t[0], m.t_world_keyframe[2])
    np.testing.assert_allclose(state.prior.inertial[0], np.r_[state.velocity[2], state.bias[2]])
    np.testing.assert_allclose(state.prior.plane_d, [d])


def test_a_rejected_scale_refinement_is_tried_again_after_refine_retry_s(monkeypatch) -> None:
    """`VioStart.refine` tries at `refine_after_s` and, after a rejected alignment, not at
    every keyframe but `refine_retry_s` later (each try is a noisy measurement: trying at
    every keyframe until one passes the σ bound picks the noisiest). Keyframes every 0.1 s
    here, the alignment rejected until 17 s after the start: tried at 15 and 20 s, applied at
    20 s; with the retry sooner than the next keyframe it is applied at 17 s, after 20 rejected tries."""
    import dataclasses
    import types

    from backend.pipeline import vio_start
    from backend.pipeline.vio_settings import VioSettings

    stamps_ns = np.arange(400) * 100_000_000
    the_map = types.SimpleNamespace(segment_start=0, keyframe_stamp_ns=stamps_ns, keyframe_frame=np.arange(400), t_world_keyframe=np.zeros((400, 3)))
    source = types.SimpleNamespace(ground_truth_valid=np.zeros(400, dtype=bool))
    tried: list[float] = []
    scaled: list[float] = []

    def fake_align(kfs, span_s, ctx, settings):
        since = 1e-9 * float(stamps_ns[kfs[-1]])
        tried.append(round(since, 1))
        ok = since >= 17.0
        quality = types.SimpleNamespace(scale_rel_std=0.05, chi2_per_dof=0.1)
        return np.arange(len(kfs)), types.SimpleNamespace(success=ok, reason="" if ok else "scale poorly determined: relative std 0.2 > 0.15", scale=1.1, quality=quality)

    monkeypatch.setattr(vio_start, "_align", fake_align)
    monkeypatch.setattr(vio_start, "scale_segment", lambda the_map, state, *, scale, center_world: scaled.append(scale))

    def run(settings: VioSettings) -> vio_start.VioStart:
        tried.clear()
        scaled.clear()
        start = vio_start.VioStart(keyframe=0)
        ctx = types.SimpleNamespace(map=the_map, inertial=None, source=source, settings=settings, messages=[])
        for k in range(1, 400):
            start.refine(k, ctx)
        return start

    start = run(VioSettings())
    assert tried == [15.0, 20.0] and scaled == [1.1]
    assert start.report["refinement_rejections"] == 1 and start.report["refinements"][0]["after_start_s"] == 20.0
    assert start.report["refinement_last_rejection"].startswith("scale poorly determined")
    eager = run(dataclasses.replace(VioSettings(), refine_retry_s=0.05))
    assert tried[0] == 15.0 and tried[-1] == 17.0 and len(tried) == 21 and scaled == [1.1]
    assert eager.report["refinement_rejections"] == 20
