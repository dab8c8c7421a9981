"""The displacement layer's arithmetic (landmarks matched by id, distances in metres), its
colours, and the A/B run's colour, far from every colour the map already uses."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from backend.common.palette import NON_PLANAR, PLANE_COLORS
from backend.optim.variant import Variant
from backend.pipeline.sim_engine import SimEngine, SimSettings
from viewer import scene
from viewer.displacement import COLOR_UNMATCHED, displacement, displacement_colors, match_ids, summary_markdown
from viewer.displacement_layer import B_OPTION, comparable


def test_ids_match_whatever_their_order() -> None:
    np.testing.assert_array_equal(match_ids(np.array([5, 1, 9, 3]), np.array([3, 5, 7, 1])), [1, 3, -1, 0])
    np.testing.assert_array_equal(match_ids(np.array([1, 2]), np.array([], int)), [-1, -1])


def _snapshot():
    engine = SimEngine(SimSettings(sequence="a"))
    for _ in range(6):
        snap = engine.step()
    return snap


def test_displacements_are_the_distances_of_the_same_landmarks() -> None:
    snap = _snapshot()
    pts, lns = snap.points, snap.lines
    order = np.arange(len(pts.id))[::-1]  # the other snapshot lists them in another order, one missing
    moved_p = pts.p_world[order] + np.array([0.0, 0.03, 0.04])  # 5 cm
    other = dataclasses.replace(
        snap,
        points=dataclasses.replace(pts, id=pts.id[order][1:], p_world=moved_p[1:]),
        lines=dataclasses.replace(lns, segment_world=lns.segment_world + np.array([0.02, 0.0, 0.0])),  # 2 cm
    )
    d = displacement(snap, other)
    finite = np.isfinite(pts.p_world).all(axis=1)
    assert np.isnan(d.point_m[order[0]])  # not in the other snapshot
    matched = np.ones(len(pts.id), bool)
    matched[order[0]] = False
    np.testing.assert_allclose(d.point_m[matched & finite], 0.05, atol=1e-9)
    np.testing.assert_allclose(d.p_world_other[matched], pts.p_world[matched] + [0.0, 0.03, 0.04])
    np.testing.assert_allclose(d.line_m[np.isfinite(d.line_m)], 0.02, atol=1e-9)
    assert d.scale_m == pytest.approx(0.05)
    text = summary_markdown(d, shown="PL-w", other="P-wo")
    assert f"{matched.sum() - (~finite).sum()} of {len(pts.id)} points" in text and "median 5.00 cm" in text and "max 5.00 cm" in text
    assert "not in P-wo" in text


def test_identical_snapshots_have_no_displacement_and_one_colour() -> None:
    snap = _snapshot()
    d = displacement(snap, snap)
    assert np.nanmax(d.point_m) == 0.0 and d.scale_m > 0.0
    colors = displacement_colors(d.point_m, scale_m=d.scale_m)
    assert len(np.unique(colors[np.isfinite(d.point_m)], axis=0)) == 1


def test_colours_run_from_dark_to_bright_and_grey_marks_unmatched() -> None:
    colors = displacement_colors(np.array([0.0, 0.01, 0.02, 0.5, np.nan]), scale_m=0.02)
    brightness = colors.astype(int).sum(axis=1)
    assert brightness[0] < brightness[1] < brightness[2] == brightness[3]
    assert tuple(colors[4]) == COLOR_UNMATCHED


def test_the_menu_offers_the_other_variants_and_b() -> None:
    snap = _snapshot()
    other_variant = dataclasses.replace(snap, report=dataclasses.replace(snap.report, variant=Variant.P_WO))
    options = comparable(snap, variants={snap.variant: snap, Variant.P_WO: other_variant}, other=None)
    assert list(options) == ["P-wo"]
    options = comparable(snap, variants={snap.variant: snap}, other=other_variant)
    assert list(options) == [B_OPTION]


def _lab(rgb: np.ndarray) -> np.ndarray:
    """CIELAB (D65) of sRGB colours (..., 3) in 0-255."""
    c = np.asarray(rgb, float) / 255.0
    c = np.where(c > 0.04045, ((c + 0.055) / 1.055) ** 2.4, c / 12.92)
    xyz = c @ np.array([[0.4124, 0.3576, 0.1805], [0.2126, 0.7152, 0.0722], [0.0193, 0.1192, 0.9505]]).T / [0.95047, 1.0, 1.08883]
    f = np.where(xyz > 0.008856, np.cbrt(xyz), 7.787 * xyz + 16 / 116)
    return np.stack([116 * f[..., 1] - 16, 500 * (f[..., 0] - f[..., 1]), 200 * (f[..., 1] - f[..., 2])], axis=-1)


def test_the_ab_colour_is_far_from_every_colour_of_the_map() -> None:
    """B was magenta (200, 0, 200): 24 CIELAB units from a plane's pink (240, 50, 230) and
    close to the newest camera's red; now none of the map's colours is within 40."""
    used = np.array([*PLANE_COLORS, NON_PLANAR, scene.COLOR_KEYFRAME, scene.COLOR_WINDOW, scene.COLOR_CURRENT, scene.COLOR_ESTIMATE, scene.COLOR_INLIER, scene.COLOR_OUTLIER, scene.COLOR_GRID])
    distance = np.linalg.norm(_lab(used) - _lab(np.array(scene.COLOR_B)), axis=1)
    assert distance.min() > 40.0, distance.round()
