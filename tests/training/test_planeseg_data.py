"""The segmenter's training data (no torch needed): random layouts with exact labels."""

from __future__ import annotations

import pathlib
import sys

import numpy as np

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parents[2] / "training"))

from planeseg_data import IGNORE, INPUT_H, INPUT_W, NON_PLANAR, OUTPUT_H, OUTPUT_W, pseudo_labelled, rendered_samples


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


def test_pseudo_labels_keep_the_large_instances_with_normals_towards_the_camera() -> None:
    """A real image labelled by a segmenter's masks: the instance covering 60 % of the image
    is kept (its normal, given facing away from the camera, turned towards it); the one
    covering 2 % and the pixels on no plane are left out of the loss (IGNORE), never taught
    as non-planar."""
    from backend.frontend.segmentation import NO_PLANE, PlaneMasks

    labels = np.full((480, 752), NO_PLANE, np.int16)
    labels[:288] = 0  # 60 %
    labels[400:, :90] = 1  # 80 x 90 pixels: 2 %
    normals = np.array([[0.0, 0.0, 1.0], [1.0, 0.0, 0.0]])  # plane 0: z = 2 (n·X + d = 0 with d = -2): n faces away
    masks = PlaneMasks(labels, normals, np.array([-2.0, 1.0]))
    image = np.full((480, 752), 100, np.uint8)
    s = pseudo_labelled(image, masks, min_share=0.03)
    assert s.image.shape == (INPUT_H, INPUT_W) and s.labels.shape == (OUTPUT_H, OUTPUT_W)
    assert set(np.unique(s.labels).tolist()) == {0, IGNORE}
    assert abs(np.mean(s.labels == 0) - 0.6) < 0.05
    n = s.normals.astype(np.float32)
    np.testing.assert_allclose(n[:, s.labels == 0].T, np.tile([0.0, 0.0, -1.0], (np.count_nonzero(s.labels == 0), 1)), atol=1e-3)
    assert np.all(n[:, s.labels == IGNORE] == 0.0)
