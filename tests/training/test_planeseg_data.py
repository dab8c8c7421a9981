"""The segmenter's training data (no torch needed): random layouts with exact labels."""

from __future__ import annotations

import pathlib
import sys

import numpy as np

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parents[2] / "training"))

from planeseg_data import INPUT_H, INPUT_W, NON_PLANAR, OUTPUT_H, OUTPUT_W, rendered_samples  # noqa: E402


def test_rendered_samples_are_reproducible_and_labelled() -> None:
    a = rendered_samples(7, layouts=2, views_per_layout=3)
    b = rendered_samples(7, layouts=2, views_per_layout=3)
    c = rendered_samples(8, layouts=2, views_per_layout=3)
    assert len(a) == 6
    for s, t in zip(a, b):
        assert s.image.shape == (INPUT_H, INPUT_W) and s.image.dtype == np.uint8
        assert s.labels.shape == (OUTPUT_H, OUTPUT_W)
        np.testing.assert_array_equal(s.image, t.image)
        np.testing.assert_array_equal(s.labels, t.labels)
    assert any(not np.array_equal(s.image, t.image) for s, t in zip(a, c))  # another seed, other layouts
    several = 0
    for s in a:
        ids = np.unique(s.labels)
        assert np.all((ids >= 0) | (ids == NON_PLANAR))
        assert np.count_nonzero(s.labels >= 0) > 0.5 * s.labels.size  # rooms are mostly planes
        several += len(ids[ids >= 0]) >= 2
    assert several >= len(a) // 2  # most views see more than one plane
