"""The excitation onset (backend/eval/excitation.py) that the robustness sweep times the VIO
start from."""

from __future__ import annotations

import math

import numpy as np

from backend.eval.excitation import excitation_onset_s, true_acceleration

RATE_HZ = 20.0


def _stamps(duration_s: float, rate_hz: float = RATE_HZ) -> np.ndarray:
    return np.arange(0, int(duration_s * 1e9) + 1, int(1e9 / rate_hz), dtype=np.int64)


def test_the_acceleration_of_a_known_motion() -> None:
    """x = ½ a t² has acceleration a everywhere the difference reaches; the ends are unknown."""
    t_ns = _stamps(5.0)
    t = 1e-9 * t_ns
    p = np.stack([0.5 * 0.4 * t**2, 0.3 * t, np.zeros_like(t)], axis=1)
    a = true_acceleration(t_ns, p, step_s=0.25)
    k = 5  # 0.25 s at 20 Hz
    assert np.all(np.isnan(a[:k])) and np.all(np.isnan(a[-k:]))
    np.testing.assert_allclose(a[k:-k], 0.4, rtol=1e-9)


def test_still_and_constant_velocity_are_never_excited() -> None:
    """No acceleration: no onset, however long the recording (a start cannot be expected)."""
    t_ns = _stamps(20.0)
    t = 1e-9 * t_ns
    assert excitation_onset_s(t_ns, np.zeros((len(t), 3))) is None
    assert excitation_onset_s(t_ns, np.stack([0.5 * t, -0.2 * t, 0.1 * t], axis=1)) is None


def test_the_onset_is_where_the_motion_starts_to_accelerate() -> None:
    """Still for 4 s, then a swing of 0.5 m/s² amplitude: the onset lies within the window
    (1 s) before the swing's first frames and never before the rig could have moved."""
    t_ns = _stamps(12.0)
    t = 1e-9 * t_ns
    moving = np.clip(t - 4.0, 0.0, None)
    amplitude = 0.5 / (2 * math.pi * 0.5) ** 2  # 0.5 m/s² at 0.5 Hz
    p = np.stack([amplitude * (1.0 - np.cos(2 * math.pi * 0.5 * moving)), np.zeros_like(t), np.zeros_like(t)], axis=1)
    onset = excitation_onset_s(t_ns, p)
    assert onset is not None and 3.0 <= onset <= 4.5


def test_motion_capture_noise_does_not_look_like_excitation() -> None:
    """A rig at rest seen by a motion capture with 1 mm of noise per axis: no onset."""
    t_ns = _stamps(30.0)
    p = np.random.default_rng(0).normal(0.0, 0.001, (len(t_ns), 3))
    assert excitation_onset_s(t_ns, p) is None


def test_frames_without_ground_truth_are_skipped() -> None:
    """NaN rows (no ground truth) leave the acceleration unknown around them; the onset comes
    from the frames that have it, and none at all gives None."""
    t_ns = _stamps(10.0)
    t = 1e-9 * t_ns
    p = np.stack([0.5 * 0.6 * t**2, np.zeros_like(t), np.zeros_like(t)], axis=1)
    p[:60] = np.nan  # the first 3 s
    onset = excitation_onset_s(t_ns, p)
    assert onset is not None and math.isclose(onset, 2.25, abs_tol=1e-9)  # the first window that reaches a known acceleration (3.25 s)
    assert excitation_onset_s(t_ns, np.full((len(t_ns), 3), np.nan)) is None


def test_the_slow_start_scene_is_excited_only_after_its_still_seconds() -> None:
    """`slow-start` creeps for 3 s (millimetres per second) before its motion: its onset
    comes after them; `room` at half speed (about 0.05 m/s²) is never excited."""
    from backend.data.scenes import builtin_scene
    from backend.data.synthetic import SequenceSettings, SyntheticSequence

    for seed in (0, 1):
        seq = SyntheticSequence(builtin_scene("slow-start"), settings=SequenceSettings(seed=seed, duration_s=15.0))
        onset = excitation_onset_s(seq.timestamps_ns, seq.T_world_rect0[:, :3, 3])
        assert onset is not None and 2.5 <= onset <= 6.0
        slow = SyntheticSequence(builtin_scene("room"), settings=SequenceSettings(seed=seed, speed=0.5))
        assert excitation_onset_s(slow.timestamps_ns, slow.T_world_rect0[:, :3, 3]) is None
