"""The view that frames the map: the whole map projects inside the 3D canvas."""

from __future__ import annotations

import numpy as np
import pytest

from backend.pipeline.sim_engine import SimEngine, SimSettings
from viewer.framing import Bounds, follow_pose, framing_pose, marker_size_m, snapshot_bounds


def _project(position: np.ndarray, look_at: np.ndarray, p: np.ndarray, fov_y: float, aspect: float) -> np.ndarray:
    """Normalized device coordinates (x, y in [-1, 1] inside the view) of world points,
    for a camera at `position` looking at `look_at` with z up."""
    f = (look_at - position) / np.linalg.norm(look_at - position)
    r = np.cross(f, [0.0, 0.0, 1.0])
    r /= np.linalg.norm(r)
    u = np.cross(r, f)
    d = p - position
    z = d @ f
    assert np.all(z > 0)
    ty = np.tan(fov_y / 2)
    return np.stack([(d @ r) / z / (ty * aspect), (d @ u) / z / ty], axis=1)


@pytest.mark.parametrize("aspect", [0.65, 1.0, 1.8])
def test_the_framed_map_projects_inside_the_view(aspect: float) -> None:
    engine = SimEngine(SimSettings(sequence="a"))
    for _ in range(30):
        snap = engine.step()
    b = snapshot_bounds(snap)
    fov = np.radians(75.0)
    position, look_at = framing_pose(b, fov_y=fov, aspect=aspect)
    np.testing.assert_allclose(look_at, b.centre)
    ndc = _project(position, look_at, np.concatenate([snap.estimate.t_world_camera, snap.points.p_world]), fov, aspect)
    assert np.all(np.abs(ndc) < 1.0), np.abs(ndc).max()
    assert np.abs(ndc).max() > 0.3  # framed, not a dot in the middle


def test_bounds_ignore_a_far_outlier_and_hold_every_keyframe() -> None:
    engine = SimEngine(SimSettings(sequence="b"))
    for _ in range(10):
        snap = engine.step()
    b0 = snapshot_bounds(snap)
    p = np.asarray(snap.points.p_world).copy()
    p[0] = [500.0, 500.0, 500.0]
    import dataclasses

    far = dataclasses.replace(snap, points=dataclasses.replace(snap.points, p_world=p))
    b1 = snapshot_bounds(far)
    assert b1.radius < 2 * b0.radius
    t = snap.estimate.t_world_camera
    assert np.all(np.linalg.norm(t - b1.centre, axis=1) <= b1.radius + 1e-9)


def test_follow_keeps_the_offset_and_sizes_follow_the_extent() -> None:
    position, look_at = follow_pose(np.array([1.0, 2.0, 3.0]), np.array([0.0, 0.0, 1.0]), np.array([5.0, 5.0, 5.0]))
    np.testing.assert_allclose(position - look_at, [1.0, 2.0, 2.0])
    np.testing.assert_allclose(look_at, [5.0, 5.0, 5.0])
    small, large = Bounds(np.zeros(3), 1.5), Bounds(np.zeros(3), 10.0)
    assert marker_size_m(small) == pytest.approx(0.012)
    assert marker_size_m(large) == pytest.approx(0.08)
    assert marker_size_m(large, scale=2.0) == pytest.approx(0.16)
