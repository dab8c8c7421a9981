"""Plausibility checks of a recorded input, with reasons (DESIGN §8, issue 29): what a file
can say that no parser rejects and that would make a run silently wrong. A finding that
makes the data unusable is a one-line DatasetError naming the file (exit code 2); one where
the data may still be usable is a one-line warning, which the run prints and writes to
`metrics.json` (`warnings`).

- The cameras (`check_calibration`, before rectifying): the field of view the focal length
  gives, the principal point inside the image, a radial distortion that folds the image or
  moves its corners by more than they are, and the stereo baseline (a `T_BS` in millimetres
  gives one of metres).
- The stereo pairs (`check_pairs`, on a few pairs of the first frames): cam0 and cam1
  swapped (matched features lie to the right in cam0: negative disparity) or out of step
  (matches disagree in their row: a pair taken at two instants, or a wrong rectification).
- The ground truth (`check_ground_truth`): how much of the frames' time it covers, so that
  a clock offset reads as one, not as "no ground truth"; after a run
  (`ground_truth_scale_warning`), a Sim(3) scale far from 1 between the metric stereo
  estimate and the ground truth (positions in millimetres).
- The IMU (`check_imu`, where VIO uses it): the accelerometer's mean magnitude against
  gravity (samples in g or cm/s²) and gyro rates no body reaches in rad/s (deg/s).

The thresholds are physical or a factor of two or more from what correct data give; the
pair checks were set on the MH_01 slice (correct: median row difference 0.0-0.4 px, cam1 one
frame late: 0.5-10 px, swapped: 100 % negative disparity) and hold on the rendered scenes
(0.0 px correct, 1.2-10 px one frame late).
"""

from __future__ import annotations

import dataclasses
import math
import pathlib
from typing import Any

import numpy as np

from backend.data.calibration import CameraCalibration, CameraModel
from backend.data.errors import DatasetError
from backend.geometry.camera import PinholeCamera

#: Widest horizontal field of view of a pinhole (radial-tangential) lens, and of a fisheye.
MAX_FOV_PINHOLE_DEG = 170.0
MAX_FOV_FISHEYE_DEG = 240.0
#: Narrowest field of view accepted (a focal length in the wrong unit: 1 px per metre ...).
MIN_FOV_DEG = 1.0
#: Stereo baselines in metres: shorter is one camera twice, longer a unit mistake.
MIN_BASELINE_M, MAX_BASELINE_M = 0.005, 5.0
#: The radial distortion may move the image's corners by at most this factor in or out.
MAX_CORNER_DISTORTION = 2.0
#: Pair checks: how many pairs of the first frames, matches needed, thresholds.
PAIR_SAMPLES, PAIR_SPAN, MIN_MATCHES = 6, 200, 20
MAX_ROW_DIFFERENCE_PX = 0.75
SWAPPED_FRACTION = 0.5
#: Ground truth: below this share of frames covered, a warning says how much.
MIN_COVERED = 0.5
#: A Sim(3) scale between the stereo estimate and the ground truth outside this range.
SCALE_RANGE = (0.5, 2.0)
#: IMU: the accelerometer's median magnitude (m/s²) and the largest plausible rotation rate.
GRAVITY_RANGE_M_S2 = (6.0, 14.0)
MAX_GYRO_RAD_S = 20.0


def check_calibration(cam0: CameraCalibration, cam1: CameraCalibration) -> None:
    """DatasetError (naming the camera's file) for intrinsics or extrinsics no camera has."""
    for cam in (cam0, cam1):
        _check_intrinsics(cam)
    baseline = float(np.linalg.norm(cam0.T_body_camera[:3, 3] - cam1.T_body_camera[:3, 3]))
    if not MIN_BASELINE_M <= baseline <= MAX_BASELINE_M:
        hint = " (T_BS translations in millimetres? they are metres)" if baseline > MAX_BASELINE_M else " (the same camera twice?)"
        raise DatasetError(cam1.source or "cam1", f"stereo baseline {baseline:.4g} m from the cameras' T_BS, outside [{MIN_BASELINE_M:g}, {MAX_BASELINE_M:g}] m{hint}")


def check_rectified_camera(camera: PinholeCamera, *, where: pathlib.Path | str) -> None:
    """DatasetError (naming `where`, the calibration file) for a rectified stereo camera (as
    KITTI's calib.txt gives it: P0's intrinsics, the baseline from P1) that no camera has:
    the same field-of-view, principal-point and baseline limits as :func:`check_calibration`."""
    _check_pinhole(camera.fx, camera.fy, camera.cx, camera.cy, camera.width, camera.height, widest=MAX_FOV_PINHOLE_DEG, fisheye=False, where=where, names=("P0 fx", "P0 fy"))
    if not MIN_BASELINE_M <= camera.baseline <= MAX_BASELINE_M:
        hint = " (P1[0,3] in millimetres? -P1[0,3] is fx times the baseline in metres)" if camera.baseline > MAX_BASELINE_M else " (the same camera twice?)"
        raise DatasetError(where, f"stereo baseline {camera.baseline:.4g} m (-P1[0,3] / P1[0,0]), outside [{MIN_BASELINE_M:g}, {MAX_BASELINE_M:g}] m{hint}")


def _check_intrinsics(cam: CameraCalibration) -> None:
    where = cam.source or "the camera calibration"
    fisheye = cam.model is CameraModel.EQUIDISTANT
    widest = MAX_FOV_FISHEYE_DEG if fisheye else MAX_FOV_PINHOLE_DEG
    _check_pinhole(cam.fx, cam.fy, cam.cx, cam.cy, cam.width, cam.height, widest=widest, fisheye=fisheye, where=where, names=("fu", "fv"))
    if cam.model is CameraModel.RADIAL_TANGENTIAL:
        _check_radial(cam, where)


def _check_pinhole(fx: float, fy: float, cx: float, cy: float, width: int, height: int, *, widest: float, fisheye: bool, where: pathlib.Path | str, names: tuple[str, str]) -> None:
    """The field of view each focal length (px) gives over the image, and the principal
    point (px) inside it."""
    for f, size, axis in ((fx, width, names[0]), (fy, height, names[1])):
        fov = math.degrees(size / f) if fisheye else math.degrees(2.0 * math.atan2(0.5 * size, f))
        if not MIN_FOV_DEG <= fov <= widest:
            raise DatasetError(where, f"focal length {axis} = {f:g} px gives a {fov:.1f}° field of view over {size} px (expected {MIN_FOV_DEG:g}-{widest:g}°): intrinsics in another unit?")
    if not (0.0 <= cx <= width and 0.0 <= cy <= height):
        raise DatasetError(where, f"principal point ({cx:g}, {cy:g}) px lies outside the {width}x{height} image")


def _check_radial(cam: CameraCalibration, where: str) -> None:
    """The radial-tangential model's radial part over the image: `r_d = r (1 + k1 r² + k2 r⁴
    [+ k3 r⁶])` must grow with `r` (else the image folds onto itself) and keep the corners
    within a factor MAX_CORNER_DISTORTION of where a pinhole puts them."""
    d = np.asarray(cam.distortion, float)
    k = [d[0], d[1], d[4] if d.shape[0] > 4 else 0.0]
    corners = np.array([[0, 0], [cam.width, 0], [0, cam.height], [cam.width, cam.height]], float)
    r_corner = float(np.max(np.hypot((corners[:, 0] - cam.cx) / cam.fx, (corners[:, 1] - cam.cy) / cam.fy)))
    r = np.linspace(0.0, r_corner, 200)
    slope = 1.0 + 3.0 * k[0] * r**2 + 5.0 * k[1] * r**4 + 7.0 * k[2] * r**6
    if np.any(slope <= 0.0):
        fold = float(r[np.argmax(slope <= 0.0)])
        raise DatasetError(where, f"distortion coefficients {d.tolist()} fold the image onto itself {100 * fold / r_corner:.0f} % of the way to its corners")
    factor = 1.0 + k[0] * r_corner**2 + k[1] * r_corner**4 + k[2] * r_corner**6
    if not 1.0 / MAX_CORNER_DISTORTION <= factor <= MAX_CORNER_DISTORTION:
        raise DatasetError(where, f"distortion coefficients {d.tolist()} move the image's corners by a factor {factor:.3g} (no lens does: coefficients in another convention?)")


def check_pairs(source: Any, *, where: str) -> list[str]:
    """A few rectified pairs of the first frames, matched (ORB): DatasetError when cam0 and
    cam1 look swapped (negative disparities; or, where the pairs' rows disagree, rows that
    agree once the raw images are exchanged), a warning when their rows disagree (out of
    step or misrectified). `where` names the input in the messages."""
    n = len(source)
    if n == 0:
        return []
    indices = sorted(set(np.linspace(0, min(n, PAIR_SPAN) - 1, PAIR_SAMPLES).astype(int).tolist()))
    given = _pair_figures([source.rectified_pair(i) for i in indices])
    if given.row_px is None:
        return []
    if given.negative_share > SWAPPED_FRACTION:
        share = 100 * given.negative_share
        raise DatasetError(where, f"{share:.0f} % of the features matched in the first stereo pairs lie farther right in cam0 than in cam1 (negative disparity): cam0 and cam1 swapped?")
    if given.row_px <= MAX_ROW_DIFFERENCE_PX:
        return []
    exchanged = _exchanged_pairs(source, indices)
    if exchanged is not None:
        other = _pair_figures(exchanged)
        if other.row_px is not None and other.row_px <= MAX_ROW_DIFFERENCE_PX and other.negative_share < SWAPPED_FRACTION:
            raise DatasetError(
                where,
                f"the first stereo pairs' rows disagree by a median of {given.row_px:.1f} px, and by {other.row_px:.1f} px with cam0's and cam1's images exchanged: cam0 and cam1 swapped?",
            )
    return [
        f"{where}: features matched in the first stereo pairs differ by a median of {given.row_px:.1f} px in their row (under {MAX_ROW_DIFFERENCE_PX:g} px in "
        "synchronized, well rectified pairs): cam1's images out of step with cam0's, or a wrong calibration; tracking and depth suffer"
    ]


@dataclasses.dataclass(frozen=True)
class _PairFigures:
    """Over sampled pairs: the median of each pair's median row difference (px; None: too
    few matches) and, over pairs whose rows agree, the share of negative disparities."""

    row_px: float | None
    negative_share: float


def _pair_figures(pairs: list[tuple[np.ndarray, np.ndarray]]) -> _PairFigures:
    import cv2

    orb = cv2.ORB_create(1000)  # type: ignore[attr-defined]  # not in OpenCV's stubs
    matcher = cv2.BFMatcher(cv2.NORM_HAMMING, crossCheck=True)
    rows, negative, consistent = [], 0, 0
    for left, right in pairs:
        p_left, p_right = _matches(orb, matcher, left, right)
        if p_left.shape[0] < MIN_MATCHES:
            continue
        dy = p_left[:, 1] - p_right[:, 1]
        dx = p_left[:, 0] - p_right[:, 0]
        rows.append(float(np.median(np.abs(dy))))
        if rows[-1] <= MAX_ROW_DIFFERENCE_PX:  # a pair taken at one instant: its disparities' sign counts
            on_row = np.abs(dy) < 2.0
            negative += int(np.sum(dx[on_row] < -0.5))
            consistent += int(np.sum(on_row))
    share = negative / consistent if consistent >= MIN_MATCHES else 0.0
    return _PairFigures(row_px=float(np.median(rows)) if rows else None, negative_share=share)


def _exchanged_pairs(source: Any, indices: list[int]) -> list[tuple[np.ndarray, np.ndarray]] | None:
    """The sampled pairs rectified with cam0's and cam1's raw images exchanged (None where
    the source has no raw images and rectification maps: already rectified inputs)."""
    import cv2

    maps = getattr(getattr(source, "rectification", None), "maps", None)
    if maps is None or not hasattr(source, "raw_pair"):
        return None
    x0, y0, x1, y1 = maps
    out = []
    for i in indices:
        raw0, raw1 = source.raw_pair(i)
        out.append((cv2.remap(raw1, x0, y0, cv2.INTER_LINEAR), cv2.remap(raw0, x1, y1, cv2.INTER_LINEAR)))
    return out


def _matches(orb: Any, matcher: Any, left: np.ndarray, right: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Cross-checked ORB matches (Hamming distance under 40) as pixel positions (M, 2) each."""
    kl, dl = orb.detectAndCompute(left, None)
    kr, dr = orb.detectAndCompute(right, None)
    if dl is None or dr is None:
        return np.zeros((0, 2)), np.zeros((0, 2))
    good = [m for m in matcher.match(dl, dr) if m.distance < 40]
    return np.array([kl[m.queryIdx].pt for m in good]).reshape(-1, 2), np.array([kr[m.trainIdx].pt for m in good]).reshape(-1, 2)


def check_ground_truth(timestamps_ns: np.ndarray, truth_ns: np.ndarray | None, valid: np.ndarray, *, where: str) -> list[str]:
    """Warnings when a ground-truth file covers none or under half of the frames: its time
    span against the frames', so that a clock offset shows as one."""
    if truth_ns is None or truth_ns.shape[0] == 0 or timestamps_ns.shape[0] == 0:
        return []
    share = float(np.mean(valid))
    if share >= MIN_COVERED:
        return []
    t0 = float(timestamps_ns[0]) * 1e-9
    first, last, end = float(truth_ns[0]) * 1e-9 - t0, float(truth_ns[-1]) * 1e-9 - t0, float(timestamps_ns[-1]) * 1e-9 - t0
    span = f"the ground truth spans {first:+.1f} to {last:+.1f} s from the first frame, the frames 0 to {end:.1f} s"
    if share == 0.0:
        return [f"{where}: the ground truth overlaps none of the frames ({span}): a clock offset? No trajectory error can be computed"]
    return [f"{where}: the ground truth covers {100 * share:.0f} % of the frames ({span}); the trajectory error is over those only"]


def ground_truth_scale_warning(p_estimate: np.ndarray, p_truth: np.ndarray, *, stereo: bool) -> str | None:
    """A warning when the ground truth's size differs from the estimate's (metres, metric in
    stereo) by more than `SCALE_RANGE` allows: the ground truth in another unit."""
    ok = np.all(np.isfinite(p_estimate), axis=1) & np.all(np.isfinite(p_truth), axis=1)
    if ok.sum() < 3 or not stereo:
        return None
    estimate, truth = p_estimate[ok], p_truth[ok]
    spread = float(np.sqrt(np.mean(np.sum((estimate - estimate.mean(axis=0)) ** 2, axis=1))))
    if spread < 0.02:  # too little motion to tell a scale
        return None
    # The similarity's scale up to the fit's quality: the ratio of the two paths' spreads
    # about their centroids (Umeyama's scale when the shapes agree; a unit slip is 10-1000).
    scale = float(np.sqrt(np.mean(np.sum((truth - truth.mean(axis=0)) ** 2, axis=1)))) / spread
    if SCALE_RANGE[0] <= scale <= SCALE_RANGE[1]:
        return None
    unit = " (in millimetres?)" if 300 < scale < 3000 else " (in centimetres?)" if 30 < scale < 300 else ""
    return f"the ground truth is {scale:.4g} times the metric stereo trajectory in size{unit}: its positions are not in metres, so the trajectory errors (ATE, RMSE) compare different units"


def check_imu(timestamp_ns: np.ndarray, gyro: np.ndarray, accel: np.ndarray, *, where: str) -> None:
    """DatasetError when the IMU's samples are not in m/s² and rad/s: the accelerometer's
    median magnitude far from gravity (samples in g, or cm/s²), or rotation rates beyond
    what a moving body reaches (deg/s)."""
    if timestamp_ns.shape[0] < 10:
        return
    g = float(np.median(np.linalg.norm(accel, axis=1)))
    if not GRAVITY_RANGE_M_S2[0] <= g <= GRAVITY_RANGE_M_S2[1]:
        unit = " (in g?)" if 0.6 < g < 1.4 else " (in cm/s²?)" if 600 < g < 1400 else ""
        raise DatasetError(where, f"the accelerometer's median magnitude is {g:.4g}, not gravity's 9.81 m/s² within [{GRAVITY_RANGE_M_S2[0]:g}, {GRAVITY_RANGE_M_S2[1]:g}]{unit}")
    w = float(np.percentile(np.linalg.norm(gyro, axis=1), 99))
    if w > MAX_GYRO_RAD_S:
        raise DatasetError(where, f"the gyroscope's rates reach {w:.4g} (99th percentile), beyond the {MAX_GYRO_RAD_S:g} rad/s a moving body reaches: degrees per second?")
