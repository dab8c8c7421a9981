"""Plane instances of the geometric segmenter on the real EuRoC V1_01 pairs, as PNGs.

Reads `../shared/data/euroc_v101_pairs/ForLoopClosureDetector/` (next to the repository),
rectifies each pair, segments it and writes the left image with colour-overlaid instance
masks to `docs/segmentation/euroc_pair_{i}.png`. Prints per pair the instances' image share
and their normal's angle to the world's vertical (z up, from the ground-truth pose).

    .venv/bin/python scripts/segmentation_gallery.py
"""

from __future__ import annotations

import pathlib
import sys
import time

import cv2
import numpy as np

REPO = pathlib.Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from backend.data.calibration import read_camera_yaml, stereo_rectification
from backend.data.euroc import read_indexed_poses
from backend.frontend.segmentation import PlaneMasks
from backend.frontend.segmentation_geometric import GeometricPlaneSegmenter

PAIRS = REPO / ".." / "shared" / "data" / "euroc_v101_pairs" / "ForLoopClosureDetector"
PALETTE = np.array(
    [
        [230, 25, 75],
        [60, 180, 75],
        [255, 225, 25],
        [0, 130, 200],
        [245, 130, 48],
        [145, 30, 180],
        [70, 240, 240],
        [240, 50, 230],
        [210, 245, 60],
        [250, 190, 212],
        [0, 128, 128],
        [220, 190, 255],
        [170, 110, 40],
        [255, 250, 200],
        [128, 0, 0],
        [170, 255, 195],
    ],
    np.uint8,
)  # RGB


def overlay(image: np.ndarray, masks: PlaneMasks, *, alpha: float = 0.45) -> np.ndarray:
    """Grey image (H, W) with each instance tinted in its colour, RGB (H, W, 3)."""
    rgb = np.repeat(image[..., None], 3, axis=2).astype(np.float32)
    on = masks.labels >= 0
    rgb[on] = (1.0 - alpha) * rgb[on] + alpha * PALETTE[masks.labels[on] % len(PALETTE)]
    return rgb.astype(np.uint8)


def real_pairs():
    """(index, rectified left, rectified right, rectified camera, R_world_rect0) of each pair."""
    rect = stereo_rectification(read_camera_yaml(PAIRS / "sensorLeft.yaml"), read_camera_yaml(PAIRS / "sensorRight.yaml"))
    poses = read_indexed_poses(PAIRS / "groundtruth_from_openvins_original.txt")
    for i in sorted(poses):
        raw0 = cv2.imread(str(PAIRS / f"left_img_{i}.png"), cv2.IMREAD_GRAYSCALE)
        raw1 = cv2.imread(str(PAIRS / f"right_img_{i}.png"), cv2.IMREAD_GRAYSCALE)
        left, right = rect.rectify(raw0, raw1)
        yield i, left, right, rect.camera, (poses[i] @ rect.T_body_rect0)[:3, :3]


def main() -> int:
    if not PAIRS.is_dir():
        print(f"no EuRoC pairs at {PAIRS}", file=sys.stderr)
        return 2
    rect = stereo_rectification(read_camera_yaml(PAIRS / "sensorLeft.yaml"), read_camera_yaml(PAIRS / "sensorRight.yaml"))
    poses = read_indexed_poses(PAIRS / "groundtruth_from_openvins_original.txt")
    segmenter = GeometricPlaneSegmenter()
    out = REPO / "docs" / "segmentation"
    out.mkdir(parents=True, exist_ok=True)
    for i in sorted(poses):
        raw0 = cv2.imread(str(PAIRS / f"left_img_{i}.png"), cv2.IMREAD_GRAYSCALE)
        raw1 = cv2.imread(str(PAIRS / f"right_img_{i}.png"), cv2.IMREAD_GRAYSCALE)
        left, right = rect.rectify(raw0, raw1)
        start = time.perf_counter()
        masks = segmenter.segment(left, right, rect.camera)
        ms = (time.perf_counter() - start) * 1e3
        R_world_rect0 = (poses[i] @ rect.T_body_rect0)[:3, :3]
        tilt = [np.degrees(np.arccos(min(1.0, abs(float((R_world_rect0 @ n)[2]))))) for n in masks.normals_camera]
        summary = ", ".join(f"{f:.0%} at {t:.0f}° from vertical" for f, t in zip(masks.fractions(), tilt))
        print(f"pair {i}: {masks.count} planes in {ms:.0f} ms: {summary}")
        cv2.imwrite(str(out / f"euroc_pair_{i}.png"), cv2.cvtColor(overlay(left, masks), cv2.COLOR_RGB2BGR))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
