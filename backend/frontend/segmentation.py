"""Plane-instance segmentation: the interface every segmenter implements.

A segmenter takes a rectified stereo pair (left camera frame, OpenCV convention) and returns
instance masks: one label per pixel, `-1` where no plane was found, `0..K-1` for the K plane
instances. It may also return each instance's plane in the left camera frame, `n·X + d = 0`
(`|n| = 1`, metres), oriented so that `d > 0` (the normal points toward the camera).
Implementations: `segmentation_geometric` (stereo disparity, the default for stereo input);
a learned ONNX segmenter will implement the same protocol.
"""

from __future__ import annotations

import dataclasses
from typing import Protocol, runtime_checkable

import numpy as np

from backend.geometry.camera import PinholeCamera

NO_PLANE = -1  # label of pixels that belong to no plane instance


@dataclasses.dataclass(frozen=True, eq=False)
class PlaneMasks:
    """Instance masks of one left image.

    `labels` (H, W) int16: `NO_PLANE` or an instance index `0..K-1`. `normals_camera` (K, 3)
    and `offsets_camera` (K,), metres, are the instances' planes `n·X + d = 0` in the left
    camera frame, or None where the segmenter does not estimate geometry.
    """

    labels: np.ndarray
    normals_camera: np.ndarray | None = None
    offsets_camera: np.ndarray | None = None

    def __post_init__(self) -> None:
        if self.labels.ndim != 2 or self.labels.dtype != np.int16:
            raise ValueError(f"labels must be (H, W) int16, got {self.labels.shape} {self.labels.dtype}")
        if (self.normals_camera is None) != (self.offsets_camera is None):
            raise ValueError("normals_camera and offsets_camera come together")
        if self.normals_camera is not None:
            k = self.count
            assert self.offsets_camera is not None  # checked together above
            if self.normals_camera.shape != (k, 3) or self.offsets_camera.shape != (k,):
                raise ValueError(f"expected {k} planes: normals (K, 3), offsets (K,)")

    @property
    def count(self) -> int:
        """Number of instances K (labels are 0..K-1)."""
        return int(self.labels.max(initial=NO_PLANE)) + 1

    def mask(self, instance: int) -> np.ndarray:
        """Boolean (H, W) mask of one instance."""
        return self.labels == instance

    def fractions(self) -> np.ndarray:
        """Share of the image covered by each instance, (K,)."""
        counts = np.bincount(self.labels[self.labels >= 0].ravel(), minlength=self.count)
        return counts / self.labels.size


@runtime_checkable
class PlaneSegmenter(Protocol):
    """Anything that turns a rectified stereo pair into plane instance masks."""

    def segment(self, left: np.ndarray, right: np.ndarray, camera: PinholeCamera) -> PlaneMasks:
        """`left`, `right`: rectified uint8 grey images (H, W); `camera`: the rectified left
        camera with its stereo `baseline` (metres). Returns masks of the left image."""
        ...
