"""The plane segmenters by kind: the one place that builds a segmenter from its name, for
the command line, the debugger's menu and the scripts alike.

- `geometric`: plane instances from stereo disparity (the stereo default);
- `learned`: the shipped network, `assets/planeseg.onnx`, or another model file (the VIO
  default);
- `oracle`: on rendered scenes only, the renderer's exact plane ids (a reference, not a
  segmenter a real camera has).
"""

from __future__ import annotations

import enum
import pathlib

from backend.data.source import RenderedTruth
from backend.frontend.segmentation import PlaneSegmenter


class SegmenterKind(enum.StrEnum):
    GEOMETRIC = "geometric"
    LEARNED = "learned"
    ORACLE = "oracle"


class SegmenterError(ValueError):
    """A segmenter that cannot be built here (one line: why)."""


def make_segmenter(kind: SegmenterKind, *, source: object = None, model: pathlib.Path | None = None) -> PlaneSegmenter:
    """A segmenter of `kind` for `source` (the oracle reads its rendered views); `model`: the
    learned segmenter's model file (None: the shipped one). SegmenterError: a model file that
    cannot be used, a model for another kind, or the oracle without a rendered scene."""
    kind = SegmenterKind(kind)
    if model is not None and kind is not SegmenterKind.LEARNED:
        raise SegmenterError("a model file is for the learned segmenter only")
    if kind is SegmenterKind.ORACLE:
        from backend.frontend.segmentation_oracle import OracleSegmenter

        if not isinstance(source, RenderedTruth):
            raise SegmenterError("the oracle segmenter needs a rendered scene (it reads the renderer's plane ids)")
        return OracleSegmenter(source)  # type: ignore[return-value]  # segments by frame (segment_frame)
    if kind is SegmenterKind.GEOMETRIC:
        from backend.frontend.segmentation_geometric import GeometricPlaneSegmenter

        return GeometricPlaneSegmenter()
    from backend.frontend.segmentation_learned import LearnedSegmenter, LearnedSegmenterSettings, ModelError

    try:
        settings = LearnedSegmenterSettings() if model is None else LearnedSegmenterSettings(model=pathlib.Path(model))
        return LearnedSegmenter(settings=settings)
    except ModelError as e:
        raise SegmenterError(str(e)) from None


def segmenter_kind(segmenter: object) -> SegmenterKind:
    """The kind of a segmenter built here."""
    from backend.frontend.segmentation_learned import LearnedSegmenter
    from backend.frontend.segmentation_oracle import OracleSegmenter

    if isinstance(segmenter, LearnedSegmenter):
        return SegmenterKind.LEARNED
    if isinstance(segmenter, OracleSegmenter):
        return SegmenterKind.ORACLE
    return SegmenterKind.GEOMETRIC
