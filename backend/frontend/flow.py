"""Features followed from frame to frame by pyramidal Lucas-Kanade optical flow (OpenCV),
with a forward-backward check: the VIO's start follows its first keyframe's features this
way, and until the initialization it follows the candidate features of later keyframes
(`FlowTracks`) to triangulate them once they have parallax (VINS-Mono's front end).
"""

from __future__ import annotations

import dataclasses
from typing import TypedDict

import cv2
import numpy as np

from backend.geometry.camera import PinholeCamera


class _LkParams(TypedDict):
    """The pyramidal Lucas-Kanade settings, typed so that `**_LK` meets OpenCV's keywords."""

    winSize: tuple[int, int]
    maxLevel: int
    criteria: tuple[int, int, float]


_LK: _LkParams = dict(winSize=(21, 21), maxLevel=3, criteria=(cv2.TERM_CRITERIA_EPS | cv2.TERM_CRITERIA_COUNT, 30, 0.01))
GAIN_TOLERANCE = 0.1  # relative: a brightness change between two images beyond this is undone before the flow


def gain_ratio(image_reference: np.ndarray, image: np.ndarray) -> float:
    """The exposure gain that takes `image` to `image_reference` (both 8-bit grey, same
    size, consecutive frames): the median over 16×16-pixel blocks of the ratio of their
    mean grey levels, blocks with a saturated (≥ 250) or black (≤ 5) pixel in either image
    left out; 1 when fewer than 20 blocks are left. Block by block, not one ratio of whole-image
    statistics: on real EuRoC frames the content moving through the view shifts the
    image's median by 13 % where the exposure did not change (MH_01 frame 18)."""
    h, w = image.shape[:2]
    size = (max(w // 16, 1), max(h // 16, 1))
    blocks_reference = cv2.resize(image_reference, size, interpolation=cv2.INTER_AREA).astype(np.float32)
    blocks = cv2.resize(image, size, interpolation=cv2.INTER_AREA).astype(np.float32)
    clipped = (image_reference >= 250) | (image >= 250) | (image_reference <= 5) | (image <= 5)
    clean = cv2.resize(clipped.astype(np.float32), size, interpolation=cv2.INTER_AREA) == 0
    clean &= (blocks_reference > 10) & (blocks > 10)
    if int(clean.sum()) < 20:
        return 1.0
    return float(np.median(blocks_reference[clean] / blocks[clean]))


def gain_matched(image_reference: np.ndarray, image: np.ndarray, *, tolerance: float = GAIN_TOLERANCE) -> np.ndarray:
    """`image` (8-bit grey) at `image_reference`'s exposure: scaled by :func:`gain_ratio` when
    that is more than `tolerance` (relative) away from 1, else `image` itself.

    Lucas-Kanade assumes a pixel keeps its grey level; an auto-exposure step breaks that for
    every window at once (the `exposure` scene's 1.45× step at 1.5 s, after which 48 % of
    the pixels are saturated: 128 of 300 corners followed instead of 245 with the gain undone).
    Real cameras step too: EuRoC MH_01's auto-exposure changes the gain by 12-29 % between
    some of its first frames. Below the tolerance the flow copes by itself (ramps of 2-7 %
    a frame) and the images are left exactly as they are."""
    ratio = gain_ratio(image_reference, image)
    if abs(ratio - 1.0) <= tolerance:
        return image
    return cv2.convertScaleAbs(image, alpha=ratio)


def follow(
    image_prev: np.ndarray,
    image: np.ndarray,
    uv_prev: np.ndarray,
    camera: PinholeCamera,
    *,
    R_prev_cur: np.ndarray | None = None,
    uv_guess: np.ndarray | None = None,
    max_back_px: float = 0.5,
) -> tuple[np.ndarray, np.ndarray]:
    """Pixels `uv_prev` (N, 2) of `image_prev` followed into `image` (both 8-bit grey, same
    size). `R_prev_cur` (3, 3), the rotation of the current camera in the previous one (from
    the gyroscope), starts the flow where that rotation alone moves each pixel (as
    VINS-Fusion does): at 5° per frame (`boxes` at 2× speed) plain pyramidal flow keeps 34-73 %
    of the features from one frame to the next, started from the rotation 81-89 %. Returns the followed pixels
    (N, 2) and whether each was found (forward and backward flow converged, the backward flow
    returns within `max_back_px` pixels, inside the image). `uv_guess` (N, 2), where given
    instead of `R_prev_cur`, starts each pixel's flow there (NaN rows: at its own pixel; e.g.
    where a predicted pose puts a point of known depth). A change of exposure between the
    two images beyond `GAIN_TOLERANCE` is undone first (:func:`gain_matched`)."""
    if len(uv_prev) == 0:
        return np.zeros((0, 2)), np.zeros(0, bool)
    image = gain_matched(image_prev, image)
    p0 = uv_prev.astype(np.float32).reshape(-1, 1, 2)
    if uv_guess is None and R_prev_cur is not None:
        rays = camera.normalize(uv_prev) @ R_prev_cur
        ahead = rays[:, 2] > 0.1
        uv_guess = np.full((len(uv_prev), 2), np.nan)
        uv_guess[ahead] = camera.project(rays[ahead])
    if uv_guess is None:
        p1, st, _ = cv2.calcOpticalFlowPyrLK(image_prev, image, p0, None, **_LK)  # type: ignore[call-overload]  # OpenCV's stubs: nextPts may be None (an output)
    else:
        start = np.where(np.all(np.isfinite(uv_guess), axis=1)[:, None], uv_guess, uv_prev).astype(np.float32).reshape(-1, 1, 2)
        p1, st, _ = cv2.calcOpticalFlowPyrLK(image_prev, image, p0, start, flags=cv2.OPTFLOW_USE_INITIAL_FLOW, **_LK)
    back, st_b, _ = cv2.calcOpticalFlowPyrLK(image, image_prev, p1, p0.copy(), flags=cv2.OPTFLOW_USE_INITIAL_FLOW, **_LK)
    uv = p1.reshape(-1, 2).astype(float)
    ok = (st.ravel() == 1) & (st_b.ravel() == 1) & (np.linalg.norm((back - p0).reshape(-1, 2), axis=1) < max_back_px)
    ok &= np.all(np.isfinite(uv), axis=1) & camera.in_image(uv)
    return uv, ok


def follow_along_row(
    left: np.ndarray,
    right: np.ndarray,
    uv_left: np.ndarray,
    camera: PinholeCamera,
    *,
    min_disparity_px: float,
    max_disparity_px: float,
    half_window_px: int = 5,
    min_score: float = 0.7,
    uniqueness: float = 0.05,
    max_back_px: float = 0.5,
) -> tuple[np.ndarray, np.ndarray]:
    """Pixels `uv_left` (N, 2) of the rectified `left` image found in `right` (both 8-bit grey,
    same size): a search along the pixel's row over disparities [`min_disparity_px`,
    `max_disparity_px`] (normalized cross-correlation of a (2·`half_window_px` + 1)² patch;
    the best score at least `min_score` and above every score more than 2 px from it by
    `uniqueness`: an edge along the row or a repeated pattern has no one disparity), then
    Lucas-Kanade from there for the sub-pixel position, forward-backward checked within
    `max_back_px`. Pyramidal flow started at zero disparity, as `follow` does, converges on
    the wrong grain of a bare wall where the disparity is tens of pixels (`low-texture` seed 3:
    the median disparity found 0.3-5 px where the truth is ~33). Returns the pixels in
    `right` (N, 2) and whether each was found."""
    n = len(uv_left)
    uv_right = np.full((n, 2), np.nan)
    found = np.zeros(n, bool)
    if n == 0:
        return uv_right, found
    h = int(half_window_px)
    height, width = left.shape[:2]
    d_min = max(0, int(np.floor(min_disparity_px)))
    d_max = int(np.ceil(max_disparity_px))
    guess = np.full((n, 2), np.nan, np.float32)
    for j, (u, v) in enumerate(np.rint(uv_left).astype(np.int64)):
        if not (h <= v < height - h and h <= u < width - h):
            continue
        lo = max(h, u - d_max)  # leftmost centre in the right image
        hi = u - d_min  # rightmost centre
        if hi - lo < 1:
            continue
        template = left[v - h : v + h + 1, u - h : u + h + 1]
        strip = right[v - h : v + h + 1, lo - h : hi + h + 1]
        score = cv2.matchTemplate(strip, template, cv2.TM_CCOEFF_NORMED).ravel()  # centre lo + k
        if not np.all(np.isfinite(score)):
            continue  # a flat patch: no correlation
        best = int(np.argmax(score))
        far = np.abs(np.arange(len(score)) - best) > 2
        if score[best] < min_score or (np.any(far) and score[far].max() > score[best] - uniqueness):
            continue
        guess[j] = (lo + best + (uv_left[j, 0] - u), uv_left[j, 1])
    ok = np.all(np.isfinite(guess), axis=1)
    if not ok.any():
        return uv_right, found
    p0 = uv_left[ok].astype(np.float32).reshape(-1, 1, 2)
    params: _LkParams = {**_LK, "maxLevel": 1}  # the search is within a pixel: no pyramid to jump from
    p1, st, _ = cv2.calcOpticalFlowPyrLK(left, right, p0, guess[ok].reshape(-1, 1, 2), flags=cv2.OPTFLOW_USE_INITIAL_FLOW, **params)
    back, st_b, _ = cv2.calcOpticalFlowPyrLK(right, left, p1, p0.copy(), flags=cv2.OPTFLOW_USE_INITIAL_FLOW, **params)
    uv = p1.reshape(-1, 2).astype(float)
    good = (st.ravel() == 1) & (st_b.ravel() == 1) & (np.linalg.norm((back - p0).reshape(-1, 2), axis=1) < max_back_px)
    good &= np.all(np.isfinite(uv), axis=1) & camera.in_image(uv)
    idx = np.flatnonzero(ok)
    uv_right[idx[good]] = uv[good]
    found[idx[good]] = True
    return uv_right, found


@dataclasses.dataclass(frozen=True, eq=False)
class FlowTracks:
    """Candidate features followed since the keyframe that detected them: `anchor` (N,)
    keyframe index, `anchor_kp` (N,) their keypoint index there, `uv_anchor` (N, 2) their
    pixel there, `uv` (N, 2) their pixel in the last frame followed."""

    anchor: np.ndarray
    anchor_kp: np.ndarray
    uv_anchor: np.ndarray
    uv: np.ndarray

    @staticmethod
    def empty() -> FlowTracks:
        return FlowTracks(np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros((0, 2)), np.zeros((0, 2)))

    def __len__(self) -> int:
        return len(self.anchor)

    def subset(self, keep: np.ndarray) -> FlowTracks:
        return FlowTracks(self.anchor[keep], self.anchor_kp[keep], self.uv_anchor[keep], self.uv[keep])

    def followed(self, uv: np.ndarray, ok: np.ndarray) -> FlowTracks:
        """The tracks found in the next frame, at their new pixels."""
        return FlowTracks(self.anchor[ok], self.anchor_kp[ok], self.uv_anchor[ok], uv[ok])

    def seeded(self, k: int, uv: np.ndarray, kp_index: np.ndarray, *, min_distance_px: float, max_tracks: int) -> FlowTracks:
        """New tracks at keyframe k from its candidate keypoints (pixels `uv` (M, 2), indices
        `kp_index` (M,)), in order, each at least `min_distance_px` from every track and earlier
        candidate, up to `max_tracks` tracks in all."""
        room = max_tracks - len(self)
        if room <= 0 or len(uv) == 0:
            return self
        chosen = []
        cell = max(min_distance_px, 1.0)
        grid: dict[tuple[int, int], list[np.ndarray]] = {}
        for p in self.uv:
            grid.setdefault((int(p[0] // cell), int(p[1] // cell)), []).append(p)
        for j, p in enumerate(uv):
            cx, cy = int(p[0] // cell), int(p[1] // cell)
            near = [q for dx in (-1, 0, 1) for dy in (-1, 0, 1) for q in grid.get((cx + dx, cy + dy), ())]
            if near and min(float(np.hypot(*(q - p))) for q in near) < min_distance_px:
                continue
            grid.setdefault((cx, cy), []).append(p)
            chosen.append(j)
            if len(chosen) >= room:
                break
        if not chosen:
            return self
        sel = np.asarray(chosen, np.int64)
        return FlowTracks(
            np.concatenate([self.anchor, np.full(len(sel), k, np.int64)]),
            np.concatenate([self.anchor_kp, np.asarray(kp_index, np.int64)[sel]]),
            np.concatenate([self.uv_anchor, uv[sel]]),
            np.concatenate([self.uv, uv[sel]]),
        )
