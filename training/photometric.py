"""Photometric augmentation of the segmenter's training batches (training time only; numpy
and OpenCV, no torch).

Real cameras differ from the renderer in tone curve, focus, noise and fall-off towards the
image corners; `augment` draws each of these per image, on the network's input (intensity
0–1, `INPUT_H` × `INPUT_W` pixels).
"""

from __future__ import annotations

import dataclasses

import cv2
import numpy as np


@dataclasses.dataclass(frozen=True)
class Photometric:
    """Strengths of the augmentation (0 turns one off).

    gamma: the tone curve x**g with g drawn log-uniform from exp(±gamma).
    blur_px: Gaussian blur with sigma drawn from 0–blur_px input pixels (half the images).
    noise: additive Gaussian noise with sigma drawn from 0–noise (intensity units).
    vignette: fall-off x * (1 - k r²) with k drawn from 0–vignette, r the distance from a
        centre near the image's, in half-diagonals; plus a linear illumination ramp of
        the same strength in a random direction.
    """

    gamma: float = 0.3
    blur_px: float = 1.2
    noise: float = 0.03
    vignette: float = 0.5


def _falloff(b: int, h: int, w: int, rng: np.random.Generator, strength: float) -> np.ndarray:
    """(b, h, w) gains: radial vignetting around a jittered centre times a linear ramp,
    drawn per image."""
    yy = (np.arange(h, dtype=np.float32) / h - 0.5)[None, :, None]  # -0.5..0.5 of the height
    xx = (np.arange(w, dtype=np.float32) / w - 0.5)[None, None, :]
    cy, cx = (rng.uniform(-0.1, 0.1, (b, 1, 1)).astype(np.float32) for _ in range(2))
    r2 = ((yy - cy) ** 2 * h**2 + (xx - cx) ** 2 * w**2) / ((h / 2) ** 2 + (w / 2) ** 2)  # in half-diagonals²
    k = rng.uniform(0.0, strength, (b, 1, 1)).astype(np.float32)
    angle = rng.uniform(0, 2 * np.pi, (b, 1, 1)).astype(np.float32)
    ramp = (np.cos(angle) * xx + np.sin(angle) * yy) * rng.uniform(0.0, strength, (b, 1, 1)).astype(np.float32)
    return np.clip((1.0 - k * r2) * (1.0 + ramp), 0.2, 1.5)


def augment(x: np.ndarray, rng: np.random.Generator, settings: Photometric) -> np.ndarray:
    """Augmented copy of a batch `x` (B, H, W) float32 in 0–1, each image drawn on its
    own from `rng`; the result is clipped to 0–1."""
    b, h, w = x.shape
    y = x.astype(np.float32, copy=True)
    if settings.vignette > 0:
        y *= _falloff(b, h, w, rng, settings.vignette)
    if settings.gamma > 0:
        y = np.clip(y, 0.0, 1.0) ** np.exp(rng.uniform(-settings.gamma, settings.gamma, (b, 1, 1))).astype(np.float32)
    if settings.blur_px > 0:
        for i in np.flatnonzero(rng.random(b) < 0.5):
            y[i] = cv2.GaussianBlur(y[i], (0, 0), float(rng.uniform(0.3, settings.blur_px)))
    if settings.noise > 0:
        y += rng.standard_normal(y.shape, dtype=np.float32) * rng.uniform(0.0, settings.noise, (b, 1, 1)).astype(np.float32)
    return np.clip(y, 0.0, 1.0)
