"""The VIO start's choice of keyframes for the visual-inertial alignment (`vio_start`)."""

from __future__ import annotations

import numpy as np

from backend.data.scenes import builtin_scene
from backend.data.synthetic import SequenceSettings, SyntheticSequence
from backend.geometry import line as line_geo
from backend.geometry import so3
from backend.pipeline.vio_start import similarity_plucker, thinned
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
