"""The "oracle" plane segmenter of rendered scenes: the renderer's exact plane ids.

Not a segmenter a real camera has: it is the reference against which the learned one is
judged (VIO on rendered scenes, the debugger's A/B runs), and every place that shows it
labels it so. Instances are the plane ids covering at least `min_share` of the image,
renumbered 0..K-1 by decreasing area; the rest of the image is `NO_PLANE`.
"""

from __future__ import annotations

import numpy as np

from backend.data.source import RenderedTruth
from backend.frontend.segmentation import NO_PLANE, PlaneMasks


class OracleSegmenter:
    """Ground-truth instance masks of a rendered sequence (its `left_plane_ids(i)`)."""

    name = "oracle (ground-truth masks of the rendered scene)"

    def __init__(self, source, *, min_share: float = 0.01) -> None:
        if not isinstance(source, RenderedTruth):
            raise ValueError("the oracle segmenter needs a rendered scene (its exact plane ids)")
        self.source = source
        self.min_share = float(min_share)

    def segment_frame(self, index: int) -> PlaneMasks:
        """Instance masks of frame `index`'s left image."""
        plane_id = np.asarray(self.source.left_plane_ids(index))
        ids, counts = np.unique(plane_id[plane_id >= 0], return_counts=True)
        keep = counts >= self.min_share * plane_id.size
        ids = ids[keep][np.argsort(-counts[keep], kind="stable")]
        lut = np.full(int(plane_id.max(initial=0)) + 2, NO_PLANE, np.int16)
        lut[ids] = np.arange(len(ids), dtype=np.int16)
        labels = np.where(plane_id >= 0, lut[np.clip(plane_id, 0, None)], NO_PLANE).astype(np.int16)
        return PlaneMasks(labels=labels)
