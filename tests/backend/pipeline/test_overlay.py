"""The keyframe image: features and plane instances drawn over the left image, as JPEG."""

from __future__ import annotations

import io
import time

import numpy as np
import pytest

from backend.common.palette import NON_PLANAR, plane_color
from backend.pipeline import overlay
from backend.pipeline.overlay import (
    POINT_COLORS,
    POINT_NEW,
    POINT_OUTLIER,
    POINT_TRACKED,
    POINT_UNUSED,
    REJECTED_TINT,
    TINT_ALPHA,
    decode_keyframe_image,
    draw_keyframe_image,
)
from backend.pipeline.snapshot import KeyframeImage

H, W = 480, 752
GREY = 128
JPEG_TOL = 24  # per channel, for flat colour areas after JPEG at quality 95


def _none(**kw: object) -> dict[str, object]:
    """Empty feature arrays and no instances, overridden by `kw`."""
    args: dict[str, object] = dict(
        points_uv=np.zeros((0, 2)),
        point_status=np.zeros(0, np.uint8),
        segments_uv=np.zeros((0, 2, 2)),
        segment_plane=np.zeros(0, np.int64),
        instance_labels=None,
        instance_plane=None,
        quality=95,
    )
    args.update(kw)
    return args


def _grey(value: int = GREY) -> np.ndarray:
    return np.full((H, W), value, np.uint8)


def _rect_labels(*rects: tuple[int, int, int, int]) -> np.ndarray:
    """Labels (H, W) int16: instance i fills rows r0:r1, columns c0:c1 of rects[i]."""
    labels = np.full((H, W), -1, np.int16)
    for i, (r0, r1, c0, c1) in enumerate(rects):
        labels[r0:r1, c0:c1] = i
    return labels


def test_decodes_to_input_size_and_scaled_size() -> None:
    image = draw_keyframe_image(_grey(), **_none())
    assert isinstance(image, KeyframeImage) and isinstance(image.jpeg, bytes)
    assert image.jpeg[:2] == b"\xff\xd8"  # JPEG SOI
    rgb = decode_keyframe_image(image)
    assert (image.width, image.height) == (W, H) and rgb.shape == (H, W, 3) and rgb.dtype == np.uint8
    assert np.abs(rgb.astype(int) - GREY).max() <= 2

    half = draw_keyframe_image(_grey(), **_none(scale=0.5))
    assert (half.width, half.height) == (W // 2, H // 2)
    assert decode_keyframe_image(half).shape == (H // 2, W // 2, 3)


def test_empty_arrays_and_no_instances() -> None:
    image = np.tile(np.arange(W, dtype=np.uint8)[None, :], (H, 1))  # a ramp, not flat
    rgb = decode_keyframe_image(draw_keyframe_image(image, **_none()))
    assert np.abs(rgb.astype(int) - image[..., None].astype(int)).max() <= 6
    # Plain lists and 1-D empties are accepted as well.
    draw_keyframe_image(image, points_uv=[], point_status=[], segments_uv=[], segment_plane=[], instance_labels=None, instance_plane=None)
    # Labels without any instance, instance_plane empty.
    draw_keyframe_image(image, **_none(instance_labels=np.full((H, W), -1, np.int16), instance_plane=np.zeros(0, np.int64)))


def test_accepted_instance_is_tinted_toward_its_plane_colour() -> None:
    labels = _rect_labels((100, 300, 200, 500))
    rgb = decode_keyframe_image(draw_keyframe_image(_grey(), **_none(instance_labels=labels, instance_plane=np.array([2]))))
    inside = rgb[110:290, 210:490].reshape(-1, 3).mean(axis=0)
    target = plane_color(2).astype(float)
    assert np.linalg.norm(inside - target) < np.linalg.norm(GREY - target) - 30.0
    np.testing.assert_allclose(inside, (1 - TINT_ALPHA) * GREY + TINT_ALPHA * target, atol=6.0)
    # Outside the instance the image is untouched.
    assert np.abs(rgb[:90].astype(int) - GREY).max() <= 3
    # The contour carries the plane colour at full strength.
    contour = rgb[100, 250:450].reshape(-1, 3).mean(axis=0)
    assert np.linalg.norm(contour - target) < np.linalg.norm(inside - target)


def test_rejected_instance_is_neutral_and_hatched() -> None:
    labels = _rect_labels((100, 300, 100, 300), (100, 300, 400, 600))
    rgb = decode_keyframe_image(draw_keyframe_image(_grey(), **_none(instance_labels=labels, instance_plane=np.array([-1, 0]))))
    rejected = rgb[110:290, 110:290].astype(float)
    accepted = rgb[110:290, 410:590].astype(float)
    mean = rejected.reshape(-1, 3).mean(axis=0)
    assert np.ptp(mean) < 6.0, "rejected instances carry no plane colour"
    assert mean.mean() > GREY + 20.0, "lightened toward the grey tint"
    assert REJECTED_TINT.mean() > GREY
    # Hatching: the rejected region is striped, the accepted one flat.
    assert rejected.std(axis=(0, 1)).min() > 3.0 * accepted.std(axis=(0, 1)).max() + 2.0
    # The accepted one is tinted by plane 0, clearly distinct.
    assert np.linalg.norm(accepted.reshape(-1, 3).mean(axis=0) - plane_color(0)) < np.linalg.norm(mean - plane_color(0)) - 30.0


def test_instances_without_a_plane_entry_count_as_rejected() -> None:
    # instance_plane=None, and labels beyond its length (with a huge label value: the
    # look-up table must not grow with it).
    labels = _rect_labels((100, 300, 100, 300))
    labels[350:450, 100:300] = 30000
    for plane in (None, np.array([-1])):
        rgb = decode_keyframe_image(draw_keyframe_image(_grey(), **_none(instance_labels=labels, instance_plane=plane)))
        for region in (rgb[110:290, 110:290], rgb[360:440, 110:290]):
            mean = region.reshape(-1, 3).mean(axis=0)
            assert np.ptp(mean) < 6.0 and mean.mean() > GREY + 20.0


def test_segment_pixels_carry_their_plane_colour() -> None:
    segments = np.array([[[100.0, 200.0], [600.0, 200.0]], [[100.0, 300.0], [600.0, 300.0]]])
    rgb = decode_keyframe_image(draw_keyframe_image(_grey(), **_none(segments_uv=segments, segment_plane=np.array([1, -1])))).astype(float)
    for row, color in ((200, plane_color(1)), (300, NON_PLANAR)):
        band = rgb[row - 1 : row + 2, 150:550]  # 2 px thick, anti-aliased: the closest row
        errors = [np.linalg.norm(band[i].mean(axis=0) - color) for i in range(3)]
        assert min(errors) < 40.0, (row, errors)
    # Plane 1 is orange: red well above blue on the line, grey elsewhere.
    line = rgb[199:202, 150:550].reshape(-1, 3)
    assert (line[:, 0] - line[:, 2]).max() > 120.0
    assert np.abs(rgb[250, 150:550] - GREY).max() <= 3


def test_points_are_drawn_in_their_state_colour_at_their_position() -> None:
    uv = np.array([[50.0, 60.0], [300.0, 100.0], [400.0, 300.0], [600.0, 420.0], [700.0, 50.0]])
    status = np.array([POINT_TRACKED, POINT_TRACKED, POINT_NEW, POINT_OUTLIER, POINT_UNUSED], np.uint8)
    rgb = decode_keyframe_image(draw_keyframe_image(_grey(), **_none(points_uv=uv, point_status=status))).astype(int)
    for (u, v), s in zip(uv.astype(int), status):
        centre = rgb[v - 1 : v + 2, u - 1 : u + 2].reshape(-1, 3).mean(axis=0) if s != POINT_UNUSED else rgb[v, u]
        assert np.abs(centre - POINT_COLORS[s]).max() < 40, (s, centre)
    green = rgb[60, 50]
    assert green[1] > 180 and green[0] < 100 and green[2] < 100  # RGB order, not BGR
    red = rgb[420, 600]
    assert red[0] > 180 and red[1] < 100 and red[2] < 100
    assert np.abs(rgb[200, 200] - GREY).max() <= 3  # nothing drawn away from points


def test_jpeg_colours_read_the_same_in_another_decoder() -> None:
    pil = pytest.importorskip("PIL.Image")
    image = draw_keyframe_image(_grey(), **_none(points_uv=np.array([[100.0, 100.0]]), point_status=np.array([POINT_OUTLIER], np.uint8)))
    rgb = np.asarray(pil.open(io.BytesIO(image.jpeg)).convert("RGB")).astype(int)
    assert rgb[100, 100, 0] > 180 and rgb[100, 100, 2] < 100


def test_scale_maps_feature_positions() -> None:
    uv = np.array([[200.0, 100.0]])
    image = draw_keyframe_image(_grey(), **_none(points_uv=uv, point_status=np.array([POINT_TRACKED], np.uint8), scale=0.5))
    rgb = decode_keyframe_image(image).astype(int)
    assert np.abs(rgb[50, 100] - POINT_COLORS[POINT_TRACKED]).max() < 40
    labels = _rect_labels((100, 300, 200, 500))
    rgb = decode_keyframe_image(draw_keyframe_image(_grey(), **_none(instance_labels=labels, instance_plane=np.array([2]), scale=0.5))).astype(float)
    inside = rgb[55:145, 105:245].reshape(-1, 3).mean(axis=0)
    np.testing.assert_allclose(inside, (1 - TINT_ALPHA) * GREY + TINT_ALPHA * plane_color(2), atol=6.0)


def test_features_outside_the_image_or_not_finite_are_skipped() -> None:
    uv = np.array([[-10.0, 5.0], [W + 100.0, 20.0], [np.nan, 3.0], [1.0, 1.0], [W - 1.0, H - 1.0], [1e12, -1e12]])
    status = np.full(len(uv), POINT_NEW, np.uint8)
    segments = np.array([[[-1e9, 10.0], [1e9, 10.0]], [[np.inf, 0.0], [3.0, 4.0]]])
    image = draw_keyframe_image(_grey(), **_none(points_uv=uv, point_status=status, segments_uv=segments, segment_plane=np.array([0, 1])))
    rgb = decode_keyframe_image(image).astype(int)
    assert np.abs(rgb[H - 1, W - 1] - POINT_COLORS[POINT_NEW]).max() < 60
    assert np.linalg.norm(rgb[10, 300] - plane_color(0)) < 60


@pytest.mark.parametrize(
    "change",
    [
        dict(point_status=np.array([7], np.uint8), points_uv=np.zeros((1, 2))),
        dict(point_status=np.zeros(2, np.uint8), points_uv=np.zeros((1, 2))),
        dict(points_uv=np.zeros((1, 3)), point_status=np.zeros(1, np.uint8)),
        dict(segments_uv=np.zeros((1, 2, 3)), segment_plane=np.zeros(1, np.int64)),
        dict(segments_uv=np.zeros((2, 2, 2)), segment_plane=np.zeros(1, np.int64)),
        dict(instance_labels=np.zeros((H, W + 1), np.int16)),
        dict(instance_labels=np.zeros((H, W), np.float32)),
        dict(scale=0.0),
        dict(quality=0),
    ],
)
def test_bad_input_raises(change: dict[str, object]) -> None:
    with pytest.raises(ValueError):
        draw_keyframe_image(_grey(), **_none(**change))


def test_bad_image_raises() -> None:
    with pytest.raises(ValueError):
        draw_keyframe_image(np.zeros((H, W, 3), np.uint8), **_none())
    with pytest.raises(ValueError):
        decode_keyframe_image(KeyframeImage(jpeg=b"not a jpeg", width=1, height=1))


def test_drawing_a_busy_keyframe_is_fast() -> None:
    """752 x 480, 1000 points, 150 segments, 12 instances: a few ms (measured ≈ 4-5 ms on
    the project's 2-core machine); the bound only catches a regression by an order."""
    rng = np.random.default_rng(0)
    image = rng.integers(0, 255, (H, W), dtype=np.uint8)
    labels = np.full((H, W), -1, np.int16)
    for i in range(12):
        r, c = divmod(i, 4)
        labels[r * 160 : (r + 1) * 160 - 10, c * 188 : (c + 1) * 188 - 10] = i
    args = dict(
        points_uv=rng.uniform(0, [W, H], (1000, 2)),
        point_status=rng.integers(0, 4, 1000).astype(np.uint8),
        segments_uv=rng.uniform(0, [W, H], (150, 2, 2)),
        segment_plane=rng.integers(-1, 8, 150),
        instance_labels=labels,
        instance_plane=np.where(np.arange(12) % 3 == 2, -1, np.arange(12)),
    )
    draw_keyframe_image(image, **args)
    times = []
    for _ in range(5):
        t = time.perf_counter()
        draw_keyframe_image(image, **args)
        times.append(time.perf_counter() - t)
    assert np.median(times) < 0.1
    assert overlay.POINT_RADII[POINT_UNUSED] < overlay.POINT_RADII[POINT_TRACKED]
