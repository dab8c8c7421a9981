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


def test_rendered_normals_are_unit_face_the_camera_and_follow_the_labels() -> None:
    """Every planar pixel carries its plane's unit normal in the camera frame, turned
    towards the camera (its dot product with the pixel's viewing ray is negative); one
    plane has one normal, and non-planar pixels have none."""
    from backend.data.synthetic import CAMERA

    for s in rendered_samples(7, layouts=2, views_per_layout=3):
        n = s.normals.astype(np.float64)
        assert n.shape == (3, OUTPUT_H, OUTPUT_W)
        planar = s.labels >= 0
        np.testing.assert_allclose(np.linalg.norm(n[:, planar], axis=0), 1.0, atol=2e-3)
        assert np.all(n[:, ~planar] == 0)
        scale_x, scale_y = CAMERA.width / OUTPUT_W, CAMERA.height / OUTPUT_H
        u = (np.arange(OUTPUT_W) + 0.5) * scale_x
        v = (np.arange(OUTPUT_H) + 0.5) * scale_y
        ray = np.stack([(u[None, :] - CAMERA.cx) / CAMERA.fx + 0 * v[:, None], (v[:, None] - CAMERA.cy) / CAMERA.fy + 0 * u[None, :], np.ones((OUTPUT_H, OUTPUT_W))])
        assert np.all((n * ray).sum(0)[planar] < 0)
        for pid in np.unique(s.labels[planar]):
            per_plane = n[:, s.labels == pid]
            assert np.ptp(per_plane, axis=1).max() < 2e-3
