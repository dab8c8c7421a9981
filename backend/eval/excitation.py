"""When a recording first moves enough for a VIO start to see its scale: the *excitation
onset*, from the ground-truth positions (rendered scenes, or a dataset's motion capture).

A monocular VIO learns its metric scale from the accelerometer: with the rig nearly still
or at constant velocity, nothing tells the scale, and any start must wait. VINS-Mono judges
the excitation by the spread of the accelerometer's mean over the frames of its window and
warns below 0.25 m/s². The onset here is the same threshold applied to the true motion:
the first frame from which the magnitude of the true acceleration (world frame, gravity
removed, m/s²), averaged over the next `window_s` seconds, reaches `threshold_mps2`. The
acceleration is the central second difference of the positions `step_s` apart (smooth
enough for millimetre motion-capture noise: 2 mm over 0.25 s gives 0.06 m/s²).

A pure function of arrays (no files); the VIO goals of the robustness sweep time the start
from it (`scripts/robustness_table.py`)."""

from __future__ import annotations

import numpy as np

VINS_MONO_EXCITATION_MPS2 = 0.25  # m/s², VINS-Mono's "IMU excitation not enough" threshold


def true_acceleration(timestamps_ns: np.ndarray, p_world: np.ndarray, *, step_s: float = 0.25) -> np.ndarray:
    """(N,) magnitude of the acceleration (m/s²) at each of N frames from the positions
    `p_world` (N, 3) metres at `timestamps_ns` (N,) (rows with NaN: unknown), by the central
    second difference over the frames about `step_s` before and after (the mean frame period
    sets how many frames that is); NaN where a neighbour is missing or unknown."""
    t = np.asarray(timestamps_ns, dtype=np.int64)
    p = np.asarray(p_world, dtype=float)
    n = len(t)
    out = np.full(n, np.nan)
    if n < 3:
        return out
    period_s = 1e-9 * float(t[-1] - t[0]) / (n - 1)
    k = max(1, round(step_s / period_s)) if period_s > 0 else 1
    if n <= 2 * k:
        return out
    h_before = 1e-9 * (t[k:-k] - t[: -2 * k]).astype(float)
    h_after = 1e-9 * (t[2 * k :] - t[k:-k]).astype(float)
    # Second derivative for uneven steps: 2 [(p+ - p)/h+ - (p - p-)/h-] / (h+ + h-)
    with np.errstate(invalid="ignore", divide="ignore"):
        a = 2.0 * ((p[2 * k :] - p[k:-k]) / h_after[:, None] - (p[k:-k] - p[: -2 * k]) / h_before[:, None]) / (h_before + h_after)[:, None]
    out[k:-k] = np.linalg.norm(a, axis=1)
    return out


def excitation_onset_s(
    timestamps_ns: np.ndarray,
    p_world: np.ndarray,
    *,
    threshold_mps2: float = VINS_MONO_EXCITATION_MPS2,
    window_s: float = 1.0,
    step_s: float = 0.25,
) -> float | None:
    """Seconds from the first frame to the excitation onset (module docstring): the first
    frame whose following `window_s` seconds have a mean true acceleration of at least
    `threshold_mps2` m/s² (frames without an acceleration are skipped in the mean). None when
    the recording never moves that much (a VIO start cannot be expected) or has no usable
    ground truth."""
    t = np.asarray(timestamps_ns, dtype=np.int64)
    a = true_acceleration(t, p_world, step_s=step_s)
    known = np.isfinite(a)
    if not known.any():
        return None
    window_ns = int(round(window_s * 1e9))
    csum = np.concatenate([[0.0], np.cumsum(np.where(known, a, 0.0))])
    ccount = np.concatenate([[0], np.cumsum(known)])
    end = np.searchsorted(t, t + window_ns, side="right")
    count = ccount[end] - ccount[:-1]  # the frames with an acceleration in each frame's window
    with np.errstate(invalid="ignore", divide="ignore"):
        mean = (csum[end] - csum[:-1]) / count
    excited = np.flatnonzero((count > 0) & (mean >= threshold_mps2))
    if len(excited) == 0:
        return None
    return 1e-9 * float(t[excited[0]] - t[0])
